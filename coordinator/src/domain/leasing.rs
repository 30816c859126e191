//! The lease cycle, as workers drive it: lease (a long poll that sweeps
//! expired leases at most every [`CLAIM_SWEEP_MS`] and turns a claimed row
//! into the [`JobSpec`] the worker runs), heartbeat, result, fail and
//! release. Each call checks its input, runs one store operation (the lease
//! check is the store's, inside that operation), keeps the lease cycle's
//! hot cache and the metrics, and acts on the operation's side effects.

use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use shared::api::{
    FailReport, Heartbeat, JobSpec, JobState, Lease, LeaseRequest, ResultAck, ResultUpload,
    SolverSpec,
};

use super::{search_info, DomainError, DomainResult};
use crate::intake;
use crate::metrics::Metrics;
use crate::state::{AppState, CLAIM_SWEEP_MS};
use crate::store::now_ms;
use crate::store::queue::{self, Claimed, SearchInfo};

/// Longest long-poll of a lease request.
pub const MAX_WAIT_SECS: u32 = 30;
/// Longest failure message kept.
pub const MAX_ERROR_CHARS: usize = 4000;

fn lock<T>(m: &std::sync::Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Checks a lease request: a printable worker name of 1..=200 characters
/// (counted as sent, as the OpenAPI `maxLength` does) and a wait of at most
/// [`MAX_WAIT_SECS`]. Returns the trimmed worker name.
fn check_lease_request(req: &LeaseRequest) -> DomainResult<&str> {
    let worker = req.worker.trim();
    if worker.is_empty()
        || req.worker.chars().count() > 200
        || req.worker.chars().any(char::is_control)
    {
        return Err(DomainError::Invalid(
            "worker: must be 1..=200 printable characters".into(),
        ));
    }
    if req.wait_secs > MAX_WAIT_SECS {
        return Err(DomainError::Invalid(format!(
            "wait_secs: must be in 0..={MAX_WAIT_SECS}, got {}",
            req.wait_secs
        )));
    }
    Ok(worker)
}

/// Leases the next job to the requesting worker, waiting up to
/// `wait_secs` for one to be queued: `Some(lease)`, or `None` when none
/// came.
pub async fn lease(s: &AppState, req: &LeaseRequest) -> DomainResult<Option<Lease>> {
    let worker = check_lease_request(req)?;
    let deadline = Instant::now() + Duration::from_secs(u64::from(req.wait_secs));
    loop {
        let notified = s.notify.notified();
        tokio::pin!(notified);
        notified.as_mut().enable();
        if let Some(lease) = lease_once(s, worker).await? {
            return Ok(Some(lease));
        }
        let now = Instant::now();
        if now >= deadline {
            Metrics::inc(&s.metrics.leases_empty);
            return Ok(None);
        }
        let nap = (deadline - now).min(Duration::from_secs(1));
        tokio::select! {
            _ = &mut notified => {}
            _ = tokio::time::sleep(nap) => {}
        }
    }
}

/// Whether this lease request sweeps expired leases: at most one request
/// every [`CLAIM_SWEEP_MS`] does (the sweeper task covers the rest).
fn sweep_due(s: &AppState, now: i64) -> bool {
    let last = s.hot.last_sweep_ms.load(Ordering::Relaxed);
    now - last >= CLAIM_SWEEP_MS
        && s.hot
            .last_sweep_ms
            .compare_exchange(last, now, Ordering::Relaxed, Ordering::Relaxed)
            .is_ok()
}

/// One claim: the lease of the job claimed, if any was queued.
async fn lease_once(s: &AppState, worker: &str) -> DomainResult<Option<Lease>> {
    let now = now_ms();
    let sweep = sweep_due(s, now);
    let (claimed, eff) = queue::claim_with(&s.db, worker, s.lease_ms(), now, sweep).await?;
    s.apply(eff);
    let Some(c) = claimed else { return Ok(None) };
    Metrics::inc(&s.metrics.leases_granted);
    let first = lock(&s.hot.started).insert(c.search_id.clone());
    if first {
        queue::mark_started(&s.db, &c.search_id, now).await?;
    }
    {
        let mut m = lock(&s.hot.job_search);
        if m.len() > 100_000 {
            m.clear();
        }
        m.insert(c.job_id, (c.search_id.clone(), c.variant));
    }
    let mut info = search_info(s, &c.search_id).await?;
    if c.point_idx as usize >= info.points.len() {
        // A point added by an extension after these facts were cached:
        // load them again.
        s.forget_search(&c.search_id).await;
        info = search_info(s, &c.search_id).await?;
    }
    tracing::debug!(job_id = c.job_id, "job leased");
    let (lease_secs, spec) = (s.cfg.lease_secs, job_spec(&c, &info)?);
    Ok(Some(Lease {
        job_id: c.job_id,
        lease_token: c.token,
        lease_secs,
        heartbeat_secs: (lease_secs / 3).max(1),
        spec,
    }))
}

/// What a worker runs for a claimed job: the grid point's parameters, the
/// solver variant (none for a search without variants: PPO with the
/// search's `training`) and the search's settings.
fn job_spec(c: &Claimed, info: &SearchInfo) -> DomainResult<JobSpec> {
    let params = info
        .points
        .get(c.point_idx as usize)
        .cloned()
        .ok_or_else(|| {
            DomainError::internal(format!(
                "job {}: grid point #{} of search {} is not stored",
                c.job_id, c.point_idx, c.search_id
            ))
        })?;
    let solver = match &info.resolved.solvers[..] {
        [] => None,
        list => Some(list.get(c.variant as usize).cloned().ok_or_else(|| {
            DomainError::internal(format!(
                "job {}: solver variant #{} of search {} is not stored",
                c.job_id, c.variant, c.search_id
            ))
        })?),
    };
    // A PPO variant trains with its own settings.
    let training = match &solver {
        Some(SolverSpec::Ppo { training, .. }) => training.clone(),
        _ => info.resolved.training.clone(),
    };
    Ok(JobSpec {
        search_id: c.search_id.clone(),
        search_name: info.name.clone(),
        point_idx: c.point_idx,
        params,
        trial: c.trial,
        seed: c.seed,
        attempt: c.attempt,
        training,
        sampling: info.resolved.sampling.clone(),
        env: info.resolved.env.clone(),
        convergence_threshold: info.threshold,
        solver,
    })
}

/// Renews a lease and records progress; answers with the lease length.
pub async fn heartbeat(s: &AppState, job_id: i64, hb: &Heartbeat) -> DomainResult<u64> {
    intake::validate_heartbeat(hb)?;
    queue::heartbeat(
        &s.db,
        job_id,
        &hb.lease_token,
        hb.phase,
        &hb.progress,
        s.lease_ms(),
        now_ms(),
    )
    .await?;
    Metrics::inc(&s.metrics.heartbeats);
    Ok(s.cfg.lease_secs)
}

/// Accepts a result: the first valid upload under the current lease wins;
/// anything else is refused and changes nothing. Counts both outcomes.
pub async fn result(s: &AppState, job_id: i64, up: ResultUpload) -> DomainResult<ResultAck> {
    let outcome = accept_result(s, job_id, up).await;
    match &outcome {
        Ok(_) => Metrics::inc(&s.metrics.uploads_accepted),
        Err(e) => {
            Metrics::inc(&s.metrics.uploads_rejected);
            tracing::info!(error = %e, "result refused");
        }
    }
    outcome
}

async fn accept_result(s: &AppState, id: i64, up: ResultUpload) -> DomainResult<ResultAck> {
    intake::validate_token(&up.lease_token)?;
    let cached = lock(&s.hot.job_search).get(&id).cloned();
    let (search_id, variant) = match cached {
        Some(sv) => sv,
        None => crate::store::reads::job_search(&s.db, id)
            .await?
            .ok_or_else(|| DomainError::NotFound(format!("no job with id {id}")))?,
    };
    let info = search_info(s, &search_id).await?;
    intake::validate_output(&up.output, &info.resolved, variant)?;
    // Digest and compress off the async threads (about a millisecond).
    let output = up.output;
    let upload = tokio::task::spawn_blocking(move || queue::Upload::of(output))
        .await
        .map_err(|e| DomainError::internal(format!("digesting an output: {e}")))?
        .map_err(|e| DomainError::Internal(e.context("digesting an output")))?;
    let done =
        queue::complete_with(&s.db, id, &up.lease_token, upload, info.threshold, now_ms()).await?;
    lock(&s.hot.job_search).remove(&id);
    tracing::debug!(converged = done.converged, "result accepted");
    let ack = ResultAck {
        converged: done.converged,
        replacement_enqueued: done.replacement,
    };
    s.apply(done.effects);
    Ok(ack)
}

/// The worker gave up on its job: retried until its attempts are used up.
/// Answers with the job's state after.
pub async fn fail(s: &AppState, job_id: i64, f: &FailReport) -> DomainResult<JobState> {
    intake::validate_token(&f.lease_token)?;
    let msg: String = f.error.chars().take(MAX_ERROR_CHARS).collect();
    let msg = if msg.trim().is_empty() {
        "worker reported a failure without a message".to_string()
    } else {
        msg
    };
    let (status, eff) = queue::fail(&s.db, job_id, &f.lease_token, &msg, now_ms()).await?;
    Metrics::inc(&s.metrics.jobs_failed_reports);
    tracing::warn!(error = %msg, ?status, "worker reported failure");
    s.apply(eff);
    Ok(status)
}

/// The worker hands an unfinished job back without using an attempt.
pub async fn release(s: &AppState, job_id: i64, lease_token: &str) -> DomainResult<JobState> {
    intake::validate_token(lease_token)?;
    let eff = queue::release(&s.db, job_id, lease_token).await?;
    Metrics::inc(&s.metrics.leases_released);
    s.apply(eff);
    Ok(JobState::Queued)
}
