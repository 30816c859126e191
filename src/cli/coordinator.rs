//! `irlgrid coordinator`: runs the coordinator service until Ctrl-C or
//! SIGTERM. Also home of the tracing set-up and the shutdown signal shared
//! by the service subcommands.

use std::net::SocketAddr;
use std::path::PathBuf;

use anyhow::Context;
use coordinator::CoordinatorConfig;

#[derive(clap::Args, Debug)]
pub struct CoordinatorArgs {
    /// Listen address. A non-loopback address needs a token (or --insecure).
    #[arg(long, env = "IRLGRID_BIND", default_value = "127.0.0.1:8080")]
    pub bind: SocketAddr,
    /// SQLite database file (created and migrated if needed).
    #[arg(long, env = "IRLGRID_DB", default_value = "irlgrid.db")]
    pub db: PathBuf,
    /// Lease length in seconds; workers renew it by heartbeat.
    #[arg(long, env = "IRLGRID_LEASE_SECONDS", default_value_t = coordinator::config::DEFAULT_LEASE_SECS)]
    pub lease_seconds: u64,
    /// Admin bearer token: every /api/v1 route and the dashboard.
    #[arg(long, env = "IRLGRID_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// File holding the bearer token (instead of --token), e.g. a mounted
    /// secret.
    #[arg(long, env = "IRLGRID_TOKEN_FILE")]
    pub token_file: Option<PathBuf>,
    /// Worker bearer token: the five worker calls only (lease, heartbeat,
    /// result, fail, release).
    #[arg(long, env = "IRLGRID_WORKER_TOKEN", hide_env_values = true)]
    pub worker_token: Option<String>,
    /// File holding the worker token (instead of --worker-token), e.g. a
    /// mounted secret.
    #[arg(long, env = "IRLGRID_WORKER_TOKEN_FILE")]
    pub worker_token_file: Option<PathBuf>,
    /// Reader bearer token: the GET /api/v1 reads and the dashboard only.
    #[arg(long, env = "IRLGRID_READ_TOKEN", hide_env_values = true)]
    pub read_token: Option<String>,
    /// Serve reads and dashboard pages without a token even when tokens are
    /// set: for a trusted network only.
    #[arg(long, env = "IRLGRID_PUBLIC_READS")]
    pub public_reads: bool,
    /// Allow listening on a non-loopback address without a token.
    #[arg(long, env = "IRLGRID_INSECURE")]
    pub insecure: bool,
    /// Request body limit in bytes.
    #[arg(long, env = "IRLGRID_BODY_LIMIT", default_value_t = coordinator::config::DEFAULT_BODY_LIMIT)]
    pub body_limit: usize,
}

impl CoordinatorArgs {
    /// The coordinator configuration these flags describe.
    pub fn config(&self) -> Result<CoordinatorConfig, super::InputError> {
        let mut cfg = CoordinatorConfig::new(self.bind, &self.db);
        cfg.lease_secs = self.lease_seconds;
        cfg.token = super::resolve_token(self.token.as_deref(), self.token_file.as_deref())?;
        let set = |t: &Option<String>| t.clone().filter(|t| !t.is_empty());
        cfg.worker_token = super::resolve_token(
            self.worker_token.as_deref(),
            self.worker_token_file.as_deref(),
        )?;
        cfg.read_token = set(&self.read_token);
        cfg.public_reads = self.public_reads || deprecated_dashboard_public();
        cfg.insecure = self.insecure;
        cfg.body_limit = self.body_limit;
        Ok(cfg)
    }
}

/// The old name of `IRLGRID_PUBLIC_READS`, still accepted (with a
/// warning).
fn deprecated_dashboard_public() -> bool {
    let on = std::env::var("IRLGRID_DASHBOARD_PUBLIC").is_ok_and(|v| {
        matches!(
            v.trim().to_ascii_lowercase().as_str(),
            "1" | "true" | "yes" | "on"
        )
    });
    if on {
        tracing::warn!("IRLGRID_DASHBOARD_PUBLIC is deprecated: set IRLGRID_PUBLIC_READS=1 instead (it now opens the API reads too)");
    }
    on
}

/// Starts tracing once: fmt subscriber, `RUST_LOG` filter (default
/// `default_level`), JSON lines when `IRLGRID_LOG_JSON` is set.
pub fn init_tracing(default_level: &str) {
    use tracing_subscriber::EnvFilter;
    let filter =
        EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new(default_level));
    let json = std::env::var_os("IRLGRID_LOG_JSON").is_some_and(|v| !v.is_empty() && v != "0");
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr);
    let _ = if json {
        builder.json().try_init()
    } else {
        builder.try_init()
    };
}

/// Resolves on Ctrl-C or SIGTERM.
pub async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        _ = ctrl_c => {}
        _ = term => {}
    }
}

/// A multi-threaded runtime for the service subcommands.
pub fn runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")
}

pub fn run(args: CoordinatorArgs) -> anyhow::Result<()> {
    init_tracing("info");
    let cfg = args.config()?;
    cfg.validate()
        .map_err(|e| super::InputError(format!("{e:#}")))?;
    runtime()?.block_on(coordinator::serve(cfg, shutdown_signal()))
}
