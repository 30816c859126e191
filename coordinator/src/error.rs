//! The HTTP error type: each variant is an HTTP outcome, and every answer
//! carries `{"error": "..."}`. The store's and the domain's errors
//! ([`StoreError`], [`DomainError`]) become answers here, at the edge, and
//! nowhere below.

use axum::extract::rejection::{JsonRejection, PathRejection, QueryRejection};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::Json;
use shared::api::ErrorBody;

use crate::domain::DomainError;
use crate::store::StoreError;

/// Outcome of a failed request.
#[derive(Debug, thiserror::Error)]
pub enum ApiError {
    /// Unknown id or route.
    #[error("{0}")]
    NotFound(String),
    /// Invalid input; the message names the field and the problem.
    #[error("{0}")]
    BadRequest(String),
    /// Missing or wrong bearer token.
    #[error("missing or invalid bearer token")]
    Unauthorized,
    /// A valid token whose role may not call this route.
    #[error("this token's role may not call this route")]
    Forbidden,
    /// The request conflicts with the current state (lost lease, job
    /// already done, search already completed).
    #[error("{0}")]
    Conflict(String),
    /// Request body over the limit.
    #[error("{0}")]
    PayloadTooLarge(String),
    /// The database cannot take the request now (disk full, read-only
    /// file system or file, I/O error, locked past the busy timeout): 503
    /// with `Retry-After`; the message says what the storage reported.
    #[error("{0}")]
    Unavailable(String),
    /// Anything else; logged with its cause chain, answered generically.
    #[error(transparent)]
    Internal(anyhow::Error),
}

impl ApiError {
    /// The status this error answers with.
    pub fn status(&self) -> StatusCode {
        match self {
            Self::NotFound(_) => StatusCode::NOT_FOUND,
            Self::BadRequest(_) => StatusCode::BAD_REQUEST,
            Self::Unauthorized => StatusCode::UNAUTHORIZED,
            Self::Forbidden => StatusCode::FORBIDDEN,
            Self::Conflict(_) => StatusCode::CONFLICT,
            Self::PayloadTooLarge(_) => StatusCode::PAYLOAD_TOO_LARGE,
            Self::Unavailable(_) => StatusCode::SERVICE_UNAVAILABLE,
            Self::Internal(_) => StatusCode::INTERNAL_SERVER_ERROR,
        }
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let status = self.status();
        let error = match &self {
            Self::Internal(e) => {
                tracing::error!(error = format!("{e:#}"), "internal error");
                "internal error".to_string()
            }
            Self::Unavailable(m) => {
                tracing::warn!(error = %m, "database unavailable; answering 503");
                m.clone()
            }
            other => other.to_string(),
        };
        let mut resp = (status, Json(ErrorBody { error })).into_response();
        if status == StatusCode::UNAUTHORIZED {
            resp.headers_mut().insert(
                axum::http::header::WWW_AUTHENTICATE,
                axum::http::HeaderValue::from_static("Bearer"),
            );
        }
        if status == StatusCode::SERVICE_UNAVAILABLE {
            resp.headers_mut().insert(
                axum::http::header::RETRY_AFTER,
                axum::http::HeaderValue::from_static(RETRY_AFTER_SECS),
            );
        }
        resp
    }
}

impl From<JsonRejection> for ApiError {
    fn from(r: JsonRejection) -> Self {
        if r.status() == StatusCode::PAYLOAD_TOO_LARGE {
            return Self::PayloadTooLarge(format!("request body too large: {}", r.body_text()));
        }
        // The text names the JSON path of the offending field.
        Self::BadRequest(format!("invalid JSON body: {}", r.body_text()))
    }
}

impl From<PathRejection> for ApiError {
    fn from(r: PathRejection) -> Self {
        Self::BadRequest(format!("invalid path parameter: {}", r.body_text()))
    }
}

impl From<QueryRejection> for ApiError {
    fn from(r: QueryRejection) -> Self {
        Self::BadRequest(format!("invalid query string: {}", r.body_text()))
    }
}

