//! From a trained policy to trajectories (docs/science.md#sampling): roll out the stochastic
//! policy until enough successful episodes are found (or an attempt cap is
//! hit, reported rather than hidden) and keep the best `top_k` successes by
//! return, each with its centre-of-mass path at every RK4 sub-step.
//!
//! Only the current top `top_k` are held (a small min-heap); every
//! environment records its own COM path, and a path is copied out only when
//! its episode enters the top `top_k`. Deterministic from the seed.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use serde::{Deserialize, Serialize};

use crate::analysis::EpisodeRecord;
use crate::env::{BatchEnv, EnvError, Outcome, StepInfo};
use crate::ppo::{rng_for, Actor, ActorCritic, Net, PpoError, Stream, TrainedPolicy};

/// Sampling parameters. `Default` equals docs/science.md#sampling.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(default, deny_unknown_fields)]
pub struct SamplingConfig {
    /// Successful episodes to collect before stopping (default 1000).
    pub successful_episodes: u32,
    /// Successful episodes kept, those with the highest return (default 10).
    pub top_k: u32,
    /// Cap on episodes tried; reaching it stops sampling with a shortfall.
    pub max_attempts: u32,
    /// Environments stepped together.
    pub n_envs: u32,
}

impl Default for SamplingConfig {
    fn default() -> Self {
        Self {
            successful_episodes: 1000,
            top_k: 10,
            max_attempts: 20_000,
            n_envs: 64,
        }
    }
}

impl SamplingConfig {
    /// Checks ranges.
    pub fn validate(&self) -> Result<(), SampleError> {
        let bad = |m: String| Err(SampleError::InvalidConfig(m));
        if self.successful_episodes == 0 {
            return bad("successful_episodes must be at least 1".into());
        }
        if self.top_k == 0 || self.top_k > self.successful_episodes {
            return bad(format!(
                "top_k must be in 1..=successful_episodes ({}), got {}",
                self.successful_episodes, self.top_k
            ));
        }
        if self.max_attempts < self.successful_episodes {
            return bad(format!(
                "max_attempts ({}) must be at least successful_episodes ({})",
                self.max_attempts, self.successful_episodes
            ));
        }
        if !(1..=4096).contains(&self.n_envs) {
            return bad(format!("n_envs must be in 1..=4096, got {}", self.n_envs));
        }
        Ok(())
    }
}

/// What sampling produced.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SampleOutput {
    /// The kept successful episodes, highest return first (at most `top_k`).
    pub episodes: Vec<EpisodeRecord>,
    /// Successful episodes found.
    pub successes_found: u32,
    /// Successful episodes asked for; `successes_found < successes_wanted`
    /// means the attempt cap was hit.
    pub successes_wanted: u32,
    /// Episodes run.
    pub attempts: u32,
}

impl SampleOutput {
    /// Fraction of attempted episodes that succeeded.
    pub fn success_rate(&self) -> f64 {
        f64::from(self.successes_found) / f64::from(self.attempts.max(1))
    }
}

/// Errors of sampling.
#[derive(Debug, thiserror::Error)]
pub enum SampleError {
    /// A sampling parameter is out of range.
    #[error("invalid sampling configuration: {0}")]
    InvalidConfig(String),
    /// The policy file does not fit.
    #[error(transparent)]
    Policy(#[from] PpoError),
    /// The environment rejected its configuration.
    #[error(transparent)]
    Env(#[from] EnvError),
}

/// A heap entry ordered so that the *worst* kept episode is on top: lower
/// return first, and among equal returns the later one (earlier wins ties).
struct Kept {
    ret: f64,
    order: u32,
    record: EpisodeRecord,
}

impl Ord for Kept {
    fn cmp(&self, other: &Self) -> Ordering {
        other
            .ret
            .total_cmp(&self.ret)
            .then(self.order.cmp(&other.order))
    }
}
impl PartialOrd for Kept {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl PartialEq for Kept {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}
impl Eq for Kept {}

/// Rolls out `policy` (stochastic actions) in its own environment
/// configuration until `cfg.successful_episodes` successes or
/// `cfg.max_attempts` episodes, and returns the `top_k` successes by return.
pub fn sample(
    policy: &TrainedPolicy,
    cfg: &SamplingConfig,
    seed: u64,
) -> Result<SampleOutput, SampleError> {
    cfg.validate()?;
    policy.validate()?;
    let model: ActorCritic<Net> = policy.model()?.cast();
    let norm = policy.obs_normalizer();
    let n = cfg.n_envs.min(cfg.max_attempts) as usize;
    let mut env = BatchEnv::new(&policy.env, n, seed)?;
    env.set_record_com(true);
    let mut rng = rng_for(seed, Stream::Actions);
    let mut actor = Actor::<Net>::new();
    let mut actions = vec![0.0; n * BatchEnv::ACT_DIM];
    let mut infos: Vec<StepInfo> = Vec::with_capacity(n);
    let mut heap: BinaryHeap<Kept> = BinaryHeap::with_capacity(cfg.top_k as usize + 1);
    let (mut attempts, mut successes) = (0u32, 0u32);
    'outer: while successes < cfg.successful_episodes && attempts < cfg.max_attempts {
        actor.act(&model, &norm, env.observations(), &mut rng, &mut actions);
        infos.clear();
        infos.extend_from_slice(env.step(&actions)?);
        for (i, info) in infos.iter().enumerate() {
            if !info.outcome.is_done() {
                continue;
            }
            attempts += 1;
            if info.outcome == Outcome::Success {
                successes += 1;
                let worst = heap.peek().map(|k| (k.ret, k.order));
                let enters = heap.len() < cfg.top_k as usize
                    || worst.is_some_and(|(r, _)| info.episode_return > r);
                if enters {
                    let path = env.finished_path(i);
                    heap.push(Kept {
                        ret: info.episode_return,
                        order: attempts,
                        record: EpisodeRecord {
                            com_t: path.t.clone(),
                            com_x: path.x.clone(),
                            com_z: path.z.clone(),
                            ret: info.episode_return,
                            torque_usage: info.episode_torque_usage,
                            steps: info.episode_len,
                        },
                    });
                    if heap.len() > cfg.top_k as usize {
                        heap.pop();
                    }
                }
            }
            if successes >= cfg.successful_episodes || attempts >= cfg.max_attempts {
                break 'outer;
            }
        }
    }
    // into_sorted_vec is ascending in `Kept` order, i.e. best first.
    let episodes = heap
        .into_sorted_vec()
        .into_iter()
        .map(|k| k.record)
        .collect();
    Ok(SampleOutput {
        episodes,
        successes_found: successes,
        successes_wanted: cfg.successful_episodes,
        attempts,
    })
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)] // index loops read clearer in checks
mod tests {
    use std::ops::ControlFlow;

