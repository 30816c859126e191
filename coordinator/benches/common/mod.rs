//! Helpers shared by the queue benchmark (`benches/queue.rs`) and the load
//! generator (`examples/load.rs`): settings from the environment, latency
//! percentiles and job outputs for simulated workers.

#![allow(dead_code)]

use serde_json::{json, Value};

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
    let eps: Vec<Value> = (0..episodes)
        .map(|e| {
            let phase = (seed.wrapping_mul(31).wrapping_add(e as u64) % 1000) as f64 / 997.0;
            let s: Vec<f64> = (0..points)
                .map(|i| i as f64 / (points - 1) as f64)
                .collect();
            let com_t: Vec<f64> = s.iter().map(|x| x * 1.7 + phase * 1e-3).collect();
            let com_x: Vec<f64> = s
                .iter()
                .map(|x| (0.05 + 0.1 * phase) * (std::f64::consts::PI * x).sin())
                .collect();
            let com_z: Vec<f64> = s.iter().map(|x| 0.55 + 0.41 * x + 0.01 * phase).collect();
            json!({"com_t": com_t, "com_x": com_x, "com_z": com_z,
                   "return": 900.0 + phase, "torque_usage": 40.0 + phase, "steps": points as u32})
        })
        .collect();
    json!({"final_success_rate": 0.9, "env_steps": 1000, "successes_found": wanted,
           "successes_wanted": wanted, "sampling_attempts": wanted + 2, "episodes": eps,
           "train_secs": 12.5, "sample_secs": 1.5})
}
