//! The job queue: every state change of searches and jobs (in `ops`, each
//! one operation of the group-committing writer thread, [`super::writer`]),
//! plus the read queries behind the status endpoints on the sqlx reader
//! pool.
//!
//! A lease is (owner, random token, expiry). Expired leases go back to the
//! queue (attempts + 1) at every lease request and on the periodic sweep;
//! after `max_attempts` lost or failed leases a job fails with its last
//! error. Job calls match the token in the same conditional `UPDATE` that
//! changes the row, so of two racing uploads exactly one wins.

use std::collections::BTreeMap;

use anyhow::Context;
use rand::RngCore;
use shared::analysis::{parse_subjects_csv, SubjectPath, SubjectRefinement, TrialDigest};
use shared::api::{
    JobCounts, JobInfo, JobOutput, JobState, ProgressPoint, RefineRound, RefineSpec,
    ResolvedConfig, SearchState,
};
use sqlx::Row;

use super::error::{StoreError, StoreResult};
use super::Db;
use crate::auth::ct_eq;

/// Progress points kept per job; past this the history is thinned to every
/// other point, so it stays bounded but still spans the whole run.
pub const HISTORY_CAP: i64 = 512;

/// A search ready to insert; validated by the caller.
#[derive(Debug, Clone)]
pub struct NewSearch {
    /// Public id.
    pub id: String,
    /// Label.
    pub name: String,
    /// Request body as submitted (JSON).
    pub request: String,
    /// Resolved configuration (JSON).
    pub config: String,
    /// Converged trials wanted per point.
    pub trials: u32,
    /// Base seed.
    pub base_seed: u64,
    /// Convergence threshold on the final success rate.
    pub threshold: f64,
    /// Enqueue replacements for unconverged or failed trials.
    pub replace_unconverged: bool,
    /// Cap on trials per point.
    pub max_trials_per_point: u32,
    /// Leases a job may lose before failing.
    pub max_attempts: u32,
    /// Subjects, in the CSV form `subjects_to_csv` writes (intake parsed
    /// them).
    pub subjects_csv: Option<String>,
    /// Grid points in order.
    pub points: Vec<BTreeMap<String, f64>>,
    /// Refinement once the grid has finished, if asked for.
    pub refine: Option<RefineSpec>,
    /// Solver variants each (point, trial) runs as (1 for a search that
    /// names none).
    pub variants: u32,
}

/// A job just leased.
#[derive(Debug, Clone, PartialEq)]
pub struct Claimed {
    /// Job id.
    pub job_id: i64,
    /// Search id.
    pub search_id: String,
    /// Grid point.
    pub point_idx: u32,
    /// Solver variant (index into the search's solvers).
    pub variant: u32,
    /// Trial.
    pub trial: u32,
    /// Seed.
    pub seed: u64,
    /// 1-based lease number.
    pub attempt: u32,
    /// Lease token.
    pub token: String,
}

/// What a state change did besides its own row, for the caller's
/// notifications and metrics.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Effects {
    /// Leases that had expired and were swept.
    pub expired: u64,
    /// Jobs that became queued (requeued, released or replacements).
    pub requeued: u64,
    /// Searches that just completed.
    pub completed: Vec<String>,
}

/// An output ready to store: the figures its job row keeps, the output
/// in the store's encoding ([`super::codec`]) and its digest, all computed
/// before the write so that the writer thread only writes.
#[derive(Debug, Clone)]
pub struct Upload {
    /// Final success rate.
    pub final_success_rate: f64,
    /// Successful episodes found.
    pub successes_found: u32,
    /// Successful episodes wanted.
    pub successes_wanted: u32,
    /// Environment steps the trainer used.
    pub env_steps: u64,
    /// The output, encoded ([`super::codec::encode`]).
    pub output: Vec<u8>,
    /// JSON of its [`TrialDigest`].
    pub digest: String,
}

impl Upload {
    /// Encodes and digests an output (CPU work: resamples every episode
    /// once and compresses the trajectories; about a millisecond for a
    /// real-sized output).
    pub fn of(output: JobOutput) -> anyhow::Result<Self> {
        let digest = TrialDigest::of(
            &output.episodes,
            output.final_success_rate,
            output.successes_found,
            output.successes_wanted,
        );
        Ok(Self {
            final_success_rate: output.final_success_rate,
            successes_found: output.successes_found,
            successes_wanted: output.successes_wanted,
            env_steps: output.env_steps,
            digest: serde_json::to_string(&digest).context("encoding a trial digest")?,
            output: super::codec::encode(output)?,
        })
    }
}

