//! Storage faults without root: the coordinator's one writer connection
//! (the group-commit thread's) is made read-only (`pragma query_only`) or full (`pragma
//! max_page_count` pinned to its current size), which makes SQLite refuse
//! writes with the same SQLITE_READONLY / SQLITE_FULL codes as a read-only
//! file system or a full disk. The API must answer 503 with a clear JSON
//! message and `Retry-After`, `/healthz` must say unhealthy, and both must
//! recover, with an intact database, once the fault is lifted. (The real
//! tmpfs / remount tests are `tests/reliability/disk_faults.sh`; the group
//! commit writer's rollback path is tested in
//! `coordinator/src/store/queue/tests.rs`.)

use coordinator::store::WriterPragma;
use reqwest::StatusCode;
use serde_json::Value;

use crate::helpers::*;

async fn pragma(app: &TestApp, p: WriterPragma) -> Option<i64> {
    let db = &app.running.as_ref().unwrap().state.db;
    db.writer_pragma(p).await.unwrap()
}

async fn integrity(app: &TestApp) -> String {
    let db = &app.running.as_ref().unwrap().state.db;
    sqlx::query_scalar("pragma integrity_check")
        .fetch_one(&db.read)
        .await
        .unwrap()
}

async fn raw_healthz(app: &TestApp) -> (StatusCode, Option<String>, Value) {
    let r = app
        .client
        .get(format!("{}/healthz", app.url))
        .send()
        .await
        .unwrap();
    let st = r.status();
    let retry = r
        .headers()
        .get("retry-after")
        .map(|v| v.to_str().unwrap().to_string());
    (st, retry, r.json().await.unwrap())
}

#[tokio::test]
async fn read_only_database_answers_503_and_recovers() {
    let app = spawn_app().await;
    assert_eq!(raw_healthz(&app).await.0, StatusCode::OK);
    pragma(&app, WriterPragma::QueryOnly(true)).await;
    let (st, v) = app
        .post(E::Submit.path(), &search_body(&[1.0, 2.0], 1))
        .await;
    assert_eq!(st, StatusCode::SERVICE_UNAVAILABLE, "{v}");
    let msg = v["error"].as_str().unwrap();
    assert!(
        msg.starts_with("database unavailable: database is read-only (SQLITE_READONLY)"),
        "{msg}"
    );
    assert!(msg.ends_with("retry later"), "{msg}");
    let (st, retry, v) = raw_healthz(&app).await;
    assert_eq!(st, StatusCode::SERVICE_UNAVAILABLE, "{v}");
    assert_eq!(retry.as_deref(), Some("5"));
    assert!(v["error"].as_str().unwrap().contains("read-only"), "{v}");
    let (_, searches) = app.get(E::ListSearches.path()).await;
    assert_eq!(searches.as_array().unwrap().len(), 0, "nothing was stored");
    pragma(&app, WriterPragma::QueryOnly(false)).await;
    assert_eq!(raw_healthz(&app).await.0, StatusCode::OK);
    app.submit(&search_body(&[1.0, 2.0], 1)).await;
    assert_eq!(integrity(&app).await, "ok");
}

#[tokio::test]
async fn full_database_answers_503_and_recovers_when_space_returns() {
    let app = spawn_app().await;
    let pages = pragma(&app, WriterPragma::PageCount).await.unwrap();
    assert_eq!(pragma(&app, WriterPragma::Full(true)).await, Some(pages));
    // 64 points x 100 trials = 6,400 job rows: far more than the free pages.
    let w1: Vec<f64> = (1..=64).map(f64::from).collect();
    let big = search_body(&w1, 100);
    let (st, v) = app.post(E::Submit.path(), &big).await;
    assert_eq!(st, StatusCode::SERVICE_UNAVAILABLE, "{v}");
    assert!(
        v["error"]
            .as_str()
            .unwrap()
            .starts_with("database unavailable: database or disk is full (SQLITE_FULL)"),
        "{v}"
    );
    let (_, searches) = app.get(E::ListSearches.path()).await;
    assert_eq!(searches.as_array().unwrap().len(), 0, "nothing half-stored");
    // Space returns.
    assert_eq!(
        pragma(&app, WriterPragma::Full(false)).await,
        Some(1_073_741_823)
    );
    let id = app.submit(&big).await;
    assert_eq!(app.status(&id).await.jobs.total, 6400);
    assert_eq!(raw_healthz(&app).await.0, StatusCode::OK);
    assert_eq!(integrity(&app).await, "ok");
}
