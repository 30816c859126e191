//! Load generator against a coordinator running as a separate
//! process: `--clients` concurrent clients (default 200) for `--secs`
//! seconds. Three in five are simulated workers (lease, two heartbeats
//! with learning-curve points, then a result upload sized like a real one:
//! 10 trajectories of 400 samples; now and then a failure report, a
//! release, or a stale upload that must get 409); the rest read (search
//! list and status, result documents, job lists and details, dashboard
//! pages, metrics, health).
//!
//! It reports throughput, p50/p99 latency per request kind, errors (any
//! 5xx, transport error or unexpected status fails the run) and the
//! coordinator's peak RSS (`VmHWM` of `--pid`); with `--stop` it then
//! stops the coordinator (SIGTERM), waits for it to exit and checks the
//! database (`--db`): `PRAGMA integrity_check`, every done job has exactly
//! one result, no result without a done job, lease columns match the
//! state, job counts add up, and the accepted uploads it counted equal the
//! stored results. `--check-only` does just the database check.
//!
//! `tests/reliability/load.sh` builds and runs it:
//! `load --url http://127.0.0.1:PORT [--token T] --pid PID --db FILE --stop`.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, ensure, Context};
use rand::{Rng, SeedableRng};
use reqwest::StatusCode;
use serde_json::{json, Value};

#[path = "../tests/support/mod.rs"]
mod support;
use shared::api::routes::Endpoint as E;
use support::{percentile, realistic_output, sorted};

/// Successes each load search asks for (and trajectories per upload).
const WANTED: u32 = 10;
/// Samples per uploaded trajectory.
const POINTS: usize = 400;

#[derive(Debug, Clone)]
struct Args {
    url: String,
    token: Option<String>,
    secs: u64,
    clients: usize,
    pid: Option<u32>,
    db: Option<String>,
    stop: bool,
    check_only: bool,
    json_out: Option<String>,
    /// Scale mode: `workers` simulated workers at a real worker's cadence
    /// and `readers` polling readers, instead of `clients`.
    scale: bool,
    workers: usize,
    readers: usize,
    /// A simulated job's length, uniform in this range (s).
    job_secs: (f64, f64),
    /// A polling reader's pause between requests (ms).
    reader_pause_ms: u64,
}

fn args() -> anyhow::Result<Args> {
    let mut a = Args {
        url: "http://127.0.0.1:8080".into(),
        token: std::env::var("IRLGRID_TOKEN")
            .ok()
            .filter(|t| !t.is_empty()),
        secs: 30,
        clients: 200,
        pid: None,
        db: None,
        stop: false,
        check_only: false,
        json_out: None,
        scale: false,
        workers: 1000,
        readers: 50,
        job_secs: (20.0, 50.0),
        reader_pause_ms: 1000,
    };
    let mut it = std::env::args().skip(1);
    while let Some(k) = it.next() {
        let mut v = || it.next().with_context(|| format!("{k} needs a value"));
        match k.as_str() {
            "--url" => a.url = v()?,
            "--token" => a.token = Some(v()?),
            "--secs" => a.secs = v()?.parse()?,
            "--clients" => a.clients = v()?.parse()?,
            "--pid" => a.pid = Some(v()?.parse()?),
            "--db" => a.db = Some(v()?),
            "--json" => a.json_out = Some(v()?),
            "--stop" => a.stop = true,
            "--check-only" => a.check_only = true,
            "--scale" => a.scale = true,
            "--workers" => a.workers = v()?.parse()?,
            "--readers" => a.readers = v()?.parse()?,
            "--reader-pause-ms" => a.reader_pause_ms = v()?.parse()?,
            "--job-secs" => {
                let text = v()?;
                let (lo, hi) = text.split_once(':').context("--job-secs LO:HI")?;
                a.job_secs = (lo.parse()?, hi.parse()?);
                ensure!(
                    a.job_secs.0 > 0.0 && a.job_secs.0 <= a.job_secs.1,
                    "--job-secs: need 0 < LO <= HI"
                );
            }
            other => bail!("unknown argument {other}"),
        }
    }
    Ok(a)
}

/// Request kinds, in report order.
const KINDS: &[&str] = &[
    "lease",
    "heartbeat",
    "upload",
    "upload_stale",
    "fail",
    "release",
    "searches",
    "status",
    "results",
    "jobs",
    "job",
    "dashboard_index",
    "dashboard_search",
    "metrics",
    "healthz",
];

