//! `spawn_app()` and one helper per endpoint.

use std::sync::Once;
use std::time::Duration;

use coordinator::Running;
use reqwest::StatusCode;
use serde_json::{json, Value};
use shared::analysis::{subjects_to_csv, EpisodeRecord, SubjectPath};
use shared::api::{JobOutput, Lease, SearchStatus};
use shared::test_support::StandUp;

use crate::support;
pub use shared::api::routes::{Endpoint as E, API_PREFIX};

static TRACING: Once = Once::new();

/// Tracing once per test binary, silent unless `TEST_LOG` is set.
pub fn init_tracing() {
    TRACING.call_once(|| {
        if std::env::var_os("TEST_LOG").is_some() {
            let _ = tracing_subscriber::fmt()
                .with_env_filter(tracing_subscriber::EnvFilter::new("info"))
                .with_test_writer()
                .try_init();
        }
    });
}

pub struct TestApp {
    pub running: Option<Running>,
    pub url: String,
    pub client: reqwest::Client,
    pub token: Option<String>,
    pub dir: tempfile::TempDir,
}

#[derive(Default)]
pub struct Opts {
    /// The admin token; `TestApp`'s helpers send it on every request.
    pub token: Option<&'static str>,
    pub worker_token: Option<&'static str>,
    pub read_token: Option<&'static str>,
    pub public_reads: bool,
    pub lease_secs: Option<u64>,
    pub body_limit: Option<usize>,
}

pub async fn spawn_app() -> TestApp {
    spawn_with(Opts::default()).await
}

/// Expired leases are swept every 100 ms, so lease tests run quickly.
const SWEEP: Duration = Duration::from_millis(100);

pub async fn spawn_with(o: Opts) -> TestApp {
    init_tracing();
    let (running, dir) = support::start(|cfg| {
        cfg.token = o.token.map(str::to_string);
        cfg.worker_token = o.worker_token.map(str::to_string);
        cfg.read_token = o.read_token.map(str::to_string);
        cfg.public_reads = o.public_reads;
        if let Some(l) = o.lease_secs {
            cfg.lease_secs = l;
        }
        if let Some(b) = o.body_limit {
            cfg.body_limit = b;
        }
        cfg.sweep_interval = SWEEP;
    })
    .await
    .unwrap();
    TestApp {
        url: running.url(),
        running: Some(running),
        client: reqwest::Client::new(),
        token: o.token.map(str::to_string),
        dir,
    }
}

/// Minimal valid search over `w1` values with tiny sampling numbers.
pub fn search_body(w1: &[f64], trials: u32) -> Value {
    json!({
        "name": "test",
        "reward_grid": {"w1": w1},
        "trials": trials,
        "seed": 7,
        "training": {"env_steps": 1000},
        "sampling": {"successful_episodes": 3, "top_k": 2, "max_attempts": 50, "n_envs": 4}
    })
}

/// The API tests' stand-up COM path (the shared bulging stand-up, 0.5 s,
/// 40 samples): rises 0.4 m with a forward bulge.
pub fn episode(bulge: f64) -> EpisodeRecord {
    stand_up(bulge).ret(900.0 + bulge).episode()
}

fn stand_up(bulge: f64) -> StandUp {
    StandUp::new(bulge)
        .sampled(40, 0.5)
        .torque_usage(50.0)
        .steps(10)
}

/// A subject CSV of bulging stand-ups, one subject per bulge.
pub fn subjects_csv(subjects: &[(&str, f64)]) -> String {
    let paths: Vec<SubjectPath> = subjects
        .iter()
        .map(|(name, bulge)| stand_up(*bulge).subject(name))
        .collect();
    subjects_to_csv(&paths)
}

/// An output matching `search_body`'s sampling config.
pub fn output(rate: f64, found: u32, bulge: f64) -> JobOutput {
    JobOutput {
        final_success_rate: rate,
        env_steps: 1024,
        successes_found: found,
        successes_wanted: 3,
        sampling_attempts: 10,
        episodes: (0..found.min(2))
            .map(|k| episode(bulge + 0.01 * k as f64))
            .collect(),
        train_secs: 0.1,
        sample_secs: 0.1,
    }
}

impl TestApp {
    fn auth(&self, r: reqwest::RequestBuilder) -> reqwest::RequestBuilder {
        match &self.token {
            Some(t) => r.bearer_auth(t),
            None => r,
        }
    }

