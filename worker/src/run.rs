//! The worker loop: `jobs` slots, each leasing a job, running its body on a
//! blocking thread while a heartbeat task renews the lease and reports
//! progress, then uploading the output. Finished outputs are spooled to disk
//! before the first upload and re-sent until the coordinator accepts or
//! refuses them, across restarts. A shutdown signal stops leasing, cancels
//! running training, releases unfinished leases and returns.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Context;
use serde::{Deserialize, Serialize};
use shared::api::{FailReport, Heartbeat, Lease, ResultUpload};
use tokio::sync::watch;
use tracing::{info_span, Instrument};

use crate::client::{Backoff, CallError, Client};
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
}

/// A finished result waiting in the spool.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct Spooled {
    coordinator: String,
    job_id: i64,
    upload: ResultUpload,
}

struct Ctx {
    cfg: WorkerConfig,
    client: Client,
    body: JobBody,
    stats: Arc<RunStats>,
}

/// Runs the worker with the real job body until `shutdown` turns true.
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
    let ctx = Arc::new(Ctx {
        cfg,
        client,
        body,
        stats: Arc::default(),
    });
    tracing::info!(coordinator = %ctx.cfg.coordinator, jobs = ctx.cfg.jobs, name = %ctx.cfg.name,
        spool = %ctx.cfg.spool_dir.display(), "worker started");
    let mut tasks = tokio::task::JoinSet::new();
    {
        let ctx = ctx.clone();
        let shutdown = shutdown.clone();
        tasks.spawn(async move { resend_spool(&ctx, shutdown).await });
    }
    for slot in 0..ctx.cfg.jobs {
        let ctx = ctx.clone();
        let shutdown = shutdown.clone();
        let owner = format!("{}/{slot}", ctx.cfg.name);
        tasks.spawn(
            async move { slot_loop(&ctx, &owner, shutdown).await }
                .instrument(info_span!("slot", slot)),
        );
    }
    while let Some(r) = tasks.join_next().await {
        if let Err(e) = r {
            tracing::error!(error = %e, "worker task panicked");
        }
    }
    let s = &ctx.stats;
    tracing::info!(
        accepted = s.accepted.load(Ordering::Relaxed),
        lost = s.lost.load(Ordering::Relaxed),
        failed = s.failed.load(Ordering::Relaxed),
        released = s.released.load(Ordering::Relaxed),
        spooled = s.spooled.load(Ordering::Relaxed),
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

async fn slot_loop(ctx: &Ctx, owner: &str, mut shutdown: watch::Receiver<bool>) {
    let mut backoff = Backoff::new(ctx.cfg.backoff_base, ctx.cfg.backoff_max);
    let mut failures = 0u64;
    while !*shutdown.borrow() {
        match ctx.client.lease(owner, ctx.cfg.lease_wait_secs).await {
            Ok(None) => backoff.reset(),
            Ok(Some(lease)) => {
                backoff.reset();
                failures = 0;
                if *shutdown.borrow() {
                    release(ctx, &lease).await;
                    break;
                }
                let span = info_span!(
                    "job",
                    job_id = lease.job_id,
                    trial = lease.spec.trial,
                    point = lease.spec.point_idx,
                    attempt = lease.spec.attempt
                );
                process(ctx, lease, shutdown.clone()).instrument(span).await;
            }
            Err(e) => {
                failures += 1;
                // Log the first failure and then every tenth, not each retry.
                if failures == 1 || failures.is_multiple_of(10) {
                    tracing::warn!(error = %e, failures, "lease request failed; backing off");
                }
                if nap(backoff.next_delay(), &mut shutdown).await {
                    break;
                }
            }
        }
    }
}

async fn release(ctx: &Ctx, lease: &Lease) {
    match ctx.client.release(lease.job_id, &lease.lease_token).await {
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
async fn process(ctx: &Ctx, lease: Lease, mut shutdown: watch::Receiver<bool>) {
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
            shutdown.clone(),
        )
        .in_current_span(),
    );
    let body = ctx.body.clone();
    let spec = lease.spec.clone();
    let h = hooks.clone();
    let span = tracing::Span::current();
    tracing::info!(params = ?spec.params, seed = spec.seed, "job started");
    let t0 = Instant::now();
    let outcome = tokio::task::spawn_blocking(move || span.in_scope(|| body(&spec, &h))).await;
    let _ = done_tx.send(true);
    let _ = heartbeats.await;
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
        match ctx.client.fail(lease.job_id, &f).await {
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
/// After shutdown it keeps trying for the grace period, then leaves the
/// result in the spool for the next start.
async fn deliver(ctx: &Ctx, s: &Spooled, path: &Path, shutdown: &mut watch::Receiver<bool>) {
    let mut backoff = Backoff::new(ctx.cfg.backoff_base, ctx.cfg.backoff_max);
    let mut grace_until: Option<Instant> = None;
    let mut failures = 0u64;
    loop {
        match ctx.client.result(s.job_id, &s.upload).await {
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
                let _ = ctx.client.fail(s.job_id, &f).await;
                return;
            }
            Err(e) => {
                failures += 1;
                if failures == 1 || failures.is_multiple_of(10) {
                    tracing::warn!(job_id = s.job_id, error = %e, failures, "upload failed; will retry");
                }
            }
        }
        if *shutdown.borrow() && grace_until.is_none() {
            grace_until = Some(Instant::now() + ctx.cfg.shutdown_grace);
        }
        let delay = backoff.next_delay();
        match grace_until {
            Some(until) => {
                if Instant::now() + delay > until {
                    ctx.stats.spooled.fetch_add(1, Ordering::Relaxed);
                    tracing::warn!(job_id = s.job_id, path = %path.display(),
                        "coordinator unreachable at shutdown; result left in the spool");
                    return;
                }
                tokio::time::sleep(delay).await;
            }
            None => {
                if nap(delay, shutdown).await {
                    grace_until = Some(Instant::now() + ctx.cfg.shutdown_grace);
                }
            }
        }
    }
}

/// Re-sends results spooled by an earlier run against this coordinator.
async fn resend_spool(ctx: &Ctx, mut shutdown: watch::Receiver<bool>) {
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
