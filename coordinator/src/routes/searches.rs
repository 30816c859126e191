//! Search endpoints: submit, list, status, cancel, results (JSON and CSV),
//! the job list and the raw aggregation inputs.

use axum::extract::State;
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use shared::analysis::{report_to_csv, WeightInput};
use shared::api::{Created, JobInfo, SearchRequest, SearchState, SearchStatus};
use tracing::instrument;

use super::{ApiJson, ApiPath, AppState};
use crate::db::{now_ms, rfc3339};
use crate::error::ApiError;
use crate::metrics::Metrics;
use crate::queue::{self, SearchRow};
use crate::results::{self, ResultsView};
use crate::science;

fn status_of(r: SearchRow) -> SearchStatus {
    let eta_secs = match (r.status, r.mean_job_ms) {
        (SearchState::Running, Some(ms)) => {
            let parallel = r.jobs.leased.max(1) as f64;
            Some((ms / 1000.0) * (r.jobs.queued + r.jobs.leased) as f64 / parallel)
        }
        (SearchState::Running, None) => None,
        _ => Some(0.0),
    };
    SearchStatus {
        id: r.id,
        name: r.name,
        status: r.status,
        points: r.points,
        trials: r.trials,
        jobs: r.jobs,
        trials_converged: r.converged,
        trials_not_converged: r.not_converged,
        trials_with_shortfall: r.shortfall,
        workers_busy: r.workers_busy,
        created_at: rfc3339(r.created_at),
        started_at: r.started_at.map(rfc3339),
        finished_at: r.finished_at.map(rfc3339),
        eta_secs,
        convergence_threshold: r.threshold,
    }
}

async fn one(s: &AppState, id: &str) -> Result<SearchStatus, ApiError> {
    queue::search_rows(&s.db, Some(id))
        .await?
        .pop()
        .map(status_of)
        .ok_or_else(|| ApiError::NotFound(format!("no search with id {id}")))
}

/// `POST /api/v1/searches` -> 201 `{"id", "jobs"}`.
#[instrument(skip_all)]
pub async fn create(
    State(s): State<AppState>,
    ApiJson(req): ApiJson<SearchRequest>,
) -> Result<Response, ApiError> {
    let id = uuid::Uuid::new_v4().to_string();
    let new = science::prepare_search(&req, id.clone())?;
    let jobs = queue::insert_search(&s.db, &new, now_ms()).await?;
    Metrics::inc(&s.metrics.searches_created);
    s.notify.notify_waiters();
    tracing::info!(search_id = %id, jobs, name = %new.name, "search submitted");
    let location = format!("/api/v1/searches/{id}");
    Ok((
        StatusCode::CREATED,
        [(header::LOCATION, location)],
        Json(Created { id, jobs }),
    )
        .into_response())
}

/// `GET /api/v1/searches`: all searches, newest first.
pub async fn list(State(s): State<AppState>) -> Result<Json<Vec<SearchStatus>>, ApiError> {
    let rows = queue::search_rows(&s.db, None).await?;
    Ok(Json(rows.into_iter().map(status_of).collect()))
}

/// `GET /api/v1/searches/{id}`.
pub async fn status(
    State(s): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Json<SearchStatus>, ApiError> {
    Ok(Json(one(&s, &id).await?))
}

/// `POST /api/v1/searches/{id}/cancel`.
#[instrument(skip_all, fields(search_id = %id))]
pub async fn cancel(
    State(s): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Json<SearchStatus>, ApiError> {
    queue::cancel(&s.db, &id, now_ms()).await?;
    tracing::info!("search cancelled");
    Ok(Json(one(&s, &id).await?))
}

/// `GET /api/v1/searches/{id}/results`.
pub async fn results(
    State(s): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Response, ApiError> {
    let (row, doc) = results::document(&s, &id).await?;
    let view = ResultsView {
        search_id: &id,
        status: row.status,
        partial: row.status != SearchState::Completed,
        jobs: &row.jobs,
        document: &doc,
    };
    Ok(Json(view).into_response())
}

/// `GET /api/v1/searches/{id}/results.csv`.
pub async fn results_csv(
    State(s): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Response, ApiError> {
    let (_, doc) = results::document(&s, &id).await?;
    Ok((
        [(header::CONTENT_TYPE, "text/csv; charset=utf-8")],
        report_to_csv(&doc),
    )
        .into_response())
}

/// `GET /api/v1/searches/{id}/jobs`.
pub async fn jobs(
    State(s): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Json<Vec<JobInfo>>, ApiError> {
    s.search_info(&id).await?;
    Ok(Json(queue::list_jobs(&s.db, &id).await?))
}

/// `GET /api/v1/searches/{id}/outputs`: the aggregation input (every done
/// trial's output by grid point), exactly what the result document is
/// built from, so that `irlgrid analyze` can reproduce it.
pub async fn outputs(
    State(s): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Json<Vec<WeightInput>>, ApiError> {
    let info = s.search_info(&id).await?;
    Ok(Json(results::inputs(&s, &info).await?))
}
