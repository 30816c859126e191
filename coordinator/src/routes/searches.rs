//! Search endpoints: submit, list, status, cancel, extend, refine, results
//! (JSON and CSV), the job list and the raw aggregation inputs.

use std::borrow::Cow;
use std::collections::BTreeMap;

use axum::body::Bytes;
use axum::extract::rejection::QueryRejection;
use axum::extract::{Query, State};
use axum::http::HeaderMap;
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use shared::analysis::{
    build_report_from, report_to_csv, subjects_to_csv, Identifiability, Observables,
};
use shared::api::routes::Endpoint;
use shared::api::{
    Created, ExtendRequest, Extended, JobInfo, PageQuery, RefineRequest, Refinement, ResultsView,
    ScoreQuery, ScoredSubjects, SearchRequest, SearchState, SearchStatus, SubjectsBody,
};
use tracing::instrument;

use crate::error::ApiError;
use crate::extract::{ApiJson, ApiPath};
use crate::intake;
use crate::metrics::Metrics;
use crate::results;
use crate::state::AppState;
use crate::store::queue::{self, SearchRow};
use crate::store::{now_ms, rfc3339};

fn status_of(r: SearchRow) -> SearchStatus {
    let eta_secs = r.eta_secs();
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
    let new = intake::prepare_search(&req, id.clone())?;
    let jobs = queue::insert_search(&s.db, &new, now_ms()).await?;
    Metrics::inc(&s.metrics.searches_created);
    s.notify.notify_waiters();
    tracing::info!(search_id = %id, jobs, name = %new.name, "search submitted");
    let location = Endpoint::SearchStatus.path_of(&id);
    Ok((
        StatusCode::CREATED,
        [(header::LOCATION, location)],
        Json(Created { id, jobs }),
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
    let list: Vec<SearchStatus> = rows.into_iter().map(status_of).collect();
    Ok(([(PageQuery::TOTAL_HEADER, total.to_string())], Json(list)).into_response())
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

/// `POST /api/v1/searches/{id}/extend`: more trials per point and/or more
/// grid values (see [`queue::extend`]). 200 with what was added; 400 names
/// the field, 404 unknown search, 409 cancelled search.
#[instrument(skip_all, fields(search_id = %id))]
pub async fn extend(
    State(s): State<AppState>,
    ApiPath(id): ApiPath<String>,
    ApiJson(req): ApiJson<ExtendRequest>,
) -> Result<Json<Extended>, ApiError> {
    let info = s.search_info(&id).await?;
    intake::check_extension(&req, &info.resolved.env)?;
    let text = serde_json::to_string(&req).map_err(|e| ApiError::Internal(e.into()))?;
    let plan_req = req.clone();
    let done = queue::extend(
        &s.db,
        &id,
        &text,
        move |now| intake::plan_extension(&plan_req, now),
        now_ms(),
    )
    .await?;
    // After the commit: the next read loads the new points and rebuilds
    // the document; waiting workers learn of the new jobs.
    s.search_extended(&id).await;
    tracing::info!(
        trials = done.trials,
        points_added = done.points_added,
        jobs_added = done.jobs_added,
        extension = done.extension,
        "search extended"
    );
    Ok(Json(done))
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
    let info = s.search_info(&id).await?;
    if info.subjects.is_empty() {
        return Err(ApiError::BadRequest(
            "refine: the search has no subjects to refine toward (add them with POST \
             /api/v1/searches/{id}/subjects?save=true)"
                .to_string(),
        ));
    }
    let mut grid: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    for p in &info.points {
        for (k, v) in p {
            grid.entry(k.clone()).or_default().push(*v);
        }
    }
    let status = queue::request_refinement(&s.db, &id, move |trials, rounds| {
        intake::resolve_refine(&req, &grid, trials, rounds)
    })
    .await?;
    if status == SearchState::Completed {
        s.search_completed(id.clone());
    }
    tracing::info!("refinement requested");
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
    s.search_info(&id).await?;
    Ok(Json(queue::list_jobs(&s.db, &id).await?))
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
    let info = s.search_info(&id).await?;
    let json = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("application/json"));
    let text = if json {
        serde_json::from_slice::<SubjectsBody>(&body)
            .map_err(|e| ApiError::BadRequest(format!("body: {e}")))?
            .subjects_csv
    } else {
        String::from_utf8(body.to_vec())
            .map_err(|_| ApiError::BadRequest("subjects_csv: the body is not UTF-8".into()))?
    };
    let subjects = intake::parse_subjects(&text)?;
    let weights = results::digests(&s, &info).await?;
    if !weights.iter().flat_map(|w| &w.trials).any(|t| t.converged) {
        return Err(ApiError::Conflict(
            "no grid point has a converged trial yet; score subjects once one has".into(),
        ));
    }
    let mut stored = Vec::new();
    if q.save {
        stored = info.subjects.clone();
        if let Some(dup) = subjects
            .iter()
            .find(|n| stored.iter().any(|o| o.subject == n.subject))
        {
            return Err(ApiError::Conflict(format!(
                "subject {:?} is already stored with this search; rename it to add it",
                dup.subject
            )));
        }
        if stored.len() + subjects.len() > intake::MAX_SUBJECTS {
            return Err(ApiError::BadRequest(format!(
                "subjects_csv: {} stored and {} new subjects exceed the limit {}",
                stored.len(),
                subjects.len(),
                intake::MAX_SUBJECTS
            )));
        }
    }
    let mut report = info.resolved.report.clone();
    if let Some(name) = &q.observables {
        report.posterior.observables = Observables::parse(name).ok_or_else(|| {
            ApiError::BadRequest(format!(
                "observables: {name:?} is none of {}",
                Observables::ALL.map(|o| o.key()).join(", ")
            ))
        })?;
    }
    let points: Vec<BTreeMap<String, f64>> = weights.iter().map(|w| w.params.clone()).collect();
    let (doc, subjects) = tokio::task::spawn_blocking(move || {
        let doc = build_report_from(&weights, &subjects, &report, Identifiability::Never);
        (doc, subjects)
    })
    .await
    .map_err(|e| ApiError::Internal(anyhow::anyhow!("scoring subjects: {e}")))?;
    if q.save {
        stored.extend(subjects);
        queue::set_subjects(&s.db, &id, &subjects_to_csv(&stored)).await?;
        s.forget_search(&id).await;
        tracing::info!(added = doc.subjects.len(), "subjects added to the search");
    }
    Ok(Json(ScoredSubjects {
        search_id: id,
        saved: q.save,
        points,
        subjects: doc.subjects,
        notes: doc.notes,
    }))
}
