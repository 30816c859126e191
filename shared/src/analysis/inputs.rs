//! The inputs of aggregation (docs/science.md#aggregation): each grid
//! point's finished trials and their kept episodes, as uploaded and stored.
//! Their own module, below both the digest of a trial ([`super::digest`])
//! and the aggregation that reads it ([`super::aggregate`]).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::solvers::SolverTag;

/// One sampled, kept episode of one trial (docs/science.md#sampling), as stored/uploaded.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct EpisodeRecord {
    /// Sample times of the COM trajectory (s), one per RK4 sub-step.
    pub com_t: Vec<f64>,
    /// Forward COM coordinate (m).
    pub com_x: Vec<f64>,
    /// Vertical COM coordinate (m).
    pub com_z: Vec<f64>,
    /// Episode return.
    #[serde(rename = "return")]
    pub ret: f64,
    /// Sum over control steps of ||tau||_2 * 0.05 s (N m s), docs/science.md#sampling.
    pub torque_usage: f64,
    /// Control steps taken.
    pub steps: u32,
}

/// One finished (w, trial) job's data as input to aggregation.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct TrialInput {
    /// Trial number within its grid point.
    pub trial: u32,
    /// Training seed.
    pub seed: u64,
    /// Success rate at the end of training.
    pub final_success_rate: f64,
    /// Whether training met its convergence criterion; only converged trials
    /// enter the means.
    pub converged: bool,
    /// The kept episodes (docs/science.md#sampling: the 10 best successful ones).
    pub episodes: Vec<EpisodeRecord>,
    /// Successful episodes found while sampling.
    pub successes_found: u32,
    /// Successful episodes wanted (docs/science.md#sampling: 1000).
    pub successes_wanted: u32,
    /// The solver variant that produced it (`ppo` when the search names
    /// none).
    #[serde(default)]
    pub solver: SolverTag,
}

/// All trials of one reward-grid point. `params` e.g. {"w1": 1.0}.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
pub struct WeightInput {
    /// Reward parameters of this grid point.
    pub params: BTreeMap<String, f64>,
    /// Its finished trials.
    pub trials: Vec<TrialInput>,
}
