//! `irlgrid worker`: leases jobs from a coordinator and runs them until
//! Ctrl-C or SIGTERM (running jobs are handed back to the queue without
//! using an attempt), until the queue stays empty for `--exit-when-idle`, or
//! after `--max-jobs` jobs; then exits 0.

use std::path::PathBuf;
use std::time::Duration;

use tokio::sync::watch;
use worker::WorkerConfig;

use super::coordinator::{init_tracing, runtime, shutdown_signal};

#[derive(clap::Args, Debug)]
pub struct WorkerArgs {
    /// Coordinator base URL.
    #[arg(
        long,
        env = "IRLGRID_COORDINATOR",
        default_value = "http://127.0.0.1:8080"
    )]
    pub coordinator: String,
    /// Jobs run in parallel (default: the number of cores).
    #[arg(long, env = "IRLGRID_JOBS")]
    pub jobs: Option<usize>,
    /// Name recorded as the owner of this worker's leases (default:
    /// host-pid).
    #[arg(long, env = "IRLGRID_NAME")]
    pub name: Option<String>,
    /// Bearer token of the coordinator: the worker token; without one,
    /// `IRLGRID_TOKEN` (the admin token) is used.
    #[arg(long, env = "IRLGRID_WORKER_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// File holding the bearer token (instead of --token), e.g. a mounted
    /// secret.
    #[arg(long, env = "IRLGRID_TOKEN_FILE")]
    pub token_file: Option<PathBuf>,
    /// Directory where finished results wait until accepted.
    #[arg(long, env = "IRLGRID_SPOOL")]
    pub spool_dir: Option<PathBuf>,
    /// Exit 0 once the coordinator has had no job for this many seconds
    /// while none ran here (for batch schedulers: the allocation ends when
    /// the grid is done).
    #[arg(long, env = "IRLGRID_EXIT_WHEN_IDLE", value_name = "SECS")]
    pub exit_when_idle: Option<u64>,
    /// Exit 0 after this many jobs have ended.
    #[arg(long, env = "IRLGRID_MAX_JOBS", value_name = "N")]
    pub max_jobs: Option<u64>,
    /// Seconds from SIGTERM to exit: running jobs are cancelled and handed
    /// back within it. Keep it below the engine's kill delay (Slurm
    /// KillWait, Kubernetes terminationGracePeriodSeconds, Docker
    /// stop_grace_period).
    #[arg(
        long,
        env = "IRLGRID_SHUTDOWN_GRACE",
        value_name = "SECS",
        default_value_t = 10
    )]
    pub shutdown_grace: u64,
}

impl WorkerArgs {
    /// The worker configuration these flags describe.
    pub fn config(&self) -> Result<WorkerConfig, super::InputError> {
        let mut cfg = WorkerConfig::new(&self.coordinator);
        if let Some(j) = self.jobs {
            cfg.jobs = j;
        }
        if let Some(n) = &self.name {
            cfg.name = n.clone();
        }
        // The worker token, else the admin token from the environment
        // (unless a token file was given instead).
        let token = self.token.clone().filter(|t| !t.is_empty()).or_else(|| {
            if self.token_file.is_some() {
                return None;
            }
            std::env::var("IRLGRID_TOKEN")
                .ok()
                .filter(|t| !t.is_empty())
        });
        cfg.token = super::resolve_token(token.as_deref(), self.token_file.as_deref())?;
        if let Some(d) = &self.spool_dir {
            cfg.spool_dir = d.clone();
        }
        cfg.exit_when_idle = self.exit_when_idle.map(Duration::from_secs);
        cfg.max_jobs = self.max_jobs;
        cfg.shutdown_grace = Duration::from_secs(self.shutdown_grace);
        Ok(cfg)
    }
}

pub fn run(args: WorkerArgs) -> anyhow::Result<()> {
    init_tracing("info");
    let cfg = args.config()?;
    cfg.validate()
        .map_err(|e| super::InputError(format!("{e:#}")))?;
    let rt = runtime()?;
    let result = rt.block_on(async move {
        let (stop, stopped) = watch::channel(false);
        tokio::spawn(async move {
            shutdown_signal().await;
            tracing::info!("shutdown requested");
            let _ = stop.send(true);
        });
        worker::run(cfg, stopped).await.map(|_| ())
    });
    // A job body that did not stop within the grace still holds a blocking
    // thread; its lease is already handed back, so do not wait for it.
    rt.shutdown_background();
    result
}