#[derive(Default)]
struct Tally {
    lat_ms: BTreeMap<&'static str, Vec<f64>>,
    status_5xx: u64,
    transport: u64,
    unexpected: Vec<String>,
    accepted_uploads: u64,
}

impl Tally {
    fn merge(&mut self, o: Tally) {
        for (k, v) in o.lat_ms {
            self.lat_ms.entry(k).or_default().extend(v);
        }
        self.status_5xx += o.status_5xx;
        self.transport += o.transport;
        self.unexpected.extend(o.unexpected);
        self.accepted_uploads += o.accepted_uploads;
    }
}

struct Client {
    http: reqwest::Client,
    url: String,
    token: Option<String>,
    cookie: Option<String>,
    tally: Tally,
}

impl Client {
    /// One request; records its latency under `kind` and classifies the
    /// answer. Returns the status and body when the status is expected.
    /// Uploads `output` for `job` under `token`, counting it when accepted.
    async fn upload(&mut self, job: i64, token: &str, output: &Value) {
        let body = json!({"lease_token": token, "output": output});
        let path = E::Result.path_of(job);
        if self
            .call("upload", reqwest::Method::POST, &path, Some(&body), &[200])
            .await
            .is_some()
        {
            self.tally.accepted_uploads += 1;
        }
    }

    async fn call(
        &mut self,
        kind: &'static str,
        method: reqwest::Method,
        path: &str,
        body: Option<&Value>,
        expect: &[u16],
    ) -> Option<(StatusCode, Vec<u8>)> {
        let mut r = self.http.request(method, format!("{}{path}", self.url));
        if let Some(t) = &self.token {
            r = r.bearer_auth(t);
        }
        if let Some(c) = &self.cookie {
            r = r.header("cookie", c);
        }
        if let Some(b) = body {
            r = r.json(b);
        }
        let t = Instant::now();
        let res = match r.send().await {
            Ok(res) => res,
            Err(e) => {
                self.tally.transport += 1;
                self.tally.unexpected.push(format!("{kind} {path}: {e}"));
                return None;
            }
        };
        let st = res.status();
        let bytes = match res.bytes().await {
            Ok(b) => b,
            Err(e) => {
                self.tally.transport += 1;
                self.tally
                    .unexpected
                    .push(format!("{kind} {path}: body: {e}"));
                return None;
            }
        };
        self.tally
            .lat_ms
            .entry(kind)
            .or_default()
            .push(t.elapsed().as_secs_f64() * 1e3);
        if st.is_server_error() {
            self.tally.status_5xx += 1;
        }
        if !expect.contains(&st.as_u16()) {
            let text = String::from_utf8_lossy(&bytes[..bytes.len().min(300)]).into_owned();
            self.tally
                .unexpected
                .push(format!("{kind} {path}: {st} {text}"));
            return None;
        }
        // Only lease answers are read further; skip copying big bodies.
        let keep = if kind == "lease" {
            bytes.to_vec()
        } else {
            Vec::new()
        };
        Some((st, keep))
    }
}

