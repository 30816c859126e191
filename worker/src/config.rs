//! Worker configuration: one typed struct, filled by the CLI from flags or
//! `IRLGRID_*` environment variables; defaults in code.

use std::path::PathBuf;
use std::time::Duration;

/// How a worker process runs.
#[derive(Debug, Clone)]
pub struct WorkerConfig {
    /// Coordinator base URL, e.g. `http://127.0.0.1:8080`.
    pub coordinator: String,
    /// Bearer token for the coordinator's worker calls (the worker token, or
    /// the admin token).
    pub token: Option<String>,
    /// Jobs run in parallel (each trains on its own blocking thread).
    pub jobs: usize,
    /// Name recorded as the owner of this worker's leases.
    pub name: String,
    /// Where finished results wait until the coordinator accepts them.
    pub spool_dir: PathBuf,
    /// First retry delay after a transient failure.
    pub backoff_base: Duration,
    /// Longest retry delay.
    pub backoff_max: Duration,
    /// Seconds a lease request waits at the coordinator for a job.
    pub lease_wait_secs: u32,
    /// Longest gap between progress reports (the lease's heartbeat period
    /// applies when shorter).
    pub progress_every: Duration,
    /// Longest time from a shutdown signal to the end of [`crate::run`]:
    /// running jobs are cancelled and must stop within it (less a reserve
    /// for the release calls) or their leases are handed back anyway;
    /// finished results are uploaded until it ends, then left in the spool.
    /// Keep it below the engine's kill delay (Slurm `KillWait`, Kubernetes
    /// `terminationGracePeriodSeconds`, Docker `stop_grace_period`).
    pub shutdown_grace: Duration,
    /// Stop once the coordinator has answered "no job" for this long while
    /// no job ran here (time it was unreachable does not count).
    pub exit_when_idle: Option<Duration>,
    /// Stop after leasing this many jobs, once they have ended.
    pub max_jobs: Option<u64>,
}

impl WorkerConfig {
    /// Defaults for this coordinator: one job per core, a name from the host
    /// and process id, a spool under the cache directory.
    pub fn new(coordinator: impl Into<String>) -> Self {
        let name = default_name();
        Self {
            coordinator: coordinator.into().trim_end_matches('/').to_string(),
            token: None,
            jobs: default_jobs(),
            spool_dir: default_spool_dir(),
            name,
            backoff_base: Duration::from_millis(250),
            backoff_max: Duration::from_secs(30),
            lease_wait_secs: 5,
            progress_every: Duration::from_secs(2),
            shutdown_grace: Duration::from_secs(10),
            exit_when_idle: None,
            max_jobs: None,
        }
    }

    /// Refuses meaningless settings.
    pub fn validate(&self) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.coordinator.starts_with("http://") || self.coordinator.starts_with("https://"),
            "--coordinator must be an http:// or https:// URL, got {:?}",
            self.coordinator
        );
        anyhow::ensure!(
            (1..=1024).contains(&self.jobs),
            "--jobs must be in 1..=1024, got {}",
            self.jobs
        );
        anyhow::ensure!(
            !self.name.trim().is_empty() && self.name.chars().count() <= 150,
            "--name must be 1..=150 characters"
        );
        anyhow::ensure!(
            self.shutdown_grace >= Duration::from_secs(1),
            "--shutdown-grace must be at least 1 second"
        );
        anyhow::ensure!(self.max_jobs != Some(0), "--max-jobs must be at least 1");
        Ok(())
    }

    /// The part of the shutdown grace that running jobs get to stop; the
    /// rest is kept for handing their leases back.
    pub fn job_stop_grace(&self) -> Duration {
        let reserve = (self.shutdown_grace / 3).min(Duration::from_secs(3));
        self.shutdown_grace - reserve
    }
}

/// The number of cores (at least 1).
pub fn default_jobs() -> usize {
    std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1)
}

/// `<hostname>-<pid>`.
pub fn default_name() -> String {
    let host = std::fs::read_to_string("/etc/hostname")
        .ok()
        .map(|h| h.trim().to_string())
        .filter(|h| !h.is_empty())
        .or_else(|| std::env::var("HOSTNAME").ok())
        .unwrap_or_else(|| "worker".to_string());
    format!("{host}-{}", std::process::id())
}

/// `$XDG_CACHE_HOME/irlgrid/spool`, `~/.cache/irlgrid/spool`, or one under
/// the temporary directory.
pub fn default_spool_dir() -> PathBuf {
    if let Some(d) = std::env::var_os("XDG_CACHE_HOME").filter(|d| !d.is_empty()) {
        return PathBuf::from(d).join("irlgrid").join("spool");
    }
    if let Some(h) = std::env::var_os("HOME").filter(|h| !h.is_empty()) {
        return PathBuf::from(h)
            .join(".cache")
            .join("irlgrid")
            .join("spool");
    }
    std::env::temp_dir().join("irlgrid-spool")
}
