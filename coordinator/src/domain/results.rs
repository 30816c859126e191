//! Result documents: the aggregation inputs of a search from its accepted
//! outputs' stored digests (never their trajectories), the `shared::analysis` document built from them (off the async
//! runtime), cached in memory while the search runs and in the database
//! once it has completed.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Instant;

use anyhow::Context;
use shared::analysis::{
    build_report_from, identifiability_from, refine, DigestedTrial, Identifiability, PointDigests,
    ReportOptions, ResultDocument, SolverTag, TrialInput, ANALYSIS_VERSION,
};
use shared::api::{point_label, Refinement, SearchState};

use crate::domain::doc_cache::{HeldOut, HeldOutPlan, Lookup, PartialDoc};
use crate::domain::DomainError;
use crate::state::AppState;
use crate::store::now_ms;
use crate::store::queue::{self, OutputRef, RoundDecision, SearchInfo, SearchRow};

/// Orders grid points by their values: parameters in name order, each by
/// value (for a grid submitted in increasing order this is the submission
/// order; points added by an extension take their place by value).
pub fn cmp_points(a: &BTreeMap<String, f64>, b: &BTreeMap<String, f64>) -> std::cmp::Ordering {
    for ((ka, va), (kb, vb)) in a.iter().zip(b) {
        let o = ka.cmp(kb).then(va.total_cmp(vb));
        if o != std::cmp::Ordering::Equal {
            return o;
        }
    }
    a.len().cmp(&b.len())
}

/// The grid facts that every accepted output of a search must fit: the
/// points (reloaded when an output names one that `info` lacks: facts
/// loaded before an extension) and the solver tags by variant. An output
/// of a point or variant the search does not have is an error, never
/// silently dropped.
async fn grid_of(
    state: &AppState,
    info: &SearchInfo,
    outputs: &[OutputRef],
) -> anyhow::Result<(Vec<BTreeMap<String, f64>>, Vec<SolverTag>)> {
    let points = if outputs
        .iter()
        .any(|o| o.point_idx as usize >= info.points.len())
    {
        queue::search_info(&state.db, &info.id)
            .await?
            .with_context(|| format!("search {} vanished", info.id))?
            .points
    } else {
        info.points.clone()
    };
    let solvers: Vec<SolverTag> = info
        .resolved
        .solver_specs()
        .iter()
        .map(|s| s.tag())
        .collect();
    for o in outputs {
        if o.variant as usize >= solvers.len() {
            anyhow::bail!(
                "search {}: an output of solver variant #{} that the search lacks",
                info.id,
                o.variant
            );
        }
        if o.point_idx as usize >= points.len() {
            anyhow::bail!(
                "search {}: an output of grid point #{} that the loaded grid ({} points) lacks",
                info.id,
                o.point_idx,
                points.len()
            );
        }
    }
    Ok((points, solvers))
}

/// The grid points in document order ([`cmp_points`]), as indices.
fn point_order(points: &[BTreeMap<String, f64>]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..points.len()).collect();
    // Stable: points that compare equal keep their grid order.
    order.sort_by(|&a, &b| cmp_points(&points[a], &points[b]));
    order
}

/// The aggregation input of a search from its stored trial digests: one
/// entry per grid point, ordered by value ([`cmp_points`]), with every
/// done trial (converged or not), by variant then trial.
pub async fn digests(state: &AppState, info: &SearchInfo) -> anyhow::Result<Vec<PointDigests>> {
    let rows = queue::digests(&state.db, &info.id).await?;
    let refs: Vec<OutputRef> = rows.iter().map(|(r, _)| *r).collect();
    let (points, solvers) = grid_of(state, info, &refs).await?;
    let mut weights: Vec<PointDigests> = points
        .iter()
        .map(|p| PointDigests {
            params: p.clone(),
            trials: Vec::new(),
        })
        .collect();
    for (o, digest) in rows {
        weights[o.point_idx as usize].trials.push(DigestedTrial {
            trial: o.trial,
            seed: o.seed,
            converged: o.converged,
            solver: solvers[o.variant as usize].clone(),
            digest: Arc::new(digest),
        });
    }
    let mut slots: Vec<Option<PointDigests>> = weights.into_iter().map(Some).collect();
    Ok(point_order(&points)
        .into_iter()
        .filter_map(|i| slots[i].take())
        .collect())
}

