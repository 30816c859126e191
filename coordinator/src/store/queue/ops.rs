//! Every state change of searches and jobs, each one operation of the
//! group-committing writer thread ([`crate::store::writer`]): the public
//! functions hand their statements to the writer, which runs them in a
//! savepoint of its group transaction. The steps they share (one job
//! insert, one lease check, one attempts rule, one replacement rule, one
//! grid extension) take the writer's transaction.

use std::collections::{BTreeMap, HashSet};

use anyhow::Context;
use rusqlite::{params, OptionalExtension, Transaction};
use shared::api::{
    variant_seed, Extended, JobPhase, JobState, ProgressPoint, RefineSpec, SearchState,
};

use super::{
    new_token, parse_params, Claimed, Completion, Effects, ExtensionPlan, GridNow, NewSearch,
    RoundDecision, Upload,
};
use crate::store::error::{StoreError, StoreResult};
use crate::store::states::RefineState;
use crate::store::writer::{db_err, with_tx};
use crate::store::Db;

/// Returns expired leases to the queue or fails them (attempts used up),
/// each by the one attempts rule ([`lose_lease`]).
fn sweep_leases(tx: &Transaction<'_>, now: i64) -> StoreResult<Effects> {
    let expired: Vec<(i64, String)> = tx
        .prepare_cached(
            "select id, coalesce(worker_id, '?') from jobs
             where status = ?2 and lease_expires_at < ?1",
        )
        .map_err(db_err)?
        .query_map(params![now, JobState::Leased.as_str()], |r| {
            Ok((r.get(0)?, r.get(1)?))
        })
        .map_err(db_err)?
        .collect::<Result<_, _>>()
        .map_err(db_err)?;
    let mut eff = Effects {
        expired: expired.len() as u64,
        ..Effects::default()
    };
    for (job_id, owner) in expired {
        let (_, e) = lose_lease(tx, job_id, &format!("lease expired (owner {owner})"), now)?;
        eff.requeued += e.requeued;
        eff.completed.extend(e.completed);
    }
    Ok(eff)
}

/// The one attempts rule: a leased job that lost its lease (expired, or
/// its worker gave up) uses an attempt and goes back to the queue, or fails
/// with `error` once its attempts are used up. The caller has checked the
/// lease where a token is involved.
fn lose_lease(
    tx: &Transaction<'_>,
    job_id: i64,
    error: &str,
    now: i64,
) -> StoreResult<(JobState, Effects)> {
    let (search_id, point, status) = tx
        .prepare_cached(
            "update jobs set
                 status = case when attempts + 1 >= max_attempts then ?4 else ?5 end,
                 attempts = attempts + 1, lease_token = null,
                 last_error = case when attempts + 1 >= max_attempts
                     then ?1 || '; all ' || max_attempts || ' attempts used' else ?1 end,
                 lease_expires_at = null,
                 finished_at = case when attempts + 1 >= max_attempts then ?2 else null end
             where id = ?3 and status = ?6
             returning search_id, point_idx, variant, status",
        )
        .map_err(db_err)?
        .query_row(
            params![
                error,
                now,
                job_id,
                JobState::Failed.as_str(),
                JobState::Queued.as_str(),
                JobState::Leased.as_str(),
            ],
            |r| {
                Ok((
                    r.get::<_, String>(0)?,
                    (r.get::<_, i64>(1)? as u32, r.get::<_, i64>(2)? as u32),
                    r.get::<_, String>(3)?,
                ))
            },
        )
        .map_err(db_err)?;
    let mut eff = Effects::default();
    if JobState::parse(&status) == Some(JobState::Failed) {
        let (replaced, completed) = after_job_end(tx, search_id, point, true, now)?;
        eff.requeued += u64::from(replaced);
        eff.completed = completed;
        Ok((JobState::Failed, eff))
    } else {
        eff.requeued = 1;
        Ok((JobState::Queued, eff))
    }
}

/// Leases the next job fairly (see `queue::claim_with`): within the
/// search, jobs that lost fewer leases go first. A job whose lease was just
/// lost therefore waits behind the fresh ones, so a burst of dying workers
/// spreads its lost attempts over the queue instead of spending one job's
/// `max_attempts` (ordering by id alone re-leased the same few jobs to every
/// restarted worker; a soak with 100 worker kills failed one job that way).
fn claim(
    tx: &Transaction<'_>,
    worker: &str,
    token: String,
    lease_ms: i64,
    now: i64,
) -> StoreResult<Option<Claimed>> {
    let row = tx
        .prepare_cached(
            "update jobs set status = ?5, worker_id = ?1, lease_token = ?2,
                 lease_expires_at = ?3, leased_at = ?4, lease_count = lease_count + 1,
                 progress = null, phase = null
             where id = (
                 select j.id from jobs j
                 where j.status = ?6 and j.search_id = (
                     select s.id from searches s
                     where s.status = ?7
                       and exists (select 1 from jobs q
                                   where q.search_id = s.id and q.status = ?6)
                     order by (select count(*) from jobs l
                               where l.search_id = s.id and l.status = ?5),
                              s.seq
                     limit 1)
                 order by j.attempts, j.id limit 1)
             returning id, search_id, point_idx, trial, seed, lease_count, variant",
        )
        .map_err(db_err)?
        .query_row(
            params![
                worker,
                token,
                now + lease_ms,
                now,
                JobState::Leased.as_str(),
                JobState::Queued.as_str(),
                SearchState::Running.as_str(),
            ],
            |r| {
                Ok((
                    r.get::<_, i64>(0)?,
                    r.get::<_, String>(1)?,
                    (r.get::<_, i64>(2)?, r.get::<_, i64>(6)?),
                    r.get::<_, i64>(3)?,
                    r.get::<_, i64>(4)?,
                    r.get::<_, i64>(5)?,
                ))
            },
        )
        .optional()
        .map_err(db_err)?;
    let Some((job_id, search_id, (point, variant), trial, seed, count)) = row else {
        return Ok(None);
    };
    if count > 1 {
        // A re-lease starts a new learning curve.
        tx.prepare_cached("delete from job_progress where job_id = ?1")
            .map_err(db_err)?
            .execute(params![job_id])
            .map_err(db_err)?;
    }
    Ok(Some(Claimed {
        job_id,
        search_id,
        point_idx: point as u32,
        variant: variant as u32,
        trial: trial as u32,
        seed: seed as u64,
        attempt: count as u32,
        token,
    }))
}