/// Outcome of an accepted result.
#[derive(Debug, Clone, PartialEq)]
pub struct Completion {
    /// Final success rate reached the threshold.
    pub converged: bool,
    /// A replacement trial was enqueued.
    pub replacement: bool,
    /// Side effects.
    pub effects: Effects,
}

/// Immutable facts of a search that every lease needs (cached by the
/// router).
#[derive(Debug, Clone, PartialEq)]
pub struct SearchInfo {
    /// Id.
    pub id: String,
    /// Label.
    pub name: String,
    /// Resolved configuration.
    pub resolved: ResolvedConfig,
    /// Convergence threshold.
    pub threshold: f64,
    /// Stored subjects, parsed once when the search is loaded; a stored text
    /// that no longer parses is an error there, never an empty list.
    pub subjects: Vec<SubjectPath>,
    /// Grid points in order.
    pub points: Vec<BTreeMap<String, f64>>,
}

/// A new random lease token: 128 bits, hex.
pub fn new_token() -> String {
    let mut b = [0u8; 16];
    rand::thread_rng().fill_bytes(&mut b);
    b.iter().map(|x| format!("{x:02x}")).collect()
}

fn parse_params(text: &str) -> anyhow::Result<BTreeMap<String, f64>> {
    serde_json::from_str(text).context("stored point parameters")
}

/// What an extension sees of its search, read inside its write
/// transaction (so that two extensions never plan from the same state).
#[derive(Debug, Clone, PartialEq)]
pub struct GridNow {
    /// State before the extension.
    pub status: SearchState,
    /// Converged trials wanted per point.
    pub trials: u32,
    /// Cap on trials per point, replacements included.
    pub max_trials_per_point: u32,
    /// Grid points by index (submitted ones first, then added ones in the
    /// order they were added).
    pub points: Vec<BTreeMap<String, f64>>,
    /// Solver variants each (point, trial) runs as.
    pub variants: u32,
}

/// What an extension changes, planned from [`GridNow`] (see
/// `intake::plan_extension`).
#[derive(Debug, Clone, PartialEq)]
pub struct ExtensionPlan {
    /// Converged trials wanted per point from now on (>= the current).
    pub trials: u32,
    /// Cap on trials per point from now on (>= `trials`).
    pub max_trials_per_point: u32,
    /// Points to add, none of them already in the grid.
    pub new_points: Vec<BTreeMap<String, f64>>,
    /// Trials wanted at the new points when not the search's (refinement).
    pub new_point_trials: Option<u32>,
}

/// The verdict on a job call given the job's (status, current lease token)
/// if it exists: `Ok` only for a leased job whose token equals `token`
/// (constant-time comparison). The one lease check: every job call runs it
/// inside its write transaction (`ops::check_lease`) before changing the
/// row, so nothing can change in between.
pub(crate) fn lease_verdict(
    job_id: i64,
    row: Option<(JobState, Option<String>)>,
    token: &str,
) -> StoreResult<()> {
    if let Some((status, Some(current))) = &row {
        if *status == JobState::Leased && ct_eq(current, token) {
            return Ok(());
        }
    }
    Err(refusal(job_id, row, token))
}

/// The refusal for a job call whose token matched no leased row, given the
/// job's (status, current lease token) if the job exists.
pub(crate) fn refusal(
    job_id: i64,
    row: Option<(JobState, Option<String>)>,
    token: &str,
) -> StoreError {
    let Some((status, current)) = row else {
        return StoreError::NotFound(format!("no job with id {job_id}"));
    };
    let mine = current.as_deref().is_some_and(|c| ct_eq(c, token));
    StoreError::Conflict(match status {
        JobState::Done if mine => format!("job {job_id}: result already accepted for this lease"),
        JobState::Done => format!("job {job_id} is already done (lease token is stale)"),
        JobState::Cancelled => format!("job {job_id} was cancelled"),
        JobState::Failed => format!("job {job_id} has failed (lease token is stale)"),
        JobState::Queued | JobState::Leased => {
            format!("job {job_id}: lease token is not current (the lease expired or was released)")
        }
    })
}

