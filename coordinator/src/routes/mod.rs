//! The HTTP surface: the router, built from the route table
//! (`shared::api::routes`), and its bearer-token check. Handlers are
//! thin: each parses its request, calls the domain layer
//! ([`crate::domain`]) and maps the answer (no `pub async fn` here is over
//! 40 lines; CI's `tools/handler_length.py` holds it). Nothing below
//! imports from here.

mod jobs;
mod ops;
mod searches;

use std::time::Duration;

use axum::extract::{DefaultBodyLimit, MatchedPath, Request, State};
use axum::http::header;
use axum::middleware::{from_fn_with_state, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::{on, MethodFilter, MethodRouter};
use axum::Router;
use tower_http::trace::TraceLayer;

use crate::auth::{access_of, Access, Refusal, Tokens};
use crate::dashboard::auth::has_session;
use crate::error::ApiError;
use crate::state::AppState;

pub use shared::api::routes::ROUTES;
use shared::api::routes::{Endpoint, Method, Route};

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

/// The handler serving an endpoint, on the method the route table gives
/// it. The match is exhaustive: a new endpoint in the table needs its
/// handler here before the crate compiles.
fn handler(route: &Route) -> MethodRouter<AppState> {
    use Endpoint as E;
    let m = match route.method {
        Method::Get => MethodFilter::GET,
        Method::Post => MethodFilter::POST,
    };
    match route.endpoint {
        E::Healthz => on(m, ops::healthz),
        E::Metrics => on(m, ops::metrics),
        E::OpenApi => on(m, ops::openapi),
        E::ListSearches => on(m, searches::list),
        E::Submit => on(m, searches::create),
        E::SearchStatus => on(m, searches::status),
        E::Cancel => on(m, searches::cancel),
        E::Extend => on(m, searches::extend),
        E::Refine => on(m, searches::refine),
        E::Refinement => on(m, searches::refinement),
        E::Results => on(m, searches::results),
        E::ResultsCsv => on(m, searches::results_csv),
        E::SearchJobs => on(m, searches::jobs),
        E::Outputs => on(m, searches::outputs),
        E::ScoreSubjects => on(m, searches::score_subjects),
        E::JobDetail => on(m, jobs::detail),
        E::Lease => on(m, jobs::lease),
        E::Heartbeat => on(m, jobs::heartbeat),
        E::Result => on(m, jobs::result),
        E::Fail => on(m, jobs::fail),
        E::Release => on(m, jobs::release),
    }
}

/// The application router: every route of the table ([`ROUTES`]) behind
/// the token check (open routes pass it), the dashboard, and the
/// fallbacks.
pub fn router(state: AppState) -> Router {
    let api = ROUTES
        .iter()
        .fold(Router::new(), |r, route| {
            r.route(route.path, handler(route))
        })
        .route_layer(from_fn_with_state(state.clone(), require_token));
    Router::new()
        .merge(api)
        .merge(crate::dashboard::router(state.clone()))
        .fallback(ops::not_found)
        .method_not_allowed_fallback(ops::method_not_allowed)
        .route_layer(from_fn_with_state(
            state.metrics.clone(),
            crate::metrics::track,
        ))
        .layer(DefaultBodyLimit::max(state.cfg.body_limit))
        .layer(from_fn_with_state(state.clone(), refuse_oversized))
        .layer(TraceLayer::new_for_http().make_span_with(crate::dashboard::auth::request_span))
        .layer(tower_http::timeout::TimeoutLayer::with_status_code(
            axum::http::StatusCode::REQUEST_TIMEOUT,
            Duration::from_secs(120),
        ))
        .with_state(state)
}