/// The job's (status, current lease token), if it exists.
fn lease_row(tx: &Transaction<'_>, job_id: i64) -> StoreResult<Option<(JobState, Option<String>)>> {
    let row = tx
        .prepare_cached("select status, lease_token from jobs where id = ?1")
        .map_err(db_err)?
        .query_row(params![job_id], |r| {
            Ok((r.get::<_, String>(0)?, r.get::<_, Option<String>>(1)?))
        })
        .optional()
        .map_err(db_err)?;
    row.map(|(status, token)| {
        JobState::parse(&status)
            .map(|st| (st, token))
            .ok_or_else(|| StoreError::internal(format!("stored job status {status:?}")))
    })
    .transpose()
}

/// Checks in constant time that the job is leased under `token` (see
/// `queue::lease_verdict`); runs in the operation's savepoint before its
/// conditional `UPDATE`.
pub(crate) fn check_lease(tx: &Transaction<'_>, job_id: i64, token: &str) -> StoreResult<()> {
    super::lease_verdict(job_id, lease_row(tx, job_id)?, token)
}

/// Explains why a job call with this token matched no leased row.
pub(crate) fn refusal(tx: &Transaction<'_>, job_id: i64, token: &str) -> StoreError {
    match lease_row(tx, job_id) {
        Err(e) => e,
        Ok(row) => super::refusal(job_id, row, token),
    }
}

/// Accepts a result if `token` is the job's current lease: the job becomes
/// done, the output is stored, a replacement is enqueued for an
/// unconverged trial when the search asks for it, and the search completes
/// when nothing is left. Any other token gets 409 and changes nothing.
pub async fn complete_with(
    db: &Db,
    job_id: i64,
    token: &str,
    upload: Upload,
    threshold: f64,
    now: i64,
) -> StoreResult<Completion> {
    let token = token.to_string();
    with_tx(&db.writer, move |tx| {
        let token: &str = &token;
        let output: &Upload = &upload;
        check_lease(tx, job_id, token)?;
        let row = tx
            .prepare_cached(
                "update jobs set status = ?4, finished_at = ?1, lease_expires_at = null
                 where id = ?2 and status = ?5 and lease_token = ?3
                 returning search_id, point_idx, variant, worker_id, trial, seed",
            )
            .map_err(db_err)?
            .query_row(
                params![
                    now,
                    job_id,
                    token,
                    JobState::Done.as_str(),
                    JobState::Leased.as_str(),
                ],
                |r| {
                    Ok((
                        r.get::<_, String>(0)?,
                        (r.get::<_, i64>(1)? as u32, r.get::<_, i64>(2)? as u32),
                        r.get::<_, Option<String>>(3)?,
                        (r.get::<_, i64>(4)?, r.get::<_, i64>(5)?),
                    ))
                },
            )
            .optional()
            .map_err(db_err)?;
        let Some((search_id, point, worker, (trial, seed))) = row else {
            return Err(refusal(tx, job_id, token));
        };
        let converged = output.final_success_rate >= threshold;
        tx.prepare_cached(
            "insert into job_results (job_id, worker_id, final_success_rate, converged,
                 successes_found, successes_wanted, env_steps, output, uploaded_at)
             values (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9)",
        )
        .map_err(db_err)?
        .execute(params![
            job_id,
            worker.unwrap_or_default(),
            output.final_success_rate,
            converged,
            output.successes_found,
            output.successes_wanted,
            output.env_steps as i64,
            output.output,
            now
        ])
        .map_err(db_err)?;
        crate::faults::hit(crate::faults::Point::BetweenResultAndSummary);
        tx.prepare_cached(
            "insert into trial_summaries (job_id, search_id, point_idx, variant, trial, seed,
                 converged, digest)
             values (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
        )
        .map_err(db_err)?
        .execute(params![
            job_id,
            search_id,
            point.0,
            point.1,
            trial,
            seed,
            converged,
            output.digest
        ])
        .map_err(db_err)?;
        let (replacement, completed) = after_job_end(tx, search_id, point, !converged, now)?;
        Ok(Completion {
            converged,
            replacement,
            effects: Effects {
                requeued: u64::from(replacement),
                completed,
                ..Effects::default()
            },
        })
    })
    .await
}