/// A simulated worker: lease, two heartbeats, then upload (or fail,
/// release, or try a stale token first).
async fn worker_loop(mut c: Client, id: usize, stop: Arc<AtomicBool>) -> Tally {
    let mut rng = rand::rngs::StdRng::seed_from_u64(id as u64);
    let name = format!("load-{id}");
    let post = reqwest::Method::POST;
    while !stop.load(Ordering::Relaxed) {
        let Some((st, body)) = c
            .call(
                "lease",
                post.clone(),
                E::Lease.path(),
                Some(&json!({"worker": name})),
                &[200, 204],
            )
            .await
        else {
            tokio::time::sleep(Duration::from_millis(50)).await;
            continue;
        };
        if st == StatusCode::NO_CONTENT {
            tokio::time::sleep(Duration::from_millis(100)).await;
            continue;
        }
        let Ok(lease) = serde_json::from_slice::<Value>(&body) else {
            c.tally.unexpected.push("lease: unreadable body".into());
            continue;
        };
        let job = lease["job_id"].as_i64().unwrap_or(-1);
        let token = lease["lease_token"].as_str().unwrap_or("").to_string();
        for h in 0..2u64 {
            let progress: Vec<Value> = (0..5u64)
                .map(|k| {
                    let steps = (h * 5 + k + 1) * 100;
                    json!({"env_steps": steps, "total_env_steps": 1000, "mean_return": 10.0 * k as f64,
                           "success_rate": 0.1 * k as f64, "mean_episode_length": 100.0,
                           "policy_loss": 0.01, "value_loss": 0.5, "entropy": 1.2, "approx_kl": 0.001})
                })
                .collect();
            let phase = if h == 0 { "training" } else { "sampling" };
            c.call(
                "heartbeat",
                post.clone(),
                &E::Heartbeat.path_of(job),
                Some(&json!({"lease_token": token, "phase": phase, "progress": progress})),
                &[200],
            )
            .await;
        }
        let roll: f64 = rng.gen();
        if roll < 0.03 {
            c.call(
                "fail",
                post.clone(),
                &E::Fail.path_of(job),
                Some(&json!({"lease_token": token, "error": "simulated failure"})),
                &[200],
            )
            .await;
            continue;
        }
        if roll < 0.06 {
            c.call(
                "release",
                post.clone(),
                &E::Release.path_of(job),
                Some(&json!({"lease_token": token})),
                &[200],
            )
            .await;
            continue;
        }
        let output = realistic_output(WANTED as usize, POINTS, WANTED, job as u64);
        if roll < 0.10 {
            // A stale or forged token: refused, nothing changes.
            c.call(
                "upload_stale",
                post.clone(),
                &E::Result.path_of(job),
                Some(&json!({"lease_token": format!("{token}ff"), "output": output})),
                &[409],
            )
            .await;
        }
        c.upload(job, &token, &output).await;
    }
    c.tally
}

/// A reader: the API's and the dashboard's GETs, weighted.
async fn reader_loop(
    mut c: Client,
    id: usize,
    searches: Arc<Vec<String>>,
    stop: Arc<AtomicBool>,
) -> Tally {
    let mut rng = rand::rngs::StdRng::seed_from_u64(1_000_000 + id as u64);
    let get = reqwest::Method::GET;
    while !stop.load(Ordering::Relaxed) {
        let s = &searches[rng.gen_range(0..searches.len())];
        let job = rng.gen_range(1..=2000);
        let (kind, path): (&'static str, String) = match rng.gen_range(0..100) {
            0..=14 => ("status", E::SearchStatus.path_of(s)),
            15..=24 => ("searches", E::ListSearches.path().into()),
            25..=34 => ("results", E::Results.path_of(s)),
            35..=37 => ("jobs", E::SearchJobs.path_of(s)),
            38..=51 => ("job", E::JobDetail.path_of(job)),
            52..=61 => ("dashboard_index", "/".into()),
            62..=74 => ("dashboard_search", format!("/searches/{s}")),
            75..=89 => ("metrics", "/metrics".into()),
            _ => ("healthz", "/healthz".into()),
        };
        c.call(kind, get.clone(), &path, None, &[200]).await;
    }
    c.tally
}

/// Sleeps `d`, waking early (false) when the run stops.
async fn nap(d: Duration, stop: &AtomicBool) -> bool {
    let end = Instant::now() + d;
    loop {
        if stop.load(Ordering::Relaxed) {
            return false;
        }
        let left = end.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return true;
        }
        tokio::time::sleep(left.min(Duration::from_millis(500))).await;
    }
}

