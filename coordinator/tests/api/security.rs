//! Hostile-input checks: a worker cannot act on a job it does
//! not hold, huge and deeply nested bodies are refused early with 4xx.
//! (Missing or wrong bearer tokens: `auth.rs`; no secret in the logs:
//! `tests/log_secrets.rs`; parameterized SQL: `tests/sql_guard.rs`.)

use std::io::{Read, Write};
use std::time::{Duration, Instant};

use reqwest::StatusCode;
use serde_json::{json, Value};

use crate::helpers::*;

/// Everything observable about one job.
async fn job_state(app: &TestApp, job: i64) -> Value {
    let (st, v) = app.get(&E::JobDetail.path_of(job)).await;
    assert_eq!(st, StatusCode::OK, "{v}");
    v
}

#[tokio::test]
async fn a_worker_cannot_touch_a_job_it_does_not_hold() {
    let app = spawn_with(Opts {
        token: Some("bearer-secret"),
        ..Opts::default()
    })
    .await;
    let id = app.submit(&search_body(&[1.0, 2.0], 1)).await;
    let a = app.lease("a").await.unwrap();
    let b = app.lease("b").await.unwrap();
    assert_ne!(a.job_id, b.job_id);
    let (st, _) = app
        .heartbeat(
            a.job_id,
            &a.lease_token,
            json!([{"env_steps": 10, "total_env_steps": 100}]),
        )
        .await;
    assert_eq!(st, StatusCode::OK);
    let before = job_state(&app, a.job_id).await;
    let t = &a.lease_token;
    let mut upper = t.to_uppercase();
    if upper == *t {
        upper = format!("{}x", &t[..t.len() - 1]);
    }
    let wrong = [
        b.lease_token.clone(),        // another worker's real lease
        format!("{t}0"),              // longer
        t[..t.len() - 1].to_string(), // prefix
        upper,                        // case changed
        "0".repeat(t.len()),          // same length
        format!("{t}' or '1'='1"),    // SQL-looking
    ];
    let out = output(0.9, 3, 0.1);
    for w in &wrong {
        let job = a.job_id;
        let calls = [
            app.heartbeat(job, w, json!([{"env_steps": 99, "total_env_steps": 100}]))
                .await,
            app.upload(job, w, &out).await,
            app.fail(job, w, "sabotage").await,
            app.release(job, w).await,
        ];
        for (k, (st, v)) in calls.iter().enumerate() {
            assert_eq!(*st, StatusCode::CONFLICT, "call {k} with {w:?}: {v}");
            assert!(v["error"].as_str().unwrap().contains("lease token"), "{v}");
        }
    }
    // A lease token of another job, and an unknown job.
    let (st, _) = app.upload(b.job_id, &a.lease_token, &out).await;
    assert_eq!(st, StatusCode::CONFLICT);
    let (st, _) = app.upload(999_999, &a.lease_token, &out).await;
    assert_eq!(st, StatusCode::NOT_FOUND);
    // Nothing changed: same owner, attempts, curve, no result.
    assert_eq!(job_state(&app, a.job_id).await, before);
    assert_eq!(before["status"], "leased");
    assert_eq!(before["worker"], "a");
    let (_, m) = app.get_text("/metrics").await;
    assert!(m.contains("irlgrid_uploads_accepted_total 0"), "{m}");
    // The holder still can, exactly once.
    let (st, v) = app.upload(a.job_id, &a.lease_token, &out).await;
    assert_eq!(st, StatusCode::OK, "{v}");
    for w in [&a.lease_token, &b.lease_token] {
        let (st, _) = app.upload(a.job_id, w, &out).await;
        assert_eq!(st, StatusCode::CONFLICT);
    }
    let (_, jobs) = app.get(&E::SearchJobs.path_of(&id)).await;
    let done: Vec<_> = jobs
        .as_array()
        .unwrap()
        .iter()
        .filter(|j| j["status"] == "done")
        .collect();
    assert_eq!(done.len(), 1);
    assert_eq!(done[0]["id"], a.job_id);
}

/// Sends raw bytes, returns the status line, and how long it took.
fn raw_request(addr: &str, head: &str, body: &[u8]) -> (String, Duration) {
    let t = Instant::now();
    let mut s = std::net::TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    s.write_all(head.as_bytes()).unwrap();
    // The server may answer and close before the body is all sent.
    let _ = s.write_all(body);
    let mut buf = [0u8; 512];
    let mut got = Vec::new();
    while !got.windows(2).any(|w| w == b"\r\n") {
        match s.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => got.extend_from_slice(&buf[..n]),
        }
    }
    let text = String::from_utf8_lossy(&got);
    (text.lines().next().unwrap_or("").to_string(), t.elapsed())
}

