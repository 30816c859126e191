//! Search endpoints: submit, list, status, cancel, extend, refine, results
//! (JSON and CSV), the job list and the raw aggregation inputs.

use std::borrow::Cow;

use axum::body::Bytes;
use axum::extract::rejection::QueryRejection;
use axum::extract::{Query, State};
use axum::http::HeaderMap;
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use shared::analysis::report_to_csv;
use shared::api::routes::Endpoint;
use shared::api::{
    ExtendRequest, Extended, JobInfo, PageQuery, RefineRequest, Refinement, ResultsView,
    ScoreQuery, ScoredSubjects, SearchRequest, SearchState, SearchStatus,
};
use tracing::instrument;

use crate::domain::results;
use crate::domain::scoring::{self, SubjectsUpload};
use crate::domain::searches;
use crate::error::ApiError;
use crate::extract::{ApiJson, ApiPath};
use crate::state::AppState;
use crate::store::queue::SearchRow;

/// `POST /api/v1/searches` -> 201 `{"id", "jobs"}`.
#[instrument(skip_all)]
pub async fn create(
    State(s): State<AppState>,
    ApiJson(req): ApiJson<SearchRequest>,
) -> Result<Response, ApiError> {
    let created = searches::create(&s, &req).await?;
    let location = Endpoint::SearchStatus.path_of(&created.id);
    Ok((
        StatusCode::CREATED,
        [(header::LOCATION, location)],
        Json(created),
    )
        .into_response())
}

/// `GET /api/v1/searches[?limit=N&offset=M]`: one page of searches,
/// newest first, with the total in `X-Total-Count`.
pub async fn list(
    State(s): State<AppState>,
    query: Result<Query<PageQuery>, QueryRejection>,
) -> Result<Response, ApiError> {
    let Query(q) = query.map_err(|e| ApiError::BadRequest(format!("query: {}", e.body_text())))?;
    let (total, rows) =
        crate::store::reads::search_slice(&s.db, i64::from(q.limit()), i64::from(q.offset()))
            .await?;
    let list: Vec<SearchStatus> = rows.into_iter().map(searches::status_of).collect();
    Ok(([(PageQuery::TOTAL_HEADER, total.to_string())], Json(list)).into_response())
}

/// `GET /api/v1/searches/{id}`.
pub async fn status(
    State(s): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Json<SearchStatus>, ApiError> {
    Ok(Json(searches::status(&s, &id).await?))
}

/// `POST /api/v1/searches/{id}/cancel`.
#[instrument(skip_all, fields(search_id = %id))]
pub async fn cancel(
    State(s): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Json<SearchStatus>, ApiError> {
    Ok(Json(searches::cancel(&s, &id).await?))
}

/// `POST /api/v1/searches/{id}/extend`: more trials per point and/or more
/// grid values (see [`searches::extend`]). 200 with what was added; 400 names
/// the field, 404 unknown search, 409 cancelled search.
#[instrument(skip_all, fields(search_id = %id))]
pub async fn extend(
    State(s): State<AppState>,
    ApiPath(id): ApiPath<String>,
    ApiJson(req): ApiJson<ExtendRequest>,
) -> Result<Json<Extended>, ApiError> {
    Ok(Json(searches::extend(&s, &id, req).await?))
}

/// `POST /api/v1/searches/{id}/refine`: refine the grid toward the
/// search's subjects once it has completed, at once if it has (see
/// `results::refine_step`). 200 with the refinement; 400 names the field
/// (or says the grid has several parameters or no subjects), 404 unknown
/// search, 409 cancelled search.
#[instrument(skip_all, fields(search_id = %id))]
pub async fn refine(
    State(s): State<AppState>,
    ApiPath(id): ApiPath<String>,
    ApiJson(req): ApiJson<RefineRequest>,
) -> Result<Json<Refinement>, ApiError> {
    searches::refine(&s, &id, req).await?;
    Ok(Json(results::refinement(&s, &id).await?))
}

/// `GET /api/v1/searches/{id}/refinement`.
pub async fn refinement(
    State(s): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Json<Refinement>, ApiError> {
    Ok(Json(results::refinement(&s, &id).await?))
}

/// `GET /api/v1/searches/{id}/results`.
pub async fn results(
    State(s): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Response, ApiError> {
    if let Some((row, text)) = results::final_text(&s, &id).await? {
        return spliced(&id, &row, &text);
    }
    match results::current(&s, &id).await? {
        (row, results::Current::Partial(entry)) => spliced(&id, &row, &entry.text),
        (row, results::Current::Final(doc)) => {
            let view = ResultsView {
                search_id: Cow::Borrowed(&id),
                status: row.status,
                partial: false,
                jobs: Cow::Borrowed(&row.jobs),
                document: Cow::Borrowed(&doc),
            };
            Ok(Json(view).into_response())
        }
    }
}

/// A [`ResultsView`] from a document's JSON text: the view's own fields,
/// then the document's, the bytes serde writes for the flattened view,
/// without parsing or encoding the document again.
fn spliced(id: &str, row: &SearchRow, text: &str) -> Result<Response, ApiError> {
    #[derive(serde::Serialize)]
    struct Head<'a> {
        search_id: &'a str,
        status: SearchState,
        partial: bool,
        jobs: &'a shared::api::JobCounts,
    }
    let mut body = serde_json::to_vec(&Head {
        search_id: id,
        status: row.status,
        partial: row.status != SearchState::Completed,
        jobs: &row.jobs,
    })
    .map_err(|e| ApiError::Internal(e.into()))?;
    body.pop();
    body.push(b',');
    body.extend_from_slice(&text.as_bytes()[1..]);
    Ok(([(header::CONTENT_TYPE, "application/json")], body).into_response())
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
    Ok(Json(searches::jobs(&s, &id).await?))
}

/// `GET /api/v1/searches/{id}/outputs`: the aggregation input (every done
/// trial's output by grid point, the JSON of a `Vec<WeightInput>`), what
/// the result document's digests were computed from, so that `irlgrid
/// analyze` can reproduce it. Streamed one output at a time.
pub async fn outputs(
    State(s): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Response, ApiError> {
    let info = s.search_info(&id).await?;
    let rx = results::stream_outputs(s.clone(), info).await?;
    let chunks =
        futures_util::stream::unfold(rx, |mut rx| async move { rx.recv().await.map(|c| (c, rx)) });
    Ok((
        [(header::CONTENT_TYPE, "application/json")],
        axum::body::Body::from_stream(chunks),
    )
        .into_response())
}

/// `POST /api/v1/searches/{id}/subjects[?save=true]`: scores new subjects
/// (a CSV body, or JSON `{"subjects_csv": ...}`) against the search's
/// finished trials without running a job.
#[instrument(skip_all, fields(search_id = %id))]
pub async fn score_subjects(
    State(s): State<AppState>,
    ApiPath(id): ApiPath<String>,
    query: Result<Query<ScoreQuery>, QueryRejection>,
    headers: HeaderMap,
    body: Bytes,
) -> Result<Json<ScoredSubjects>, ApiError> {
    let Query(q) = query.map_err(|e| ApiError::BadRequest(format!("query: {}", e.body_text())))?;
    let json = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("application/json"));
    let upload = SubjectsUpload { json, body: &body };
    Ok(Json(scoring::score_subjects(&s, &id, &q, upload).await?))
}