/// The raw aggregation input of a search (`/outputs`: every done trial's
/// output by grid point, in [`digests`]' order), written as the JSON of a
/// `Vec<WeightInput>` one output at a time: the chunks go to `tx` as they
/// are encoded, so at most one output (plus what the channel holds) is in
/// memory. The facts are checked before the first byte; a read failing
/// later ends the stream early (the client sees a truncated body).
pub async fn stream_outputs(
    state: AppState,
    info: Arc<SearchInfo>,
) -> anyhow::Result<tokio::sync::mpsc::Receiver<anyhow::Result<Vec<u8>>>> {
    let refs = queue::output_refs(&state.db, &info.id).await?;
    let (points, solvers) = grid_of(&state, &info, &refs).await?;
    let mut by_point: Vec<Vec<OutputRef>> = vec![Vec::new(); points.len()];
    for r in refs {
        by_point[r.point_idx as usize].push(r);
    }
    let (tx, rx) = tokio::sync::mpsc::channel(2);
    tokio::spawn(async move {
        let mut first_point = true;
        for i in point_order(&points) {
            let mut head = Vec::from(if first_point {
                &b"[{\"params\":"[..]
            } else {
                &b",{\"params\":"[..]
            });
            first_point = false;
            let chunk = serde_json::to_writer(&mut head, &points[i]).map(|()| {
                head.extend_from_slice(b",\"trials\":[");
                head
            });
            if tx.send(chunk.map_err(Into::into)).await.is_err() {
                return;
            }
            for (k, r) in by_point[i].iter().enumerate() {
                let chunk = async {
                    let o = queue::output(&state.db, r.job_id).await?;
                    let t = TrialInput {
                        trial: r.trial,
                        seed: r.seed,
                        final_success_rate: o.final_success_rate,
                        converged: r.converged,
                        episodes: o.episodes,
                        successes_found: o.successes_found,
                        successes_wanted: o.successes_wanted,
                        solver: solvers[r.variant as usize].clone(),
                    };
                    let mut buf = if k == 0 { Vec::new() } else { b",".to_vec() };
                    serde_json::to_writer(&mut buf, &t)?;
                    Ok(buf)
                }
                .await;
                let failed = chunk.is_err();
                if tx.send(chunk).await.is_err() || failed {
                    return;
                }
            }
            if tx.send(Ok(b"]}".to_vec())).await.is_err() {
                return;
            }
        }
        let _ = tx
            .send(Ok(if first_point {
                b"[]".to_vec()
            } else {
                b"]".to_vec()
            }))
            .await;
    });
    Ok(rx)
}

async fn build(
    state: &AppState,
    info: &SearchInfo,
    row: &SearchRow,
) -> anyhow::Result<ResultDocument> {
    let weights = Arc::new(digests(state, info).await?);
    let opts = info.resolved.report.clone();
    let subjects = info.subjects.clone();
    let mut doc = if row.status == SearchState::Running {
        build_running(state, info, row, weights, opts).await?
    } else {
        // A finished grid always gets its identifiability report.
        let when = match row.status {
            SearchState::Completed => Identifiability::Always,
            _ => Identifiability::WhenReady,
        };
        tokio::task::spawn_blocking(move || build_report_from(&weights, &subjects, &opts, when))
            .await
            .context("building the result document")?
    };
    for (point, trial, err) in queue::failed_jobs(&state.db, &info.id).await? {
        let params = info
            .points
            .get(point as usize)
            .map(point_label)
            .unwrap_or_else(|| format!("grid point #{point}"));
        doc.notes.push(format!(
            "{params} trial {trial}: job failed ({}); not in the statistics",
            err.unwrap_or_else(|| "no error recorded".to_string())
        ));
    }
    match row.status {
        SearchState::Running => doc.notes.push(format!(
            "partial: {} of {} jobs finished; the search is still running",
            row.jobs.done + row.jobs.failed,
            row.jobs.total
        )),
        SearchState::Cancelled => doc.notes.push(format!(
            "search cancelled: {} of {} jobs had finished",
            row.jobs.done, row.jobs.total
        )),
        SearchState::Completed => {}
    }
    Ok(doc)
}

