//! The worker loop: `jobs` slots, each leasing a job, running its body on a
//! blocking thread while a heartbeat task renews the lease and reports
//! progress, then uploading the output. Finished outputs are spooled to disk
//! before the first upload and re-sent until the coordinator accepts or
//! refuses them, across restarts.
//!
//! A worker stops on a shutdown signal, after `exit_when_idle` without a job
//! or after `max_jobs` jobs. A shutdown stops leasing and cancels running
//! training; within `shutdown_grace` every unfinished lease is handed back
//! (release: the job is queued again without using an attempt), even when a
//! job body does not return in time, and the run returns. A worker started
//! before its coordinator waits for it with backoff, naming the URL.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use irlgrid_client::{CallError, Client};
use serde::{Deserialize, Serialize};
use shared::api::{FailReport, Heartbeat, Lease, ResultUpload};
use tokio::sync::watch;
use tracing::{info_span, Instrument};

use crate::backoff::Backoff;
use crate::config::WorkerConfig;
use crate::job::{run_job, JobBody, JobError, JobHooks};

/// Counts of what a worker did.
#[derive(Debug, Default)]
pub struct RunStats {
    /// Results accepted.
    pub accepted: AtomicU64,
    /// Jobs whose lease was lost (409) and were dropped.
    pub lost: AtomicU64,
    /// Jobs that failed and were reported.
    pub failed: AtomicU64,
    /// Leases released at shutdown.
    pub released: AtomicU64,
    /// Results left in the spool at exit.
    pub spooled: AtomicU64,
    /// Leases handed back because their job did not stop within the grace.
    pub abandoned: AtomicU64,
}

/// A finished result waiting in the spool.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct Spooled {
    coordinator: String,
    job_id: i64,
    upload: ResultUpload,
}

/// How many jobs a worker may still lease (`max_jobs`). A slot reserves a
/// ticket before asking for a job and gives it back when no job came, so
/// concurrent slots never lease more than the limit together.
#[derive(Debug)]
struct JobBudget {
    max: Option<u64>,
    reserved: AtomicU64,
    used: AtomicU64,
}

impl JobBudget {
    fn new(max: Option<u64>) -> Self {
        Self {
            max,
            reserved: AtomicU64::new(0),
            used: AtomicU64::new(0),
        }
    }

    fn try_reserve(&self) -> bool {
        let Some(max) = self.max else { return true };
        self.reserved
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |r| {
                (r < max).then_some(r + 1)
            })
            .is_ok()
    }

    /// The reserved ticket bought a lease.
    fn spend(&self) {
        self.used.fetch_add(1, Ordering::AcqRel);
    }

    /// The reserved ticket bought nothing.
    fn give_back(&self) {
        if self.max.is_some() {
            self.reserved.fetch_sub(1, Ordering::AcqRel);
        }
    }

    fn spent(&self) -> bool {
        self.max
            .is_some_and(|max| self.used.load(Ordering::Acquire) >= max)
    }
}

struct Ctx {
    cfg: WorkerConfig,
    client: Client,
    body: JobBody,
    stats: Arc<RunStats>,
    /// Raised once to stop: no more leases, running jobs cancelled.
    stop: watch::Sender<bool>,
    /// Why and until when the stop may take (set before `stop` is raised).
    stopping: Mutex<Option<(String, Instant)>>,
    budget: JobBudget,
    /// Jobs leased and not yet ended.
    running: AtomicUsize,
    /// Last time a job ran here or the coordinator could not be asked.
    last_busy: Mutex<Instant>,
}

impl Ctx {
    /// Raises the stop (once) and starts the shutdown grace.
    fn begin_stop(&self, reason: &str) {
        {
            let mut st = self.stopping.lock().unwrap_or_else(|e| e.into_inner());
            if st.is_none() {
                tracing::info!(
                    reason,
                    grace_secs = self.cfg.shutdown_grace.as_secs_f64(),
                    "stopping: no new jobs; running ones are handed back"
                );
                *st = Some((reason.to_string(), Instant::now() + self.cfg.shutdown_grace));
            }
        }
        self.stop.send_replace(true);
    }

