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

#[cfg(test)]
mod tests {
    use std::str::FromStr;

    use sqlx::sqlite::SqliteConnectOptions;
    use sqlx::{ConnectOptions, Connection};

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
    async fn real_sqlite_refusals_map_to_503_with_a_json_message() {
        let dir = tempfile::tempdir().unwrap();
        let opts = SqliteConnectOptions::from_str("sqlite:")
            .unwrap()
            .filename(dir.path().join("e.db"))
            .create_if_missing(true);
        let mut rw = opts.connect().await.unwrap();
        sqlx::query("create table t (x blob unique)")
            .execute(&mut rw)
            .await
            .unwrap();
        // A read-only connection: SQLITE_READONLY.
        let mut ro = opts.clone().read_only(true).connect().await.unwrap();
        let e = sqlx::query("insert into t values (1)")
            .execute(&mut ro)
            .await
            .unwrap_err();
        let (st, retry, msg) = body(ApiError::from(e)).await;
        assert_eq!(st, StatusCode::SERVICE_UNAVAILABLE);
        assert_eq!(retry.as_deref(), Some(RETRY_AFTER_SECS));
        assert_eq!(
            msg,
            "database unavailable: database is read-only (SQLITE_READONLY): \
             attempt to write a readonly database; retry later"
        );
        ro.close().await.unwrap();
        // No page left: SQLITE_FULL, also through an anyhow chain. (SQLite
        // never sets max_page_count below the file's size, so 1 pins it
        // there.)
        sqlx::query("pragma max_page_count = 1")
            .execute(&mut rw)
            .await
            .unwrap();
        let e = sqlx::query("insert into t values (zeroblob(100000))")
            .execute(&mut rw)
            .await
            .unwrap_err();
        let e = anyhow::Error::new(e).context("inserting");
        let (st, _, msg) = body(ApiError::from(e)).await;
        assert_eq!(st, StatusCode::SERVICE_UNAVAILABLE);
        assert!(msg.contains("(SQLITE_FULL)"), "{msg}");
        // A constraint violation is not a storage fault: 500, no detail.
        sqlx::query("pragma max_page_count = 1073741823")
            .execute(&mut rw)
            .await
            .unwrap();
        sqlx::query("insert into t values (1)")
            .execute(&mut rw)
            .await
            .unwrap();
        let e = sqlx::query("insert into t values (1)")
            .execute(&mut rw)
            .await
            .unwrap_err();
        let (st, retry, msg) = body(ApiError::from(e)).await;
        assert_eq!(
            (st, retry, msg.as_str()),
            (StatusCode::INTERNAL_SERVER_ERROR, None, "internal error")
        );
        // rusqlite (the group-commit writer's driver) maps the same way.
        let conn = rusqlite::Connection::open_with_flags(
            dir.path().join("e.db"),
            rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY,
        )
        .unwrap();
        let e = conn.execute("insert into t values (2)", []).unwrap_err();
        assert!(
            matches!(ApiError::from(e), ApiError::Unavailable(m) if m.contains("SQLITE_READONLY"))
        );
    }
}