    use super::*;
    use crate::env::EnvConfig;
    use crate::ppo::{train, PpoConfig};

    fn policy(env: &EnvConfig) -> TrainedPolicy {
        let cfg = PpoConfig {
            env_steps: 256,
            n_envs: 8,
            n_steps: 32,
            epochs: 1,
            minibatch_size: 64,
            hidden: vec![8, 8],
            ..PpoConfig::default()
        };
        train(&cfg, env, 1, &mut |_| ControlFlow::Continue(()))
            .unwrap()
            .policy
    }

    /// A task where standing still near the start counts as success, so an
    /// untrained policy succeeds within a step or two.
    fn easy_env() -> EnvConfig {
        let mut env = EnvConfig::default();
        env.reward.success_height = 0.6;
        env.reward.success_speed = 5.0;
        env
    }

    #[test]
    fn keeps_the_best_successes_with_their_com_paths() {
        let p = policy(&easy_env());
        let cfg = SamplingConfig {
            successful_episodes: 40,
            top_k: 5,
            max_attempts: 400,
            n_envs: 16,
        };
        let out = sample(&p, &cfg, 3).unwrap();
        assert_eq!(out.successes_found, 40);
        assert_eq!(out.successes_wanted, 40);
        assert!(out.attempts >= 40 && out.attempts <= 400);
        assert_eq!(out.episodes.len(), 5);
        for w in out.episodes.windows(2) {
            assert!(w[0].ret >= w[1].ret);
        }
        let substeps = p.env.sim.substeps as usize;
        for e in &out.episodes {
            let n = e.steps as usize * substeps + 1;
            assert_eq!((e.com_t.len(), e.com_x.len(), e.com_z.len()), (n, n, n));
            assert_eq!(e.com_t[0], 0.0);
            assert!((e.com_t[n - 1] - e.steps as f64 * p.env.sim.control_dt()).abs() < 1e-12);
            assert!(e.torque_usage > 0.0);
        }
        assert_eq!(out, sample(&p, &cfg, 3).unwrap());
        // A different seed samples different episodes.
        assert_ne!(out, sample(&p, &cfg, 4).unwrap());
    }

    #[test]
    fn the_attempt_cap_reports_a_shortfall() {
        let p = policy(&EnvConfig::default());
        let cfg = SamplingConfig {
            successful_episodes: 1000,
            top_k: 10,
            max_attempts: 1000,
            n_envs: 32,
        };
        let out = sample(&p, &cfg, 1).unwrap();
        assert_eq!(out.attempts, 1000);
        assert!(out.successes_found < 1000);
        assert_eq!(out.successes_wanted, 1000);
        assert!(out.episodes.len() <= 10);
    }

    #[test]
    fn invalid_configs_are_rejected() {
        let p = policy(&EnvConfig::default());
        for cfg in [
            SamplingConfig {
                top_k: 0,
                ..Default::default()
            },
            SamplingConfig {
                top_k: 2000,
                ..Default::default()
            },
            SamplingConfig {
                max_attempts: 10,
                ..Default::default()
            },
            SamplingConfig {
                n_envs: 0,
                ..Default::default()
            },
            SamplingConfig {
                successful_episodes: 0,
                ..Default::default()
            },
        ] {
            assert!(matches!(
                sample(&p, &cfg, 1),
                Err(SampleError::InvalidConfig(_))
            ));
        }
    }

    #[test]
    fn heap_order_puts_the_worst_on_top_and_earlier_wins_ties() {
        let rec = |ret| EpisodeRecord {
            com_t: vec![],
            com_x: vec![],
            com_z: vec![],
            ret,
            torque_usage: 0.0,
            steps: 0,
        };
        let mut heap = BinaryHeap::new();
        for (order, ret) in [(1, 5.0), (2, 9.0), (3, 5.0), (4, 7.0)] {
            heap.push(Kept {
                ret,
                order,
                record: rec(ret),
            });
        }
        let top = heap.peek().unwrap();
        assert_eq!((top.ret, top.order), (5.0, 3));
        let sorted: Vec<(f64, u32)> = heap
            .into_sorted_vec()
            .iter()
            .map(|k| (k.ret, k.order))
            .collect();
        assert_eq!(sorted, vec![(9.0, 2), (7.0, 4), (5.0, 1), (5.0, 3)]);
    }
}