    /// The end of the shutdown grace, once stopping.
    fn deadline(&self) -> Option<Instant> {
        self.stopping
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .as_ref()
            .map(|(_, d)| *d)
    }

    fn stop_reason(&self) -> Option<String> {
        self.stopping
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .as_ref()
            .map(|(r, _)| r.clone())
    }

    fn touch(&self) {
        *self.last_busy.lock().unwrap_or_else(|e| e.into_inner()) = Instant::now();
    }

    fn idle_for(&self) -> Duration {
        self.last_busy
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .elapsed()
    }

    /// Resolves when running jobs must have stopped: the grace less the
    /// reserve kept for release calls, counted from the stop.
    async fn jobs_must_stop(&self) {
        let mut stop = self.stop.subscribe();
        let _ = stop.wait_for(|s| *s).await;
        if let Some(deadline) = self.deadline() {
            let reserve = self.cfg.shutdown_grace - self.cfg.job_stop_grace();
            tokio::time::sleep_until((deadline - reserve).into()).await;
        }
    }

    /// Runs a coordinator call, cut off at the end of the shutdown grace
    /// (with a little slack, so a call started at the very end can land).
    async fn bounded<T>(
        &self,
        call: impl std::future::Future<Output = Result<T, CallError>>,
    ) -> Result<T, CallError> {
        match self.deadline() {
            None => call.await,
            Some(d) => {
                let until = d.max(Instant::now() + Duration::from_millis(250));
                tokio::time::timeout_at(until.into(), call)
                    .await
                    .unwrap_or_else(|_| {
                        Err(CallError::Transient(
                            "no answer before the end of the shutdown grace".into(),
                        ))
                    })
            }
        }
    }
}

/// Runs the worker with the real job body until `shutdown` turns true (or
/// the idle or job limits of `cfg` end it).
pub async fn run(
    cfg: WorkerConfig,
    shutdown: watch::Receiver<bool>,
) -> anyhow::Result<Arc<RunStats>> {
    run_with(cfg, shutdown, Arc::new(run_job)).await
}

/// Runs the worker with a given job body.
pub async fn run_with(
    cfg: WorkerConfig,
    shutdown: watch::Receiver<bool>,
    body: JobBody,
) -> anyhow::Result<Arc<RunStats>> {
    cfg.validate()?;
    std::fs::create_dir_all(&cfg.spool_dir)
        .with_context(|| format!("creating spool directory {}", cfg.spool_dir.display()))?;
    let client = Client::new(&cfg.coordinator, cfg.token.clone())?;
    let (stop, _) = watch::channel(false);
    let ctx = Arc::new(Ctx {
        budget: JobBudget::new(cfg.max_jobs),
        cfg,
        client,
        body,
        stats: Arc::default(),
        stop,
        stopping: Mutex::new(None),
        running: AtomicUsize::new(0),
        last_busy: Mutex::new(Instant::now()),
    });
    let forward = {
        let ctx = ctx.clone();
        let mut shutdown = shutdown;
        tokio::spawn(async move {
            if shutdown.wait_for(|s| *s).await.is_ok() {
                ctx.begin_stop("shutdown signal");
            }
        })
    };
    tracing::info!(coordinator = %ctx.cfg.coordinator, jobs = ctx.cfg.jobs, name = %ctx.cfg.name,
        spool = %ctx.cfg.spool_dir.display(),
        exit_when_idle_secs = ctx.cfg.exit_when_idle.map(|d| d.as_secs_f64()),
        max_jobs = ctx.cfg.max_jobs, "worker started");
    if wait_for_coordinator(&ctx).await {
        ctx.touch();
        let mut tasks = tokio::task::JoinSet::new();
        {
            let ctx = ctx.clone();
            tasks.spawn(async move { resend_spool(&ctx).await });
        }
        for slot in 0..ctx.cfg.jobs {
            let ctx = ctx.clone();
            let owner = format!("{}/{slot}", ctx.cfg.name);
            tasks.spawn(
                async move { slot_loop(&ctx, &owner).await }.instrument(info_span!("slot", slot)),
            );
        }
        while let Some(r) = tasks.join_next().await {
            if let Err(e) = r {
                tracing::error!(error = %e, "worker task panicked");
            }
        }
    }
    forward.abort();
    let reason = ctx.stop_reason().unwrap_or_else(|| {
        if ctx.budget.spent() {
            "max jobs reached".to_string()
        } else {
            "all slots ended".to_string()
        }
    });
    let s = &ctx.stats;
    tracing::info!(
        %reason,
        accepted = s.accepted.load(Ordering::Relaxed),
        lost = s.lost.load(Ordering::Relaxed),
        failed = s.failed.load(Ordering::Relaxed),
        released = s.released.load(Ordering::Relaxed),
        spooled = s.spooled.load(Ordering::Relaxed),
        abandoned = s.abandoned.load(Ordering::Relaxed),
        "worker stopped"
    );
    Ok(ctx.stats.clone())
}