/// A running search's document: the identifiability block (once every
/// point has enough trials to hold one out) comes from the cache's plan
/// ([`doc_cache::plan_held_out`]): built inline while cheap, else the last
/// one, with a note when it lags, while the next is built in the
/// background.
async fn build_running(
    state: &AppState,
    info: &SearchInfo,
    row: &SearchRow,
    weights: Arc<Vec<PointDigests>>,
    opts: ReportOptions,
) -> anyhow::Result<ResultDocument> {
    let finished = row.jobs.done + row.jobs.failed;
    let points = weights.len();
    let subjects = info.subjects.clone();
    let plan = state.docs.plan_held_out(&info.id, finished, points);
    let inline = matches!(plan, HeldOutPlan::Inline);
    let (w, o) = (weights.clone(), opts.clone());
    let (mut doc, built) = tokio::task::spawn_blocking(move || {
        let doc = build_report_from(&w, &subjects, &o, Identifiability::Never);
        let started = Instant::now();
        let held = inline.then(|| identifiability_from(&w, &o, Identifiability::WhenReady));
        (doc, held.map(|h| (h, started.elapsed())))
    })
    .await
    .context("building the result document")?;
    match (plan, built) {
        (_, Some((report, build_time))) => {
            doc.identifiability = report.clone();
            state.docs.put_held_out(
                &info.id,
                HeldOut::built_now(finished, points, build_time, report),
            );
        }
        (HeldOutPlan::Cached { held, refresh }, None) => {
            doc.identifiability = held.report.as_deref().cloned();
            if held.jobs_finished != finished && held.report.is_some() {
                doc.notes.push(format!(
                    "identifiability: from the {} jobs finished when it was last built; \
                     it is rebuilt in the background while the search runs",
                    held.jobs_finished
                ));
            }
            if refresh {
                spawn_held_out_refresh(state, &info.id, weights, opts, finished);
            }
        }
        (HeldOutPlan::Inline, None) => unreachable!("an inline plan builds the block"),
    }
    Ok(doc)
}

/// Builds the identifiability block of a running search in the background
/// (one such build at a time across all searches), then drops the cached
/// document so that the next read carries the new block.
fn spawn_held_out_refresh(
    state: &AppState,
    id: &str,
    weights: Arc<Vec<PointDigests>>,
    opts: ReportOptions,
    finished: u64,
) {
    if !state.docs.start_refresh(id) {
        return;
    }
    let (state, id) = (state.clone(), id.to_string());
    tokio::spawn(async move {
        let points = weights.len();
        let built = match state.docs.held_out_permit.acquire().await {
            Ok(_permit) => {
                let started = Instant::now();
                tokio::task::spawn_blocking(move || {
                    identifiability_from(&weights, &opts, Identifiability::WhenReady)
                })
                .await
                .map(|r| (r, started.elapsed()))
            }
            Err(_) => return,
        };
        // Not kept when the search completed or was extended meanwhile.
        if !state.docs.end_refresh(&id) {
            return;
        }
        match built {
            Ok((report, build_time)) => {
                state.docs.put_held_out(
                    &id,
                    HeldOut::built_now(finished, points, build_time, report),
                );
                state.docs.forget_doc(&id).await;
            }
            Err(e) => tracing::warn!(search_id = %id, error = %e, "identifiability build failed"),
        }
    });
}

/// The stored final document of a completed search as its JSON text, if
/// it was stored by the current analysis (the text starts with the
/// version: `analysis_version` is the document's first field). Served as
/// it is, without parsing it: reading a finished document costs one row
/// read whatever its size.
pub async fn final_text(
    state: &AppState,
    search_id: &str,
) -> Result<Option<(SearchRow, String)>, DomainError> {
    let Some(row) = queue::search_rows(&state.db, Some(search_id)).await?.pop() else {
        return Ok(None);
    };
    if row.status != SearchState::Completed {
        return Ok(None);
    }
    let current = format!("{{\"analysis_version\":{ANALYSIS_VERSION},");
    Ok(queue::final_document(&state.db, search_id)
        .await?
        .filter(|t| t.starts_with(&current))
        .map(|t| (row, t)))
}

/// The current document of a search: the cached final one once completed,
/// else a partial one (see [`doc_cache`] for when it is rebuilt).
pub async fn document(
    state: &AppState,
    search_id: &str,
) -> Result<(SearchRow, Arc<ResultDocument>), DomainError> {
    let (row, current) = current(state, search_id).await?;
    Ok((row, current.doc()))
}

/// A search's current document as [`current`] finds it.
pub enum Current {
    /// A completed search's final document.
    Final(Arc<ResultDocument>),
    /// A running or cancelled search's document, with its JSON text.
    Partial(Arc<PartialDoc>),
}

impl Current {
    /// The document.
    pub fn doc(&self) -> Arc<ResultDocument> {
        match self {
            Current::Final(d) => d.clone(),
            Current::Partial(p) => p.doc.clone(),
        }
    }
}