/// A worker gave up on its job: attempts + 1 and back to the queue, or
/// failed with this error once the attempts are used up.
pub async fn fail(
    db: &Db,
    job_id: i64,
    token: &str,
    error: &str,
    now: i64,
) -> StoreResult<(JobState, Effects)> {
    let token = token.to_string();
    let error = error.to_string();
    with_tx(&db.writer, move |tx| {
        let token: &str = &token;
        let error: &str = &error;
        check_lease(tx, job_id, token)?;
        lose_lease(tx, job_id, error, now)
    })
    .await
}

/// Renews a lease and records progress. Refused (409) unless the token is
/// the job's current lease.
pub async fn heartbeat(
    db: &Db,
    job_id: i64,
    token: &str,
    phase: JobPhase,
    progress: &[ProgressPoint],
    lease_ms: i64,
    now: i64,
) -> StoreResult<()> {
    let encoded = progress
        .iter()
        .map(serde_json::to_string)
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| StoreError::Internal(anyhow::Error::new(e).context("encoding progress")))?;
    let phase = serde_json::to_value(phase)
        .ok()
        .and_then(|v| v.as_str().map(str::to_string));
    let token = token.to_string();
    with_tx(&db.writer, move |tx| {
        let token: &str = &token;
        let phase: Option<&str> = phase.as_deref();
        let progress: &[String] = &encoded;
        check_lease(tx, job_id, token)?;
        tx.prepare_cached(
            "update jobs set lease_expires_at = ?1, progress = coalesce(?2, progress), phase = ?3
             where id = ?4 and status = ?5",
        )
        .map_err(db_err)?
        .execute(params![
            now + lease_ms,
            progress.last(),
            phase,
            job_id,
            JobState::Leased.as_str(),
        ])
        .map_err(db_err)?;
        if progress.is_empty() {
            return Ok(());
        }
        let next: i64 = tx
            .prepare_cached("select coalesce(max(seq), 0) + 1 from job_progress where job_id = ?1")
            .map_err(db_err)?
            .query_row(params![job_id], |r| r.get(0))
            .map_err(db_err)?;
        for (i, p) in progress.iter().enumerate() {
            tx.prepare_cached(
                "insert into job_progress (job_id, seq, progress) values (?1, ?2, ?3)",
            )
            .map_err(db_err)?
            .execute(params![job_id, next + i as i64, p])
            .map_err(db_err)?;
        }
        loop {
            let n: i64 = tx
                .prepare_cached("select count(*) from job_progress where job_id = ?1")
                .map_err(db_err)?
                .query_row(params![job_id], |r| r.get(0))
                .map_err(db_err)?;
            if n <= super::HISTORY_CAP {
                return Ok(());
            }
            // Drop every other point (never the last one).
            tx.prepare_cached(
                "delete from job_progress where job_id = ?1 and seq in (
                     select seq from (select seq, row_number() over (order by seq desc) as rn
                                      from job_progress where job_id = ?1)
                     where rn % 2 = 0)",
            )
            .map_err(db_err)?
            .execute(params![job_id])
            .map_err(db_err)?;
        }
    })
    .await
}

/// A worker hands its job back unfinished (shutting down): back to the
/// queue without using an attempt.
pub async fn release(db: &Db, job_id: i64, token: &str) -> StoreResult<Effects> {
    let token = token.to_string();
    with_tx(&db.writer, move |tx| {
        let token: &str = &token;
        check_lease(tx, job_id, token)?;
        tx.prepare_cached(
            "update jobs set status = ?2, lease_token = null, lease_expires_at = null
             where id = ?1 and status = ?3",
        )
        .map_err(db_err)?
        .execute(params![
            job_id,
            JobState::Queued.as_str(),
            JobState::Leased.as_str(),
        ])
        .map_err(db_err)?;
        Ok(Effects {
            requeued: 1,
            ..Effects::default()
        })
    })
    .await
}

/// Cancels a search: queued and leased jobs become cancelled (their workers
/// learn it at the next heartbeat); finished jobs are kept. Cancelling a
/// cancelled search is a no-op; a completed one is a conflict.
pub async fn cancel(db: &Db, search_id: &str, now: i64) -> StoreResult<SearchState> {
    let id = search_id.to_string();
    with_tx(&db.writer, move |tx| {
        let search_id: &str = &id;
        let status: Option<String> = tx
            .prepare_cached("select status from searches where id = ?1")
            .map_err(db_err)?
            .query_row(params![search_id], |r| r.get(0))
            .optional()
            .map_err(db_err)?;
        match status.as_deref().map(SearchState::parse) {
            None => {
                return Err(StoreError::NotFound(format!(
                    "no search with id {search_id}"
                )))
            }
            Some(Some(SearchState::Completed)) => {
                return Err(StoreError::Conflict(format!(
                    "search {search_id} has already completed"
                )))
            }
            Some(Some(SearchState::Cancelled)) => return Ok(SearchState::Cancelled),
            Some(Some(SearchState::Running)) => {}
            Some(None) => {
                return Err(StoreError::internal(format!(
                    "stored search status {status:?}"
                )))
            }
        }
        tx.prepare_cached("update searches set status = ?3, finished_at = ?1 where id = ?2")
            .map_err(db_err)?
            .execute(params![now, search_id, SearchState::Cancelled.as_str()])
            .map_err(db_err)?;
        tx.prepare_cached(
            "update jobs set status = ?3, lease_token = null, lease_expires_at = null,
                 finished_at = ?1
             where search_id = ?2 and status in (?4, ?5)",
        )
        .map_err(db_err)?
        .execute(params![
            now,
            search_id,
            JobState::Cancelled.as_str(),
            JobState::Queued.as_str(),
            JobState::Leased.as_str(),
        ])
        .map_err(db_err)?;
        Ok(SearchState::Cancelled)
    })
    .await
}

