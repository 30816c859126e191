//! No secret reaches the logs: with every log line captured at
//! `trace` level, a session of API calls carrying the bearer token (right
//! and wrong), lease tokens, and dashboard logins by `?token=` and by form
//! leaves neither the token, nor a lease token, nor the session cookie in
//! the output. Its own test binary: it installs the global subscriber.

use std::io::Write;
use std::sync::{Arc, Mutex};

use coordinator::CoordinatorConfig;
use serde_json::json;
use shared::api::routes::Endpoint as E;

const SECRET: &str = "Sup3r-Secret-Bearer-7f3a9c";
const WRONG: &str = "Wr0ng-Guess-Of-The-Token-51b2";

#[derive(Clone, Default)]
struct Capture(Arc<Mutex<Vec<u8>>>);

impl Write for Capture {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl<'a> tracing_subscriber::fmt::MakeWriter<'a> for Capture {
    type Writer = Capture;
    fn make_writer(&'a self) -> Self::Writer {
        self.clone()
    }
}

#[tokio::test]
async fn tokens_never_appear_in_the_logs() {
    let cap = Capture::default();
    // Everything the service and its libraries log, except the test's own
    // HTTP client (which is not the coordinator).
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::new(
            "trace,reqwest=off,hyper_util::client=off,hyper::client=off",
        ))
        .with_writer(cap.clone())
        .with_ansi(false)
        .init();
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = CoordinatorConfig::new("127.0.0.1:0".parse().unwrap(), dir.path().join("c.db"));
    cfg.token = Some(SECRET.into());
    let running = coordinator::start(cfg).await.unwrap();
    let url = running.url();
    let http = reqwest::Client::builder()
        .redirect(reqwest::redirect::Policy::none())
        .build()
        .unwrap();

    let r = http
        .post(format!("{url}/api/v1/searches"))
        .bearer_auth(SECRET)
        .json(
            &json!({"name": "logs", "reward_grid": {"w1": [1.0, 2.0]}, "trials": 1,
                      "sampling": {"successful_episodes": 1, "top_k": 1, "max_attempts": 5}}),
        )
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 201);
    let id = r.json::<serde_json::Value>().await.unwrap()["id"]
        .as_str()
        .unwrap()
        .to_string();
    let mut lease_tokens = Vec::new();
    for _ in 0..2 {
        let lease: serde_json::Value = http
            .post(format!("{url}/api/v1/leases"))
            .bearer_auth(SECRET)
            .json(&json!({"worker": "w"}))
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        let (job, tok) = (
            lease["job_id"].clone(),
            lease["lease_token"].as_str().unwrap().to_string(),
        );
        let hb = http
            .post(format!("{url}/api/v1/jobs/{job}/heartbeat"))
            .bearer_auth(SECRET)
            .json(
                &json!({"lease_token": tok, "progress": [{"env_steps": 1, "total_env_steps": 2}]}),
            )
            .send()
            .await
            .unwrap();
        assert_eq!(hb.status(), 200);
        // A refused upload (stale token) and a failure report get logged.
        let bad = http
            .post(format!("{url}/api/v1/jobs/{job}/result"))
            .bearer_auth(SECRET)
            .json(&json!({"lease_token": format!("{tok}00"), "output": {
                "final_success_rate": 0.5, "env_steps": 1, "successes_found": 0,
                "successes_wanted": 1, "sampling_attempts": 1, "episodes": []}}))
            .send()
            .await
            .unwrap();
        assert_eq!(bad.status(), 409);
        let f = http
            .post(format!("{url}/api/v1/jobs/{job}/fail"))
            .bearer_auth(SECRET)
            .json(&json!({"lease_token": tok, "error": "boom"}))
            .send()
            .await
            .unwrap();
        assert_eq!(f.status(), 200);
        lease_tokens.push(tok);
    }
    // Wrong bearer tokens.
    for auth in [format!("Bearer {WRONG}"), WRONG.to_string()] {
        let r = http
            .post(format!("{url}/api/v1/leases"))
            .header("authorization", auth)
            .json(&json!({"worker": "w"}))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 401);
    }
    // Dashboard: token in the query (right and wrong), then the form.
    for q in [
        format!("/?token={SECRET}"),
        format!("/searches/{id}?token={SECRET}&jobs_page=1"),
        format!("/?token={WRONG}"),
    ] {
        let r = http.get(format!("{url}{q}")).send().await.unwrap();
        assert!(
            r.status() == 303 || r.status() == 401,
            "{q}: {}",
            r.status()
        );
    }
    let r = http
        .post(format!("{url}/login"))
        .form(&[("token", SECRET), ("next", "/")])
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 303);
    let cookie = coordinator::dashboard::auth::session_value(SECRET);
    let r = http
        .get(format!("{url}/searches/{id}"))
        .header(
            "cookie",
            format!("{}={cookie}", coordinator::dashboard::auth::COOKIE),
        )
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    running.shutdown().await.unwrap();

    let logs = String::from_utf8(cap.0.lock().unwrap().clone()).unwrap();
    // The capture works and saw these requests (so the check can fail).
    assert!(logs.contains("search submitted"), "{logs}");
    assert!(logs.contains("result refused"), "{logs}");
    assert!(logs.contains(E::Lease.path()), "request paths are logged");
    assert!(
        logs.contains(&format!("/searches/{id}")),
        "dashboard paths are logged"
    );
    for secret in [SECRET, WRONG, &cookie]
        .into_iter()
        .chain(lease_tokens.iter().map(String::as_str))
    {
        if let Some(at) = logs.find(secret) {
            let from = logs[..at].rfind('\n').map_or(0, |i| i + 1);
            let line = logs[from..].lines().next().unwrap_or("");
            panic!("secret {secret:?} found in the logs: {line}");
        }
    }
}
