//! State shared by every handler and background task: the database, the
//! configuration, metrics, the lease waiters' wake-up, and the in-memory
//! caches (search facts, partial result documents, the lease cycle's hot
//! cache). Below the router: routes, the dashboard, results and metrics
//! depend on it, never the other way round.

use std::collections::{HashMap, HashSet};
use std::sync::atomic::{AtomicI64, AtomicU64, Ordering};
use std::sync::Arc;

use tokio::sync::{mpsc, Notify, RwLock};

use crate::config::CoordinatorConfig;
use crate::domain::doc_cache::DocCache;
use crate::metrics::Metrics;
use crate::store::queue::{self, Effects, SearchInfo};
use crate::store::{Db, StoreError};

/// State shared by all handlers.
#[derive(Clone)]
pub struct AppState {
    /// Database pools.
    pub db: Db,
    /// Configuration.
    pub cfg: Arc<CoordinatorConfig>,
    /// Counters and histograms.
    pub metrics: Arc<Metrics>,
    /// Woken whenever jobs become queued (long-polling lease requests wait
    /// on it).
    pub notify: Arc<Notify>,
    searches: Arc<RwLock<HashMap<String, Arc<SearchInfo>>>>,
    /// Bumped by every [`AppState::forget_search`]: a load that started
    /// before it (and may have read the old rows) is not cached.
    searches_epoch: Arc<AtomicU64>,
    /// Running searches' documents and identifiability blocks, and their
    /// build locks.
    pub docs: Arc<DocCache>,
    /// Hot-path caches that save database round trips per lease cycle.
    pub hot: Arc<HotCache>,
    /// Ids of searches that just completed, for the finalizer task
    /// (`results::spawn_finalizer`). A channel rather than a task per
    /// completion: the request that completed a search answers at once, and
    /// final documents are built one at a time.
    completed: mpsc::UnboundedSender<String>,
    completed_rx: Arc<std::sync::Mutex<Option<mpsc::UnboundedReceiver<String>>>>,
}

/// Small in-memory caches of the lease cycle (all rebuilt from the database
/// after a restart).
#[derive(Default)]
pub struct HotCache {
    /// Unix ms of the last expiry sweep done by a lease request.
    pub last_sweep_ms: AtomicI64,
    /// Searches whose `started_at` is known to be set.
    pub started: std::sync::Mutex<HashSet<String>>,
    /// Search of each job leased by this process (saves a lookup per upload).
    pub job_search: std::sync::Mutex<HashMap<i64, (String, u32)>>,
}

/// Lease requests sweep expired leases at most this often (the sweeper task
/// also runs every `sweep_interval`).
pub const CLAIM_SWEEP_MS: i64 = 250;

impl AppState {
    /// State over an open database.
    pub fn new(db: Db, cfg: CoordinatorConfig) -> Self {
        let (completed, rx) = mpsc::unbounded_channel();
        Self {
            db,
            cfg: Arc::new(cfg),
            metrics: Arc::new(Metrics::default()),
            notify: Arc::new(Notify::new()),
            searches: Arc::default(),
            searches_epoch: Arc::default(),
            docs: Arc::default(),
            hot: Arc::default(),
            completed,
            completed_rx: Arc::new(std::sync::Mutex::new(Some(rx))),
        }
    }

    /// Lease length in milliseconds.
    pub fn lease_ms(&self) -> i64 {
        self.cfg.lease_secs as i64 * 1000
    }

    /// The immutable facts of a search (cached), or 404.
    pub async fn search_info(&self, id: &str) -> Result<Arc<SearchInfo>, StoreError> {
        if let Some(info) = self.searches.read().await.get(id) {
            return Ok(info.clone());
        }
        let epoch = self.searches_epoch.load(Ordering::SeqCst);
        let info = queue::search_info(&self.db, id)
            .await?
            .ok_or_else(|| StoreError::NotFound(format!("no search with id {id}")))?;
        let info = Arc::new(info);
        let mut cache = self.searches.write().await;
        // A search forgotten while this load ran (an extension committed)
        // may have been read before the change: serve it, do not cache it.
        if self.searches_epoch.load(Ordering::SeqCst) == epoch {
            cache.insert(id.to_string(), info.clone());
        }
        Ok(info)
    }

    /// A number that changes whenever [`AppState::forget_search`] runs. A
    /// rendering of a search's data stamped with it (read before the data)
    /// is stale once it differs.
    pub fn facts_epoch(&self) -> u64 {
        self.searches_epoch.load(Ordering::SeqCst)
    }

    /// Drops what is cached about a search whose stored data changed: its
    /// info and its partial document. Call it after the change committed.
    pub async fn forget_search(&self, id: &str) {
        {
            let mut cache = self.searches.write().await;
            self.searches_epoch.fetch_add(1, Ordering::SeqCst);
            cache.remove(id);
        }
        self.docs.forget_doc(id).await;
    }

    /// After an extension committed: drops what is cached about the search
    /// (its points changed), and wakes workers waiting for jobs.
    pub async fn search_extended(&self, id: &str) {
        self.forget_search(id).await;
        self.docs.forget(id).await;
        self.notify.notify_waiters();
    }

    /// Hands the receiving end of the completed-search channel to the one
    /// finalizer task; `None` once taken.
    pub fn take_completed(&self) -> Option<mpsc::UnboundedReceiver<String>> {
        self.completed_rx
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .take()
    }

    /// Sends a completed search to the finalizer.
    pub fn search_completed(&self, id: String) {
        // Fails only when no finalizer runs (a state built for a test
        // without one); the document is then built at its first read.
        let _ = self.completed.send(id);
    }

    /// Acts on a state change's side effects: metrics, waking lease
    /// waiters, handing completed searches to the finalizer.
    pub fn apply(&self, eff: Effects) {
        if eff.expired > 0 {
            self.metrics
                .leases_expired
                .fetch_add(eff.expired, Ordering::Relaxed);
            tracing::info!(expired = eff.expired, "expired leases swept");
        }
        if eff.requeued > 0 {
            self.notify.notify_waiters();
        }
        for id in eff.completed {
            self.search_completed(id);
        }
    }
}