/// Loads the immutable facts of a search, or `None` if unknown.
pub async fn search_info(db: &Db, search_id: &str) -> anyhow::Result<Option<SearchInfo>> {
    let row = sqlx::query(
        "select id, name, config, convergence_threshold, subjects_csv from searches where id = ?1",
    )
    .bind(search_id)
    .fetch_optional(&db.read)
    .await
    .context("reading search")?;
    let Some(row) = row else { return Ok(None) };
    let resolved: ResolvedConfig =
        serde_json::from_str(row.get::<&str, _>(2)).context("stored search config")?;
    let points: Vec<String> =
        sqlx::query_scalar("select params from points where search_id = ?1 order by idx")
            .bind(search_id)
            .fetch_all(&db.read)
            .await
            .context("reading points")?;
    Ok(Some(SearchInfo {
        id: row.get(0),
        name: row.get(1),
        resolved,
        threshold: row.get(3),
        subjects: match row.get::<Option<&str>, _>(4) {
            None => Vec::new(),
            Some(text) => parse_subjects_csv(text)
                .map_err(|e| anyhow::anyhow!("stored subjects of search {search_id}: {e}"))?,
        },
        points: points
            .iter()
            .map(|p| parse_params(p))
            .collect::<anyhow::Result<_>>()?,
    }))
}

/// The row behind a search's status, before the derived fields.
#[derive(Debug, Clone, PartialEq)]
pub struct SearchRow {
    /// Id.
    pub id: String,
    /// Label.
    pub name: String,
    /// State.
    pub status: SearchState,
    /// Converged trials wanted per point.
    pub trials: u32,
    /// Convergence threshold.
    pub threshold: f64,
    /// Unix ms.
    pub created_at: i64,
    /// Unix ms.
    pub started_at: Option<i64>,
    /// Unix ms.
    pub finished_at: Option<i64>,
    /// Grid points.
    pub points: u64,
    /// Jobs by state.
    pub jobs: JobCounts,
    /// Done trials converged.
    pub converged: u64,
    /// Done trials not converged.
    pub not_converged: u64,
    /// Done trials with a sampling shortfall.
    pub shortfall: u64,
    /// Distinct lease owners now.
    pub workers_busy: u64,
    /// Mean lease-to-result time of done jobs (ms).
    pub mean_job_ms: Option<f64>,
}

impl SearchRow {
    /// Rough seconds to completion, for the status API and the dashboard:
    /// mean job time so far x jobs left / jobs running; 0 once the search
    /// is over, unknown before a job has finished.
    pub fn eta_secs(&self) -> Option<f64> {
        match (self.status, self.mean_job_ms) {
            (SearchState::Running, Some(ms)) => {
                let parallel = self.jobs.leased.max(1) as f64;
                Some((ms / 1000.0) * (self.jobs.queued + self.jobs.leased) as f64 / parallel)
            }
            (SearchState::Running, None) => None,
            _ => Some(0.0),
        }
    }

    /// `status:done:failed:total:points`: what a result document depends
    /// on. A cached partial document is current while its key is; the
    /// dashboard redraws its figures when the key changes. An extension
    /// adds jobs (and maybe points) and sets the status back to running,
    /// so it always changes the key.
    pub fn doc_key(&self) -> String {
        format!(
            "{}:{}:{}:{}:{}",
            self.status.as_str(),
            self.jobs.done,
            self.jobs.failed,
            self.jobs.total,
            self.points
        )
    }
}

/// The columns of a [`SearchRow`]: the search, its point count, its busy
/// workers (an index range over its leased jobs only) and its counts
/// (`search_counts`, kept by triggers: one row whatever the search's size).
/// Its `?1` is [`JobState::Leased`]; a statement built on it numbers its own
/// parameters from `?2`.
const SEARCH_ROW_SQL: &str = "select s.id, s.name, s.status, s.trials, s.convergence_threshold,
        s.created_at, s.started_at, s.finished_at,
        (select count(*) from points p where p.search_id = s.id),
        (select count(distinct worker_id) from jobs j
          where j.search_id = s.id and j.status = ?1),
        c.done_ms_sum, c.done_ms_n, c.results, c.converged, c.shortfall,
        c.queued, c.leased, c.done, c.failed, c.cancelled
     from searches s join search_counts c on c.search_id = s.id";

