//! The coordinator's one error type: each variant is an HTTP outcome, and
//! every answer carries `{"error": "..."}`.

use axum::extract::rejection::{JsonRejection, PathRejection, QueryRejection};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::Json;
use shared::api::ErrorBody;

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

/// What a SQLite result code (primary or extended) says about the storage
/// when it means "the database cannot serve this now" rather than "the
/// request is wrong" or "a bug": `SQLITE_BUSY`, `SQLITE_LOCKED`,
/// `SQLITE_READONLY`, `SQLITE_IOERR`, `SQLITE_FULL`, `SQLITE_CANTOPEN`.
/// Everything else (constraints, corruption, misuse) stays a 500.
pub fn storage_fault(code: i32) -> Option<&'static str> {
    match code & 0xff {
        5 => Some("database is busy (SQLITE_BUSY)"),
        6 => Some("database table is locked (SQLITE_LOCKED)"),
        8 => Some("database is read-only (SQLITE_READONLY)"),
        10 => Some("disk I/O error (SQLITE_IOERR)"),
        13 => Some("database or disk is full (SQLITE_FULL)"),
        14 => Some("cannot open the database file (SQLITE_CANTOPEN)"),
        _ => None,
    }
}

fn unavailable(what: &str, detail: &str) -> ApiError {
    ApiError::Unavailable(format!(
        "database unavailable: {what}: {detail}; retry later"
    ))
}

fn sqlx_fault(e: &sqlx::Error) -> Option<ApiError> {
    match e {
        sqlx::Error::Database(d) => {
            let code = d.code().and_then(|c| c.parse::<i32>().ok());
            code.and_then(storage_fault)
                .map(|what| unavailable(what, d.message()))
        }
        sqlx::Error::Io(io) => Some(unavailable("I/O error", &io.to_string())),
        sqlx::Error::PoolTimedOut => {
            Some(unavailable("no database connection free", "pool timed out"))
        }
        _ => None,
    }
}

fn rusqlite_fault(e: &rusqlite::Error) -> Option<ApiError> {
    match e {
        rusqlite::Error::SqliteFailure(f, msg) => storage_fault(f.extended_code).map(|what| {
            let detail = msg.clone().unwrap_or_else(|| f.to_string());
            unavailable(what, &detail)
        }),
        _ => None,
    }
}

impl From<sqlx::Error> for ApiError {
    fn from(e: sqlx::Error) -> Self {
        sqlx_fault(&e).unwrap_or_else(|| Self::Internal(anyhow::Error::new(e).context("database")))
    }
}

impl From<&rusqlite::Error> for ApiError {
    fn from(e: &rusqlite::Error) -> Self {
        rusqlite_fault(e)
            .unwrap_or_else(|| Self::Internal(anyhow::anyhow!("{e}").context("database")))
    }
}

/// An error from code that returns `anyhow` is a 503 when a database
/// storage fault is anywhere in its chain, a 500 otherwise.
impl From<anyhow::Error> for ApiError {
    fn from(e: anyhow::Error) -> Self {
        for cause in e.chain() {
            let fault = cause
                .downcast_ref::<sqlx::Error>()
                .and_then(sqlx_fault)
                .or_else(|| {
                    cause
                        .downcast_ref::<rusqlite::Error>()
                        .and_then(rusqlite_fault)
                });
            if let Some(fault) = fault {
                return fault;
            }
        }
        Self::Internal(e)
    }
}

impl From<rusqlite::Error> for ApiError {
    fn from(e: rusqlite::Error) -> Self {
        Self::from(&e)
    }
}

// The mapping of real SQLite refusals is tested with the store
// (`store/error_tests.rs`), which owns every SQL statement.
#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn storage_codes_are_unavailable_and_the_rest_internal() {
        // Primary and extended codes: BUSY, LOCKED, READONLY,
        // READONLY_DBMOVED, IOERR, IOERR_WRITE, IOERR_FSYNC, FULL, CANTOPEN.
        for code in [5, 6, 8, 1032, 10, 778, 1034, 13, 14] {
            assert!(storage_fault(code).is_some(), "{code}");
        }
        // ERROR, CORRUPT, CONSTRAINT, CONSTRAINT_UNIQUE, MISUSE.
        for code in [1, 11, 19, 2067, 21] {
            assert!(storage_fault(code).is_none(), "{code}");
        }
    }
}