/// `Retry-After` of a 503 answer, in seconds.
pub const RETRY_AFTER_SECS: &str = "5";

/// The store's outcomes as answers: refusals keep their message, a storage
/// fault is a 503 with `Retry-After`, anything else a 500.
impl From<StoreError> for ApiError {
    fn from(e: StoreError) -> Self {
        match e {
            StoreError::NotFound(m) => Self::NotFound(m),
            StoreError::Conflict(m) => Self::Conflict(m),
            StoreError::Invalid(m) => Self::BadRequest(m),
            StoreError::Unavailable(m) => Self::Unavailable(m),
            StoreError::Internal(e) => Self::Internal(e),
        }
    }
}

/// The domain's outcomes as answers.
impl From<DomainError> for ApiError {
    fn from(e: DomainError) -> Self {
        match e {
            DomainError::Invalid(m) => Self::BadRequest(m),
            DomainError::NotFound(m) => Self::NotFound(m),
            DomainError::Conflict(m) => Self::Conflict(m),
            DomainError::Store(e) => Self::from(e),
            DomainError::Internal(e) => Self::Internal(e),
        }
    }
}

/// A database error read through sqlx (the dashboard's reads): classified
/// by the store.
impl From<sqlx::Error> for ApiError {
    fn from(e: sqlx::Error) -> Self {
        Self::from(StoreError::from(e))
    }
}

/// An error from code that returns `anyhow` is a 503 when a database
/// storage fault is anywhere in its chain, a 500 otherwise (the store
/// classifies it).
impl From<anyhow::Error> for ApiError {
    fn from(e: anyhow::Error) -> Self {
        Self::from(StoreError::from(e))
    }
}

// The classification of real SQLite refusals is tested with the store
// (`store/error_tests.rs`), which owns every SQL statement; their answers
// here.
#[cfg(test)]
mod tests {
    use super::*;

    async fn body(e: ApiError) -> (StatusCode, Option<String>, String) {
        let r = e.into_response();
        let st = r.status();
        let retry = r
            .headers()
            .get(axum::http::header::RETRY_AFTER)
            .map(|v| v.to_str().unwrap().to_string());
        let bytes = axum::body::to_bytes(r.into_body(), 1 << 16).await.unwrap();
        let v: serde_json::Value = serde_json::from_slice(&bytes).unwrap();
        (st, retry, v["error"].as_str().unwrap().to_string())
    }

    #[tokio::test]
    async fn store_and_domain_errors_answer_with_their_status_and_message() {
        let msg = "database unavailable: database is read-only (SQLITE_READONLY): \
                   attempt to write a readonly database; retry later";
        let (st, retry, m) = body(StoreError::Unavailable(msg.into()).into()).await;
        assert_eq!(st, StatusCode::SERVICE_UNAVAILABLE);
        assert_eq!(retry.as_deref(), Some(RETRY_AFTER_SECS));
        assert_eq!(m, msg);
        let (st, retry, m) = body(StoreError::internal("constraint").into()).await;
        assert_eq!(
            (st, retry, m.as_str()),
            (StatusCode::INTERNAL_SERVER_ERROR, None, "internal error")
        );
        for (e, want) in [
            (StoreError::NotFound("n".into()), StatusCode::NOT_FOUND),
            (StoreError::Conflict("c".into()), StatusCode::CONFLICT),
            (StoreError::Invalid("i".into()), StatusCode::BAD_REQUEST),
        ] {
            let text = e.to_string();
            let (st, _, m) = body(DomainError::from(e).into()).await;
            assert_eq!((st, m), (want, text));
        }
        let (st, _, m) = body(DomainError::Invalid("trials: no".into()).into()).await;
        assert_eq!((st, m.as_str()), (StatusCode::BAD_REQUEST, "trials: no"));
        let (st, retry, _) =
            body(DomainError::from(StoreError::Unavailable(msg.into())).into()).await;
        assert_eq!(
            (st, retry.as_deref()),
            (StatusCode::SERVICE_UNAVAILABLE, Some(RETRY_AFTER_SECS))
        );
    }
}