    pub async fn post(&self, path: &str, body: &Value) -> (StatusCode, Value) {
        let r = self
            .auth(self.client.post(format!("{}{path}", self.url)))
            .json(body)
            .send()
            .await
            .unwrap();
        let st = r.status();
        let text = r.text().await.unwrap();
        (
            st,
            serde_json::from_str(&text).unwrap_or(Value::String(text)),
        )
    }

    pub async fn get(&self, path: &str) -> (StatusCode, Value) {
        let r = self
            .auth(self.client.get(format!("{}{path}", self.url)))
            .send()
            .await
            .unwrap();
        let st = r.status();
        let text = r.text().await.unwrap();
        (
            st,
            serde_json::from_str(&text).unwrap_or(Value::String(text)),
        )
    }

    pub async fn get_text(&self, path: &str) -> (StatusCode, String) {
        let r = self
            .auth(self.client.get(format!("{}{path}", self.url)))
            .send()
            .await
            .unwrap();
        (r.status(), r.text().await.unwrap())
    }

    pub async fn submit(&self, body: &Value) -> String {
        let (st, v) = self.post(E::Submit.path(), body).await;
        assert_eq!(st, StatusCode::CREATED, "{v}");
        v["id"].as_str().unwrap().to_string()
    }

    pub async fn status(&self, id: &str) -> SearchStatus {
        let (st, v) = self.get(&E::SearchStatus.path_of(id)).await;
        assert_eq!(st, StatusCode::OK, "{v}");
        serde_json::from_value(v).unwrap()
    }

    pub async fn lease(&self, worker: &str) -> Option<Lease> {
        let (st, v) = self.post(E::Lease.path(), &json!({"worker": worker})).await;
        match st {
            StatusCode::OK => Some(serde_json::from_value(v).unwrap()),
            StatusCode::NO_CONTENT => None,
            other => panic!("lease: {other} {v}"),
        }
    }

    pub async fn heartbeat(&self, job: i64, token: &str, progress: Value) -> (StatusCode, Value) {
        self.post(
            &E::Heartbeat.path_of(job),
            &json!({"lease_token": token, "progress": progress}),
        )
        .await
    }

    pub async fn upload(&self, job: i64, token: &str, out: &JobOutput) -> (StatusCode, Value) {
        self.post(
            &E::Result.path_of(job),
            &json!({"lease_token": token, "output": out}),
        )
        .await
    }

    pub async fn fail(&self, job: i64, token: &str, error: &str) -> (StatusCode, Value) {
        self.post(
            &E::Fail.path_of(job),
            &json!({"lease_token": token, "error": error}),
        )
        .await
    }

    pub async fn release(&self, job: i64, token: &str) -> (StatusCode, Value) {
        self.post(&E::Release.path_of(job), &json!({"lease_token": token}))
            .await
    }

    pub async fn cancel(&self, id: &str) -> (StatusCode, Value) {
        self.post(&E::Cancel.path_of(id), &json!({})).await
    }

    pub async fn results(&self, id: &str) -> Value {
        let (st, v) = self.get(&E::Results.path_of(id)).await;
        assert_eq!(st, StatusCode::OK, "{v}");
        v
    }

    /// Stops the server (the database file stays).
    pub async fn stop(&mut self) {
        if let Some(r) = self.running.take() {
            r.shutdown().await.unwrap();
        }
    }

    /// Restarts on the same database file (new port).
    pub async fn restart(&mut self) {
        self.stop().await;
        let token = self.token.clone();
        let running = support::restart(self.dir.path(), |cfg| {
            cfg.token = token;
            cfg.sweep_interval = SWEEP;
        })
        .await
        .unwrap();
        self.url = running.url();
        self.running = Some(running);
    }

    /// Leases and completes every queued job with `out`; returns the job ids.
    pub async fn drain(&self, out: &JobOutput) -> Vec<i64> {
        let mut ids = Vec::new();
        while let Some(l) = self.lease("w").await {
            let (st, v) = self.upload(l.job_id, &l.lease_token, out).await;
            assert_eq!(st, StatusCode::OK, "{v}");
            ids.push(l.job_id);
        }
        ids
    }

    /// Waits until the search's final document is cached.
    pub async fn wait_final(&self, id: &str) -> Value {
        for _ in 0..100 {
            let v = self.results(id).await;
            if v["partial"] == json!(false) {
                return v;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        panic!("search {id} did not complete");
    }
}