/// A worker at a real worker's cadence (scale mode): starts at a random
/// moment of the first `stagger`, leases, heartbeats at the lease's
/// `heartbeat_secs` for a job of `job_secs` (uniform), then uploads one
/// real-sized output; releases its job when the run stops mid-job, as a
/// worker that is shut down does.
async fn scale_worker_loop(
    mut c: Client,
    id: usize,
    stop: Arc<AtomicBool>,
    job_secs: (f64, f64),
    stagger: Duration,
) -> Tally {
    let mut rng = rand::rngs::StdRng::seed_from_u64(id as u64);
    let name = format!("scale-{id}");
    let post = reqwest::Method::POST;
    if !nap(stagger.mul_f64(rng.gen()), &stop).await {
        return c.tally;
    }
    while !stop.load(Ordering::Relaxed) {
        let Some((st, body)) = c
            .call(
                "lease",
                post.clone(),
                E::Lease.path(),
                Some(&json!({"worker": name})),
                &[200, 204],
            )
            .await
        else {
            nap(Duration::from_secs(1), &stop).await;
            continue;
        };
        if st == StatusCode::NO_CONTENT {
            nap(Duration::from_secs(5), &stop).await;
            continue;
        }
        let Ok(lease) = serde_json::from_slice::<Value>(&body) else {
            c.tally.unexpected.push("lease: unreadable body".into());
            continue;
        };
        let job = lease["job_id"].as_i64().unwrap_or(-1);
        let token = lease["lease_token"].as_str().unwrap_or("").to_string();
        let every = Duration::from_secs(lease["heartbeat_secs"].as_u64().unwrap_or(20).max(1));
        let length = Duration::from_secs_f64(rng.gen_range(job_secs.0..=job_secs.1));
        let started = Instant::now();
        let mut beat = 0u64;
        let finished = loop {
            let left = length.saturating_sub(started.elapsed());
            if left.is_zero() {
                break true;
            }
            if !nap(left.min(every), &stop).await {
                break false;
            }
            if started.elapsed() >= length {
                break true;
            }
            beat += 1;
            let progress = json!([{"env_steps": beat * 1000, "total_env_steps": 100_000,
                "mean_return": 10.0 * beat as f64, "success_rate": 0.01 * beat as f64,
                "mean_episode_length": 100.0, "policy_loss": 0.01, "value_loss": 0.5,
                "entropy": 1.2, "approx_kl": 0.001}]);
            c.call(
                "heartbeat",
                post.clone(),
                &E::Heartbeat.path_of(job),
                Some(&json!({"lease_token": token, "phase": "training", "progress": progress})),
                &[200],
            )
            .await;
        };
        if !finished {
            c.call(
                "release",
                post.clone(),
                &E::Release.path_of(job),
                Some(&json!({"lease_token": token})),
                &[200],
            )
            .await;
            break;
        }
        let output = realistic_output(WANTED as usize, POINTS, WANTED, job as u64);
        c.upload(job, &token, &output).await;
    }
    c.tally
}

/// A polling reader (scale mode): result documents and dashboard pages,
/// with a pause between requests, as an open dashboard or a script
/// watching a search does.
async fn scale_reader_loop(
    mut c: Client,
    id: usize,
    searches: Arc<Vec<String>>,
    stop: Arc<AtomicBool>,
    pause: Duration,
) -> Tally {
    let mut rng = rand::rngs::StdRng::seed_from_u64(2_000_000 + id as u64);
    let get = reqwest::Method::GET;
    if !nap(pause.mul_f64(rng.gen()), &stop).await {
        return c.tally;
    }
    while !stop.load(Ordering::Relaxed) {
        let s = &searches[rng.gen_range(0..searches.len())];
        let (kind, path): (&'static str, String) = match rng.gen_range(0..100) {
            0..=34 => ("results", E::Results.path_of(s)),
            35..=64 => ("dashboard_search", format!("/searches/{s}")),
            65..=79 => ("dashboard_index", "/".into()),
            80..=89 => ("status", E::SearchStatus.path_of(s)),
            90..=94 => ("searches", E::ListSearches.path().into()),
            95..=97 => ("metrics", "/metrics".into()),
            _ => ("healthz", "/healthz".into()),
        };
        c.call(kind, get.clone(), &path, None, &[200]).await;
        nap(pause, &stop).await;
    }
    c.tally
}

/// `VmHWM` and `VmRSS` of a process in KiB.
fn memory_kib(pid: u32) -> Option<(u64, u64)> {
    let text = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let field = |name: &str| {
        text.lines()
            .find(|l| l.starts_with(name))
            .and_then(|l| l.split_whitespace().nth(1))
            .and_then(|v| v.parse().ok())
    };
    Some((field("VmHWM:")?, field("VmRSS:")?))
}

/// The database invariants after the run (the coordinator has stopped).
/// Returns the stored result count.
fn check_db(path: &str, expect_results: Option<u64>) -> anyhow::Result<u64> {
    tokio::runtime::Builder::new_current_thread()
        .build()?
        .block_on(check_db_on(path, expect_results))
}

