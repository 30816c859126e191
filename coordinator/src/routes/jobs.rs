//! Worker endpoints (lease, heartbeat, result, fail, release; each job call
//! carries its lease token) and the job detail read. The lease cycle
//! itself is the domain's ([`crate::domain::leasing`]).

use axum::extract::State;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::Json;
use shared::api::{
    FailReport, Heartbeat, HeartbeatAck, JobDetail, JobStateAck, LeaseRequest, ReleaseRequest,
    ResultAck, ResultUpload,
};
use tracing::instrument;

use crate::domain::leasing;
use crate::error::ApiError;
use crate::extract::{ApiJson, ApiPath};
use crate::state::AppState;
use crate::store::queue;

/// `POST /api/v1/leases`: 200 with a job and its lease, or 204 when none
/// is queued within `wait_secs`.
#[instrument(skip_all, fields(worker = %req.worker))]
pub async fn lease(
    State(s): State<AppState>,
    ApiJson(req): ApiJson<LeaseRequest>,
) -> Result<Response, ApiError> {
    Ok(match leasing::lease(&s, &req).await? {
        Some(lease) => Json(lease).into_response(),
        None => StatusCode::NO_CONTENT.into_response(),
    })
}

/// `POST /api/v1/jobs/{id}/heartbeat`: renews the lease, records progress.
#[instrument(skip_all, fields(job_id = %id))]
pub async fn heartbeat(
    State(s): State<AppState>,
    ApiPath(id): ApiPath<i64>,
    ApiJson(hb): ApiJson<Heartbeat>,
) -> Result<Json<HeartbeatAck>, ApiError> {
    let lease_secs = leasing::heartbeat(&s, id, &hb).await?;
    Ok(Json(HeartbeatAck { lease_secs }))
}

/// `POST /api/v1/jobs/{id}/result`: the first valid upload under the
/// current lease wins; anything else is 409 and changes nothing.
#[instrument(skip_all, fields(job_id = %id))]
pub async fn result(
    State(s): State<AppState>,
    ApiPath(id): ApiPath<i64>,
    ApiJson(up): ApiJson<ResultUpload>,
) -> Result<Json<ResultAck>, ApiError> {
    Ok(Json(leasing::result(&s, id, up).await?))
}

/// `POST /api/v1/jobs/{id}/fail`: the worker gave up; the job is retried
/// until its attempts are used up.
#[instrument(skip_all, fields(job_id = %id))]
pub async fn fail(
    State(s): State<AppState>,
    ApiPath(id): ApiPath<i64>,
    ApiJson(f): ApiJson<FailReport>,
) -> Result<Json<JobStateAck>, ApiError> {
    let status = leasing::fail(&s, id, &f).await?;
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
    let status = leasing::release(&s, id, &r.lease_token).await?;
    Ok(Json(JobStateAck { status }))
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
