//! The squat-to-stand reinforcement-learning task (docs/science.md#task), as a single
//! episode ([`Task`], [`Episode`]) and as a batch ([`BatchEnv`]).

mod batch;
mod config;
mod preset;
mod task;

pub use batch::{BatchEnv, ComPath};
pub use config::{EffortTerm, EnvConfig, FailPenalty, RewardConfig};
pub use preset::{overlay, preset, presets, RewardPreset, DEFAULT_PRESET};
pub use task::{Episode, Outcome, StepInfo, Task};

use crate::sim::SimError;

/// Errors of the environment.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum EnvError {
    /// A task parameter is out of range.
    #[error("invalid environment configuration: {0}")]
    InvalidConfig(String),
    /// The body model rejected its parameters.
    #[error(transparent)]
    Sim(#[from] SimError),
    /// `step` got the wrong number of action components.
    #[error("expected {expected} action values, got {got}")]
    ActionShape { expected: usize, got: usize },
}

#[cfg(test)]
mod tests;
