//! End-to-end tests of the distributed grid: the real coordinator (in
//! process, or the `irlgrid coordinator` binary when it must be killed),
//! real workers running real (tiny) training and sampling, and the CLI.

use std::collections::HashSet;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use serde_json::{json, Value};
use shared::analysis::{build_report, ReportOptions, ResultDocument, WeightInput};
use shared::api::routes::Endpoint as E;
use shared::api::{JobInfo, JobOutput, JobState, SearchState, SearchStatus};
use tokio::sync::watch;
use worker::{JobBody, JobError, WorkerConfig};

const BIN: &str = env!("CARGO_BIN_EXE_irlgrid");

/// A search small enough to train and sample in about a second per job.
fn tiny_search(w1: &[f64], trials: u32) -> Value {
    json!({
        "name": "e2e",
        "reward_grid": {"w1": w1},
        "trials": trials,
        "seed": 11,
        "training": {"env_steps": 4096, "n_envs": 16, "n_steps": 64, "minibatch_size": 256, "epochs": 2},
        "sampling": {"successful_episodes": 2, "top_k": 2, "max_attempts": 48, "n_envs": 8}
    })
}

fn worker_cfg(url: &str, name: &str, jobs: usize, spool: &Path) -> WorkerConfig {
    let mut c = WorkerConfig::new(url);
    c.name = name.into();
    c.jobs = jobs;
    c.spool_dir = spool.to_path_buf();
    c.lease_wait_secs = 1;
    c.backoff_base = Duration::from_millis(50);
    c.backoff_max = Duration::from_millis(500);
    c.progress_every = Duration::from_millis(200);
    c.shutdown_grace = Duration::from_secs(2);
    c
}

async fn get(url: &str) -> Value {
    reqwest::get(url).await.unwrap().json().await.unwrap()
}

async fn submit(url: &str, body: &Value) -> String {
    let r = reqwest::Client::new()
        .post(format!("{url}{}", E::Submit.path()))
        .json(body)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 201);
    r.json::<Value>().await.unwrap()["id"]
        .as_str()
        .unwrap()
        .to_string()
}