/// Sleeps for `d` unless shutdown comes first; returns whether it did.
async fn nap(d: Duration, shutdown: &mut watch::Receiver<bool>) -> bool {
    tokio::select! {
        _ = tokio::time::sleep(d) => false,
        _ = shutdown.wait_for(|s| *s) => true,
    }
}

/// Polls `/healthz` with backoff until the coordinator answers; false if
/// the worker was stopped first. Says where it is trying, on the first
/// failure and every tenth after.
async fn wait_for_coordinator(ctx: &Ctx) -> bool {
    let mut stop = ctx.stop.subscribe();
    let mut backoff = Backoff::new(ctx.cfg.backoff_base, ctx.cfg.backoff_max);
    let mut tries = 0u64;
    loop {
        if *stop.borrow() {
            return false;
        }
        match ctx.client.healthz().await {
            Ok(()) => {
                if tries > 0 {
                    tracing::info!(coordinator = %ctx.cfg.coordinator, tries, "coordinator reachable");
                }
                return true;
            }
            Err(e) => {
                tries += 1;
                let delay = backoff.next_delay();
                if tries == 1 || tries.is_multiple_of(10) {
                    tracing::warn!(coordinator = %ctx.cfg.coordinator, tries,
                        retry_in_secs = delay.as_secs_f64(), error = %e,
                        "coordinator not reachable; retrying");
                }
                if nap(delay, &mut stop).await {
                    return false;
                }
            }
        }
    }
}

async fn slot_loop(ctx: &Ctx, owner: &str) {
    let mut shutdown = ctx.stop.subscribe();
    let mut backoff = Backoff::new(ctx.cfg.backoff_base, ctx.cfg.backoff_max);
    let mut failures = 0u64;
    while !*shutdown.borrow() {
        if ctx.budget.spent() {
            break;
        }
        if !ctx.budget.try_reserve() {
            // Another slot holds the last ticket; it may come back unused.
            if nap(Duration::from_millis(200), &mut shutdown).await {
                break;
            }
            continue;
        }
        match ctx.client.lease(owner, ctx.cfg.lease_wait_secs).await {
            Ok(None) => {
                ctx.budget.give_back();
                backoff.reset();
                if let Some(idle) = ctx.cfg.exit_when_idle {
                    if ctx.running.load(Ordering::Acquire) == 0 && ctx.idle_for() >= idle {
                        ctx.begin_stop(&format!("no job for {}s", idle.as_secs_f64()));
                        break;
                    }
                }
            }
            Ok(Some(lease)) => {
                ctx.budget.spend();
                ctx.running.fetch_add(1, Ordering::AcqRel);
                ctx.touch();
                backoff.reset();
                failures = 0;
                if *shutdown.borrow() {
                    release(ctx, &lease).await;
                } else {
                    let span = info_span!(
                        "job",
                        job_id = lease.job_id,
                        trial = lease.spec.trial,
                        point = lease.spec.point_idx,
                        attempt = lease.spec.attempt
                    );
                    process(ctx, lease).instrument(span).await;
                }
                ctx.touch();
                ctx.running.fetch_sub(1, Ordering::AcqRel);
            }
            Err(e) => {
                ctx.budget.give_back();
                ctx.touch();
                failures += 1;
                // Log the first failure and then every tenth, not each retry.
                if failures == 1 || failures.is_multiple_of(10) {
                    tracing::warn!(coordinator = %ctx.cfg.coordinator, error = %e, failures,
                        "lease request failed; backing off");
                }
                if nap(backoff.next_delay(), &mut shutdown).await {
                    break;
                }
            }
        }
    }
}