/// Inserts a search with its points and its `points x trials` jobs, ordered
/// trial-major so that early trials of every point finish first and partial
/// results cover the whole grid. Returns the number of jobs.
pub async fn insert_search(db: &Db, s: &NewSearch, now: i64) -> StoreResult<u64> {
    let s = s.clone();
    with_tx(&db.writer, move |tx| {
        let s: &NewSearch = &s;
        tx.prepare_cached(
            "insert into searches (id, seq, name, status, request, config, trials, base_seed,
                 convergence_threshold, replace_unconverged, max_trials_per_point, max_attempts,
                 subjects_csv, created_at, refine, refine_state, variants)
             values (?1, (select coalesce(max(seq), 0) + 1 from searches), ?2, ?16, ?3, ?4,
                 ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15)",
        )
        .map_err(db_err)?
        .execute(params![
            s.id,
            s.name,
            s.request,
            s.config,
            s.trials,
            s.base_seed as i64,
            s.threshold,
            s.replace_unconverged,
            s.max_trials_per_point,
            s.max_attempts,
            s.subjects_csv,
            now,
            s.refine.as_ref().map(encode).transpose()?,
            s.refine.as_ref().map(|_| RefineState::Pending.as_str()),
            s.variants,
            SearchState::Running.as_str(),
        ])
        .map_err(db_err)?;
        for (idx, params) in s.points.iter().enumerate() {
            let text = serde_json::to_string(params).map_err(|e| {
                StoreError::Internal(anyhow::Error::new(e).context("encoding point"))
            })?;
            tx.prepare_cached("insert into points (search_id, idx, params) values (?1, ?2, ?3)")
                .map_err(db_err)?
                .execute(params![s.id, idx as i64, text])
                .map_err(db_err)?;
        }
        let mut n = 0u64;
        // Trial-major, so that early trials of every point finish first, and
        // every variant of a (point, trial) goes out together.
        for trial in 0..s.trials {
            for (idx, params) in s.points.iter().enumerate() {
                for variant in 0..s.variants {
                    let seed = variant_seed(s.base_seed, params, trial, variant);
                    let job = (idx as u32, variant, trial);
                    insert_job(tx, &s.id, job, seed, s.max_attempts, now)?;
                    n += 1;
                }
            }
        }
        Ok(n)
    })
    .await
}

/// The one job insert: a queued job `(point, variant, trial)`.
fn insert_job(
    tx: &Transaction<'_>,
    search_id: &str,
    (point, variant, trial): (u32, u32, u32),
    seed: u64,
    max_attempts: u32,
    now: i64,
) -> StoreResult<()> {
    tx.prepare_cached(
        "insert into jobs (search_id, point_idx, variant, trial, seed, status, max_attempts,
             queued_at)
         values (?1, ?2, ?3, ?4, ?5, ?8, ?6, ?7)",
    )
    .map_err(db_err)?
    .execute(params![
        search_id,
        point,
        variant,
        trial,
        seed as i64,
        max_attempts,
        now,
        JobState::Queued.as_str(),
    ])
    .map_err(db_err)?;
    Ok(())
}

/// Records the first lease of a search (no-op once set).
pub async fn mark_started(db: &Db, search_id: &str, now: i64) -> StoreResult<()> {
    let id = search_id.to_string();
    with_tx(&db.writer, move |tx| {
        let search_id: &str = &id;
        tx.prepare_cached(
            "update searches set started_at = ?1 where id = ?2 and started_at is null",
        )
        .map_err(db_err)?
        .execute(params![now, search_id])
        .map_err(db_err)?;
        Ok(())
    })
    .await
}

/// Caches the final document of a completed search that was built when
/// the search had `jobs_total` jobs (ignored if it has more by now).
pub async fn store_final_document(
    db: &Db,
    search_id: &str,
    doc: &str,
    jobs_total: u64,
) -> StoreResult<()> {
    let (id, doc) = (search_id.to_string(), doc.to_string());
    with_tx(&db.writer, move |tx| {
        let search_id: &str = &id;
        let doc: &str = &doc;
        tx.prepare_cached(
            "update searches set final_document = ?1
             where id = ?2 and status = ?4
               and (select count(*) from jobs where search_id = ?2) = ?3",
        )
        .map_err(db_err)?
        .execute(params![
            doc,
            search_id,
            jobs_total as i64,
            SearchState::Completed.as_str(),
        ])
        .map_err(db_err)?;
        Ok(())
    })
    .await
}

/// Replaces the stored subjects of a search and drops its cached final
/// document, which no longer shows them all; the next read rebuilds it.
pub async fn set_subjects(db: &Db, search_id: &str, subjects_csv: &str) -> StoreResult<()> {
    let (id, csv) = (search_id.to_string(), subjects_csv.to_string());
    with_tx(&db.writer, move |tx| {
        let search_id: &str = &id;
        let subjects_csv: &str = &csv;
        tx.prepare_cached(
            "update searches set subjects_csv = ?1, final_document = null where id = ?2",
        )
        .map_err(db_err)?
        .execute(params![subjects_csv, search_id])
        .map_err(db_err)?;
        Ok(())
    })
    .await
}

