//! Databases from before trial summaries (migration 0008) migrate in
//! place at start-up: every accepted output without a summary gets its
//! digest and is re-stored in the compact encoding ([`super::codec`]), a
//! batch per writer transaction, before the coordinator serves. A
//! coordinator stopped half-way resumes with the rows left. The file does
//! not shrink by itself: `VACUUM` (offline) returns the freed pages.

use super::error::StoreError;
use super::queue::Upload;
use super::writer::with_tx;
use super::{codec, Db};
use anyhow::Context;

/// Outputs converted per transaction (each ~1 ms of CPU).
const BATCH: i64 = 32;

/// Converts every output without a summary; returns how many.
pub async fn run(db: &Db) -> anyhow::Result<u64> {
    let mut total = 0;
    loop {
        let n = with_tx(&db.writer, |c| {
            Box::pin(async move {
                let rows: Vec<(i64, Vec<u8>, bool, String, i64, i64, i64, i64)> = sqlx::query_as(
                    "select r.job_id, cast(r.output as blob), r.converged, j.search_id,
                            j.point_idx, j.variant, j.trial, j.seed
                     from job_results r join jobs j on j.id = r.job_id
                     where not exists (select 1 from trial_summaries s where s.job_id = r.job_id)
                     limit ?1",
                )
                .bind(BATCH)
                .fetch_all(&mut *c)
                .await?;
                for (job_id, stored, converged, search_id, point, variant, trial, seed) in &rows {
                    let up = codec::decode(stored)
                        .and_then(|o| Upload::of(&o))
                        .with_context(|| format!("converting the output of job {job_id}"))
                        .map_err(StoreError::Internal)?;
                    sqlx::query("update job_results set output = ?1 where job_id = ?2")
                        .bind(&up.output)
                        .bind(job_id)
                        .execute(&mut *c)
                        .await?;
                    sqlx::query(
                        "insert into trial_summaries (job_id, search_id, point_idx, variant,
                             trial, seed, converged, digest)
                         values (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
                    )
                    .bind(job_id)
                    .bind(search_id)
                    .bind(point)
                    .bind(variant)
                    .bind(trial)
                    .bind(seed)
                    .bind(converged)
                    .bind(&up.digest)
                    .execute(&mut *c)
                    .await?;
                }
                Ok(rows.len() as u64)
            })
        })
        .await
        .map_err(|e: StoreError| anyhow::Error::new(e))?;
        if n == 0 {
            return Ok(total);
        }
        total += n;
    }
}