async fn release(ctx: &Ctx, lease: &Lease) {
    match ctx
        .bounded(ctx.client.release(lease.job_id, &lease.lease_token))
        .await
    {
        Ok(_) => {
            ctx.stats.released.fetch_add(1, Ordering::Relaxed);
            tracing::info!(job_id = lease.job_id, "lease released");
        }
        Err(e) => tracing::warn!(job_id = lease.job_id, error = %e,
            "releasing lease failed; the job returns to the queue when the lease expires"),
    }
}

/// Runs one leased job to its end: uploaded, dropped (lease lost), failed
/// (reported) or released (shutdown).
async fn process(ctx: &Ctx, lease: Lease) {
    let mut shutdown = ctx.stop.subscribe();
    let hooks = JobHooks::default();
    let (done_tx, done_rx) = watch::channel(false);
    let lost = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let heartbeats = tokio::spawn(
        heartbeat_loop(
            ctx.client.clone(),
            lease.job_id,
            lease.lease_token.clone(),
            Duration::from_secs(lease.heartbeat_secs.max(1)).min(ctx.cfg.progress_every),
            hooks.clone(),
            lost.clone(),
            done_rx,
            ctx.stop.subscribe(),
        )
        .in_current_span(),
    );
    let body = ctx.body.clone();
    let spec = lease.spec.clone();
    let h = hooks.clone();
    let span = tracing::Span::current();
    tracing::info!(params = ?spec.params, seed = spec.seed, "job started");
    let t0 = Instant::now();
    let mut task = tokio::task::spawn_blocking(move || span.in_scope(|| body(&spec, &h)));
    let outcome = tokio::select! {
        r = &mut task => Some(r),
        _ = ctx.jobs_must_stop() => None,
    };
    let _ = done_tx.send(true);
    let Some(outcome) = outcome else {
        // The body ignores the cancel (or is deep in a long step): hand the
        // job back now and leave the thread behind; its output, if any, is
        // never sent, so the job runs once more elsewhere and counts once.
        heartbeats.abort();
        ctx.stats.abandoned.fetch_add(1, Ordering::Relaxed);
        tracing::warn!("job did not stop within the shutdown grace; handing it back");
        release(ctx, &lease).await;
        return;
    };
    // The last heartbeat flushes the curve; once stopping it may not hold
    // up the exit past the grace.
    match ctx.deadline() {
        None => {
            let _ = heartbeats.await;
        }
        Some(d) => {
            let mut heartbeats = heartbeats;
            if tokio::time::timeout_at(d.into(), &mut heartbeats)
                .await
                .is_err()
            {
                heartbeats.abort();
            }
        }
    }
    let outcome = match outcome {
        Ok(o) => o,
        Err(e) => Err(JobError::Failed(anyhow::anyhow!("job body panicked: {e}"))),
    };
    match outcome {
        Ok(output) => {
            tracing::info!(
                secs = t0.elapsed().as_secs_f64(),
                success_rate = output.final_success_rate,
                successes = output.successes_found,
                "job finished; uploading"
            );
            let spooled = Spooled {
                coordinator: ctx.cfg.coordinator.clone(),
                job_id: lease.job_id,
                upload: ResultUpload {
                    lease_token: lease.lease_token.clone(),
                    output,
                },
            };
            let path = spool_path(&ctx.cfg.spool_dir, lease.job_id, &lease.lease_token);
            if let Err(e) = write_spool(&path, &spooled) {
                tracing::warn!(
                    error = format!("{e:#}"),
                    "could not spool result; keeping it in memory only"
                );
            }
            deliver(ctx, &spooled, &path, &mut shutdown).await;
        }
        Err(_) if lost.load(Ordering::Relaxed) => {
            ctx.stats.lost.fetch_add(1, Ordering::Relaxed);
            tracing::warn!("lease lost; job dropped");
        }
        Err(JobError::Cancelled) => release(ctx, &lease).await,
        Err(JobError::Failed(e)) => {
            ctx.stats.failed.fetch_add(1, Ordering::Relaxed);
            let msg = format!("{e:#}");
            tracing::warn!(error = %msg, "job failed");
            report_failure(ctx, &lease, msg, &mut shutdown).await;
        }
    }
}