/// The health probe: a read on the reader pool, then a one-row write
/// committed by the writer thread.
pub async fn probe(db: &Db, now: i64) -> StoreResult<()> {
    sqlx::query("select 1")
        .execute(&db.read)
        .await
        .map_err(StoreError::from)?;
    with_tx(&db.writer, move |tx| {
        tx.prepare_cached(
            "insert into health_probe (id, checked_at) values (1, ?1)
             on conflict (id) do update set checked_at = excluded.checked_at",
        )
        .map_err(db_err)?
        .execute(params![now])
        .map_err(db_err)?;
        Ok(())
    })
    .await
}

/// After a job of `(point, variant)` ended (done or failed): enqueue a
/// replacement if asked and allowed, and complete the search when nothing
/// is left. Returns (replacement enqueued, searches completed).
fn after_job_end(
    tx: &Transaction<'_>,
    search_id: String,
    point: (u32, u32),
    wants_replacement: bool,
    now: i64,
) -> StoreResult<(bool, Vec<String>)> {
    let replaced = wants_replacement && replace_one(tx, &search_id, point, now)?;
    let remaining: bool = tx
        .prepare_cached(
            "select exists (select 1 from jobs
                            where search_id = ?1 and status in (?2, ?3))",
        )
        .map_err(db_err)?
        .query_row(
            params![
                search_id,
                JobState::Queued.as_str(),
                JobState::Leased.as_str(),
            ],
            |r| r.get(0),
        )
        .map_err(db_err)?;
    let mut completed = Vec::new();
    if !remaining {
        let n = tx
            .prepare_cached(
                "update searches set status = ?3, finished_at = ?1
                 where id = ?2 and status = ?4",
            )
            .map_err(db_err)?
            .execute(params![
                now,
                search_id,
                SearchState::Completed.as_str(),
                SearchState::Running.as_str(),
            ])
            .map_err(db_err)?;
        if n == 1 {
            completed.push(search_id);
        }
    }
    Ok((replaced, completed))
}

/// The settings of a search that decide which jobs it gets.
struct SearchSettings {
    status: String,
    trials: i64,
    base_seed: i64,
    replace: bool,
    cap: i64,
    max_attempts: i64,
    /// Solver variants each (point, trial) runs as.
    variants: i64,
}

/// Reads a search's [`SearchSettings`], `None` for an unknown search.
fn search_settings(tx: &Transaction<'_>, search_id: &str) -> StoreResult<Option<SearchSettings>> {
    tx.prepare_cached(
        "select status, trials, base_seed, replace_unconverged, max_trials_per_point,
                max_attempts, variants
         from searches where id = ?1",
    )
    .map_err(db_err)?
    .query_row(params![search_id], |r| {
        Ok(SearchSettings {
            status: r.get(0)?,
            trials: r.get(1)?,
            base_seed: r.get(2)?,
            replace: r.get(3)?,
            cap: r.get(4)?,
            max_attempts: r.get(5)?,
            variants: r.get(6)?,
        })
    })
    .optional()
    .map_err(db_err)
}

/// Enqueues one replacement trial of solver variant `variant` at `point`
/// when the search is running, asks for replacements, has fewer converged
/// plus outstanding trials of that variant there than it wants, and is
/// below its cap. The trial number continues after the highest of that
/// (point, variant), with the seed [`variant_seed`] gives it.
fn replace_one(
    tx: &Transaction<'_>,
    search_id: &str,
    (point, variant): (u32, u32),
    now: i64,
) -> StoreResult<bool> {
    let Some(SearchSettings {
        status,
        trials,
        base_seed,
        replace,
        cap,
        max_attempts,
        ..
    }) = search_settings(tx, search_id)?
    else {
        return Ok(false);
    };
    if SearchState::parse(&status) == Some(SearchState::Running) && replace {
        let (converged, outstanding, total, max_trial) = tx
            .prepare_cached(
                "select coalesce(sum(case when r.converged = 1 then 1 else 0 end), 0),
                        coalesce(sum(case when j.status in (?4, ?5) then 1 else 0 end), 0),
                        count(*), max(j.trial)
                 from jobs j left join job_results r on r.job_id = j.id
                 where j.search_id = ?1 and j.point_idx = ?2 and j.variant = ?3",
            )
            .map_err(db_err)?
            .query_row(
                params![
                    search_id,
                    point,
                    variant,
                    JobState::Queued.as_str(),
                    JobState::Leased.as_str(),
                ],
                |r| {
                    Ok((
                        r.get::<_, i64>(0)?,
                        r.get::<_, i64>(1)?,
                        r.get::<_, i64>(2)?,
                        r.get::<_, i64>(3)?,
                    ))
                },
            )
            .map_err(db_err)?;
        let wanted = point_trials(tx, search_id, point)?.unwrap_or(trials);
        let cap = cap.max(wanted);
        if converged + outstanding < wanted && total < cap {
            let params_text: String = tx
                .query_row(
                    "select params from points where search_id = ?1 and idx = ?2",
                    params![search_id, point],
                    |r| r.get(0),
                )
                .map_err(db_err)?;
            let trial = (max_trial + 1) as u32;
            let seed = variant_seed(
                base_seed as u64,
                &parse_params(&params_text)?,
                trial,
                variant,
            );
            let job = (point, variant, trial);
            insert_job(tx, search_id, job, seed, max_attempts as u32, now)?;
            return Ok(true);
        }
    }
    Ok(false)
}

