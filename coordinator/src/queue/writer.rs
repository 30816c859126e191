//! The lease cycle's write path (claim, upload, failure, expiry sweep) on a
//! dedicated writer thread that owns its own `rusqlite` connection and
//! commits in groups: it takes every operation waiting in its queue (up to
//! [`MAX_BATCH`]), runs each inside a savepoint of one transaction (a failed
//! operation rolls back alone), commits once, and only then answers. sqlx
//! would run each statement as a round trip to its connection thread and
//! commit each operation separately; under load this cuts both the thread
//! hops and the commits by the batch size. SQLite serializes this writer
//! with the sqlx writer connection (used for the rarer writes) through its
//! file lock and busy timeout.

use std::collections::VecDeque;
use std::path::Path;
use std::sync::mpsc;

use rusqlite::{params, OptionalExtension, Transaction};
use shared::api::{job_seed, JobOutput, JobState};

use super::{parse_params, Claimed, Completion, Effects};
use crate::error::ApiError;

/// Most operations committed together.
pub const MAX_BATCH: usize = 128;

/// How an operation's group ended.
enum Outcome<'a> {
    /// Committed: the operation's own answer stands.
    Committed,
    /// Begin or commit failed with this error; nothing of the group is kept.
    Failed(&'a rusqlite::Error),
    /// SQLite rolled the group's transaction back after another operation's
    /// storage error; nothing of the group is kept.
    RolledBack,
}

/// Answers an operation once its group has ended.
type Deliver = Box<dyn FnOnce(Outcome<'_>) + Send>;
/// Runs an operation in the group's transaction, or answers at once with the
/// error that kept the transaction (or the operation's savepoint) from
/// starting.
type Op = Box<dyn FnOnce(Result<&Transaction<'_>, &rusqlite::Error>) -> Deliver + Send>;

enum Msg {
    Op(Op),
    Close(std::sync::mpsc::Sender<()>),
}

/// Handle of the writer thread.
#[derive(Debug, Clone)]
pub struct Writer {
    tx: mpsc::Sender<Msg>,
}

impl std::fmt::Debug for Msg {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Msg")
    }
}

impl Writer {
    /// Opens `path` (already migrated) on a new writer thread.
    pub fn start(path: &Path) -> anyhow::Result<Self> {
        let conn = rusqlite::Connection::open(path)?;
        conn.busy_timeout(std::time::Duration::from_secs(10))?;
        conn.pragma_update(None, "synchronous", "NORMAL")?;
        conn.pragma_update(None, "foreign_keys", "ON")?;
        conn.set_prepared_statement_cache_capacity(32);
        let (tx, rx) = mpsc::channel::<Msg>();
        std::thread::Builder::new()
            .name("irlgrid-writer".into())
            .spawn(move || run(conn, rx))?;
        Ok(Self { tx })
    }

    /// Stops the thread and closes its connection (pending operations are
    /// finished first).
    pub fn close(&self) {
        let (done, wait) = mpsc::channel();
        if self.tx.send(Msg::Close(done)).is_ok() {
            let _ = wait.recv();
        }
    }
}

fn run(mut conn: rusqlite::Connection, rx: mpsc::Receiver<Msg>) {
    let mut close: Option<mpsc::Sender<()>> = None;
    // Operations of a group that SQLite rolled back before they ran.
    let mut carry: VecDeque<Op> = VecDeque::new();
    while close.is_none() || !carry.is_empty() {
        let mut ops = std::mem::take(&mut carry);
        if ops.is_empty() {
            let Ok(first) = rx.recv() else { return };
            match first {
                Msg::Op(op) => ops.push_back(op),
                Msg::Close(c) => close = Some(c),
            }
        }
        while close.is_none() && ops.len() < MAX_BATCH {
            match rx.try_recv() {
                Ok(Msg::Op(op)) => ops.push_back(op),
                Ok(Msg::Close(c)) => close = Some(c),
                Err(_) => break,
            }
        }
        if ops.is_empty() {
            continue;
        }
        let tx = match conn.transaction_with_behavior(rusqlite::TransactionBehavior::Immediate) {
            Ok(tx) => tx,
            Err(e) => {
                // Each operation answers with the error (503 for a full,
                // read-only or failing disk, a lock held too long).
                tracing::error!(error = %e, "writer: begin failed");
                for op in ops {
                    op(Err(&e))(Outcome::Failed(&e));
                }
                continue;
            }
        };
        let mut delivers = Vec::with_capacity(ops.len());
        let mut rolled_back = false;
        while let Some(op) = ops.pop_front() {
            if let Err(e) = tx.execute_batch("savepoint op") {
                delivers.push(op(Err(&e)));
            } else {
                // A panicking operation answers with an error (its reply is
                // dropped) and is rolled back; the thread lives on.
                match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| op(Ok(&tx)))) {
                    Ok(d) => delivers.push(d),
                    Err(_) => {
                        tracing::error!("writer: operation panicked; rolled back");
                        let _ = tx.execute_batch("rollback to op; release op");
                    }
                }
            }
            // SQLite rolls the whole transaction back itself on some errors
            // (SQLITE_FULL, SQLITE_IOERR, ...). The group's earlier changes
            // are gone, and a later operation would run outside any
            // transaction: stop here, answer the group, and run the rest in
            // a fresh transaction.
            if tx.is_autocommit() {
                rolled_back = true;
                break;
            }
        }
        if rolled_back {
            tracing::error!(
                answered = delivers.len(),
                carried = ops.len(),
                "writer: a storage error rolled back the group's transaction"
            );
            drop(tx);
            for d in delivers {
                d(Outcome::RolledBack);
            }
            carry = ops;
            continue;
        }
        let failed = match tx.commit() {
            Ok(()) => None,
            Err(e) => {
                // The transaction is rolled back when `tx` drops: none of
                // the group's changes is kept, and each operation says so.
                tracing::error!(error = %e, "writer: commit failed");
                Some(e)
            }
        };
        for d in delivers {
            match &failed {
                None => d(Outcome::Committed),
                Some(e) => d(Outcome::Failed(e)),
            }
        }
    }
    drop(conn);
    if let Some(c) = close {
        let _ = c.send(());
    }
}