async fn report_failure(
    ctx: &Ctx,
    lease: &Lease,
    msg: String,
    shutdown: &mut watch::Receiver<bool>,
) {
    let f = FailReport {
        lease_token: lease.lease_token.clone(),
        error: msg.chars().take(4000).collect(),
    };
    let mut backoff = Backoff::new(ctx.cfg.backoff_base, ctx.cfg.backoff_max);
    for _ in 0..8 {
        match ctx.bounded(ctx.client.fail(lease.job_id, &f)).await {
            Ok(ack) => {
                tracing::info!(status = ?ack.status, "failure reported");
                return;
            }
            Err(e) if e.is_transient() => {
                if nap(backoff.next_delay(), shutdown).await {
                    return;
                }
            }
            Err(e) => {
                tracing::warn!(error = %e, "failure report refused");
                return;
            }
        }
    }
}

#[allow(clippy::too_many_arguments)]
async fn heartbeat_loop(
    client: Client,
    job_id: i64,
    token: String,
    period: Duration,
    hooks: JobHooks,
    lost: Arc<std::sync::atomic::AtomicBool>,
    mut done: watch::Receiver<bool>,
    mut shutdown: watch::Receiver<bool>,
) {
    let mut watching_shutdown = true;
    loop {
        let finished = tokio::select! {
            _ = tokio::time::sleep(period) => false,
            _ = done.wait_for(|d| *d) => true,
            _ = shutdown.wait_for(|s| *s), if watching_shutdown => {
                // Stop training at its next update; sampling runs to its end
                // and is uploaded. Heartbeats go on until the body returns.
                hooks.cancel.store(true, Ordering::Relaxed);
                watching_shutdown = false;
                continue;
            }
        };
        if finished {
            // Flush the last progress points so the curve is complete.
            let progress = hooks.take_progress();
            if !progress.is_empty() && !lost.load(Ordering::Relaxed) {
                let hb = Heartbeat {
                    lease_token: token.clone(),
                    phase: hooks.phase(),
                    progress,
                };
                let _ = client.heartbeat(job_id, &hb).await;
            }
            return;
        }
        let progress = hooks.take_progress();
        let hb = Heartbeat {
            lease_token: token.clone(),
            phase: hooks.phase(),
            progress,
        };
        match client.heartbeat(job_id, &hb).await {
            Ok(_) => {}
            Err(CallError::Conflict(m)) | Err(CallError::NotFound(m)) => {
                tracing::warn!(%job_id, error = %m, "lease lost; stopping the job");
                lost.store(true, Ordering::Relaxed);
                hooks.cancel.store(true, Ordering::Relaxed);
                return;
            }
            Err(e) if e.is_transient() => {
                tracing::debug!(%job_id, error = %e, "heartbeat failed; will retry");
                hooks.restore_progress(hb.progress);
            }
            Err(e) => tracing::warn!(%job_id, error = %e, "heartbeat refused"),
        }
    }
}

