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
    /// File holding the worker token (instead of --token), e.g. a mounted
    /// secret.
    #[arg(long, env = "IRLGRID_WORKER_TOKEN_FILE")]
    pub worker_token_file: Option<PathBuf>,
    /// File holding the bearer token when no worker token is given (the
    /// admin token; prefer the worker token).
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
        // The worker token (or its file), else the admin token from the
        // environment (unless a token file was given instead).
        let worker_token = self.token.clone().filter(|t| !t.trim().is_empty());
        cfg.token = if worker_token.is_some() || self.worker_token_file.is_some() {
            super::resolve_token(worker_token.as_deref(), self.worker_token_file.as_deref())?
        } else {
            let token = std::env::var("IRLGRID_TOKEN")
                .ok()
                .filter(|t| !t.is_empty() && self.token_file.is_none());
            super::resolve_token(token.as_deref(), self.token_file.as_deref())?
        };
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

#[cfg(test)]
mod tests {
    use clap::Parser;

    use super::WorkerArgs;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        args: WorkerArgs,
    }

    fn config(flags: &[&str]) -> Result<Option<String>, String> {
        let cli = Cli::try_parse_from(std::iter::once("worker").chain(flags.iter().copied()))
            .map_err(|e| e.to_string())?;
        cli.args.config().map(|c| c.token).map_err(|e| e.0)
    }

    #[test]
    fn the_worker_token_comes_from_its_flag_or_its_file() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("worker-token");
        std::fs::write(&file, "wrk-123\n").unwrap();
        let path = file.to_str().unwrap();
        assert_eq!(
            config(&["--worker-token-file", path]).unwrap().as_deref(),
            Some("wrk-123")
        );
        assert_eq!(
            config(&["--token", "direct"]).unwrap().as_deref(),
            Some("direct")
        );
        let both = config(&["--token", "direct", "--worker-token-file", path]).unwrap_err();
        assert!(both.contains("not both"), "{both}");
        // The worker token file wins over the admin token file.
        let admin = dir.path().join("admin-token");
        std::fs::write(&admin, "adm").unwrap();
        assert_eq!(
            config(&[
                "--worker-token-file",
                path,
                "--token-file",
                admin.to_str().unwrap()
            ])
            .unwrap()
            .as_deref(),
            Some("wrk-123")
        );
    }
}