/// A database error as an answer: 503 for a storage fault (full,
/// read-only, I/O, busy), 500 otherwise.
fn db_err(e: rusqlite::Error) -> ApiError {
    ApiError::from(&e)
}

/// Runs `f` as one operation of the writer thread's next group commit;
/// answers after the commit. An `Err` from `f` rolls back `f`'s changes
/// only.
pub(super) async fn with_tx<T: Send + 'static>(
    writer: &Writer,
    f: impl FnOnce(&Transaction<'_>) -> Result<T, ApiError> + Send + 'static,
) -> Result<T, ApiError> {
    let (reply, answer) = tokio::sync::oneshot::channel::<Result<T, ApiError>>();
    let op: Op = Box::new(move |tx| {
        let tx = match tx {
            Ok(tx) => tx,
            Err(e) => {
                let _ = reply.send(Err(ApiError::from(e)));
                return Box::new(|_| {});
            }
        };
        let out = f(tx);
        let undo = if out.is_ok() {
            tx.execute_batch("release op")
        } else {
            tx.execute_batch("rollback to op; release op")
        };
        let out = match (out, undo) {
            (Ok(_), Err(e)) => Err(db_err(e)),
            (out, _) => out,
        };
        Box::new(move |outcome| {
            let out = match (out, outcome) {
                (Ok(_), Outcome::Failed(e)) => Err(ApiError::from(e)),
                (Ok(_), Outcome::RolledBack) => Err(ApiError::Unavailable(
                    "database unavailable: a storage error rolled back the write; retry later"
                        .into(),
                )),
                (out, _) => out,
            };
            let _ = reply.send(out);
        })
    });
    writer
        .tx
        .send(Msg::Op(op))
        .map_err(|_| ApiError::Internal(anyhow::anyhow!("database writer has stopped")))?;
    answer
        .await
        .map_err(|_| ApiError::Internal(anyhow::anyhow!("database writer dropped an operation")))?
}

/// Returns expired leases to the queue or fails them (attempts used up).
pub(super) fn sweep(tx: &Transaction<'_>, now: i64) -> Result<Effects, ApiError> {
    let mut st = tx
        .prepare_cached(
            "update jobs set
                 status = case when attempts + 1 >= max_attempts then 'failed' else 'queued' end,
                 attempts = attempts + 1,
                 last_error = 'lease expired (owner ' || coalesce(worker_id, '?') || ')',
                 lease_token = null, lease_expires_at = null,
                 finished_at = case when attempts + 1 >= max_attempts then ?1 else null end
             where status = 'leased' and lease_expires_at < ?1
             returning search_id, point_idx, status",
        )
        .map_err(db_err)?;
    let rows: Vec<(String, i64, String)> = st
        .query_map(params![now], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)))
        .map_err(db_err)?
        .collect::<Result<_, _>>()
        .map_err(db_err)?;
    drop(st);
    let mut eff = Effects {
        expired: rows.len() as u64,
        ..Effects::default()
    };
    for (search_id, point, status) in rows {
        if status == "failed" {
            let (replaced, completed) = after_job_end(tx, search_id, point as u32, true, now)?;
            eff.requeued += u64::from(replaced);
            eff.completed.extend(completed);
        } else {
            eff.requeued += 1;
        }
    }
    Ok(eff)
}