async fn check_db_on(path: &str, expect_results: Option<u64>) -> anyhow::Result<u64> {
    use sqlx::ConnectOptions;
    let mut conn = sqlx::sqlite::SqliteConnectOptions::new()
        .filename(path)
        .read_only(true)
        .connect()
        .await
        .with_context(|| format!("opening {path}"))?;
    let conn = &mut conn;
    // Each check is a count that must come out as the check says.
    async fn scalar(conn: &mut sqlx::SqliteConnection, sql: &'static str) -> anyhow::Result<i64> {
        sqlx::query_scalar(sql)
            .fetch_one(conn)
            .await
            .with_context(|| sql.to_string())
    }
    let integrity: String = sqlx::query_scalar("pragma integrity_check")
        .fetch_one(&mut *conn)
        .await?;
    ensure!(integrity == "ok", "integrity_check: {integrity}");
    let fk: i64 = scalar(conn, "select count(*) from pragma_foreign_key_check").await?;
    ensure!(fk == 0, "{fk} foreign key violations");
    let checks: &[(&str, &str)] = &[
        (
            "done jobs without exactly one result",
            "select count(*) from jobs j where j.status = 'done'
               and (select count(*) from job_results r where r.job_id = j.id) != 1",
        ),
        (
            "results of jobs that are not done (or do not exist)",
            "select count(*) from job_results r left join jobs j on j.id = r.job_id
               where j.id is null or j.status != 'done'",
        ),
        (
            "leased jobs without owner, token or expiry",
            "select count(*) from jobs where status = 'leased'
               and (lease_token is null or lease_expires_at is null or worker_id is null)",
        ),
        (
            "jobs with a lease expiry but not leased (done and leased at once)",
            "select count(*) from jobs where status != 'leased' and lease_expires_at is not null",
        ),
        (
            "jobs with an unknown status",
            "select count(*) from jobs where status not in ('queued','leased','done','failed','cancelled')",
        ),
        (
            "jobs over their attempts",
            "select count(*) from jobs where attempts > max_attempts",
        ),
        (
            "searches whose job count is not points x trials",
            "select count(*) from searches s where s.replace_unconverged = 0 and
               (select count(*) from jobs j where j.search_id = s.id) !=
               (select count(*) from points p where p.search_id = s.id) * s.trials",
        ),
        (
            "completed searches with unfinished jobs",
            "select count(*) from searches s where s.status = 'completed' and exists
               (select 1 from jobs j where j.search_id = s.id and j.status in ('queued','leased'))",
        ),
    ];
    for (what, sql) in checks {
        let n = scalar(conn, sql).await?;
        ensure!(n == 0, "{n} {what}");
    }
    let total = scalar(conn, "select count(*) from jobs").await?;
    let by_state = scalar(
        conn,
        "select sum(n) from (select count(*) as n from jobs group by status)",
    )
    .await?;
    ensure!(
        total == by_state,
        "job counts by state {by_state} != total {total}"
    );
    // Databases with trial summaries (migration 0008): one per result,
    // written with it.
    let summaries: i64 = scalar(
        conn,
        "select count(*) from sqlite_master where type = 'table' and name = 'trial_summaries'",
    )
    .await?;
    if summaries > 0 {
        for (what, sql) in [
            (
                "results without exactly one trial summary",
                "select count(*) from job_results r
                   where (select count(*) from trial_summaries s where s.job_id = r.job_id) != 1",
            ),
            (
                "trial summaries without a result",
                "select count(*) from trial_summaries s left join job_results r
                   on r.job_id = s.job_id where r.job_id is null",
            ),
        ] {
            let n = scalar(conn, sql).await?;
            ensure!(n == 0, "{n} {what}");
        }
    }
    let results = scalar(conn, "select count(*) from job_results").await? as u64;
    let done = scalar(conn, "select count(*) from jobs where status = 'done'").await? as u64;
    ensure!(results == done, "{results} results but {done} done jobs");
    if let Some(want) = expect_results {
        ensure!(
            results == want,
            "{results} results stored but {want} uploads were accepted"
        );
    }
    let bytes = scalar(
        conn,
        "select page_count * page_size from pragma_page_count, pragma_page_size",
    )
    .await?;
    println!(
        "database check: integrity ok; {total} jobs, {done} done with exactly one result each{}, \
         no orphan result, lease columns consistent, counts add up; {:.1} MiB in pages, \
         {:.1} KiB per result",
        if summaries > 0 {
            " and one trial summary each"
        } else {
            ""
        },
        bytes as f64 / 1048576.0,
        if results > 0 {
            bytes as f64 / 1024.0 / results as f64
        } else {
            0.0
        }
    );
    Ok(results)
}

