//! Real SQLite refusals (constraint, full, read-only) through both drivers
//! classify as [`StoreError::Unavailable`] with the storage's message for
//! storage faults, [`StoreError::Internal`] otherwise (`crate::error` turns
//! them into 503 with `Retry-After` and 500).

use std::str::FromStr;

use sqlx::sqlite::SqliteConnectOptions;
use sqlx::{ConnectOptions, Connection};

use super::StoreError;

/// (unavailable, message) of a classified error.
fn body(e: StoreError) -> (bool, String) {
    match e {
        StoreError::Unavailable(m) => (true, m),
        other => (false, other.to_string()),
    }
}

#[tokio::test]
async fn real_sqlite_refusals_are_unavailable_with_the_storage_message() {
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
    let (unavailable, msg) = body(StoreError::from(e));
    assert!(unavailable);
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
    let (unavailable, msg) = body(StoreError::from(e));
    assert!(unavailable);
    assert!(msg.contains("(SQLITE_FULL)"), "{msg}");
    // A constraint violation is not a storage fault: internal.
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
    assert!(matches!(StoreError::from(e), StoreError::Internal(_)));
    // rusqlite (the group-commit writer's driver) maps the same way.
    let conn = rusqlite::Connection::open_with_flags(
        dir.path().join("e.db"),
        rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY,
    )
    .unwrap();
    let e = conn.execute("insert into t values (2)", []).unwrap_err();
    assert!(
        matches!(StoreError::from(e), StoreError::Unavailable(m) if m.contains("SQLITE_READONLY"))
    );
}