/// A stored search status that may still grow; 409 for a cancelled search
/// (`verb`: what it cannot be).
fn not_cancelled(search_id: &str, status: &str, verb: &str) -> StoreResult<SearchState> {
    let state = SearchState::parse(status)
        .ok_or_else(|| StoreError::Internal(anyhow::anyhow!("stored search status {status:?}")))?;
    if state == SearchState::Cancelled {
        return Err(StoreError::Conflict(format!(
            "search {search_id} was cancelled; a cancelled search cannot be {verb}"
        )));
    }
    Ok(state)
}

/// Extends a search (see `queue::extend`).
pub(crate) fn extend_grid<E: From<StoreError>>(
    tx: &Transaction<'_>,
    search_id: &str,
    request: &str,
    plan: impl FnOnce(&GridNow) -> Result<ExtensionPlan, E>,
    now: i64,
) -> Result<Extended, E> {
    let Some(SearchSettings {
        status,
        trials,
        cap,
        base_seed,
        max_attempts,
        replace,
        variants,
    }) = search_settings(tx, search_id)?
    else {
        return Err(StoreError::NotFound(format!("no search with id {search_id}")).into());
    };
    let variants = variants.max(1) as u32;
    let status = not_cancelled(search_id, &status, "extended")?;
    let stored: Vec<(i64, String, Option<i64>)> = tx
        .prepare_cached("select idx, params, trials from points where search_id = ?1 order by idx")
        .map_err(db_err)?
        .query_map(params![search_id], |r| {
            Ok((r.get(0)?, r.get(1)?, r.get(2)?))
        })
        .map_err(db_err)?
        .collect::<Result<_, _>>()
        .map_err(db_err)?;
    // (index, params, trials wanted there when not the search's).
    let mut points: Vec<(u32, BTreeMap<String, f64>, Option<u32>)> = stored
        .iter()
        .map(|(i, p, t)| Ok((*i as u32, parse_params(p)?, t.map(|t| t as u32))))
        .collect::<anyhow::Result<_>>()
        .map_err(StoreError::from)?;
    let now_grid = GridNow {
        status,
        trials: trials as u32,
        max_trials_per_point: cap as u32,
        points: points.iter().map(|(_, p, _)| p.clone()).collect(),
        variants,
    };
    let p = plan(&now_grid)?;
    if p.trials < now_grid.trials || p.max_trials_per_point < p.trials {
        return Err(StoreError::Internal(anyhow::anyhow!(
            "extension plan lowers trials or its cap: {p:?}"
        ))
        .into());
    }
    let extension: i64 = tx
        .prepare_cached(
            "select coalesce(max(seq), 0) + 1 from search_extensions where search_id = ?1",
        )
        .map_err(db_err)?
        .query_row(params![search_id], |r| r.get(0))
        .map_err(db_err)?;
    let first_idx = points.iter().map(|(i, _, _)| i + 1).max().unwrap_or(0);
    // Raising the search's trials raises every point to at least that
    // many: a point added by refinement with its own count keeps it only
    // while it is above the new one.
    if i64::from(p.trials) > trials {
        for (_, _, own) in points.iter_mut() {
            if own.is_some_and(|t| t <= p.trials) {
                *own = None;
            }
        }
        tx.prepare_cached("update points set trials = null where search_id = ?1 and trials <= ?2")
            .map_err(db_err)?
            .execute(params![search_id, p.trials])
            .map_err(db_err)?;
    }
    for (next_idx, params) in (first_idx..).zip(&p.new_points) {
        let text = serde_json::to_string(params)
            .map_err(|e| StoreError::Internal(anyhow::Error::new(e).context("encoding point")))?;
        // `unique (search_id, params)`: a point already there is refused
        // by the schema too, whatever the plan said.
        tx.prepare_cached(
            "insert into points (search_id, idx, params, extension, trials)
             values (?1, ?2, ?3, ?4, ?5)",
        )
        .map_err(db_err)?
        .execute(params![
            search_id,
            next_idx,
            text,
            extension,
            p.new_point_trials
        ])
        .map_err(|e| match e.sqlite_error_code() {
            Some(rusqlite::ErrorCode::ConstraintViolation) => {
                StoreError::Invalid(format!("reward_grid: point {text} is already in the grid"))
            }
            _ => db_err(e),
        })?;
        points.push((next_idx, params.clone(), p.new_point_trials));
    }
    tx.prepare_cached(
        "update searches set trials = ?1, max_trials_per_point = ?2, status = ?4,
             finished_at = null, final_document = null
         where id = ?3",
    )
    .map_err(db_err)?
    .execute(params![
        p.trials,
        p.max_trials_per_point,
        search_id,
        SearchState::Running.as_str(),
    ])
    .map_err(db_err)?;
    let have: HashSet<(u32, u32, u32)> = tx
        .prepare_cached("select point_idx, variant, trial from jobs where search_id = ?1")
        .map_err(db_err)?
        .query_map(params![search_id], |r| {
            Ok((
                r.get::<_, i64>(0)? as u32,
                r.get::<_, i64>(1)? as u32,
                r.get::<_, i64>(2)? as u32,
            ))
        })
        .map_err(db_err)?
        .collect::<Result<_, _>>()
        .map_err(db_err)?;
    let mut jobs_added = 0u64;
    // Trial-major, as at submission: the new trials of every point go out
    // before any point's later ones.
    let most = points
        .iter()
        .map(|(_, _, own)| own.unwrap_or(p.trials))
        .max()
        .unwrap_or(p.trials);
    for trial in 0..most {
        for (idx, params, own) in &points {
            for variant in 0..variants {
                if trial >= own.unwrap_or(p.trials) || have.contains(&(*idx, variant, trial)) {
                    continue;
                }
                let seed = variant_seed(base_seed as u64, params, trial, variant);
                let job = (*idx, variant, trial);
                insert_job(tx, search_id, job, seed, max_attempts as u32, now)?;
                jobs_added += 1;
            }
        }
    }
    if replace {
        // Points whose unconverged trials were replaced up to the old
        // count may need more replacements for the new one.
        for (idx, _, _) in &points {
            for variant in 0..variants {
                while replace_one(tx, search_id, (*idx, variant), now)? {
                    jobs_added += 1;
                }
            }
        }
    }
    if jobs_added == 0 {
        // Rolls the whole operation back (its savepoint): nothing changed.
        return Err(StoreError::Invalid(format!(
            "trials: the extension adds no job (every trial below {} of every point exists \
             already)",
            p.trials
        ))
        .into());
    }
    tx.prepare_cached(
        "insert into search_extensions (search_id, seq, request, trials_before, trials_after,
             points_added, jobs_added, created_at)
         values (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
    )
    .map_err(db_err)?
    .execute(params![
        search_id,
        extension,
        request,
        trials,
        p.trials,
        p.new_points.len() as i64,
        jobs_added as i64,
        now
    ])
    .map_err(db_err)?;
    Ok(Extended {
        id: search_id.to_string(),
        status: SearchState::Running,
        trials: p.trials,
        points: points.len() as u64,
        points_added: p.new_points.len() as u64,
        jobs_added,
        extension: extension as u32,
    })
}

