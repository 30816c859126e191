//! Worker endpoints (lease, heartbeat, result, fail, release; each job call
//! carries its lease token) and the job detail read.

use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use axum::extract::State;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::Json;
use shared::api::{
    FailReport, Heartbeat, HeartbeatAck, JobDetail, JobSpec, JobState, JobStateAck, Lease,
    LeaseRequest, ReleaseRequest, ResultAck, ResultUpload, SolverSpec,
};
use tracing::instrument;

use crate::error::ApiError;
use crate::extract::{ApiJson, ApiPath};
use crate::intake;
use crate::metrics::Metrics;
use crate::state::{AppState, CLAIM_SWEEP_MS};
use crate::store::now_ms;
use crate::store::queue;

fn lock<T>(m: &std::sync::Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Longest long-poll of a lease request.
pub const MAX_WAIT_SECS: u32 = 30;
/// Longest failure message kept.
pub const MAX_ERROR_CHARS: usize = 4000;

/// `POST /api/v1/leases`: 200 with a job and its lease, or 204 when none
/// is queued within `wait_secs`.
#[instrument(skip_all, fields(worker = %req.worker))]
pub async fn lease(
    State(s): State<AppState>,
    ApiJson(req): ApiJson<LeaseRequest>,
) -> Result<Response, ApiError> {
    let worker = req.worker.trim();
    // The length counts the name as sent (as the OpenAPI `maxLength` does).
    if worker.is_empty()
        || req.worker.chars().count() > 200
        || req.worker.chars().any(char::is_control)
    {
        return Err(ApiError::BadRequest(
            "worker: must be 1..=200 printable characters".into(),
        ));
    }
    if req.wait_secs > MAX_WAIT_SECS {
        return Err(ApiError::BadRequest(format!(
            "wait_secs: must be in 0..={MAX_WAIT_SECS}, got {}",
            req.wait_secs
        )));
    }
    let deadline = Instant::now() + Duration::from_secs(u64::from(req.wait_secs));
    loop {
        let notified = s.notify.notified();
        tokio::pin!(notified);
        notified.as_mut().enable();
        let now = now_ms();
        let last = s.hot.last_sweep_ms.load(Ordering::Relaxed);
        let sweep = now - last >= CLAIM_SWEEP_MS
            && s.hot
                .last_sweep_ms
                .compare_exchange(last, now, Ordering::Relaxed, Ordering::Relaxed)
                .is_ok();
        let (claimed, eff) = queue::claim_with(&s.db, worker, s.lease_ms(), now, sweep).await?;
        s.apply(eff);
        if let Some(c) = claimed {
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
            let mut info = s.search_info(&c.search_id).await?;
            if c.point_idx as usize >= info.points.len() {
                // A point added by an extension after these facts were
                // cached: load them again.
                s.forget_search(&c.search_id).await;
                info = s.search_info(&c.search_id).await?;
            }
            let params = info
                .points
                .get(c.point_idx as usize)
                .cloned()
                .ok_or_else(|| {
                    ApiError::Internal(anyhow::anyhow!(
                        "job {}: grid point #{} of search {} is not stored",
                        c.job_id,
                        c.point_idx,
                        c.search_id
                    ))
                })?;
            let solver = match &info.resolved.solvers[..] {
                // A search without variants: PPO with its `training`.
                [] => None,
                list => Some(list.get(c.variant as usize).cloned().ok_or_else(|| {
                    ApiError::Internal(anyhow::anyhow!(
                        "job {}: solver variant #{} of search {} is not stored",
                        c.job_id,
                        c.variant,
                        c.search_id
                    ))
                })?),
            };
            // A PPO variant trains with its own settings.
            let training = match &solver {
                Some(SolverSpec::Ppo { training, .. }) => training.clone(),
                _ => info.resolved.training.clone(),
            };
            tracing::debug!(job_id = c.job_id, "job leased");
            let lease = Lease {
                job_id: c.job_id,
                lease_token: c.token,
                lease_secs: s.cfg.lease_secs,
                heartbeat_secs: (s.cfg.lease_secs / 3).max(1),
                spec: JobSpec {
                    search_id: c.search_id,
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
                },
            };
            return Ok(Json(lease).into_response());
        }
        let now = Instant::now();
        if now >= deadline {
            Metrics::inc(&s.metrics.leases_empty);
            return Ok(StatusCode::NO_CONTENT.into_response());
        }
        let nap = (deadline - now).min(Duration::from_secs(1));
        tokio::select! {
            _ = &mut notified => {}
            _ = tokio::time::sleep(nap) => {}
        }
    }
}

/// `POST /api/v1/jobs/{id}/heartbeat`: renews the lease, records progress.
#[instrument(skip_all, fields(job_id = %id))]
pub async fn heartbeat(
    State(s): State<AppState>,
    ApiPath(id): ApiPath<i64>,
    ApiJson(hb): ApiJson<Heartbeat>,
) -> Result<Json<HeartbeatAck>, ApiError> {
    intake::validate_heartbeat(&hb)?;
    queue::heartbeat(
        &s.db,
        id,
        &hb.lease_token,
        hb.phase,
        &hb.progress,
        s.lease_ms(),
        now_ms(),
    )
    .await?;
    Metrics::inc(&s.metrics.heartbeats);
    Ok(Json(HeartbeatAck {
        lease_secs: s.cfg.lease_secs,
    }))
}

/// `POST /api/v1/jobs/{id}/result`: the first valid upload under the
/// current lease wins; anything else is 409 and changes nothing.
#[instrument(skip_all, fields(job_id = %id))]
pub async fn result(
    State(s): State<AppState>,
    ApiPath(id): ApiPath<i64>,
    ApiJson(up): ApiJson<ResultUpload>,
) -> Result<Json<ResultAck>, ApiError> {
    let outcome = accept_result(&s, id, up).await;
    match &outcome {
        Ok(_) => Metrics::inc(&s.metrics.uploads_accepted),
        Err(e) => {
            Metrics::inc(&s.metrics.uploads_rejected);
            tracing::info!(error = %e, "result refused");
        }
    }
    outcome.map(Json)
}

async fn accept_result(s: &AppState, id: i64, up: ResultUpload) -> Result<ResultAck, ApiError> {
    intake::validate_token(&up.lease_token)?;
    let cached = lock(&s.hot.job_search).get(&id).cloned();
    let (search_id, variant) = match cached {
        Some(sv) => sv,
        None => crate::store::reads::job_search(&s.db, id)
            .await?
            .ok_or_else(|| ApiError::NotFound(format!("no job with id {id}")))?,
    };
    let info = s.search_info(&search_id).await?;
    intake::validate_output(&up.output, &info.resolved, variant)?;
    // Digest and compress off the async threads (about a millisecond).
    let output = up.output;
    let upload = tokio::task::spawn_blocking(move || queue::Upload::of(&output))
        .await
        .map_err(|e| ApiError::Internal(anyhow::anyhow!("digesting an output: {e}")))?
        .map_err(|e| ApiError::Internal(e.context("digesting an output")))?;
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

/// `POST /api/v1/jobs/{id}/fail`: the worker gave up; the job is retried
/// until its attempts are used up.
#[instrument(skip_all, fields(job_id = %id))]
pub async fn fail(
    State(s): State<AppState>,
    ApiPath(id): ApiPath<i64>,
    ApiJson(f): ApiJson<FailReport>,
) -> Result<Json<JobStateAck>, ApiError> {
    intake::validate_token(&f.lease_token)?;
    let msg: String = f.error.chars().take(MAX_ERROR_CHARS).collect();
    let msg = if msg.trim().is_empty() {
        "worker reported a failure without a message".to_string()
    } else {
        msg
    };
    let (status, eff) = queue::fail(&s.db, id, &f.lease_token, &msg, now_ms()).await?;
    Metrics::inc(&s.metrics.jobs_failed_reports);
    tracing::warn!(error = %msg, ?status, "worker reported failure");
    s.apply(eff);
    Ok(Json(JobStateAck { status }))
}

/// `POST /api/v1/jobs/{id}/release`: hand an unfinished job back without
/// using an attempt.
#[instrument(skip_all, fields(job_id = %id))]
pub async fn release(
    State(s): State<AppState>,
    ApiPath(id): ApiPath<i64>,
    ApiJson(r): ApiJson<ReleaseRequest>,
) -> Result<Json<JobStateAck>, ApiError> {
    intake::validate_token(&r.lease_token)?;
    let eff = queue::release(&s.db, id, &r.lease_token).await?;
    Metrics::inc(&s.metrics.leases_released);
    s.apply(eff);
    Ok(Json(JobStateAck {
        status: JobState::Queued,
    }))
}

/// `GET /api/v1/jobs/{id}`: a job with its learning curve.
pub async fn detail(
    State(s): State<AppState>,
    ApiPath(id): ApiPath<i64>,
) -> Result<Json<JobDetail>, ApiError> {
    let (job, curve) = queue::job_detail(&s.db, id)
        .await?
        .ok_or_else(|| ApiError::NotFound(format!("no job with id {id}")))?;
    Ok(Json(JobDetail { job, curve }))
}
