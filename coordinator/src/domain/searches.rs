//! A search's life as clients drive it: submit, status, cancel, extend and
//! refine. Each call checks its request against the search (the intake's
//! rules), runs one store operation, and then tells the state what changed
//! (cached facts to drop, lease waiters to wake, a completed search for the
//! finalizer).

use std::collections::BTreeMap;

use shared::api::{
    Created, ExtendRequest, Extended, JobInfo, RefineRequest, SearchRequest, SearchState,
    SearchStatus,
};

use super::{search_info, DomainError, DomainResult};
use crate::intake;
use crate::metrics::Metrics;
use crate::state::AppState;
use crate::store::queue::{self, SearchRow};
use crate::store::{now_ms, rfc3339};

/// A status row as the API answers it.
pub fn status_of(r: SearchRow) -> SearchStatus {
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

/// The status of one search, or not found.
pub async fn status(s: &AppState, id: &str) -> DomainResult<SearchStatus> {
    queue::search_rows(&s.db, Some(id))
        .await?
        .pop()
        .map(status_of)
        .ok_or_else(|| DomainError::NotFound(format!("no search with id {id}")))
}

/// Submits a search: checks and resolves the request, stores the search
/// with its jobs under a new id, and wakes the waiting workers.
pub async fn create(s: &AppState, req: &SearchRequest) -> DomainResult<Created> {
    let id = uuid::Uuid::new_v4().to_string();
    let new = intake::prepare_search(req, id.clone())?;
    let jobs = queue::insert_search(&s.db, &new, now_ms()).await?;
    Metrics::inc(&s.metrics.searches_created);
    s.notify.notify_waiters();
    tracing::info!(search_id = %id, jobs, name = %new.name, "search submitted");
    Ok(Created { id, jobs })
}

/// Cancels a search and answers with its status after.
pub async fn cancel(s: &AppState, id: &str) -> DomainResult<SearchStatus> {
    queue::cancel(&s.db, id, now_ms()).await?;
    tracing::info!("search cancelled");
    status(s, id).await
}

/// Extends a search (more trials per point and/or more grid values, see
/// [`queue::extend`]), planned inside the store's write by the intake's
/// rules.
pub async fn extend(s: &AppState, id: &str, req: ExtendRequest) -> DomainResult<Extended> {
    let info = search_info(s, id).await?;
    intake::check_extension(&req, &info.resolved.env)?;
    let text = serde_json::to_string(&req).map_err(|e| DomainError::Internal(e.into()))?;
    let done = queue::extend(
        &s.db,
        id,
        &text,
        move |now| intake::plan_extension(&req, now),
        now_ms(),
    )
    .await?;
    // After the commit: the next read loads the new points and rebuilds
    // the document; waiting workers learn of the new jobs.
    s.search_extended(id).await;
    tracing::info!(
        trials = done.trials,
        points_added = done.points_added,
        jobs_added = done.jobs_added,
        extension = done.extension,
        "search extended"
    );
    Ok(done)
}

/// Asks for a refinement of the grid toward the search's subjects; a
/// search that has completed goes to the finalizer at once, which runs
/// the first round.
pub async fn refine(s: &AppState, id: &str, req: RefineRequest) -> DomainResult<()> {
    let info = search_info(s, id).await?;
    if info.subjects.is_empty() {
        return Err(DomainError::Invalid(
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
    let status = queue::request_refinement(&s.db, id, move |trials, rounds| {
        intake::resolve_refine(&req, &grid, trials, rounds)
    })
    .await?;
    if status == SearchState::Completed {
        s.search_completed(id.to_string());
    }
    tracing::info!("refinement requested");
    Ok(())
}

/// Every job of a known search, in queue order.
pub async fn jobs(s: &AppState, id: &str) -> DomainResult<Vec<JobInfo>> {
    search_info(s, id).await?;
    Ok(queue::list_jobs(&s.db, id).await?)
}
