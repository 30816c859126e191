//! The in-memory cache of running searches' result documents, and the rules
//! that keep their cost off the read path.
//!
//! A running search's document changes with every accepted output, and its
//! identifiability block (a posterior refit per held-out trial) costs far
//! more than the rest of it. So:
//! - a document is built once per change of the job counts and kept with
//!   its JSON text (a read copies bytes; it never encodes the document);
//! - when a build was expensive, readers are served the last document at
//!   once while one background task builds the next (stale while
//!   revalidating), at most once every few build times;
//! - the identifiability block is kept apart: rebuilt inline while it is
//!   cheap, and otherwise by one background build at a time across all
//!   searches, at most once every few build times. The document says when
//!   the block it carries lags the job counts.
//!
//! A completed search never uses this cache: its final document is built
//! once by the finalizer and served from the database.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use shared::analysis::{HoldOutReport, ResultDocument};
use tokio::sync::{Mutex, OwnedMutexGuard, Semaphore};

/// A build that took at least this long is rebuilt off the read path:
/// readers get the last one meanwhile.
pub const EXPENSIVE_BUILD: Duration = Duration::from_millis(100);

/// A cached build is not rebuilt before this many of its own build times
/// have passed (nor before [`MIN_REBUILD_GAP`]), so rebuilding one search
/// takes at most about a fifth of a core however fast outputs arrive.
const REBUILD_FACTOR: u32 = 5;

/// The least time between two rebuilds of an expensive entry.
const MIN_REBUILD_GAP: Duration = Duration::from_secs(1);

/// A partial result document, its JSON text and what it was built from.
pub struct PartialDoc {
    /// The job counts it saw ([`crate::store::queue::SearchRow::doc_key`]).
    pub key: String,
    /// When it was built.
    pub built: Instant,
    /// How long building it took.
    pub build_time: Duration,
    /// The document.
    pub doc: Arc<ResultDocument>,
    /// `doc` as JSON, encoded once.
    pub text: Arc<str>,
}

/// The identifiability block of a running search and what it was built
/// from.
#[derive(Clone)]
pub struct HeldOut {
    /// Finished jobs (done and failed) it saw.
    pub jobs_finished: u64,
    /// Grid points it saw (an extension changes them).
    pub points: usize,
    /// When it was built.
    pub built: Instant,
    /// How long building it took.
    pub build_time: Duration,
    /// The block (`None`: not ready, e.g. too few trials per point).
    pub report: Option<Arc<HoldOutReport>>,
}

impl HeldOut {
    /// A block just built from `jobs_finished` finished jobs over `points`
    /// grid points, in `build_time`.
    pub fn built_now(
        jobs_finished: u64,
        points: usize,
        build_time: Duration,
        report: Option<HoldOutReport>,
    ) -> Self {
        Self {
            jobs_finished,
            points,
            built: Instant::now(),
            build_time,
            report: report.map(Arc::new),
        }
    }
}

/// What a reader may do with the cached document of a search.
pub enum Lookup {
    /// It saw exactly the current job counts: serve it.
    Exact(Arc<PartialDoc>),
    /// It is behind but was expensive: serve it; `refresh` says whether a
    /// background rebuild is due.
    Stale {
        /// The document to serve.
        entry: Arc<PartialDoc>,
        /// Whether to start a rebuild now.
        refresh: bool,
    },
    /// Nothing usable: build it (readers wait for one shared build).
    Miss,
}

/// Whether an expensive build made at `built` that took `build_time` may be
/// rebuilt now.
fn due(built: Instant, build_time: Duration) -> bool {
    built.elapsed() >= (build_time * REBUILD_FACTOR).max(MIN_REBUILD_GAP)
}

/// The lookup rule: exact counts are served; a cheap document is rebuilt
/// at every change (small searches read their own writes); an expensive
/// one is served stale while it is rebuilt in the background. Only the
/// finished-job counts may lag that way: a document for another status,
/// job total or number of points (an extension, a completion) is never
/// served.
pub fn lookup(entry: Option<&Arc<PartialDoc>>, key: &str) -> Lookup {
    match entry {
        Some(e) if e.key == key => Lookup::Exact(e.clone()),
        Some(e) if same_shape(&e.key, key) && e.build_time >= EXPENSIVE_BUILD => Lookup::Stale {
            entry: e.clone(),
            refresh: due(e.built, e.build_time),
        },
        _ => Lookup::Miss,
    }
}

/// Whether two document keys (`status:done:failed:total:points`) agree on
/// status, job total and points.
fn same_shape(a: &str, b: &str) -> bool {
    let parts = |k: &str| {
        let v: Vec<String> = k.split(':').map(str::to_string).collect();
        (v.first().cloned(), v.get(3).cloned(), v.get(4).cloned())
    };
    parts(a) == parts(b)
}