/// Leases the next job fairly (see `queue::claim_with`).
pub(super) fn claim(
    tx: &Transaction<'_>,
    worker: &str,
    token: String,
    lease_ms: i64,
    now: i64,
) -> Result<Option<Claimed>, ApiError> {
    let row = tx
        .prepare_cached(
            "update jobs set status = 'leased', worker_id = ?1, lease_token = ?2,
                 lease_expires_at = ?3, leased_at = ?4, lease_count = lease_count + 1,
                 progress = null, phase = null
             where id = (
                 select j.id from jobs j
                 where j.status = 'queued' and j.search_id = (
                     select s.id from searches s
                     where s.status = 'running'
                       and exists (select 1 from jobs q
                                   where q.search_id = s.id and q.status = 'queued')
                     order by (select count(*) from jobs l
                               where l.search_id = s.id and l.status = 'leased'),
                              s.seq
                     limit 1)
                 order by j.id limit 1)
             returning id, search_id, point_idx, trial, seed, lease_count",
        )
        .map_err(db_err)?
        .query_row(params![worker, token, now + lease_ms, now], |r| {
            Ok((
                r.get::<_, i64>(0)?,
                r.get::<_, String>(1)?,
                r.get::<_, i64>(2)?,
                r.get::<_, i64>(3)?,
                r.get::<_, i64>(4)?,
                r.get::<_, i64>(5)?,
            ))
        })
        .optional()
        .map_err(db_err)?;
    let Some((job_id, search_id, point, trial, seed, count)) = row else {
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
        trial: trial as u32,
        seed: seed as u64,
        attempt: count as u32,
        token,
    }))
}

/// The job's (status, current lease token), if it exists.
fn lease_row(
    tx: &Transaction<'_>,
    job_id: i64,
) -> Result<Option<(String, Option<String>)>, ApiError> {
    tx.prepare_cached("select status, lease_token from jobs where id = ?1")
        .map_err(db_err)?
        .query_row(params![job_id], |r| {
            Ok((r.get::<_, String>(0)?, r.get::<_, Option<String>>(1)?))
        })
        .optional()
        .map_err(db_err)
}

/// Checks in constant time that the job is leased under `token` (see
/// `queue::lease_verdict`); runs in the operation's savepoint before its
/// conditional `UPDATE`.
pub(super) fn check_lease(tx: &Transaction<'_>, job_id: i64, token: &str) -> Result<(), ApiError> {
    super::lease_verdict(job_id, lease_row(tx, job_id)?, token)
}

/// Explains why a job call with this token matched no leased row.
pub(super) fn refusal(tx: &Transaction<'_>, job_id: i64, token: &str) -> ApiError {
    match lease_row(tx, job_id) {
        Err(e) => e,
        Ok(row) => super::refusal(job_id, row, token),
    }
}

/// Accepts a result under the current lease (see `queue::complete_with`).
#[allow(clippy::too_many_arguments)]
pub(super) fn complete(
    tx: &Transaction<'_>,
    job_id: i64,
    token: &str,
    output: &JobOutput,
    output_json: &str,
    threshold: f64,
    now: i64,
) -> Result<Completion, ApiError> {
    check_lease(tx, job_id, token)?;
    let row = tx
        .prepare_cached(
            "update jobs set status = 'done', finished_at = ?1, lease_expires_at = null
             where id = ?2 and status = 'leased' and lease_token = ?3
             returning search_id, point_idx, worker_id",
        )
        .map_err(db_err)?
        .query_row(params![now, job_id, token], |r| {
            Ok((
                r.get::<_, String>(0)?,
                r.get::<_, i64>(1)?,
                r.get::<_, Option<String>>(2)?,
            ))
        })
        .optional()
        .map_err(db_err)?;
    let Some((search_id, point, worker)) = row else {
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
        output_json,
        now
    ])
    .map_err(db_err)?;
    let (replacement, completed) = after_job_end(tx, search_id, point as u32, !converged, now)?;
    Ok(Completion {
        converged,
        replacement,
        effects: Effects {
            requeued: u64::from(replacement),
            completed,
            ..Effects::default()
        },
    })
}

