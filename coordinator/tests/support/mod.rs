//! The coordinator's one test-support module, shared by its integration
//! tests (`tests/api`, `tests/dashboard.rs`), its benches and the load
//! generator (`examples/load.rs`, included with `#[path]`): coordinator
//! start-up on a temporary database, search bodies, simulated job
//! outputs, and settings and percentiles for the benches. Synthetic
//! stand-up episodes come from `shared::test_support`.
//!
//! Each includer uses a part of it, hence `dead_code` is allowed.

#![allow(dead_code)]

use std::path::Path;

use coordinator::{CoordinatorConfig, Running};
use serde_json::{json, Value};
use shared::analysis::EpisodeRecord;
use shared::test_support::StandUp;

/// The config of a coordinator on `127.0.0.1:0` (a free port) over `db`,
/// otherwise the defaults.
pub fn config(db: &Path) -> CoordinatorConfig {
    CoordinatorConfig::new("127.0.0.1:0".parse().expect("a socket address"), db)
}

/// A coordinator started on a new temporary database (`c.db` in `dir`),
/// its config first changed by `tune`. The directory lives as long as the
/// caller keeps it.
pub async fn start(
    tune: impl FnOnce(&mut CoordinatorConfig),
) -> anyhow::Result<(Running, tempfile::TempDir)> {
    let dir = tempfile::tempdir()?;
    let running = restart(dir.path(), tune).await?;
    Ok((running, dir))
}

/// A coordinator started on the database `c.db` in `dir` (new or kept from
/// an earlier start), its config changed by `tune`.
pub async fn restart(
    dir: &Path,
    tune: impl FnOnce(&mut CoordinatorConfig),
) -> anyhow::Result<Running> {
    let mut cfg = config(&dir.join("c.db"));
    tune(&mut cfg);
    coordinator::start(cfg).await
}

/// A connection of its own to a coordinator's database file, for tests
/// and benches that look at or change rows directly (the coordinator may
/// be running: it waits up to 10 s for the writer's lock).
pub async fn connect(db: &Path) -> anyhow::Result<sqlx::SqliteConnection> {
    use sqlx::ConnectOptions;
    Ok(sqlx::sqlite::SqliteConnectOptions::new()
        .filename(db)
        .busy_timeout(std::time::Duration::from_secs(10))
        .connect()
        .await?)
}

/// A search over `w1` with `trials` trials of a 1,000-step training budget
/// keeping `kept` episodes per job: small numbers, since simulated workers
/// upload made-up outputs and never train.
pub fn search_json(name: &str, w1: &[f64], trials: u32, kept: u32) -> Value {
    json!({
        "name": name,
        "reward_grid": {"w1": w1},
        "trials": trials,
        "seed": 7,
        "training": {"env_steps": 1000},
        "sampling": {"successful_episodes": kept, "top_k": kept, "max_attempts": 1000, "n_envs": 1}
    })
}

/// `name` from the environment parsed as `T`, else `default`.
pub fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// The `p` quantile (0..=1) of sorted samples (nearest rank), NaN if empty.
pub fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((sorted.len() as f64 - 1.0) * p).round() as usize;
    sorted[i]
}

/// Sorts latency samples for [`percentile`].
pub fn sorted(mut v: Vec<f64>) -> Vec<f64> {
    v.sort_by(f64::total_cmp);
    v
}

/// An upload with no episodes for a search asking for `wanted` successes.
pub fn empty_output(wanted: u32) -> Value {
    json!({"final_success_rate": 0.0, "env_steps": 1, "successes_found": 0,
           "successes_wanted": wanted, "sampling_attempts": 1, "episodes": []})
}

/// An output sized like a real one: `episodes` stand-up trajectories of
/// `points` samples each (full-precision floats, as a worker sends them).
pub fn realistic_output(episodes: usize, points: usize, wanted: u32, seed: u64) -> Value {
    let eps: Vec<EpisodeRecord> = (0..episodes)
        .map(|e| {
            let phase = (seed.wrapping_mul(31).wrapping_add(e as u64) % 1000) as f64 / 997.0;
            StandUp::new(0.05 + 0.1 * phase)
                .sampled(points, 1.7)
                .rising(0.55 + 0.01 * phase, 0.41)
                .ret(900.0 + phase)
                .torque_usage(40.0 + phase)
                .steps(points as u32)
                .episode()
        })
        .collect();
    json!({"final_success_rate": 0.9, "env_steps": 1000, "successes_found": wanted,
           "successes_wanted": wanted, "sampling_attempts": wanted + 2, "episodes": eps,
           "train_secs": 12.5, "sample_secs": 1.5})
}
