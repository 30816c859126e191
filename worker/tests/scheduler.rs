//! The worker under a batch scheduler, against the real coordinator in
//! process and a fake job body: it exits when the queue stays empty, after
//! a set number of jobs, and on shutdown within its grace with every
//! running job handed back unused; started before its coordinator, it waits
//! and says where it is trying.

use std::io::Write;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde_json::{json, Value};
use shared::api::routes::Endpoint as E;
use shared::api::{JobInfo, JobOutput, SearchState, SearchStatus};
use tokio::sync::watch;
use worker::{JobBody, JobError, WorkerConfig};

fn search(w1: &[f64], trials: u32) -> Value {
    json!({
        "name": "sched",
        "reward_grid": {"w1": w1},
        "trials": trials,
        "seed": 3,
        "max_attempts": 2,
        "training": {"env_steps": 4096, "n_envs": 16, "n_steps": 64, "minibatch_size": 256, "epochs": 2},
        "sampling": {"successful_episodes": 2, "top_k": 2, "max_attempts": 48, "n_envs": 8}
    })
}

fn cfg(url: &str, name: &str, jobs: usize, spool: &Path) -> WorkerConfig {
    let mut c = WorkerConfig::new(url);
    c.name = name.into();
    c.jobs = jobs;
    c.spool_dir = spool.join(name);
    c.lease_wait_secs = 1;
    c.backoff_base = Duration::from_millis(50);
    c.backoff_max = Duration::from_millis(400);
    c.progress_every = Duration::from_millis(200);
    c.shutdown_grace = Duration::from_secs(2);
    c
}