/// Status rows of one search (`Some(id)`) or of all, newest first.
pub async fn search_rows(db: &Db, id: Option<&str>) -> anyhow::Result<Vec<SearchRow>> {
    let rows = match id {
        Some(id) => {
            let sql = format!("{SEARCH_ROW_SQL} where s.id = ?2");
            sqlx::query(&sql)
                .bind(JobState::Leased.as_str())
                .bind(id)
                .fetch_all(&db.read)
                .await
        }
        None => {
            let sql = format!("{SEARCH_ROW_SQL} order by s.seq desc");
            sqlx::query(&sql)
                .bind(JobState::Leased.as_str())
                .fetch_all(&db.read)
                .await
        }
    }
    .context("reading searches")?;
    rows.iter().map(search_row).collect()
}

/// At most `limit` status rows (newest first) after skipping `offset`, in
/// one query.
pub async fn search_row_slice(db: &Db, limit: i64, offset: i64) -> anyhow::Result<Vec<SearchRow>> {
    let sql = format!("{SEARCH_ROW_SQL} order by s.seq desc limit ?2 offset ?3");
    sqlx::query(&sql)
        .bind(JobState::Leased.as_str())
        .bind(limit)
        .bind(offset)
        .fetch_all(&db.read)
        .await
        .context("listing searches")?
        .iter()
        .map(search_row)
        .collect()
}

fn search_row(r: &sqlx::sqlite::SqliteRow) -> anyhow::Result<SearchRow> {
    let count = |i: usize| r.get::<i64, _>(i).max(0) as u64;
    let jobs = JobCounts {
        queued: count(15),
        leased: count(16),
        done: count(17),
        failed: count(18),
        cancelled: count(19),
        total: (15..=19).map(count).sum(),
    };
    let (ms_sum, ms_n) = (r.get::<i64, _>(10), r.get::<i64, _>(11));
    let (results, converged) = (count(12), count(13));
    Ok(SearchRow {
        status: SearchState::parse(r.get::<&str, _>(2)).context("stored search status")?,
        id: r.get(0),
        name: r.get(1),
        trials: r.get::<i64, _>(3) as u32,
        threshold: r.get(4),
        created_at: r.get(5),
        started_at: r.get(6),
        finished_at: r.get(7),
        points: count(8),
        workers_busy: count(9),
        mean_job_ms: (ms_n > 0).then(|| ms_sum as f64 / ms_n as f64),
        jobs,
        converged,
        not_converged: results.saturating_sub(converged),
        shortfall: count(14),
    })
}

const JOB_COLUMNS: &str = "j.id, j.search_id, j.point_idx, p.params, j.trial, j.seed, j.status,
    j.worker_id, j.attempts, j.lease_count, j.last_error, j.progress, j.phase,
    r.final_success_rate, r.converged, r.successes_found, r.successes_wanted,
    j.finished_at - j.leased_at, j.variant";

fn job_info(r: &sqlx::sqlite::SqliteRow) -> anyhow::Result<JobInfo> {
    let progress: Option<String> = r.get(11);
    let phase: Option<String> = r.get(12);
    let done = r.get::<Option<f64>, _>(13).is_some();
    Ok(JobInfo {
        id: r.get(0),
        search_id: r.get(1),
        point_idx: r.get::<i64, _>(2) as u32,
        params: parse_params(r.get(3))?,
        trial: r.get::<i64, _>(4) as u32,
        variant: r.get::<i64, _>(18) as u32,
        seed: r.get::<i64, _>(5) as u64,
        status: JobState::parse(r.get::<&str, _>(6)).context("stored job status")?,
        worker: r.get(7),
        attempts: r.get::<i64, _>(8) as u32,
        lease_count: r.get::<i64, _>(9) as u32,
        last_error: r.get(10),
        progress: progress
            .as_deref()
            .map(serde_json::from_str)
            .transpose()
            .context("stored progress")?,
        phase: phase
            .map(|p| serde_json::from_value(serde_json::Value::String(p)))
            .transpose()
            .context("stored phase")?,
        final_success_rate: r.get(13),
        converged: r.get::<Option<bool>, _>(14),
        successes_found: r.get::<Option<i64>, _>(15).map(|v| v as u32),
        successes_wanted: r.get::<Option<i64>, _>(16).map(|v| v as u32),
        duration_secs: if done {
            r.get::<Option<i64>, _>(17).map(|ms| ms as f64 / 1000.0)
        } else {
            None
        },
    })
}

/// Every job of a search, in queue order.
pub async fn list_jobs(db: &Db, search_id: &str) -> anyhow::Result<Vec<JobInfo>> {
    let sql = format!(
        "select {JOB_COLUMNS} from jobs j
         join points p on p.search_id = j.search_id and p.idx = j.point_idx
         left join job_results r on r.job_id = j.id
         where j.search_id = ?1 order by j.id"
    );
    let rows = sqlx::query(&sql)
        .bind(search_id)
        .fetch_all(&db.read)
        .await
        .context("listing jobs")?;
    rows.iter().map(job_info).collect()
}

