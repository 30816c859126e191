//! `irlgrid worker`: leases jobs from a coordinator and runs them until
//! Ctrl-C or SIGTERM, then releases unfinished leases and exits.

use std::path::PathBuf;

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
    /// Directory where finished results wait until accepted.
    #[arg(long, env = "IRLGRID_SPOOL")]
    pub spool_dir: Option<PathBuf>,
}

impl WorkerArgs {
    /// The worker configuration these flags describe.
    pub fn config(&self) -> WorkerConfig {
        let mut cfg = WorkerConfig::new(&self.coordinator);
        if let Some(j) = self.jobs {
            cfg.jobs = j;
        }
        if let Some(n) = &self.name {
            cfg.name = n.clone();
        }
        cfg.token = self.token.clone().filter(|t| !t.is_empty()).or_else(|| {
            std::env::var("IRLGRID_TOKEN")
                .ok()
                .filter(|t| !t.is_empty())
        });
        if let Some(d) = &self.spool_dir {
            cfg.spool_dir = d.clone();
        }
        cfg
    }
}

pub fn run(args: WorkerArgs) -> anyhow::Result<()> {
    init_tracing("info");
    let cfg = args.config();
    cfg.validate()
        .map_err(|e| super::InputError(format!("{e:#}")))?;
    runtime()?.block_on(async move {
        let (stop, stopped) = watch::channel(false);
        tokio::spawn(async move {
            shutdown_signal().await;
            tracing::info!("shutdown requested: no new jobs; releasing unfinished leases");
            let _ = stop.send(true);
        });
        worker::run(cfg, stopped).await.map(|_| ())
    })
}