/// A worker gave up on its job (see `queue::fail`).
pub(super) fn fail(
    tx: &Transaction<'_>,
    job_id: i64,
    token: &str,
    error: &str,
    now: i64,
) -> Result<(JobState, Effects), ApiError> {
    check_lease(tx, job_id, token)?;
    let row = tx
        .prepare_cached(
            "update jobs set
                 status = case when attempts + 1 >= max_attempts then 'failed' else 'queued' end,
                 attempts = attempts + 1, last_error = ?1, lease_token = null,
                 lease_expires_at = null,
                 finished_at = case when attempts + 1 >= max_attempts then ?2 else null end
             where id = ?3 and status = 'leased' and lease_token = ?4
             returning search_id, point_idx, status",
        )
        .map_err(db_err)?
        .query_row(params![error, now, job_id, token], |r| {
            Ok((
                r.get::<_, String>(0)?,
                r.get::<_, i64>(1)?,
                r.get::<_, String>(2)?,
            ))
        })
        .optional()
        .map_err(db_err)?;
    let Some((search_id, point, status)) = row else {
        return Err(refusal(tx, job_id, token));
    };
    let mut eff = Effects::default();
    if status == "failed" {
        let (replaced, completed) = after_job_end(tx, search_id, point as u32, true, now)?;
        eff.requeued += u64::from(replaced);
        eff.completed = completed;
        Ok((JobState::Failed, eff))
    } else {
        eff.requeued = 1;
        Ok((JobState::Queued, eff))
    }
}

/// After a job of `point` ended (done or failed): enqueue a replacement if
/// asked and allowed, and complete the search when nothing is left.
/// Returns (replacement enqueued, searches completed).
fn after_job_end(
    tx: &Transaction<'_>,
    search_id: String,
    point: u32,
    wants_replacement: bool,
    now: i64,
) -> Result<(bool, Vec<String>), ApiError> {
    let mut replaced = false;
    if wants_replacement {
        let (status, trials, base_seed, replace, cap, max_attempts) = tx
            .prepare_cached(
                "select status, trials, base_seed, replace_unconverged, max_trials_per_point,
                        max_attempts
                 from searches where id = ?1",
            )
            .map_err(db_err)?
            .query_row(params![search_id], |r| {
                Ok((
                    r.get::<_, String>(0)?,
                    r.get::<_, i64>(1)?,
                    r.get::<_, i64>(2)?,
                    r.get::<_, bool>(3)?,
                    r.get::<_, i64>(4)?,
                    r.get::<_, i64>(5)?,
                ))
            })
            .map_err(db_err)?;
        if status == "running" && replace {
            let (converged, outstanding, total, max_trial) = tx
                .prepare_cached(
                    "select coalesce(sum(case when r.converged = 1 then 1 else 0 end), 0),
                            coalesce(sum(case when j.status in ('queued', 'leased') then 1 else 0 end), 0),
                            count(*), max(j.trial)
                     from jobs j left join job_results r on r.job_id = j.id
                     where j.search_id = ?1 and j.point_idx = ?2",
                )
                .map_err(db_err)?
                .query_row(params![search_id, point], |r| {
                    Ok((
                        r.get::<_, i64>(0)?,
                        r.get::<_, i64>(1)?,
                        r.get::<_, i64>(2)?,
                        r.get::<_, i64>(3)?,
                    ))
                })
                .map_err(db_err)?;
            if converged + outstanding < trials && total < cap {
                let params_text: String = tx
                    .query_row(
                        "select params from points where search_id = ?1 and idx = ?2",
                        params![search_id, point],
                        |r| r.get(0),
                    )
                    .map_err(db_err)?;
                let trial = (max_trial + 1) as u32;
                let seed = job_seed(base_seed as u64, &parse_params(&params_text)?, trial);
                tx.prepare_cached(
                    "insert into jobs (search_id, point_idx, trial, seed, status, max_attempts,
                                       queued_at)
                     values (?1, ?2, ?3, ?4, 'queued', ?5, ?6)",
                )
                .map_err(db_err)?
                .execute(params![
                    search_id,
                    point,
                    trial,
                    seed as i64,
                    max_attempts,
                    now
                ])
                .map_err(db_err)?;
                replaced = true;
            }
        }
    }
    let remaining: bool = tx
        .prepare_cached(
            "select exists (select 1 from jobs
                            where search_id = ?1 and status in ('queued', 'leased'))",
        )
        .map_err(db_err)?
        .query_row(params![search_id], |r| r.get(0))
        .map_err(db_err)?;
    let mut completed = Vec::new();
    if !remaining {
        let n = tx
            .prepare_cached(
                "update searches set status = 'completed', finished_at = ?1
                 where id = ?2 and status = 'running'",
            )
            .map_err(db_err)?
            .execute(params![now, search_id])
            .map_err(db_err)?;
        if n == 1 {
            completed.push(search_id);
        }
    }
    Ok((replaced, completed))
}