/// One job and its learning curve.
pub async fn job_detail(
    db: &Db,
    job_id: i64,
) -> anyhow::Result<Option<(JobInfo, Vec<ProgressPoint>)>> {
    let sql = format!(
        "select {JOB_COLUMNS} from jobs j
         join points p on p.search_id = j.search_id and p.idx = j.point_idx
         left join job_results r on r.job_id = j.id
         where j.id = ?1"
    );
    let Some(row) = sqlx::query(&sql)
        .bind(job_id)
        .fetch_optional(&db.read)
        .await
        .context("reading job")?
    else {
        return Ok(None);
    };
    let curve: Vec<String> =
        sqlx::query_scalar("select progress from job_progress where job_id = ?1 order by seq")
            .bind(job_id)
            .fetch_all(&db.read)
            .await
            .context("reading curve")?;
    let curve = curve
        .iter()
        .map(|c| serde_json::from_str(c))
        .collect::<Result<_, _>>()
        .context("stored curve")?;
    Ok(Some((job_info(&row)?, curve)))
}

/// One accepted output as stored.
#[derive(Debug, Clone)]
pub struct StoredOutput {
    /// Grid point.
    pub point_idx: u32,
    /// Solver variant (index into the search's solvers).
    pub variant: u32,
    /// Trial.
    pub trial: u32,
    /// Seed.
    pub seed: u64,
    /// Converged at the search's threshold.
    pub converged: bool,
    /// The upload.
    pub output: JobOutput,
}

/// Every accepted output of a search, by point then trial, all in memory
/// (for tests and tools; the routes read one output at a time with
/// [`output_refs`] and [`output`]).
pub async fn outputs(db: &Db, search_id: &str) -> anyhow::Result<Vec<StoredOutput>> {
    let mut out = Vec::new();
    for r in output_refs(db, search_id).await? {
        out.push(StoredOutput {
            point_idx: r.point_idx,
            variant: r.variant,
            trial: r.trial,
            seed: r.seed,
            converged: r.converged,
            output: output(db, r.job_id).await?,
        });
    }
    Ok(out)
}

/// An accepted output's job facts, without the output.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OutputRef {
    /// Job id.
    pub job_id: i64,
    /// Grid point.
    pub point_idx: u32,
    /// Solver variant (index into the search's solvers).
    pub variant: u32,
    /// Trial.
    pub trial: u32,
    /// Seed.
    pub seed: u64,
    /// Converged at the search's threshold.
    pub converged: bool,
}

fn output_ref(r: &sqlx::sqlite::SqliteRow) -> OutputRef {
    OutputRef {
        job_id: r.get(0),
        point_idx: r.get::<i64, _>(1) as u32,
        variant: r.get::<i64, _>(2) as u32,
        trial: r.get::<i64, _>(3) as u32,
        seed: r.get::<i64, _>(4) as u64,
        converged: r.get(5),
    }
}

/// The accepted outputs of a search, by point, variant, then trial.
pub async fn output_refs(db: &Db, search_id: &str) -> anyhow::Result<Vec<OutputRef>> {
    let rows = sqlx::query(
        "select job_id, point_idx, variant, trial, seed, converged from trial_summaries
         where search_id = ?1 order by point_idx, variant, trial",
    )
    .bind(search_id)
    .fetch_all(&db.read)
    .await
    .context("listing outputs")?;
    Ok(rows.iter().map(output_ref).collect())
}

/// One accepted output, decoded.
pub async fn output(db: &Db, job_id: i64) -> anyhow::Result<JobOutput> {
    let row = sqlx::query("select output from job_results where job_id = ?1")
        .bind(job_id)
        .fetch_one(&db.read)
        .await
        .with_context(|| format!("reading the output of job {job_id}"))?;
    super::codec::decode(row.get::<&[u8], _>(0))
        .with_context(|| format!("decoding the output of job {job_id}"))
}

