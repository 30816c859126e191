//! The HTTP surface: shared state, the router, bearer-token auth, and the
//! JSON/path extractors whose rejections answer `{"error": "..."}`.

mod jobs;
mod ops;
mod searches;

use std::collections::HashMap;
use std::sync::Arc;
use std::time::Duration;

use axum::extract::{DefaultBodyLimit, FromRequest, FromRequestParts, MatchedPath, Request, State};
use axum::http::header;
use axum::middleware::{from_fn_with_state, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::Router;
use shared::analysis::ResultDocument;
use tokio::sync::{Mutex, Notify, RwLock};
use tower_http::trace::TraceLayer;

use crate::auth::{access_of, Access, Refusal, Tokens};
use crate::config::CoordinatorConfig;
use crate::dashboard::auth::has_session;
use crate::db::Db;
use crate::error::ApiError;
use crate::metrics::Metrics;
use crate::queue::{self, Effects, SearchInfo};

pub use crate::auth::ROUTES;

/// A partial result document and what it was built from.
pub struct PartialDoc {
    /// The job counts it saw.
    pub key: String,
    /// When it was built.
    pub built: std::time::Instant,
    /// How long building it took.
    pub build_time: std::time::Duration,
    /// The document.
    pub doc: Arc<ResultDocument>,
}

/// Partial result documents by search id.
pub type PartialDocs = HashMap<String, PartialDoc>;

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
    /// Partial documents by search id, keyed by the job counts they saw.
    pub partial_docs: Arc<Mutex<PartialDocs>>,
    /// One build lock per running search: concurrent readers of a partial
    /// document wait for the build in progress instead of each loading
    /// every output again.
    pub partial_builds: Arc<Mutex<HashMap<String, Arc<Mutex<()>>>>>,
    /// Hot-path caches that save database round trips per lease cycle.
    pub hot: Arc<HotCache>,
}

/// Small in-memory caches of the lease cycle (all rebuilt from the database
/// after a restart).
#[derive(Default)]
pub struct HotCache {
    /// Unix ms of the last expiry sweep done by a lease request.
    pub last_sweep_ms: std::sync::atomic::AtomicI64,
    /// Searches whose `started_at` is known to be set.
    pub started: std::sync::Mutex<std::collections::HashSet<String>>,
    /// Search of each job leased by this process (saves a lookup per upload).
    pub job_search: std::sync::Mutex<HashMap<i64, String>>,
}

/// Lease requests sweep expired leases at most this often (the sweeper task
/// also runs every `sweep_interval`).
pub const CLAIM_SWEEP_MS: i64 = 250;

impl AppState {
    /// State over an open database.
    pub fn new(db: Db, cfg: CoordinatorConfig) -> Self {
        Self {
            db,
            cfg: Arc::new(cfg),
            metrics: Arc::new(Metrics::default()),
            notify: Arc::new(Notify::new()),
            searches: Arc::default(),
            partial_docs: Arc::default(),
            partial_builds: Arc::default(),
            hot: Arc::default(),
        }
    }

    /// Lease length in milliseconds.
    pub fn lease_ms(&self) -> i64 {
        self.cfg.lease_secs as i64 * 1000
    }

    /// The immutable facts of a search (cached), or 404.
    pub async fn search_info(&self, id: &str) -> Result<Arc<SearchInfo>, ApiError> {
        if let Some(info) = self.searches.read().await.get(id) {
            return Ok(info.clone());
        }
        let info = queue::search_info(&self.db, id)
            .await?
            .ok_or_else(|| ApiError::NotFound(format!("no search with id {id}")))?;
        let info = Arc::new(info);
        self.searches
            .write()
            .await
            .insert(id.to_string(), info.clone());
        Ok(info)
    }

    /// Drops what is cached about a search whose stored data changed: its
    /// info and its partial document.
    pub async fn forget_search(&self, id: &str) {
        self.searches.write().await.remove(id);
        self.partial_docs.lock().await.remove(id);
    }

    /// Acts on a state change's side effects: metrics, waking lease
    /// waiters, finalizing completed searches.
    pub fn apply(&self, eff: Effects) {
        if eff.expired > 0 {
            self.metrics
                .leases_expired
                .fetch_add(eff.expired, std::sync::atomic::Ordering::Relaxed);
            tracing::info!(expired = eff.expired, "expired leases swept");
        }
        if eff.requeued > 0 {
            self.notify.notify_waiters();
        }
        for id in eff.completed {
            tokio::spawn(crate::results::finalize(self.clone(), id));
        }
    }
}

/// JSON body extractor whose rejection is an [`ApiError`] naming the field.
#[derive(FromRequest)]
#[from_request(via(axum::Json), rejection(ApiError))]
pub struct ApiJson<T>(pub T);

