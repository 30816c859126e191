//! Proximal Policy Optimization for the squat-to-stand task: a
//! Gaussian MLP policy and value network with hand-written batched
//! backpropagation, Adam, and the PPO loop over `BatchEnv`; the trained
//! policy file; and stochastic evaluation.
//!
//! Everything is single-threaded and seeded: training is a pure function of
//! `(PpoConfig, EnvConfig, seed)` on a given machine.

pub mod adam;
pub mod config;
pub mod gaussian;
pub mod linalg;
pub mod loss;
mod matref;
pub mod mlp;
pub mod model;
pub mod normalize;
pub mod policy_file;
pub mod real;
mod skinny;
pub mod trainer;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

pub use config::{PpoConfig, TimeLimit};
pub use model::{Actor, ActorCritic, ObsNormalizer};
pub use policy_file::{TrainedPolicy, POLICY_FORMAT, POLICY_VERSION};
pub use trainer::train;

use crate::env::{BatchEnv, EnvError, Outcome};

/// Errors of training, evaluation and policy files.
#[derive(Debug, thiserror::Error)]
pub enum PpoError {
    /// A hyperparameter is out of range.
    #[error("invalid PPO configuration: {0}")]
    InvalidConfig(String),
    /// The environment rejected its configuration or input.
    #[error(transparent)]
    Env(#[from] EnvError),
    /// The progress callback asked to stop.
    #[error("training cancelled")]
    Cancelled,
    /// A loss or parameter became non-finite.
    #[error("training diverged (non-finite loss or parameters) at update {update}")]
    Diverged {
        /// 0-based update index.
        update: u64,
    },
    /// The policy file is not valid JSON of the expected shape.
    #[error("malformed policy file: {0}")]
    MalformedPolicy(String),
    /// The policy file parses but does not fit this build or task.
    #[error("incompatible policy file: {0}")]
    IncompatiblePolicy(String),
    /// Evaluation was asked for zero episodes.
    #[error("evaluation needs at least one episode")]
    NoEpisodes,
}

/// Progress after one PPO update: one row of `learning_curve.csv`. Episode
/// statistics cover the episodes finished during that update's rollout (the
/// previous update's when none finished).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainProgress {
    /// 1-based update number.
    pub update: u64,
    /// Environment steps done so far.
    pub env_steps: u64,
    /// Environment steps the whole run will take.
    pub total_env_steps: u64,
    /// Mean undiscounted episode return.
    pub mean_return: f64,
    /// Fraction of episodes that ended in success.
    pub success_rate: f64,
    /// Mean episode length (control steps).
    pub mean_episode_length: f64,
    /// Mean clipped-surrogate loss over the update's minibatches.
    pub policy_loss: f64,
    /// Mean value loss (squared error, scaled-reward units).
    pub value_loss: f64,
    /// Policy entropy (nats).
    pub entropy: f64,
    /// Mean approximate KL(old || new) over the minibatches.
    pub approx_kl: f64,
    /// Mean fraction of clipped ratios.
    pub clip_fraction: f64,
    /// Explained variance of the value predictions on the rollout.
    pub explained_variance: f64,
    /// Learning rate used in this update.
    pub learning_rate: f64,
    /// Mean action standard deviation after the update.
    pub action_std: f64,
}

/// Result of `train`.
#[derive(Debug, Clone)]
pub struct TrainOutput {
    /// The trained policy.
    pub policy: TrainedPolicy,
    /// One progress row per update.
    pub curve: Vec<TrainProgress>,
    /// Environment steps actually taken.
    pub env_steps: u64,
}

/// Result of a stochastic evaluation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    /// Episodes run.
    pub episodes: u32,
    /// Fraction that ended in success.
    pub success_rate: f64,
    /// Mean undiscounted return.
    pub mean_return: f64,
    /// Mean torque usage, sum of ||tau||_2 * 0.05 s per episode (N m s, docs/science.md#sampling).
    pub mean_torque_usage: f64,
    /// Mean episode length (control steps).
    pub mean_episode_length: f64,
}

/// Independent random streams derived from one seed. `BatchEnv` uses
/// streams `0..n_envs` of the same seed for its initial states, so these sit
/// at the top of the stream space.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Stream {
    Init,
    Actions,
    Shuffle,
}

pub(crate) fn rng_for(seed: u64, stream: Stream) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(u64::MAX - stream as u64);
    rng
}

/// Precision the networks compute in during training, evaluation and
/// sampling (the parameters are stored and optimized in `f64`).
pub type Net = f32;

/// Most environments a rollout of a frozen policy steps at once.
pub(crate) const EVAL_ENVS: usize = 64;

/// Runs `episodes` episodes of the stochastic policy (actions sampled from
/// its Gaussian) in the environment it was trained in. Episodes are assigned
/// round-robin to a batch of environments, each running a fixed quota, so
/// short episodes are not over-represented. Deterministic from `seed`.
pub fn evaluate(policy: &TrainedPolicy, episodes: u32, seed: u64) -> Result<EvalReport, PpoError> {
    if episodes == 0 {
        return Err(PpoError::NoEpisodes);
    }
    policy.validate()?;
    let model: ActorCritic<Net> = policy.model()?.cast();
    let norm = policy.obs_normalizer();
    let n = (episodes as usize).min(EVAL_ENVS);
    let mut env = BatchEnv::new(&policy.env, n, seed)?;
    let quota: Vec<u32> = (0..n as u32)
        .map(|i| episodes / n as u32 + u32::from(i < episodes % n as u32))
        .collect();
    let mut done = vec![0u32; n];
    let mut rng = rng_for(seed, Stream::Actions);
    let mut actor = Actor::<Net>::new();
    let mut actions = vec![0.0; n * BatchEnv::ACT_DIM];
    let (mut finished, mut successes) = (0u32, 0u32);
    let (mut ret, mut torque, mut len) = (0.0, 0.0, 0.0);
    while finished < episodes {
        actor.act(&model, &norm, env.observations(), &mut rng, &mut actions);
        let infos = env.step(&actions)?;
        for (i, info) in infos.iter().enumerate() {
            if info.outcome.is_done() && done[i] < quota[i] {
                done[i] += 1;
                finished += 1;
                successes += u32::from(info.outcome == Outcome::Success);
                ret += info.episode_return;
                torque += info.episode_torque_usage;
                len += f64::from(info.episode_len);
            }
        }
    }
    let k = f64::from(episodes);
    Ok(EvalReport {
        episodes,
        success_rate: f64::from(successes) / k,
        mean_return: ret / k,
        mean_torque_usage: torque / k,
        mean_episode_length: len / k,
    })
}

#[cfg(test)]
mod tests;
