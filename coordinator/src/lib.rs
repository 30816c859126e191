//! irlgrid coordinator: enumerates (reward point, trial) jobs of
//! submitted searches into SQLite, leases them to workers, accepts their
//! results and serves the aggregated result documents over a REST API.
//!
//! [`start`] opens and migrates the database, binds, and spawns the server
//! and the lease sweeper; [`serve`] runs one until a shutdown signal.

#![recursion_limit = "256"]

pub mod api_reference;
pub mod auth;
pub mod config;
pub mod dashboard;
pub mod domain;
pub mod error;
pub mod extract;
pub mod faults;
pub mod intake;
pub mod metrics;
pub mod openapi;
pub mod routes;
pub mod state;
pub mod store;

use std::future::Future;
use std::net::SocketAddr;

use anyhow::Context;
use tokio::sync::watch;
use tokio::task::JoinHandle;

pub use config::CoordinatorConfig;
pub use state::AppState;

/// A coordinator running in this process.
pub struct Running {
    /// The bound address (the real port when the config asked for `:0`).
    pub addr: SocketAddr,
    /// Shared state (database pools, metrics).
    pub state: AppState,
    stop: watch::Sender<bool>,
    server: JoinHandle<std::io::Result<()>>,
    sweeper: JoinHandle<()>,
    finalizer: JoinHandle<()>,
}

impl Running {
    /// The base URL, e.g. `http://127.0.0.1:8080`.
    pub fn url(&self) -> String {
        format!("http://{}", self.addr)
    }

    /// Stops accepting requests, lets in-flight ones finish, closes the
    /// database.
    pub async fn shutdown(self) -> anyhow::Result<()> {
        let _ = self.stop.send(true);
        self.sweeper.abort();
        self.finalizer.abort();
        let r = self.server.await.context("server task")?;
        self.state.db.close().await;
        r.context("server")
    }
}

/// Opens the database (migrating it), binds the listener and spawns the
/// server and the expired-lease sweeper.
pub async fn start(cfg: CoordinatorConfig) -> anyhow::Result<Running> {
    cfg.validate()?;
    let db = store::Db::open(&cfg.db).await?;
    let listener = tokio::net::TcpListener::bind(cfg.bind)
        .await
        .with_context(|| format!("binding {}", cfg.bind))?;
    let addr = listener.local_addr().context("local address")?;
    let sweep_every = cfg.sweep_interval;
    let state = AppState::new(db, cfg);
    let finalizer = domain::results::spawn_finalizer(&state);
    let (stop, mut stopped) = watch::channel(false);
    let app = routes::router(state.clone());
    let mut stopped2 = stopped.clone();
    let server = tokio::spawn(async move {
        axum::serve(listener, app)
            .with_graceful_shutdown(async move {
                let _ = stopped2.wait_for(|s| *s).await;
            })
            .await
    });
    let st = state.clone();
    let sweeper = tokio::spawn(async move {
        let mut tick = tokio::time::interval(sweep_every);
        loop {
            tokio::select! {
                _ = tick.tick() => {}
                _ = stopped.wait_for(|s| *s) => break,
            }
            match store::queue::sweep_expired(&st.db, store::now_ms()).await {
                Ok(eff) => st.apply(eff),
                Err(e) => tracing::warn!(error = format!("{e:#}"), "lease sweep failed"),
            }
        }
    });
    // A coordinator killed between completing a search and caching its
    // document finishes the job now.
    for id in store::reads::unfinalized(&state.db).await? {
        state.search_completed(id);
    }
    tracing::info!(%addr, db = %state.cfg.db.display(), lease_secs = state.cfg.lease_secs,
        auth = state.cfg.has_token(), "coordinator listening");
    if state.cfg.public_reads && state.cfg.has_token() {
        tracing::warn!(
            "IRLGRID_PUBLIC_READS is set: anyone who can reach this port reads every \
             search, job and subject path without a token; use it on a trusted network only"
        );
    }
    Ok(Running {
        addr,
        state,
        stop,
        server,
        sweeper,
        finalizer,
    })
}

/// Runs a coordinator until `shutdown` resolves.
pub async fn serve(
    cfg: CoordinatorConfig,
    shutdown: impl Future<Output = ()>,
) -> anyhow::Result<()> {
    let running = start(cfg).await?;
    shutdown.await;
    tracing::info!("coordinator shutting down");
    running.shutdown().await
}