fn main() -> anyhow::Result<()> {
    let a = args()?;
    if a.check_only {
        check_db(a.db.as_deref().context("--check-only needs --db")?, None)?;
        return Ok(());
    }
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    let (tally, elapsed, searches) = rt.block_on(run(&a))?;
    let peak = a.pid.and_then(memory_kib);

    let total: usize = tally.lat_ms.values().map(Vec::len).sum();
    let secs = elapsed.as_secs_f64();
    if a.scale {
        println!(
            "load: scale mode, {} workers (jobs of {}-{} s) and {} readers (pause {} ms) for \
             {secs:.1} s against {} ({} searches)",
            a.workers, a.job_secs.0, a.job_secs.1, a.readers, a.reader_pause_ms, a.url, searches
        );
    } else {
        println!(
            "load: {} clients for {secs:.1} s against {} ({} searches)",
            a.clients, a.url, searches
        );
    }
    println!(
        "{:<18} {:>8} {:>9} {:>9} {:>9} {:>9}",
        "kind", "count", "per s", "p50 ms", "p99 ms", "max ms"
    );
    let mut report = serde_json::Map::new();
    for kind in KINDS {
        let Some(v) = tally.lat_ms.get(kind) else {
            continue;
        };
        let v = sorted(v.clone());
        let (p50, p99, max) = (percentile(&v, 0.5), percentile(&v, 0.99), v[v.len() - 1]);
        println!(
            "{kind:<18} {:>8} {:>9.1} {p50:>9.2} {p99:>9.2} {max:>9.1}",
            v.len(),
            v.len() as f64 / secs
        );
        report.insert(
            kind.to_string(),
            json!({"count": v.len(), "per_s": v.len() as f64 / secs, "p50_ms": p50, "p99_ms": p99, "max_ms": max}),
        );
    }
    let all = sorted(tally.lat_ms.values().flatten().copied().collect());
    println!(
        "{:<18} {total:>8} {:>9.1} {:>9.2} {:>9.2} {:>9.1}",
        "all",
        total as f64 / secs,
        percentile(&all, 0.5),
        percentile(&all, 0.99),
        all.last().copied().unwrap_or(f64::NAN)
    );
    println!(
        "accepted uploads: {} ({:.1}/s, {} trajectories x {POINTS} samples each)",
        tally.accepted_uploads,
        tally.accepted_uploads as f64 / secs,
        WANTED
    );
    println!(
        "errors: {} 5xx, {} transport, {} unexpected statuses",
        tally.status_5xx,
        tally.transport,
        tally.unexpected.len()
    );
    for u in tally.unexpected.iter().take(20) {
        println!("  {u}");
    }
    if let Some((hwm, rss)) = peak {
        println!(
            "coordinator memory: peak RSS (VmHWM) {:.1} MiB, RSS now {:.1} MiB",
            hwm as f64 / 1024.0,
            rss as f64 / 1024.0
        );
    }
    report.insert(
        "summary".into(),
        json!({"clients": a.clients, "scale": a.scale, "workers": a.workers, "readers": a.readers, "secs": secs, "requests": total, "per_s": total as f64 / secs,
               "p50_ms": percentile(&all, 0.5), "p99_ms": percentile(&all, 0.99),
               "accepted_uploads": tally.accepted_uploads, "status_5xx": tally.status_5xx,
               "transport_errors": tally.transport, "unexpected": tally.unexpected.len(),
               "peak_rss_kib": peak.map(|p| p.0)}),
    );
    if a.stop {
        let pid = a.pid.context("--stop needs --pid")?;
        let ok = std::process::Command::new("kill")
            .args(["-TERM", &pid.to_string()])
            .status()?
            .success();
        ensure!(ok, "could not signal the coordinator {pid}");
        let t = Instant::now();
        while std::path::Path::new(&format!("/proc/{pid}")).exists()
            && std::fs::read_to_string(format!("/proc/{pid}/stat"))
                .map(|s| !s.contains(") Z "))
                .unwrap_or(false)
        {
            ensure!(
                t.elapsed() < Duration::from_secs(30),
                "the coordinator did not stop within 30 s"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        println!("coordinator stopped in {:.2} s", t.elapsed().as_secs_f64());
        let db = a.db.as_deref().context("--stop needs --db")?;
        let results = check_db(db, Some(tally.accepted_uploads))?;
        report.insert("stored_results".into(), json!(results));
    }
    if let Some(p) = &a.json_out {
        std::fs::write(p, serde_json::to_string_pretty(&Value::Object(report))?)?;
    }
    ensure!(
        tally.status_5xx == 0 && tally.transport == 0 && tally.unexpected.is_empty(),
        "the load run saw errors"
    );
    ensure!(tally.accepted_uploads > 0, "no upload was accepted");
    Ok(())
}

async fn run(a: &Args) -> anyhow::Result<(Tally, Duration, usize)> {
    let http = reqwest::Client::builder()
        .pool_max_idle_per_host(if a.scale {
            a.workers + a.readers
        } else {
            a.clients
        })
        .timeout(Duration::from_secs(60))
        .build()?;
    let mk = |cookie: Option<String>| Client {
        http: http.clone(),
        url: a.url.trim_end_matches('/').to_string(),
        token: a.token.clone(),
        cookie,
        tally: Tally::default(),
    };
    // Searches: a small one that completes early (its final document is
    // cached) and big ones the workers drain for the whole run.
    let mut setup = mk(None);
    let mut ids = Vec::new();
    let specs: Vec<(usize, u32)> = vec![(4, 2), (64, 100), (64, 100), (64, 100)];
    for (k, (points, trials)) in specs.into_iter().enumerate() {
        let grid: Vec<f64> = (1..=points).map(|i| i as f64 * 0.25).collect();
        let body = json!({
            "name": format!("load {k}"), "reward_grid": {"w1": grid}, "trials": trials, "seed": k,
            "training": {"env_steps": 1000},
            "sampling": {"successful_episodes": WANTED, "top_k": WANTED, "max_attempts": 1000}
        });
        let r = setup.http.post(format!("{}/api/v1/searches", setup.url));
        let r = match &setup.token {
            Some(t) => r.bearer_auth(t),
            None => r,
        };
        let res = r.json(&body).send().await?;
        ensure!(
            res.status() == 201,
            "submitting: {} {}",
            res.status(),
            res.text().await?
        );
        let v: Value = res.json().await?;
        ids.push(v["id"].as_str().context("id")?.to_string());
    }
    setup.tally = Tally::default();
    let cookie = a.token.as_deref().map(|t| {
        format!(
            "{}={}",
            coordinator::dashboard::auth::COOKIE,
            coordinator::dashboard::auth::session_value(t)
        )
    });
    let searches = Arc::new(ids);
    let stop = Arc::new(AtomicBool::new(false));
    let workers = a.clients * 3 / 5;
    let t0 = Instant::now();
    let mut tasks = Vec::new();
    if a.scale {
        // Workers start over the first 10 s, as a cluster's do.
        let stagger = Duration::from_secs(10).min(Duration::from_secs(a.secs) / 2);
        let pause = Duration::from_millis(a.reader_pause_ms);
        for i in 0..a.workers {
            tasks.push(tokio::spawn(scale_worker_loop(
                mk(None),
                i,
                stop.clone(),
                a.job_secs,
                stagger,
            )));
        }
        for i in 0..a.readers {
            tasks.push(tokio::spawn(scale_reader_loop(
                mk(cookie.clone()),
                i,
                searches.clone(),
                stop.clone(),
                pause,
            )));
        }
    }
    for i in 0..if a.scale { 0 } else { a.clients } {
        let stop = stop.clone();
        if i < workers {
            tasks.push(tokio::spawn(worker_loop(mk(None), i, stop)));
        } else {
            tasks.push(tokio::spawn(reader_loop(
                mk(cookie.clone()),
                i,
                searches.clone(),
                stop,
            )));
        }
    }
    tokio::time::sleep(Duration::from_secs(a.secs)).await;
    stop.store(true, Ordering::Relaxed);
    let mut tally = Tally::default();
    for t in tasks {
        tally.merge(t.await?);
    }
    Ok((tally, t0.elapsed(), searches.len()))
}