/// [`document`], keeping a partial document's JSON text.
pub async fn current(
    state: &AppState,
    search_id: &str,
) -> Result<(SearchRow, Current), DomainError> {
    let row = queue::search_rows(&state.db, Some(search_id))
        .await?
        .pop()
        .ok_or_else(|| DomainError::NotFound(format!("no search with id {search_id}")))?;
    let info = state.search_info(search_id).await?;
    if row.status == SearchState::Completed {
        if let Some(text) = queue::final_document(&state.db, search_id).await? {
            // A document stored by an older analysis is rebuilt (and stored
            // again) rather than served without the newer blocks.
            match serde_json::from_str::<ResultDocument>(&text) {
                Ok(doc) if doc.analysis_version == ANALYSIS_VERSION => {
                    return Ok((row, Current::Final(Arc::new(doc))));
                }
                _ => tracing::info!(%search_id, "rebuilding a final document of an older analysis"),
            }
        }
        let doc = build(state, &info, &row).await?;
        let text = serde_json::to_string(&doc).context("encoding final document")?;
        queue::store_final_document(&state.db, search_id, &text, row.jobs.total).await?;
        return Ok((row, Current::Final(Arc::new(doc))));
    }
    let key = row.doc_key();
    if let Some(entry) = serve_cached(state, search_id, &key).await {
        return Ok((row, Current::Partial(entry)));
    }
    // Concurrent readers share one build.
    let _building = state.docs.build_lock(search_id).await;
    if let Some(entry) = serve_cached(state, search_id, &key).await {
        return Ok((row, Current::Partial(entry)));
    }
    let entry = build_partial(state, &info, &row).await?;
    Ok((row, Current::Partial(entry)))
}

/// The cached document of a search if it may be served for `key`, starting
/// a background rebuild when one is due.
async fn serve_cached(state: &AppState, search_id: &str, key: &str) -> Option<Arc<PartialDoc>> {
    match state.docs.lookup(search_id, key).await {
        Lookup::Exact(entry) => Some(entry),
        Lookup::Stale { entry, refresh } => {
            if refresh {
                spawn_doc_refresh(state, search_id);
            }
            Some(entry)
        }
        Lookup::Miss => None,
    }
}

/// Builds, encodes and caches a running (or cancelled) search's document.
async fn build_partial(
    state: &AppState,
    info: &SearchInfo,
    row: &SearchRow,
) -> anyhow::Result<Arc<PartialDoc>> {
    let started = Instant::now();
    let doc = build(state, info, row).await?;
    let (doc, text) = tokio::task::spawn_blocking(move || {
        let text = serde_json::to_string(&doc);
        (doc, text)
    })
    .await
    .context("encoding the result document")?;
    let entry = PartialDoc {
        key: row.doc_key(),
        built: Instant::now(),
        build_time: started.elapsed(),
        doc: Arc::new(doc),
        text: text.context("encoding the result document")?.into(),
    };
    Ok(state.docs.put(&info.id, entry).await)
}

/// Rebuilds a stale expensive document in the background, unless a build
/// of it already runs.
fn spawn_doc_refresh(state: &AppState, search_id: &str) {
    let (state, id) = (state.clone(), search_id.to_string());
    tokio::spawn(async move {
        let Some(_building) = state.docs.try_build_lock(&id).await else {
            return;
        };
        let rebuilt = async {
            let Some(row) = queue::search_rows(&state.db, Some(&id)).await?.pop() else {
                return Ok(());
            };
            if row.status != SearchState::Running
                || matches!(
                    state.docs.lookup(&id, &row.doc_key()).await,
                    Lookup::Exact(_)
                )
            {
                return Ok(());
            }
            let info = state.search_info(&id).await?;
            build_partial(&state, &info, &row).await?;
            anyhow::Ok(())
        };
        if let Err(e) = rebuilt.await {
            tracing::warn!(search_id = %id, error = %e, "rebuilding a partial document failed");
        }
    });
}

/// Starts the one task that builds and caches the final document of each
/// search sent to [`AppState::search_completed`], one at a time (a second
/// call for the same state logs a warning and ends at once).
pub fn spawn_finalizer(state: &AppState) -> tokio::task::JoinHandle<()> {
    let rx = state.take_completed();
    let state = state.clone();
    tokio::spawn(async move {
        let Some(mut rx) = rx else {
            tracing::warn!("a finalizer already runs for this state");
            return;
        };
        while let Some(id) = rx.recv().await {
            finalize(&state, id).await;
        }
    })
}

