//! Reads beyond the queue's own: the dashboard's paged lists (each bounded
//! by `LIMIT`), the search of a job, and the searches start-up must still
//! finalize.

use anyhow::Context;
use shared::api::{JobState, ProgressPoint, SearchState};
use sqlx::Row;

use super::queue::{self, SearchRow};
use super::states::RefineState;
use super::Db;

/// One page of searches (newest first) and the total count.
pub async fn search_page(
    db: &Db,
    page: i64,
    per_page: i64,
) -> anyhow::Result<(i64, Vec<SearchRow>)> {
    search_slice(db, per_page, (page.max(1) - 1) * per_page).await
}

/// At most `limit` searches (newest first) after skipping `offset`, and
/// the total count.
pub async fn search_slice(
    db: &Db,
    limit: i64,
    offset: i64,
) -> anyhow::Result<(i64, Vec<SearchRow>)> {
    let total: i64 = sqlx::query_scalar("select count(*) from searches")
        .fetch_one(&db.read)
        .await
        .context("counting searches")?;
    let rows = queue::search_row_slice(db, limit, offset).await?;
    Ok((total, rows))
}

/// A job being worked on.
#[derive(Debug, Clone)]
pub struct LeasedJob {
    /// Job id.
    pub id: i64,
    /// Grid point.
    pub point_idx: u32,
    /// Trial.
    pub trial: u32,
    /// Lease owner.
    pub worker: String,
    /// `training` or `sampling`, from the latest heartbeat.
    pub phase: Option<String>,
    /// Latest progress.
    pub progress: Option<ProgressPoint>,
    /// Start of the lease (unix ms).
    pub leased_at: Option<i64>,
    /// Lease expiry (unix ms).
    pub lease_expires_at: Option<i64>,
    /// Leases lost or failed before.
    pub attempts: u32,
}

/// The leased jobs of a search (oldest lease first), at most `limit`.
pub async fn leased_jobs(db: &Db, search_id: &str, limit: i64) -> anyhow::Result<Vec<LeasedJob>> {
    let rows = sqlx::query(
        "select id, point_idx, trial, coalesce(worker_id, '?'), phase, progress, leased_at,
                lease_expires_at, attempts
         from jobs where search_id = ?1 and status = ?3
         order by leased_at, id limit ?2",
    )
    .bind(search_id)
    .bind(limit)
    .bind(JobState::Leased.as_str())
    .fetch_all(&db.read)
    .await
    .context("listing leased jobs")?;
    Ok(rows
        .iter()
        .map(|r| LeasedJob {
            id: r.get(0),
            point_idx: r.get::<i64, _>(1) as u32,
            trial: r.get::<i64, _>(2) as u32,
            worker: r.get(3),
            phase: r.get(4),
            progress: r
                .get::<Option<String>, _>(5)
                .and_then(|p| serde_json::from_str(&p).ok()),
            leased_at: r.get(6),
            lease_expires_at: r.get(7),
            attempts: r.get::<i64, _>(8) as u32,
        })
        .collect())
}

/// Ids of the most recently finished done jobs of a search.
pub async fn recent_done(db: &Db, search_id: &str, limit: i64) -> anyhow::Result<Vec<i64>> {
    sqlx::query_scalar(
        "select id from jobs where search_id = ?1 and status = ?3
         order by finished_at desc, id desc limit ?2",
    )
    .bind(search_id)
    .bind(limit)
    .bind(JobState::Done.as_str())
    .fetch_all(&db.read)
    .await
    .context("listing recent jobs")
}

/// A job's learning curve, as a search page draws it.
#[derive(Debug, Clone, PartialEq)]
pub struct JobCurve {
    /// Job id.
    pub id: i64,
    /// Grid point.
    pub point_idx: u32,
    /// Trial.
    pub trial: u32,
    /// The worker that holds or held it.
    pub worker: Option<String>,
    /// Its progress points, oldest first (never empty).
    pub points: Vec<ProgressPoint>,
}