/// How a document build gets the identifiability block of a running search.
pub enum HeldOutPlan {
    /// Build it inline with the document (none yet for this grid, or the
    /// last one was cheap and is out of date).
    Inline,
    /// Use this one as it is; `refresh` says whether to start a background
    /// build of the next.
    Cached {
        /// The block to use.
        held: HeldOut,
        /// Whether to start a background build now.
        refresh: bool,
    },
}

/// The identifiability rule: a block for the current counts is used; an
/// out-of-date cheap one is rebuilt inline; an expensive one is used as it
/// is while the next is built in the background.
pub fn plan_held_out(held: Option<&HeldOut>, jobs_finished: u64, points: usize) -> HeldOutPlan {
    match held {
        Some(h) if h.points == points && h.jobs_finished == jobs_finished => HeldOutPlan::Cached {
            held: h.clone(),
            refresh: false,
        },
        Some(h) if h.points == points && h.build_time >= EXPENSIVE_BUILD => HeldOutPlan::Cached {
            held: h.clone(),
            refresh: due(h.built, h.build_time),
        },
        _ => HeldOutPlan::Inline,
    }
}

/// The cache: documents and identifiability blocks by search id, the build
/// locks, and the one permit of background identifiability builds.
pub struct DocCache {
    docs: Mutex<HashMap<String, Arc<PartialDoc>>>,
    builds: Mutex<HashMap<String, Arc<Mutex<()>>>>,
    held_out: std::sync::Mutex<HashMap<String, HeldOut>>,
    /// Searches with a background identifiability build queued or running.
    refreshing: std::sync::Mutex<std::collections::HashSet<String>>,
    /// One background identifiability build at a time, across all
    /// searches: however many searches run, these builds take at most one
    /// core.
    pub held_out_permit: Semaphore,
}

impl Default for DocCache {
    fn default() -> Self {
        Self {
            docs: Mutex::default(),
            builds: Mutex::default(),
            held_out: std::sync::Mutex::default(),
            refreshing: std::sync::Mutex::default(),
            held_out_permit: Semaphore::new(1),
        }
    }
}