/// Sleeps `ms` (stopping on cancel unless `ignore_cancel`) and returns an
/// empty output; counts its runs.
fn fake_body(ms: u64, ignore_cancel: bool, runs: Arc<AtomicU32>) -> JobBody {
    Arc::new(move |spec, hooks| {
        runs.fetch_add(1, Ordering::Relaxed);
        let t0 = Instant::now();
        while t0.elapsed() < Duration::from_millis(ms) {
            if hooks.cancelled() && !ignore_cancel {
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

async fn start(dir: &Path) -> coordinator::Running {
    let mut c =
        coordinator::CoordinatorConfig::new("127.0.0.1:0".parse().unwrap(), dir.join("c.db"));
    c.sweep_interval = Duration::from_millis(200);
    coordinator::start(c).await.unwrap()
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

async fn status(url: &str, id: &str) -> SearchStatus {
    reqwest::get(format!("{url}{}", E::SearchStatus.path_of(id)))
        .await
        .unwrap()
        .json()
        .await
        .unwrap()
}

async fn jobs(url: &str, id: &str) -> Vec<JobInfo> {
    reqwest::get(format!("{url}{}", E::SearchJobs.path_of(id)))
        .await
        .unwrap()
        .json()
        .await
        .unwrap()
}

/// Every job of the search is done, exactly once, without a lost attempt.
async fn assert_each_job_done_once(url: &str, id: &str, want: u64) {
    let s = status(url, id).await;
    assert_eq!(s.status, SearchState::Completed);
    assert_eq!((s.jobs.done, s.jobs.total, s.jobs.failed), (want, want, 0));
    let js = jobs(url, id).await;
    assert!(js.iter().all(|j| j.attempts == 0), "{js:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn exit_when_idle_returns_once_the_grid_is_done() {
    let dir = tempfile::tempdir().unwrap();
    let app = start(dir.path()).await;
    let url = app.url();
    let id = submit(&url, &search(&[1.0, 2.0], 2)).await;
    let runs = Arc::new(AtomicU32::new(0));
    let mut c = cfg(&url, "idle", 2, dir.path());
    c.exit_when_idle = Some(Duration::from_secs(2));
    // Never signalled: the worker must end on its own.
    let (_keep, never) = watch::channel(false);
    let t0 = Instant::now();
    let stats = tokio::time::timeout(
        Duration::from_secs(30),
        worker::run_with(c, never, fake_body(100, false, runs.clone())),
    )
    .await
    .expect("an idle worker exits")
    .unwrap();
    assert_eq!(stats.accepted.load(Ordering::Relaxed), 4);
    assert!(t0.elapsed() >= Duration::from_secs(2));
    assert_each_job_done_once(&url, &id, 4).await;
    app.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_idle_worker_with_nothing_to_do_exits_after_its_idle_time() {
    let dir = tempfile::tempdir().unwrap();
    let app = start(dir.path()).await;
    let mut c = cfg(&app.url(), "empty", 1, dir.path());
    c.exit_when_idle = Some(Duration::from_secs(1));
    let (_keep, never) = watch::channel(false);
    let t0 = Instant::now();
    let stats = tokio::time::timeout(
        Duration::from_secs(15),
        worker::run_with(c, never, fake_body(10, false, Arc::default())),
    )
    .await
    .expect("an idle worker exits")
    .unwrap();
    let secs = t0.elapsed().as_secs_f64();
    assert!((1.0..8.0).contains(&secs), "exited after {secs} s");
    assert_eq!(stats.accepted.load(Ordering::Relaxed), 0);
    app.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn max_jobs_stops_after_that_many_jobs_even_with_more_slots() {
    let dir = tempfile::tempdir().unwrap();
    let app = start(dir.path()).await;
    let url = app.url();
    let id = submit(&url, &search(&[1.0, 2.0, 4.0], 2)).await;
    let runs = Arc::new(AtomicU32::new(0));
    let mut c = cfg(&url, "max", 3, dir.path());
    c.max_jobs = Some(2);
    let (_keep, never) = watch::channel(false);
    let stats = tokio::time::timeout(
        Duration::from_secs(30),
        worker::run_with(c, never, fake_body(200, false, runs.clone())),
    )
    .await
    .expect("the worker exits after its jobs")
    .unwrap();
    assert_eq!(stats.accepted.load(Ordering::Relaxed), 2);
    assert_eq!(runs.load(Ordering::Relaxed), 2);
    let s = status(&url, &id).await;
    assert_eq!((s.jobs.done, s.jobs.queued, s.jobs.leased), (2, 4, 0));
    app.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_hands_back_a_job_that_ignores_the_cancel_within_the_grace() {
    let dir = tempfile::tempdir().unwrap();
    let app = start(dir.path()).await;
    let url = app.url();
    let id = submit(&url, &search(&[1.0, 2.0], 1)).await;
    let runs = Arc::new(AtomicU32::new(0));
    let (stop, stopped) = watch::channel(false);
    let w = tokio::spawn(worker::run_with(
        cfg(&url, "stubborn", 2, dir.path()),
        stopped,
        fake_body(30_000, true, runs.clone()),
    ));
    let t0 = Instant::now();
    while runs.load(Ordering::Relaxed) < 2 {
        assert!(t0.elapsed() < Duration::from_secs(10));
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    stop.send(true).unwrap();
    let t1 = Instant::now();
    let stats = tokio::time::timeout(Duration::from_secs(5), w)
        .await
        .expect("the worker exits within its grace")
        .unwrap()
        .unwrap();
    assert!(
        t1.elapsed() <= Duration::from_millis(2500),
        "{:?}",
        t1.elapsed()
    );
    assert_eq!(stats.released.load(Ordering::Relaxed), 2);
    assert_eq!(stats.abandoned.load(Ordering::Relaxed), 2);
    let s = status(&url, &id).await;
    assert_eq!((s.jobs.queued, s.jobs.leased), (2, 0));
    let js = jobs(&url, &id).await;
    assert!(
        js.iter().all(|j| j.attempts == 0 && j.lease_count == 1),
        "{js:?}"
    );
    // Another worker finishes them, each once.
    let (stop2, stopped2) = watch::channel(false);
    let w2 = tokio::spawn(worker::run_with(
        cfg(&url, "next", 2, dir.path()),
        stopped2,
        fake_body(50, false, Arc::default()),
    ));
    let t2 = Instant::now();
    while status(&url, &id).await.status == SearchState::Running {
        assert!(t2.elapsed() < Duration::from_secs(20));
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    stop2.send(true).unwrap();
    let st2 = w2.await.unwrap().unwrap();
    assert_eq!(st2.accepted.load(Ordering::Relaxed), 2);
    assert_each_job_done_once(&url, &id, 2).await;
    app.shutdown().await.unwrap();
}

/// Collects log lines written by the tracing subscriber.
#[derive(Clone, Default)]
struct Captured(Arc<Mutex<Vec<u8>>>);

impl Write for Captured {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(b);
        Ok(b.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

// One thread, so the subscriber set for this test sees the worker's events.
#[tokio::test(flavor = "current_thread")]
async fn a_worker_started_before_its_coordinator_waits_and_names_the_url() {
    let logs = Captured::default();
    let sink = logs.clone();
    let subscriber = tracing_subscriber::fmt()
        .with_writer(move || sink.clone())
        .with_ansi(false)
        .finish();
    let _guard = tracing::subscriber::set_default(subscriber);

    let dir = tempfile::tempdir().unwrap();
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let url = format!("http://127.0.0.1:{port}");
    let mut c = cfg(&url, "early", 1, dir.path());
    c.exit_when_idle = Some(Duration::from_secs(3));
    let (_keep, never) = watch::channel(false);
    let ended = Arc::new(AtomicBool::new(false));
    let w = {
        let ended = ended.clone();
        let body = fake_body(50, false, Arc::default());
        tokio::spawn(async move {
            let r = worker::run_with(c, never, body).await;
            ended.store(true, Ordering::Relaxed);
            r
        })
    };
    tokio::time::sleep(Duration::from_millis(1500)).await;
    assert!(
        !ended.load(Ordering::Relaxed),
        "the worker gave up before the coordinator came"
    );
    let text = String::from_utf8(logs.0.lock().unwrap().clone()).unwrap();
    assert!(
        text.contains("coordinator not reachable; retrying") && text.contains(&url),
        "{text}"
    );
    // The coordinator comes up with work; the worker finds it and does it.
    let mut cc = coordinator::CoordinatorConfig::new(
        format!("127.0.0.1:{port}").parse().unwrap(),
        dir.path().join("c.db"),
    );
    cc.sweep_interval = Duration::from_millis(200);
    let app = coordinator::start(cc).await.unwrap();
    let id = submit(&url, &search(&[1.0], 2)).await;
    let stats = tokio::time::timeout(Duration::from_secs(30), w)
        .await
        .expect("the worker finishes and exits")
        .unwrap()
        .unwrap();
    assert_eq!(stats.accepted.load(Ordering::Relaxed), 2);
    assert_each_job_done_once(&url, &id, 2).await;
    app.shutdown().await.unwrap();
}