/// Trials wanted at a point when it has its own count (points added by
/// refinement), else `None`: the search's.
fn point_trials(tx: &Transaction<'_>, search_id: &str, point: u32) -> StoreResult<Option<i64>> {
    tx.prepare_cached("select trials from points where search_id = ?1 and idx = ?2")
        .map_err(db_err)?
        .query_row(params![search_id, point], |r| r.get(0))
        .optional()
        .map(Option::flatten)
        .map_err(db_err)
}

fn encode<T: serde::Serialize>(v: &T) -> StoreResult<String> {
    serde_json::to_string(v).map_err(|e| StoreError::Internal(anyhow::Error::new(e)))
}

/// What a refinement step reads of its search.
struct RefineFacts {
    status: String,
    trials: i64,
    state: Option<String>,
    /// Rounds recorded so far.
    rounds: i64,
}

fn refine_facts(tx: &Transaction<'_>, search_id: &str) -> StoreResult<Option<RefineFacts>> {
    tx.prepare_cached(
        "select s.status, s.trials, s.refine_state,
                (select count(*) from refine_rounds r where r.search_id = s.id)
         from searches s where s.id = ?1",
    )
    .map_err(db_err)?
    .query_row(params![search_id], |r| {
        Ok(RefineFacts {
            status: r.get(0)?,
            trials: r.get(1)?,
            state: r.get(2)?,
            rounds: r.get(3)?,
        })
    })
    .optional()
    .map_err(db_err)
}

/// Asks for a refinement of a search: `spec(search trials, rounds so
/// far)` resolves the request against the stored search (a refusal
/// changes nothing). The search refines when it next completes, at once
/// if it has completed already (the caller hands it to the finalizer).
/// 404 unknown, 409 cancelled. Returns the search's state.
pub async fn request_refinement<E: From<StoreError> + Send + 'static>(
    db: &Db,
    search_id: &str,
    spec: impl FnOnce(u32, u32) -> Result<RefineSpec, E> + Send + 'static,
) -> Result<SearchState, E> {
    let id = search_id.to_string();
    with_tx(&db.writer, move |tx| {
        let search_id: &str = &id;
        let Some(RefineFacts {
            status,
            trials,
            rounds,
            ..
        }) = refine_facts(tx, search_id)?
        else {
            return Err(StoreError::NotFound(format!("no search with id {search_id}")).into());
        };
        let status = not_cancelled(search_id, &status, "refined")?;
        let spec = spec(trials as u32, rounds as u32)?;
        tx.prepare_cached("update searches set refine = ?1, refine_state = ?3 where id = ?2")
            .map_err(db_err)?
            .execute(params![
                encode(&spec)?,
                search_id,
                RefineState::Pending.as_str(),
            ])
            .map_err(db_err)?;
        Ok(status)
    })
    .await
}