fn lock<T>(m: &std::sync::Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl DocCache {
    /// The lookup of search `id`'s document for job counts `key`.
    pub async fn lookup(&self, id: &str, key: &str) -> Lookup {
        lookup(self.docs.lock().await.get(id), key)
    }

    /// Keeps a built document.
    pub async fn put(&self, id: &str, entry: PartialDoc) -> Arc<PartialDoc> {
        let entry = Arc::new(entry);
        self.docs.lock().await.insert(id.to_string(), entry.clone());
        entry
    }

    /// The build lock of search `id`, waited for.
    pub async fn build_lock(&self, id: &str) -> OwnedMutexGuard<()> {
        self.lock_of(id).await.lock_owned().await
    }

    /// The build lock of search `id` if no build holds it.
    pub async fn try_build_lock(&self, id: &str) -> Option<OwnedMutexGuard<()>> {
        self.lock_of(id).await.try_lock_owned().ok()
    }

    async fn lock_of(&self, id: &str) -> Arc<Mutex<()>> {
        self.builds
            .lock()
            .await
            .entry(id.to_string())
            .or_default()
            .clone()
    }

    /// The identifiability plan of search `id` for these counts.
    pub fn plan_held_out(&self, id: &str, jobs_finished: u64, points: usize) -> HeldOutPlan {
        plan_held_out(lock(&self.held_out).get(id), jobs_finished, points)
    }

    /// Keeps a built identifiability block (unless a newer one is there).
    pub fn put_held_out(&self, id: &str, held: HeldOut) {
        let mut map = lock(&self.held_out);
        let newer = map
            .get(id)
            .is_some_and(|h| h.points == held.points && h.jobs_finished > held.jobs_finished);
        if !newer {
            map.insert(id.to_string(), held);
        }
    }

    /// Marks a background identifiability build of `id` as started; false
    /// when one is already queued or running.
    pub fn start_refresh(&self, id: &str) -> bool {
        lock(&self.refreshing).insert(id.to_string())
    }

    /// Marks it finished; false when the search was forgotten meanwhile
    /// (completed or extended), whose block must then not be kept.
    pub fn end_refresh(&self, id: &str) -> bool {
        lock(&self.refreshing).remove(id)
    }

    /// Drops the cached document of `id` (its stored data changed).
    pub async fn forget_doc(&self, id: &str) {
        self.docs.lock().await.remove(id);
    }

    /// Drops everything cached about `id` (it completed, or its grid was
    /// extended).
    pub async fn forget(&self, id: &str) {
        self.docs.lock().await.remove(id);
        self.builds.lock().await.remove(id);
        lock(&self.held_out).remove(id);
        lock(&self.refreshing).remove(id);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entry(key: &str, age: Duration, build_time: Duration) -> Arc<PartialDoc> {
        let doc = shared::analysis::build_report(&[], &[], &Default::default());
        Arc::new(PartialDoc {
            key: key.to_string(),
            built: Instant::now() - age,
            build_time,
            text: serde_json::to_string(&doc).unwrap().into(),
            doc: Arc::new(doc),
        })
    }

    fn kind(l: Lookup) -> &'static str {
        match l {
            Lookup::Exact(_) => "exact",
            Lookup::Stale { refresh: true, .. } => "stale, refresh",
            Lookup::Stale { refresh: false, .. } => "stale",
            Lookup::Miss => "miss",
        }
    }

    #[test]
    fn cheap_documents_follow_every_change_and_expensive_ones_are_served_while_rebuilt() {
        let ms = Duration::from_millis;
        let at = |age, build, key| kind(lookup(Some(&entry("running:1:0:4:2", age, build)), key));
        // Same counts: always served.
        assert_eq!(at(ms(60_000), ms(5), "running:1:0:4:2"), "exact");
        // Cheap build, counts changed: built again (the reader waits).
        assert_eq!(at(ms(0), ms(5), "running:2:0:4:2"), "miss");
        // Expensive build (300 ms): served as it is, rebuilt in the
        // background once 1.5 s old.
        assert_eq!(at(ms(1_000), ms(300), "running:2:0:4:2"), "stale");
        assert_eq!(at(ms(1_600), ms(300), "running:2:0:4:2"), "stale, refresh");
        // Just expensive (100 ms): the 1 s floor.
        assert_eq!(at(ms(900), ms(100), "running:2:0:4:2"), "stale");
        assert_eq!(at(ms(1_100), ms(100), "running:2:0:4:2"), "stale, refresh");
        // An extension (more jobs, more points) or a new status: never
        // served, however expensive.
        for changed in ["running:1:0:6:2", "running:1:0:6:3", "completed:1:0:4:2"] {
            assert_eq!(at(ms(0), ms(300), changed), "miss");
        }
        assert_eq!(kind(lookup(None, "running:1:0:4:2")), "miss");
    }

    fn held(finished: u64, points: usize, age: Duration, build: Duration) -> HeldOut {
        HeldOut {
            jobs_finished: finished,
            points,
            built: Instant::now() - age,
            build_time: build,
            report: None,
        }
    }

    fn plan(h: Option<HeldOut>, finished: u64, points: usize) -> &'static str {
        match plan_held_out(h.as_ref(), finished, points) {
            HeldOutPlan::Inline => "inline",
            HeldOutPlan::Cached { refresh: true, .. } => "cached, refresh",
            HeldOutPlan::Cached { refresh: false, .. } => "cached",
        }
    }

    #[test]
    fn identifiability_is_inline_while_cheap_and_in_the_background_once_expensive() {
        let ms = Duration::from_millis;
        assert_eq!(plan(None, 10, 4), "inline");
        // Current: used, whatever it cost.
        assert_eq!(plan(Some(held(10, 4, ms(0), ms(5))), 10, 4), "cached");
        assert_eq!(plan(Some(held(10, 4, ms(0), ms(900))), 10, 4), "cached");
        // Out of date and cheap: inline.
        assert_eq!(plan(Some(held(9, 4, ms(0), ms(5))), 10, 4), "inline");
        // Out of date and expensive (2 s): used, rebuilt once 10 s old.
        assert_eq!(
            plan(Some(held(9, 4, ms(9_000), ms(2_000))), 10, 4),
            "cached"
        );
        assert_eq!(
            plan(Some(held(9, 4, ms(10_500), ms(2_000))), 10, 4),
            "cached, refresh"
        );
        // Another grid (an extension): inline, however expensive.
        assert_eq!(plan(Some(held(9, 4, ms(0), ms(2_000))), 10, 5), "inline");
    }

    #[test]
    fn an_older_block_never_replaces_a_newer_one() {
        let c = DocCache::default();
        let ms = Duration::from_millis;
        c.put_held_out("s", held(20, 4, ms(0), ms(1)));
        c.put_held_out("s", held(12, 4, ms(0), ms(1)));
        assert!(matches!(
            c.plan_held_out("s", 20, 4),
            HeldOutPlan::Cached { refresh: false, .. }
        ));
        // After an extension, the new grid's block replaces it.
        c.put_held_out("s", held(3, 5, ms(0), ms(1)));
        assert!(matches!(
            c.plan_held_out("s", 3, 5),
            HeldOutPlan::Cached { refresh: false, .. }
        ));
    }
}