async fn wait_done(url: &str, id: &str, limit: Duration) -> SearchStatus {
    let t0 = Instant::now();
    loop {
        if let Ok(r) = reqwest::get(format!("{url}{}", E::SearchStatus.path_of(id))).await {
            if let Ok(s) = r.json::<SearchStatus>().await {
                if s.status != SearchState::Running {
                    return s;
                }
            }
        }
        assert!(t0.elapsed() < limit, "search {id} not done after {limit:?}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// The served document's weights equal `build_report` on the served inputs.
async fn assert_consistent(url: &str, id: &str) -> Value {
    let doc = get(&format!("{url}{}", E::Results.path_of(id))).await;
    let inputs: Vec<WeightInput> =
        serde_json::from_value(get(&format!("{url}{}", E::Outputs.path_of(id))).await).unwrap();
    let local = build_report(&inputs, &[], &ReportOptions::default());
    let served: ResultDocument = serde_json::from_value(doc.clone()).unwrap();
    assert_eq!(served.weights, local.weights);
    assert!(!doc.to_string().contains("NaN"));
    doc
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_workers_finish_a_tiny_grid_each_job_exactly_once() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = coordinator::CoordinatorConfig::new(
        "127.0.0.1:0".parse().unwrap(),
        dir.path().join("c.db"),
    );
    cfg.sweep_interval = Duration::from_millis(200);
    let app = coordinator::start(cfg).await.unwrap();
    let url = app.url();
    let id = submit(&url, &tiny_search(&[1.0, 8.0], 2)).await;
    let (stop, stopped) = watch::channel(false);
    let w1 = tokio::spawn(worker::run(
        worker_cfg(&url, "a", 1, dir.path()),
        stopped.clone(),
    ));
    let w2 = tokio::spawn(worker::run(worker_cfg(&url, "b", 1, dir.path()), stopped));
    let s = wait_done(&url, &id, Duration::from_secs(120)).await;
    stop.send(true).unwrap();
    let (a, b) = (w1.await.unwrap().unwrap(), w2.await.unwrap().unwrap());
    assert_eq!(s.status, SearchState::Completed);
    assert_eq!((s.jobs.done, s.jobs.total), (4, 4));
    let accepted = a.accepted.load(Ordering::Relaxed) + b.accepted.load(Ordering::Relaxed);
    assert_eq!(accepted, 4);
    let jobs: Vec<JobInfo> =
        serde_json::from_value(get(&format!("{url}{}", E::SearchJobs.path_of(&id))).await).unwrap();
    assert!(
        jobs.iter().all(|j| j.lease_count == 1 && j.attempts == 0),
        "{jobs:?}"
    );
    let owners: HashSet<_> = jobs.iter().filter_map(|j| j.worker.clone()).collect();
    assert_eq!(owners.len(), 2, "both workers took jobs: {owners:?}");
    // Learning curves arrived by heartbeat.
    let d = get(&format!("{url}{}", E::JobDetail.path_of(jobs[0].id))).await;
    assert!(!d["curve"].as_array().unwrap().is_empty(), "{d}");
    let doc = assert_consistent(&url, &id).await;
    assert_eq!(doc["partial"], false);
    let done: u64 = doc["weights"]
        .as_array()
        .unwrap()
        .iter()
        .map(|w| w["trials_done"].as_u64().unwrap())
        .sum();
    assert_eq!(done, 4);
    // Each trial's seed is the documented derivation.
    for w in doc["weights"].as_array().unwrap() {
        let params = serde_json::from_value(w["params"].clone()).unwrap();
        for t in w["trials"].as_array().unwrap() {
            let trial = t["trial"].as_u64().unwrap() as u32;
            assert_eq!(
                t["seed"].as_u64().unwrap(),
                shared::api::job_seed(11, &params, trial)
            );
        }
    }
    app.shutdown().await.unwrap();
}

/// A body that sleeps and returns an empty output (no successful episode),
/// counting its runs.
fn fake_body(ms: u64, runs: Arc<AtomicU32>) -> JobBody {
    Arc::new(move |spec, hooks| {
        runs.fetch_add(1, Ordering::Relaxed);
        let t0 = Instant::now();
        while t0.elapsed() < Duration::from_millis(ms) {
            if hooks.cancelled() {
                return Err(JobError::Cancelled);
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        Ok(JobOutput {
            final_success_rate: 0.0,
            env_steps: 1,
            successes_found: 0,
            successes_wanted: spec.sampling.successful_episodes,
            sampling_attempts: 1,
            ..JobOutput::default()
        })
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_worker_loses_its_job_and_its_late_upload_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = coordinator::CoordinatorConfig::new(
        "127.0.0.1:0".parse().unwrap(),
        dir.path().join("c.db"),
    );
    cfg.lease_secs = 1;
    cfg.sweep_interval = Duration::from_millis(100);
    let app = coordinator::start(cfg).await.unwrap();
    let url = app.url();
    let id = submit(&url, &tiny_search(&[1.0, 2.0], 1)).await;
    let http = reqwest::Client::new();
    // A "worker" that leases and then goes silent.
    let lease: Value = http
        .post(format!("{url}{}", E::Lease.path()))
        .json(&json!({"worker": "silent"}))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(1300)).await;
    let runs = Arc::new(AtomicU32::new(0));
    let (stop, stopped) = watch::channel(false);
    let w = tokio::spawn(worker::run_with(
        worker_cfg(&url, "live", 1, dir.path()),
        stopped,
        fake_body(50, runs.clone()),
    ));
    let s = wait_done(&url, &id, Duration::from_secs(30)).await;
    stop.send(true).unwrap();
    w.await.unwrap().unwrap();
    assert_eq!((s.jobs.done, s.jobs.total), (2, 2));
    assert_eq!(runs.load(Ordering::Relaxed), 2);
    let late = http
        .post(format!("{url}{}", E::Result.path_of(&lease["job_id"])))
        .json(&json!({"lease_token": lease["lease_token"], "output": {
            "final_success_rate": 1.0, "env_steps": 1, "successes_found": 0,
            "successes_wanted": 2, "sampling_attempts": 1, "episodes": []}}))
        .send()
        .await
        .unwrap();
    assert_eq!(late.status(), 409);
    let doc = assert_consistent(&url, &id).await;
    for w in doc["weights"].as_array().unwrap() {
        assert_eq!(w["trials_done"], 1);
        assert_eq!(w["trials"][0]["final_success_rate"], 0.0);
    }
    let jobs: Vec<JobInfo> =
        serde_json::from_value(get(&format!("{url}{}", E::SearchJobs.path_of(&id))).await).unwrap();
    let retried: Vec<_> = jobs.iter().filter(|j| j.lease_count == 2).collect();
    assert_eq!(retried.len(), 1);
    assert_eq!(retried[0].attempts, 1);
    app.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_releases_unfinished_leases() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = coordinator::CoordinatorConfig::new(
        "127.0.0.1:0".parse().unwrap(),
        dir.path().join("c.db"),
    );
    let app = coordinator::start(cfg).await.unwrap();
    let url = app.url();
    let id = submit(&url, &tiny_search(&[1.0, 2.0, 4.0], 1)).await;
    let runs = Arc::new(AtomicU32::new(0));
    let (stop, stopped) = watch::channel(false);
    let w = tokio::spawn(worker::run_with(
        worker_cfg(&url, "w", 2, dir.path()),
        stopped,
        fake_body(60_000, runs.clone()),
    ));
    let t0 = Instant::now();
    while runs.load(Ordering::Relaxed) < 2 {
        assert!(t0.elapsed() < Duration::from_secs(10));
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    stop.send(true).unwrap();
    let stats = tokio::time::timeout(Duration::from_secs(10), w)
        .await
        .expect("worker exits promptly")
        .unwrap()
        .unwrap();
    assert_eq!(stats.released.load(Ordering::Relaxed), 2);
    let s: SearchStatus =
        serde_json::from_value(get(&format!("{url}{}", E::SearchStatus.path_of(&id))).await)
            .unwrap();
    assert_eq!((s.jobs.queued, s.jobs.leased), (3, 0));
    let jobs: Vec<JobInfo> =
        serde_json::from_value(get(&format!("{url}{}", E::SearchJobs.path_of(&id))).await).unwrap();
    assert!(jobs.iter().all(|j| j.attempts == 0));
    app.shutdown().await.unwrap();
}

struct Proc(Child);
impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn spawn_coordinator(db: &Path, port: u16) -> Proc {
    Proc(
        Command::new(BIN)
            .args([
                "coordinator",
                "--bind",
                &format!("127.0.0.1:{port}"),
                "--db",
            ])
            .arg(db)
            .env("RUST_LOG", "warn")
            .env_remove("IRLGRID_TOKEN")
            .env_remove("IRLGRID_WORKER_TOKEN")
            .env_remove("IRLGRID_READ_TOKEN")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    )
}

async fn wait_healthy(url: &str) {
    let t0 = Instant::now();
    while reqwest::get(format!("{url}/healthz")).await.is_err() {
        assert!(
            t0.elapsed() < Duration::from_secs(20),
            "coordinator did not start"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn cli(args: &[&str], url: &str) -> String {
    let out = Command::new(BIN)
        .args(args)
        .env("IRLGRID_COORDINATOR", url)
        .env_remove("IRLGRID_TOKEN")
        .env_remove("IRLGRID_WORKER_TOKEN")
        .env_remove("IRLGRID_READ_TOKEN")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn killed_coordinator_restarts_on_the_same_file_and_the_search_completes() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("grid.db");
    let port = free_port();
    let url = format!("http://127.0.0.1:{port}");
    let mut coord = spawn_coordinator(&db, port);
    wait_healthy(&url).await;
    let file = dir.path().join("search.json");
    std::fs::write(&file, tiny_search(&[1.0, 2.0, 4.0, 8.0], 2).to_string()).unwrap();
    let id = cli(&["submit", file.to_str().unwrap()], &url)
        .trim()
        .to_string();
    let runs = Arc::new(AtomicU32::new(0));
    let (stop, stopped) = watch::channel(false);
    let w = tokio::spawn(worker::run_with(
        worker_cfg(&url, "w", 2, &dir.path().join("spool")),
        stopped,
        fake_body(300, runs.clone()),
    ));
    // Kill -9 mid-search, stay down for a while, restart on the same file.
    let t0 = Instant::now();
    while runs.load(Ordering::Relaxed) < 3 {
        assert!(t0.elapsed() < Duration::from_secs(20));
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    coord.0.kill().unwrap();
    coord.0.wait().unwrap();
    tokio::time::sleep(Duration::from_millis(800)).await;
    let _coord = spawn_coordinator(&db, port);
    wait_healthy(&url).await;
    let s = wait_done(&url, &id, Duration::from_secs(60)).await;
    stop.send(true).unwrap();
    w.await.unwrap().unwrap();
    assert_eq!(s.status, SearchState::Completed);
    assert_eq!((s.jobs.done, s.jobs.total), (8, 8));
    let jobs: Vec<JobInfo> =
        serde_json::from_value(get(&format!("{url}{}", E::SearchJobs.path_of(&id))).await).unwrap();
    assert_eq!(jobs.len(), 8);
    // Results finished while the coordinator was down were kept and
    // re-uploaded under their original lease: nothing ran twice.
    assert_eq!(runs.load(Ordering::Relaxed), 8);
    assert!(jobs.iter().all(|j| j.lease_count == 1), "{jobs:?}");
    let doc = assert_consistent(&url, &id).await;
    assert_eq!(doc["jobs"]["done"], 8);
    // The CLI reads the same results.
    let status = cli(&["status", &id], &url);
    assert!(
        status.contains("completed") && status.contains("8/8 done"),
        "{status}"
    );
    let csv = cli(&["results", &id, "--csv"], &url);
    assert!(csv.starts_with("section,subject,param_value"), "{csv}");
    let json: Value = serde_json::from_str(&cli(&["results", &id], &url)).unwrap();
    assert_eq!(json["weights"], doc["weights"]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigterm_hands_the_running_job_back_unused_and_the_worker_exits_in_its_grace() {
    // What Slurm (time limit, scancel) and Kubernetes (pod deletion) do to a
    // worker: SIGTERM, then a kill after their grace period.
    let dir = tempfile::tempdir().unwrap();
    let cfg = coordinator::CoordinatorConfig::new(
        "127.0.0.1:0".parse().unwrap(),
        dir.path().join("c.db"),
    );
    let app = coordinator::start(cfg).await.unwrap();
    let url = app.url();
    let mut body = tiny_search(&[1.0], 1);
    // Long enough to be mid-training when the signal comes.
    body["training"]["env_steps"] = json!(50_000_000);
    let id = submit(&url, &body).await;
    let mut w = Proc(
        Command::new(BIN)
            .args(["worker", "--coordinator", &url, "--jobs", "1"])
            .args(["--shutdown-grace", "3", "--name", "sigterm"])
            .arg("--spool-dir")
            .arg(dir.path().join("spool"))
            .env("RUST_LOG", "warn")
            .env_remove("IRLGRID_TOKEN")
            .env_remove("IRLGRID_TOKEN_FILE")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let t0 = Instant::now();
    loop {
        let jobs: Vec<JobInfo> =
            serde_json::from_value(get(&format!("{url}{}", E::SearchJobs.path_of(&id))).await)
                .unwrap();
        if jobs[0].progress.is_some() {
            break;
        }
        assert!(t0.elapsed() < Duration::from_secs(20), "{jobs:?}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let killed = Command::new("kill")
        .args(["-TERM", &w.0.id().to_string()])
        .status()
        .unwrap();
    assert!(killed.success());
    let t1 = Instant::now();
    let code = loop {
        if let Some(st) = w.0.try_wait().unwrap() {
            break st;
        }
        assert!(
            t1.elapsed() < Duration::from_secs(4),
            "still running after its grace"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    assert!(code.success(), "{code:?}");
    let jobs: Vec<JobInfo> =
        serde_json::from_value(get(&format!("{url}{}", E::SearchJobs.path_of(&id))).await).unwrap();
    let j = &jobs[0];
    assert_eq!(
        (j.status, j.attempts, j.lease_count),
        (JobState::Queued, 0, 1),
        "{j:?}"
    );
    app.shutdown().await.unwrap();
}