#[tokio::test]
async fn huge_bodies_are_refused_before_they_are_read() {
    let app = spawn_with(Opts {
        token: Some("bearer-secret"),
        body_limit: Some(64 * 1024),
        ..Opts::default()
    })
    .await;
    let addr = app.url.trim_start_matches("http://").to_string();
    // A Content-Length far over the limit, with no body sent at all: the
    // answer must not wait for the body.
    for path in [
        E::Submit.path().to_string(),
        E::Result.path_of(1),
        E::Lease.path().to_string(),
    ] {
        let head = format!(
            "POST {path} HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer bearer-secret\r\n\
             Content-Type: application/json\r\nContent-Length: 10000000000\r\n\r\n"
        );
        let a = addr.clone();
        let (line, took) = tokio::task::spawn_blocking(move || raw_request(&a, &head, b"{"))
            .await
            .unwrap();
        assert!(line.contains(" 413 "), "{path}: {line:?}");
        assert!(took < Duration::from_secs(5), "{path}: took {took:?}");
    }
    // A chunked body without a length, streamed past the limit.
    let head =
        "POST /api/v1/searches HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer bearer-secret\r\n\
                Content-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\n";
    let mut body = Vec::new();
    let chunk = vec![b' '; 16 * 1024];
    for _ in 0..16 {
        body.extend_from_slice(format!("{:x}\r\n", chunk.len()).as_bytes());
        body.extend_from_slice(&chunk);
        body.extend_from_slice(b"\r\n");
    }
    body.extend_from_slice(b"0\r\n\r\n");
    let a = addr.clone();
    let (line, _) = tokio::task::spawn_blocking(move || raw_request(&a, head, &body))
        .await
        .unwrap();
    assert!(line.contains(" 413 "), "{line:?}");
    // A real over-limit upload through a client: 413 and a JSON error.
    let l = app.submit(&search_body(&[1.0], 1)).await;
    let lease = app.lease("w").await.unwrap();
    let mut big = output(0.9, 3, 0.1);
    big.episodes[0].com_t = (0..20_000).map(f64::from).collect();
    let (st, v) = app.upload(lease.job_id, &lease.lease_token, &big).await;
    assert_eq!(st, StatusCode::PAYLOAD_TOO_LARGE, "{v}");
    assert!(v["error"].is_string(), "{v}");
    assert_eq!(job_state(&app, lease.job_id).await["status"], "leased");
    assert_eq!(app.status(&l).await.jobs.done, 0);
}

#[tokio::test]
async fn deeply_nested_bodies_are_400_not_a_crash() {
    let app = spawn_app().await;
    let deep = |n: usize| format!("{}{}", "[".repeat(n), "]".repeat(n));
    let deep_obj = |n: usize| format!("{}1{}", "{\"a\":".repeat(n), "}".repeat(n));
    let cases = [
        (E::Submit.path().to_string(), deep(100_000)),
        (
            E::Submit.path().to_string(),
            format!(
                r#"{{"reward_grid": {{"w1": [1]}}, "trials": 1, "training": {}}}"#,
                deep_obj(50_000)
            ),
        ),
        (
            E::Submit.path().to_string(),
            format!(
                r#"{{"reward_grid": {{"w1": [1]}}, "trials": 1, "env": {}}}"#,
                deep(129)
            ),
        ),
        (E::Lease.path().to_string(), deep_obj(100_000)),
        (
            E::Result.path_of(1),
            format!(r#"{{"lease_token": "x", "output": {}}}"#, deep(100_000)),
        ),
        (
            E::Heartbeat.path_of(1),
            format!(r#"{{"lease_token": "x", "progress": {}}}"#, deep(100_000)),
        ),
    ];
    for (path, body) in cases {
        let t = Instant::now();
        let r = app
            .client
            .post(format!("{}{path}", app.url))
            .header("content-type", "application/json")
            .body(body)
            .send()
            .await
            .unwrap();
        let st = r.status();
        let v: Value = r.json().await.unwrap();
        assert_eq!(st, StatusCode::BAD_REQUEST, "{path}: {v}");
        assert!(v["error"].as_str().unwrap().contains("JSON"), "{path}: {v}");
        assert!(t.elapsed() < Duration::from_secs(5), "{path}: slow");
    }
    // Still serving, nothing created.
    let (st, list) = app.get(E::ListSearches.path()).await;
    assert_eq!(st, StatusCode::OK);
    assert_eq!(list, json!([]));
}
