//! Operational endpoints: health, Prometheus metrics, the OpenAPI document,
//! and JSON answers for unknown routes and methods.

use axum::extract::State;
use axum::http::{header, Method, StatusCode, Uri};
use axum::response::{IntoResponse, Response};
use axum::Json;
use shared::api::ErrorBody;

use crate::error::ApiError;
use crate::state::AppState;

/// `GET /healthz`: 200 when the database answers a read and commits a
/// one-row write; 503 (`ApiError::Unavailable`, with the storage's message)
/// when the disk is full, the file or file system is read-only, I/O fails
/// or the database stays locked.
pub async fn healthz(State(s): State<AppState>) -> Result<Json<serde_json::Value>, ApiError> {
    crate::store::queue::probe(&s.db, crate::store::now_ms()).await?;
    Ok(Json(serde_json::json!({"status": "ok"})))
}

/// `GET /metrics`: Prometheus text format.
pub async fn metrics(State(s): State<AppState>) -> Result<Response, ApiError> {
    let jobs = crate::store::queue::global_counts(&s.db).await?;
    Ok((
        [(header::CONTENT_TYPE, "text/plain; version=0.0.4")],
        s.metrics.render(&jobs),
    )
        .into_response())
}

/// `GET /api/v1/openapi.json`.
pub async fn openapi(State(s): State<AppState>) -> Json<serde_json::Value> {
    Json(crate::openapi::document_for(
        s.cfg.has_token(),
        s.cfg.public_reads,
    ))
}

/// Unknown route.
pub async fn not_found(uri: Uri) -> (StatusCode, Json<ErrorBody>) {
    (
        StatusCode::NOT_FOUND,
        Json(ErrorBody {
            error: format!("no route for {}", uri.path()),
        }),
    )
}

/// Known route, wrong method.
pub async fn method_not_allowed(method: Method, uri: Uri) -> (StatusCode, Json<ErrorBody>) {
    (
        StatusCode::METHOD_NOT_ALLOWED,
        Json(ErrorBody {
            error: format!("method {method} not allowed on {}", uri.path()),
        }),
    )
}
