//! Databases from before trial summaries (migration 0008) migrate in
//! place at start-up: every accepted output without a summary gets its
//! digest and is re-stored in the compact encoding ([`super::codec`]), a
//! batch per writer transaction, before the coordinator serves. A
//! coordinator stopped half-way resumes with the rows left. The file does
//! not shrink by itself: `VACUUM` (offline) returns the freed pages.

use anyhow::Context;
use rusqlite::params;

use super::error::StoreError;
use super::queue::Upload;
use super::writer::{db_err, with_tx};
use super::{codec, Db};

/// Outputs converted per transaction (each ~1 ms of CPU).
const BATCH: i64 = 32;

/// An output stored without a summary, with its job's facts.
struct Legacy {
    job_id: i64,
    stored: Vec<u8>,
    /// converged, search, point, variant, trial.
    facts: (bool, String, i64, i64, i64),
    seed: i64,
}

/// Converts every output without a summary; returns how many.
pub async fn run(db: &Db) -> anyhow::Result<u64> {
    let mut total = 0;
    loop {
        let n = with_tx(&db.writer, |tx| {
            let rows: Vec<Legacy> = tx
                .prepare(
                    "select r.job_id, cast(r.output as blob), r.converged, j.search_id,
                            j.point_idx, j.variant, j.trial, j.seed
                     from job_results r join jobs j on j.id = r.job_id
                     where not exists (select 1 from trial_summaries s where s.job_id = r.job_id)
                     limit ?1",
                )
                .map_err(db_err)?
                .query_map(params![BATCH], |r| {
                    Ok(Legacy {
                        job_id: r.get(0)?,
                        stored: r.get(1)?,
                        facts: (r.get(2)?, r.get(3)?, r.get(4)?, r.get(5)?, r.get(6)?),
                        seed: r.get(7)?,
                    })
                })
                .map_err(db_err)?
                .collect::<Result<_, _>>()
                .map_err(db_err)?;
            for row in &rows {
                let Legacy {
                    job_id,
                    stored,
                    facts: (converged, search_id, point, variant, trial),
                    seed,
                } = row;
                let up = codec::decode(stored)
                    .and_then(Upload::of)
                    .with_context(|| format!("converting the output of job {job_id}"))
                    .map_err(StoreError::Internal)?;
                tx.execute(
                    "update job_results set output = ?1 where job_id = ?2",
                    params![up.output, job_id],
                )
                .map_err(db_err)?;
                tx.execute(
                    "insert into trial_summaries (job_id, search_id, point_idx, variant, trial,
                         seed, converged, digest)
                     values (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
                    params![job_id, search_id, point, variant, trial, seed, converged, up.digest],
                )
                .map_err(db_err)?;
            }
            Ok(rows.len() as u64)
        })
        .await
        .map_err(|e: StoreError| anyhow::Error::new(e))?;
        if n == 0 {
            return Ok(total);
        }
        total += n;
    }
}