fn spool_path(dir: &Path, job_id: i64, token: &str) -> PathBuf {
    dir.join(format!("{job_id}-{token}.json"))
}

fn write_spool(path: &Path, s: &Spooled) -> anyhow::Result<()> {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, serde_json::to_vec(s)?)
        .with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("renaming to {}", path.display()))?;
    Ok(())
}

/// Uploads a finished result until the coordinator accepts or refuses it.
/// Once stopping it keeps trying until the end of the shutdown grace, then
/// leaves the result in the spool for the next start.
async fn deliver(ctx: &Ctx, s: &Spooled, path: &Path, shutdown: &mut watch::Receiver<bool>) {
    let mut backoff = Backoff::new(ctx.cfg.backoff_base, ctx.cfg.backoff_max);
    let mut failures = 0u64;
    loop {
        match ctx.bounded(ctx.client.result(s.job_id, &s.upload)).await {
            Ok(ack) => {
                ctx.stats.accepted.fetch_add(1, Ordering::Relaxed);
                tracing::info!(
                    job_id = s.job_id,
                    converged = ack.converged,
                    "result accepted"
                );
                let _ = std::fs::remove_file(path);
                return;
            }
            Err(CallError::Conflict(m)) | Err(CallError::NotFound(m)) => {
                ctx.stats.lost.fetch_add(1, Ordering::Relaxed);
                tracing::warn!(job_id = s.job_id, error = %m, "result refused; dropped");
                let _ = std::fs::remove_file(path);
                return;
            }
            Err(CallError::Rejected { status, message }) => {
                ctx.stats.failed.fetch_add(1, Ordering::Relaxed);
                tracing::error!(job_id = s.job_id, status, error = %message, "result invalid; reporting failure");
                let _ = std::fs::remove_file(path);
                let f = FailReport {
                    lease_token: s.upload.lease_token.clone(),
                    error: format!("result refused ({status}): {message}")
                        .chars()
                        .take(4000)
                        .collect(),
                };
                let _ = ctx.bounded(ctx.client.fail(s.job_id, &f)).await;
                return;
            }
            Err(e) => {
                failures += 1;
                if failures == 1 || failures.is_multiple_of(10) {
                    tracing::warn!(job_id = s.job_id, error = %e, failures, "upload failed; will retry");
                }
            }
        }
        let delay = backoff.next_delay();
        match ctx.deadline() {
            Some(until) => {
                if Instant::now() + delay > until {
                    ctx.stats.spooled.fetch_add(1, Ordering::Relaxed);
                    tracing::warn!(job_id = s.job_id, path = %path.display(),
                        "coordinator unreachable at shutdown; result left in the spool");
                    return;
                }
                tokio::time::sleep(delay).await;
            }
            // A stop during the nap sets the deadline; the loop goes on.
            None => {
                nap(delay, shutdown).await;
            }
        }
    }
}

/// Re-sends results spooled by an earlier run against this coordinator.
async fn resend_spool(ctx: &Ctx) {
    let mut shutdown = ctx.stop.subscribe();
    let Ok(dir) = std::fs::read_dir(&ctx.cfg.spool_dir) else {
        return;
    };
    for entry in dir.flatten() {
        let path = entry.path();
        if path.extension().and_then(|e| e.to_str()) != Some("json") {
            continue;
        }
        let Ok(bytes) = std::fs::read(&path) else {
            continue;
        };
        let Ok(s) = serde_json::from_slice::<Spooled>(&bytes) else {
            tracing::warn!(path = %path.display(), "unreadable spool file skipped");
            continue;
        };
        if s.coordinator != ctx.cfg.coordinator {
            continue;
        }
        tracing::info!(job_id = s.job_id, "re-sending spooled result");
        deliver(ctx, &s, &path, &mut shutdown).await;
    }
}
