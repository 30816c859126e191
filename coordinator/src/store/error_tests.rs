//! Real SQLite refusals (constraint, full, read-only) through both drivers
//! map to the API's answers: 503 with `Retry-After` for storage faults, 500
//! otherwise (see `crate::error`).

use std::str::FromStr;

use axum::http::StatusCode;
use axum::response::IntoResponse;
use sqlx::sqlite::SqliteConnectOptions;
use sqlx::{ConnectOptions, Connection};

use crate::error::{ApiError, RETRY_AFTER_SECS};

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
    assert!(matches!(ApiError::from(e), ApiError::Unavailable(m) if m.contains("SQLITE_READONLY")));
}