/// The learning curves of the jobs `ids`, in that order, in one query;
/// a job without progress points (or unknown) is left out.
pub async fn job_curves(db: &Db, ids: &[i64]) -> anyhow::Result<Vec<JobCurve>> {
    let ids_json = serde_json::to_string(ids).context("encoding job ids")?;
    let rows = sqlx::query(
        "select j.id, j.point_idx, j.trial, j.worker_id, g.progress
         from jobs j join job_progress g on g.job_id = j.id
         where j.id in (select value from json_each(?1))
         order by j.id, g.seq",
    )
    .bind(ids_json)
    .fetch_all(&db.read)
    .await
    .context("reading learning curves")?;
    let mut by_id: std::collections::HashMap<i64, JobCurve> = std::collections::HashMap::new();
    for row in &rows {
        let id: i64 = row.get(0);
        let point: ProgressPoint =
            serde_json::from_str(row.get::<&str, _>(4)).context("stored curve")?;
        by_id
            .entry(id)
            .or_insert_with(|| JobCurve {
                id,
                point_idx: row.get::<i64, _>(1) as u32,
                trial: row.get::<i64, _>(2) as u32,
                worker: row.get(3),
                points: Vec::new(),
            })
            .points
            .push(point);
    }
    Ok(ids.iter().filter_map(|id| by_id.remove(id)).collect())
}

/// A row of the job table.
#[derive(Debug, Clone)]
pub struct JobRow {
    /// Job id.
    pub id: i64,
    /// Grid point.
    pub point_idx: u32,
    /// Trial.
    pub trial: u32,
    /// Seed (u64 bit pattern).
    pub seed: u64,
    /// State.
    pub status: String,
    /// Owner of the current or last lease.
    pub worker: Option<String>,
    /// Leases lost or failed.
    pub attempts: u32,
    /// Last error.
    pub last_error: Option<String>,
    /// Final success rate, once done.
    pub final_success_rate: Option<f64>,
    /// Converged, once done.
    pub converged: Option<bool>,
    /// Successes found / wanted, once done.
    pub successes: Option<(i64, i64)>,
    /// Lease-to-result seconds, once done.
    pub duration_secs: Option<f64>,
}

/// One page of a search's jobs in queue order, optionally of one state.
pub async fn job_page(
    db: &Db,
    search_id: &str,
    status: Option<JobState>,
    page: i64,
    per_page: i64,
) -> anyhow::Result<Vec<JobRow>> {
    let rows = sqlx::query(
        "select j.id, j.point_idx, j.trial, j.seed, j.status, j.worker_id, j.attempts,
                j.last_error, r.final_success_rate, r.converged, r.successes_found,
                r.successes_wanted,
                case when j.status = ?5 then j.finished_at - j.leased_at end
         from jobs j left join job_results r on r.job_id = j.id
         where j.search_id = ?1 and (?2 is null or j.status = ?2)
         order by j.id limit ?3 offset ?4",
    )
    .bind(search_id)
    .bind(status.map(|s| s.as_str()))
    .bind(per_page)
    .bind((page.max(1) - 1) * per_page)
    .bind(JobState::Done.as_str())
    .fetch_all(&db.read)
    .await
    .context("listing jobs")?;
    Ok(rows
        .iter()
        .map(|r| JobRow {
            id: r.get(0),
            point_idx: r.get::<i64, _>(1) as u32,
            trial: r.get::<i64, _>(2) as u32,
            seed: r.get::<i64, _>(3) as u64,
            status: r.get(4),
            worker: r.get(5),
            attempts: r.get::<i64, _>(6) as u32,
            last_error: r.get(7),
            final_success_rate: r.get(8),
            converged: r.get(9),
            successes: match (r.get::<Option<i64>, _>(10), r.get::<Option<i64>, _>(11)) {
                (Some(f), Some(w)) => Some((f, w)),
                _ => None,
            },
            duration_secs: r.get::<Option<i64>, _>(12).map(|ms| ms as f64 / 1000.0),
        })
        .collect())
}

/// The search a job belongs to, if the job exists.
pub async fn job_search(db: &Db, job_id: i64) -> anyhow::Result<Option<(String, u32)>> {
    let row: Option<(String, i64)> =
        sqlx::query_as("select search_id, variant from jobs where id = ?1")
            .bind(job_id)
            .fetch_optional(&db.read)
            .await
            .context("reading the job's search")?;
    Ok(row.map(|(s, v)| (s, v as u32)))
}

/// Completed searches without a cached final document, or with a
/// refinement round still to decide (a coordinator killed between
/// completing a search and finalizing it).
pub async fn unfinalized(db: &Db) -> anyhow::Result<Vec<String>> {
    sqlx::query_scalar(
        "select id from searches where status = ?1
             and (final_document is null or refine_state = ?2)",
    )
    .bind(SearchState::Completed.as_str())
    .bind(RefineState::Pending.as_str())
    .fetch_all(&db.read)
    .await
    .context("finding searches to finalize")
}