/// Every accepted output's job facts and digest, by point, variant, then
/// trial: what result documents are built from.
pub async fn digests(db: &Db, search_id: &str) -> anyhow::Result<Vec<(OutputRef, TrialDigest)>> {
    let rows = sqlx::query(
        "select job_id, point_idx, variant, trial, seed, converged, digest from trial_summaries
         where search_id = ?1 order by point_idx, variant, trial",
    )
    .bind(search_id)
    .fetch_all(&db.read)
    .await
    .context("reading trial summaries")?;
    rows.iter()
        .map(|r| {
            let d = serde_json::from_str(r.get::<&str, _>(6))
                .with_context(|| format!("trial summary of job {}", r.get::<i64, _>(0)))?;
            Ok((output_ref(r), d))
        })
        .collect()
}

/// Failed jobs of a search: (point, trial, last error).
pub async fn failed_jobs(
    db: &Db,
    search_id: &str,
) -> anyhow::Result<Vec<(u32, u32, Option<String>)>> {
    let rows = sqlx::query(
        "select point_idx, trial, last_error from jobs
         where search_id = ?1 and status = ?2 order by point_idx, trial",
    )
    .bind(search_id)
    .bind(JobState::Failed.as_str())
    .fetch_all(&db.read)
    .await
    .context("reading failed jobs")?;
    Ok(rows
        .iter()
        .map(|r| {
            (
                r.get::<i64, _>(0) as u32,
                r.get::<i64, _>(1) as u32,
                r.get(2),
            )
        })
        .collect())
}

/// The cached final document of a completed search.
pub async fn final_document(db: &Db, search_id: &str) -> anyhow::Result<Option<String>> {
    let doc: Option<Option<String>> =
        sqlx::query_scalar("select final_document from searches where id = ?1")
            .bind(search_id)
            .fetch_optional(&db.read)
            .await
            .context("reading final document")?;
    Ok(doc.flatten())
}

/// What one refinement round decided, to store with [`refine_round`].
#[derive(Debug, Clone)]
pub struct RoundDecision {
    /// Evaluation number (rounds recorded so far).
    pub round: u32,
    /// Every subject's reading of the grid.
    pub subjects: Vec<SubjectRefinement>,
    /// Values to add (empty: refinement ends here).
    pub added: Vec<f64>,
    /// Trials per added point.
    pub trials: u32,
    /// Why refinement ends here, when `added` is empty.
    pub stop: Option<String>,
}

/// A search's refinement: the spec asked for, its state (`pending`,
/// `settled`, or `None`), and every round so far. `None` for an unknown
/// search.
pub async fn refinement(
    db: &Db,
    search_id: &str,
) -> anyhow::Result<Option<(Option<RefineSpec>, Option<String>, Vec<RefineRound>)>> {
    let Some(row) = sqlx::query("select refine, refine_state from searches where id = ?1")
        .bind(search_id)
        .fetch_optional(&db.read)
        .await
        .context("reading the search's refinement")?
    else {
        return Ok(None);
    };
    let spec = row
        .get::<Option<String>, _>(0)
        .map(|t| serde_json::from_str::<RefineSpec>(&t))
        .transpose()
        .context("stored refine spec")?;
    let rows = sqlx::query(
        "select round, subjects, added, stop, created_at from refine_rounds
         where search_id = ?1 order by round",
    )
    .bind(search_id)
    .fetch_all(&db.read)
    .await
    .context("reading refinement rounds")?;
    let rounds = rows
        .iter()
        .map(|r| {
            Ok(RefineRound {
                round: r.get::<i64, _>(0) as u32,
                subjects: serde_json::from_str(r.get::<&str, _>(1))?,
                added: serde_json::from_str(r.get::<&str, _>(2))?,
                stop: r.get(3),
                at: super::rfc3339(r.get(4)),
            })
        })
        .collect::<anyhow::Result<_>>()
        .context("stored refinement round")?;
    Ok(Some((spec, row.get(1), rounds)))
}

/// Job counts by state over all searches (for `/metrics`).
pub async fn global_counts(db: &Db) -> anyhow::Result<BTreeMap<String, i64>> {
    let rows = sqlx::query("select status, count(*) from jobs group by status")
        .fetch_all(&db.read)
        .await
        .context("counting jobs")?;
    let mut m: BTreeMap<String, i64> = JobState::ALL
        .iter()
        .map(|s| (s.as_str().to_string(), 0))
        .collect();
    for r in rows {
        m.insert(r.get(0), r.get(1));
    }
    Ok(m)
}

mod ops;
pub use ops::{
    cancel, claim_with, complete_with, extend, fail, heartbeat, insert_search, mark_started, probe,
    refine_round, release, request_refinement, set_subjects, store_final_document, sweep_expired,
};

#[cfg(test)]
mod tests;