/// Builds and caches the final document of a just-completed search, or,
/// for a refining one with rounds to come, adds the next round's points.
async fn finalize(state: &AppState, search_id: String) {
    state.docs.forget(&search_id).await;
    match refine_step(state, &search_id).await {
        Ok(Refined::Extended) => return,
        Ok(Refined::Settled(doc, jobs_total)) => {
            let stored = match serde_json::to_string(&doc) {
                Ok(text) => {
                    queue::store_final_document(&state.db, &search_id, &text, jobs_total).await
                }
                Err(e) => Err(crate::store::StoreError::Internal(e.into())),
            };
            match stored {
                Ok(()) => tracing::info!(%search_id, "refinement settled; final document cached"),
                Err(e) => tracing::warn!(%search_id, error = %e, "caching final document failed"),
            }
            return;
        }
        Ok(Refined::NotRefining) => {}
        Err(e) => tracing::warn!(%search_id, error = %e, "refinement round failed"),
    }
    match document(state, &search_id).await {
        Ok(_) => tracing::info!(%search_id, "search completed; final document cached"),
        Err(e) => tracing::warn!(%search_id, error = %e, "building final document failed"),
    }
}

/// A search's refinement as `GET /api/v1/searches/{id}/refinement`
/// serves it (also shown on the dashboard).
pub async fn refinement(state: &AppState, search_id: &str) -> Result<Refinement, DomainError> {
    let status = queue::search_rows(&state.db, Some(search_id))
        .await?
        .pop()
        .ok_or_else(|| DomainError::NotFound(format!("no search with id {search_id}")))?
        .status;
    let (spec, refine_state, rounds) = queue::refinement(&state.db, search_id)
        .await?
        .ok_or_else(|| DomainError::NotFound(format!("no search with id {search_id}")))?;
    Ok(Refinement {
        id: search_id.to_string(),
        status,
        spec,
        state: refine_state.unwrap_or_else(|| "none".to_string()),
        rounds,
    })
}

/// What [`refine_step`] did.
enum Refined {
    /// The search does not refine now (none asked for, settled, or not
    /// completed).
    NotRefining,
    /// Points were added; the search runs again.
    Extended,
    /// Refinement ended with this round; the final document of the grid
    /// and the job total it was built from.
    Settled(Box<ResultDocument>, u64),
}

/// The next round of a completed search that refines: reads every subject
/// against the finished grid (docs/science.md#refinement) and stores the
/// round, adding the midpoints the subjects ask for, or settles when none
/// asks for one, the rounds are used up, or the grid's limits are reached.
async fn refine_step(state: &AppState, search_id: &str) -> Result<Refined, DomainError> {
    let Some((Some(spec), Some(pending), rounds)) = queue::refinement(&state.db, search_id).await?
    else {
        return Ok(Refined::NotRefining);
    };
    let row = queue::search_rows(&state.db, Some(search_id))
        .await?
        .pop()
        .ok_or_else(|| DomainError::NotFound(format!("no search with id {search_id}")))?;
    if pending != "pending" || row.status != SearchState::Completed {
        return Ok(Refined::NotRefining);
    }
    let info = state.search_info(search_id).await?;
    let doc = build(state, &info, &row).await?;
    let round = rounds.len() as u32;
    let subjects = refine::evaluate(&doc, spec.rule());
    let wanted = refine::midpoints(&subjects);
    let used = round.saturating_sub(spec.first_round);
    let stop = if doc.subjects.is_empty() {
        Some("no subjects to refine toward".to_string())
    } else if wanted.is_empty() {
        Some(format!(
            "no subject asks for a point: each one's neighbouring candidates are within the \
             target ratio {}, its posterior does not straddle two neighbours (the grid does not \
             resolve it), or it has no answer",
            spec.target_ratio
        ))
    } else if used >= spec.rounds {
        Some(format!("all {} rounds used", spec.rounds))
    } else {
        None
    };
    let decision = RoundDecision {
        round,
        subjects,
        added: if stop.is_none() { wanted } else { Vec::new() },
        trials: spec.trials,
        stop,
    };
    let stored = match queue::refine_round(
        &state.db,
        search_id,
        decision.clone(),
        crate::intake::plan_refine_round,
        now_ms(),
    )
    .await
    {
        // The grid's limits refuse the points: refinement ends there.
        Err(DomainError::Invalid(why)) => {
            let settle = RoundDecision {
                added: Vec::new(),
                stop: Some(why),
                ..decision
            };
            queue::refine_round(
                &state.db,
                search_id,
                settle,
                crate::intake::plan_refine_round,
                now_ms(),
            )
            .await?
        }
        other => other?,
    };
    match stored {
        Some(Some(ext)) => {
            state.search_extended(search_id).await;
            tracing::info!(
                round,
                points_added = ext.points_added,
                jobs_added = ext.jobs_added,
                "refinement round added points"
            );
            Ok(Refined::Extended)
        }
        Some(None) => Ok(Refined::Settled(Box::new(doc), row.jobs.total)),
        // Another caller stored this round first.
        None => Ok(Refined::NotRefining),
    }
}