/// Stores a refinement round of a completed, pending search in one write:
/// the round's row and, when it adds values, the extension that adds them
/// (the search runs again); when it adds none, the search is settled.
/// `None` when that round is stored already or the search is not a
/// completed, pending one any more (a second caller): nothing changes.
/// `plan` turns the added values into the extension against the grid as it
/// stands in that write, within the intake's limits (the store enforces
/// none: `intake::plan_refine_round`).
pub async fn refine_round<E: From<StoreError> + Send + 'static>(
    db: &Db,
    search_id: &str,
    d: RoundDecision,
    plan: fn(&GridNow, &str, &[f64], u32) -> Result<ExtensionPlan, E>,
    now: i64,
) -> Result<Option<Option<Extended>>, E> {
    let id = search_id.to_string();
    let subjects =
        serde_json::to_string(&d.subjects).map_err(|e| StoreError::Internal(e.into()))?;
    with_tx(&db.writer, move |tx| {
        let search_id: &str = &id;
        let round: u32 = d.round;
        let subjects: &str = &subjects;
        let added: &[f64] = &d.added;
        let trials: u32 = d.trials;
        let stop: Option<&str> = d.stop.as_deref();
        match refine_facts(tx, search_id)? {
            Some(RefineFacts {
                status,
                state: Some(state),
                rounds,
                ..
            }) if SearchState::parse(&status) == Some(SearchState::Completed)
                && RefineState::parse(&state) == Some(RefineState::Pending)
                && rounds == i64::from(round) => {}
            _ => return Ok(None),
        }
        let extended = if added.is_empty() {
            None
        } else {
            let param = serde_json::from_str::<RefineSpec>(
                &tx.query_row(
                    "select refine from searches where id = ?1",
                    params![search_id],
                    |r| r.get::<_, String>(0),
                )
                .map_err(db_err)?,
            )
            .map_err(|e| StoreError::Internal(anyhow::Error::new(e).context("stored refine spec")))?
            .param;
            let request =
                encode(&serde_json::json!({ "refine_round": round, "reward_grid": { &param: added }}))?;
            let values = added.to_vec();
            Some(extend_grid(
                tx,
                search_id,
                &request,
                move |now: &GridNow| plan(now, &param, &values, trials),
                now,
            )?)
        };
        tx.prepare_cached(
            "insert into refine_rounds (search_id, round, subjects, added, extension, stop, created_at)
             values (?1, ?2, ?3, ?4, ?5, ?6, ?7)",
        )
        .map_err(db_err)?
        .execute(params![
            search_id,
            round,
            subjects,
            encode(&added)?,
            extended.as_ref().map(|e| e.extension),
            stop,
            now
        ])
        .map_err(db_err)?;
        if extended.is_none() {
            tx.prepare_cached("update searches set refine_state = ?2 where id = ?1")
                .map_err(db_err)?
                .execute(params![search_id, RefineState::Settled.as_str()])
                .map_err(db_err)?;
        }
        Ok(Some(extended))
    })
    .await
}

/// Extends a search in one write operation and answers with the wire
/// type the route sends: reads its grid and trials,
/// asks `plan` what to add (a refusal changes nothing), adds the new points
/// and every missing job `(point, trial)` for `trial < plan.trials` with
/// the seed [`shared::api::job_seed`] gives it, tops up replacements where
/// the search asks for them, and puts the search back to `running` with no
/// cached final document. Jobs already there are not touched. 404 for an
/// unknown search, 409 for a cancelled one, 400 when nothing would be
/// added. The writer thread runs operations one at a time, so concurrent
/// extensions apply one after the other, each planned from the state the
/// one before left; `unique (search_id, point_idx, trial)` on jobs and
/// `unique (search_id, params)` on points make a duplicate impossible.
pub async fn extend<E: From<StoreError> + Send + 'static>(
    db: &Db,
    search_id: &str,
    request: &str,
    plan: impl FnOnce(&GridNow) -> Result<ExtensionPlan, E> + Send + 'static,
    now: i64,
) -> Result<Extended, E> {
    let (id, request) = (search_id.to_string(), request.to_string());
    with_tx(&db.writer, move |tx| {
        extend_grid(tx, &id, &request, plan, now)
    })
    .await
}

/// Returns expired leases to the queue (attempts + 1), or fails the jobs
/// that have used up their attempts.
pub async fn sweep_expired(db: &Db, now: i64) -> anyhow::Result<Effects> {
    // Cheap read first: most sweeps find nothing and need no write.
    let any: Option<i64> = sqlx::query_scalar(
        "select id from jobs where status = ?2 and lease_expires_at < ?1 limit 1",
    )
    .bind(now)
    .bind(JobState::Leased.as_str())
    .fetch_optional(&db.read)
    .await
    .context("looking for expired leases")?;
    if any.is_none() {
        return Ok(Effects::default());
    }
    with_tx(&db.writer, move |tx| sweep_leases(tx, now))
        .await
        .map_err(|e| anyhow::anyhow!("{e}"))
}

/// Leases the next job to `worker`: the oldest queued job of the running
/// search with the fewest leased jobs (ties: the older search), so that
/// concurrent searches share the workers evenly. With `sweep`, expired
/// leases are first returned to the queue.
///
/// The choice and the claim are one conditional `UPDATE ... RETURNING`
/// (atomic on its own), so the common path is a single statement.
pub async fn claim_with(
    db: &Db,
    worker: &str,
    lease_ms: i64,
    now: i64,
    sweep: bool,
) -> StoreResult<(Option<Claimed>, Effects)> {
    let token = new_token();
    let worker = worker.to_string();
    with_tx(&db.writer, move |tx| {
        let eff = if sweep {
            sweep_leases(tx, now)?
        } else {
            Effects::default()
        };
        Ok((claim(tx, &worker, token, lease_ms, now)?, eff))
    })
    .await
}