/// Path extractor whose rejection is an [`ApiError`].
#[derive(FromRequestParts)]
#[from_request(via(axum::extract::Path), rejection(ApiError))]
pub struct ApiPath<T>(pub T);

/// Lets a request through when its bearer token's role covers its route
/// (see [`crate::auth`]), or, for a read, when it carries a dashboard
/// session; a route missing from [`ROUTES`] is refused.
async fn require_token(
    State(state): State<AppState>,
    matched: Option<MatchedPath>,
    req: Request,
    next: Next,
) -> Result<Response, ApiError> {
    let tokens = Tokens::of(&state.cfg);
    let path = matched.as_ref().map(MatchedPath::as_str).unwrap_or("");
    let Some(access) = access_of(req.method().as_str(), path) else {
        return Err(ApiError::Internal(anyhow::anyhow!(
            "route {} {path} has no entry in the access table",
            req.method()
        )));
    };
    let given = req
        .headers()
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.strip_prefix("Bearer "));
    let mut verdict = tokens.check(access, given);
    // The dashboard's links to the JSON and CSV reads: a browser logged in
    // with the admin or reader token sends its session cookie, not a
    // bearer token. Reads only; the cookie is SameSite=Strict.
    if verdict == Err(Refusal::Unauthorized)
        && given.is_none()
        && access == Access::Read
        && tokens
            .dashboard_tokens()
            .iter()
            .any(|t| has_session(req.headers(), t))
    {
        verdict = Ok(());
    }
    match verdict {
        Ok(()) => Ok(next.run(req).await),
        Err(Refusal::Unauthorized) => Err(ApiError::Unauthorized),
        Err(Refusal::Forbidden) => Err(ApiError::Forbidden),
    }
}

/// Answers 413 at once when the declared `Content-Length` is over the body
/// limit, before anything reads the body: without it a client could
/// announce gigabytes, send nothing and hold the connection until the
/// request timeout (the body limit alone only trips while reading).
async fn refuse_oversized(State(state): State<AppState>, req: Request, next: Next) -> Response {
    let declared = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().parse::<u64>().ok());
    match declared {
        Some(len) if len > state.cfg.body_limit as u64 => {
            let mut resp = ApiError::PayloadTooLarge(format!(
                "request body too large: {len} bytes declared, the limit is {} bytes",
                state.cfg.body_limit
            ))
            .into_response();
            // The body is left unread: do not keep the connection.
            resp.headers_mut().insert(
                header::CONNECTION,
                header::HeaderValue::from_static("close"),
            );
            resp
        }
        _ => next.run(req).await,
    }
}

/// The application router.
pub fn router(state: AppState) -> Router {
    let api = Router::new()
        .route("/api/v1/openapi.json", get(ops::openapi))
        .route(
            "/api/v1/searches",
            get(searches::list).post(searches::create),
        )
        .route("/api/v1/searches/{id}", get(searches::status))
        .route("/api/v1/searches/{id}/cancel", post(searches::cancel))
        .route("/api/v1/searches/{id}/results", get(searches::results))
        .route(
            "/api/v1/searches/{id}/results.csv",
            get(searches::results_csv),
        )
        .route("/api/v1/searches/{id}/jobs", get(searches::jobs))
        .route("/api/v1/searches/{id}/outputs", get(searches::outputs))
        .route(
            "/api/v1/searches/{id}/subjects",
            post(searches::score_subjects),
        )
        .route("/api/v1/jobs/{id}", get(jobs::detail))
        .route("/api/v1/leases", post(jobs::lease))
        .route("/api/v1/jobs/{id}/heartbeat", post(jobs::heartbeat))
        .route("/api/v1/jobs/{id}/result", post(jobs::result))
        .route("/api/v1/jobs/{id}/fail", post(jobs::fail))
        .route("/api/v1/jobs/{id}/release", post(jobs::release))
        .route_layer(from_fn_with_state(state.clone(), require_token));
    Router::new()
        .merge(api)
        .merge(crate::dashboard::router(state.clone()))
        .route("/healthz", get(ops::healthz))
        .route("/metrics", get(ops::metrics))
        .fallback(ops::not_found)
        .method_not_allowed_fallback(ops::method_not_allowed)
        .route_layer(from_fn_with_state(state.clone(), crate::metrics::track))
        .layer(DefaultBodyLimit::max(state.cfg.body_limit))
        .layer(from_fn_with_state(state.clone(), refuse_oversized))
        .layer(TraceLayer::new_for_http().make_span_with(crate::dashboard::auth::request_span))
        .layer(tower_http::timeout::TimeoutLayer::with_status_code(
            axum::http::StatusCode::REQUEST_TIMEOUT,
            Duration::from_secs(120),
        ))
        .with_state(state)
}
