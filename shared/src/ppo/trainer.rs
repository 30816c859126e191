//! The PPO training loop: batched rollouts through `BatchEnv`, reward
//! scaling, GAE, and minibatch epochs of the clipped objective.

use std::ops::ControlFlow;

use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;

use super::adam::Adam;
use super::config::{PpoConfig, TimeLimit};
use super::gaussian;
use super::loss::{ppo_loss, Grads, LossCoefs, LossStats, LossWorkspace, Minibatch};
use super::mlp::MlpWorkspace;
use super::model::{widen, ActorCritic, ObsNormalizer};
use super::normalize::{RewardScaler, RunningMeanStd};
use super::policy_file::TrainedPolicy;
use super::{rng_for, Net, PpoError, Stream, TrainOutput, TrainProgress};
use crate::env::{BatchEnv, EnvConfig, Outcome};

/// Trains a policy with PPO on `env` (its `reward.w1` is the torque weight).
/// A pure function of `(cfg, env, seed)`: single-threaded, every random draw
/// from seeded ChaCha streams. `on_update` sees every update's progress;
/// returning `Break` cancels training (`PpoError::Cancelled`).
pub fn train(
    cfg: &PpoConfig,
    env: &EnvConfig,
    seed: u64,
    on_update: &mut dyn FnMut(&TrainProgress) -> ControlFlow<()>,
) -> Result<TrainOutput, PpoError> {
    cfg.validate()?;
    let env_cfg = cfg.effective_env(env);
    let mut benv = BatchEnv::new(&env_cfg, cfg.n_envs, seed)?;
    let mut trainer = Trainer::new(cfg, &env_cfg, seed);
    let n_updates = cfg.n_updates();
    let total_env_steps = n_updates * cfg.batch_size() as u64;
    let mut curve = Vec::with_capacity(n_updates.min(100_000) as usize);
    let mut last_episodes = EpisodeStats::default();
    for update in 0..n_updates {
        let lr = if cfg.anneal_lr {
            cfg.learning_rate * (1.0 - update as f64 / n_updates as f64)
        } else {
            cfg.learning_rate
        };
        let episodes = trainer.collect(&mut benv)?;
        if episodes.count > 0 {
            last_episodes = episodes;
        }
        trainer.compute_gae();
        let explained_variance = trainer.explained_variance();
        let stats = trainer.optimize(lr);
        if !(trainer.model.is_finite() && stats.total.is_finite()) {
            return Err(PpoError::Diverged { update });
        }
        let progress = TrainProgress {
            update: update + 1,
            env_steps: (update + 1) * cfg.batch_size() as u64,
            total_env_steps,
            mean_return: last_episodes.mean_return(),
            success_rate: last_episodes.success_rate(),
            mean_episode_length: last_episodes.mean_length(),
            policy_loss: stats.policy_loss,
            value_loss: stats.value_loss,
            entropy: stats.entropy,
            approx_kl: stats.approx_kl,
            clip_fraction: stats.clip_fraction,
            explained_variance,
            learning_rate: lr,
            action_std: trainer.model.log_std.iter().map(|l| l.exp()).sum::<f64>()
                / trainer.model.log_std.len() as f64,
        };
        let flow = on_update(&progress);
        curve.push(progress);
        if flow.is_break() {
            return Err(PpoError::Cancelled);
        }
    }
    let policy = TrainedPolicy::new(
        trainer.model,
        trainer.obs_norm.rms,
        cfg.clone(),
        env_cfg,
        seed,
        total_env_steps,
    );
    Ok(TrainOutput {
        policy,
        curve,
        env_steps: total_env_steps,
    })
}

/// Episodes finished during one rollout.
#[derive(Debug, Clone, Copy, Default)]
struct EpisodeStats {
    count: u32,
    successes: u32,
    return_sum: f64,
    length_sum: f64,
}

impl EpisodeStats {
    fn mean_return(&self) -> f64 {
        self.return_sum / f64::from(self.count.max(1))
    }
    fn success_rate(&self) -> f64 {
        f64::from(self.successes) / f64::from(self.count.max(1))
    }
    fn mean_length(&self) -> f64 {
        self.length_sum / f64::from(self.count.max(1))
    }
}

/// Everything the loop keeps between updates; buffers are allocated once.
struct Trainer {
    cfg: PpoConfig,
    n_envs: usize,
    obs_dim: usize,
    act_dim: usize,
    /// Master parameters (f64, what Adam updates and the file stores).
    model: ActorCritic,
    /// The same parameters in the networks' compute precision.
    net: ActorCritic<Net>,
    obs_norm: ObsNormalizer,
    reward_scaler: RewardScaler,
    adam_policy: Adam,
    adam_log_std: Adam,
    adam_value: Adam,
    rng_actions: ChaCha8Rng,
    rng_shuffle: ChaCha8Rng,
    // Rollout storage, sample index s = t * n_envs + i, per-sample columns.
    obs: Vec<Net>,
    actions: Vec<f64>,
    logp: Vec<f64>,
    values: Vec<f64>,
    rewards: Vec<f64>,
    dones: Vec<bool>,
    advantages: Vec<f64>,
    returns: Vec<f64>,
    last_values: Vec<f64>,
    last_obs: Vec<Net>,
    outcomes: Vec<Outcome>,
    // Scratch.
    rms_scratch: Vec<f64>,
    policy_ws: MlpWorkspace<Net>,
    value_ws: MlpWorkspace<Net>,
    rollout_value_ws: MlpWorkspace<Net>,
    single_ws: MlpWorkspace<Net>,
    single_obs: Vec<Net>,
    mean: Vec<f64>,
    perm: Vec<usize>,
    mb_obs: Vec<Net>,
    mb_actions: Vec<f64>,
    mb_logp: Vec<f64>,
    mb_adv: Vec<f64>,
    mb_ret: Vec<f64>,
    mb_values: Vec<f64>,
    loss_ws: LossWorkspace<Net>,
    grads: Grads<Net>,
}

impl Trainer {
    fn new(cfg: &PpoConfig, env_cfg: &EnvConfig, seed: u64) -> Self {
        let n_envs = cfg.n_envs;
        let obs_dim = env_cfg.obs_dim();
        let act_dim = BatchEnv::ACT_DIM;
        let batch = cfg.batch_size();
        let mb = cfg.minibatch_size;
        let mut rng_init = rng_for(seed, Stream::Init);
        let model = ActorCritic::new(
            obs_dim,
            act_dim,
            &cfg.hidden,
            cfg.init_log_std,
            &mut rng_init,
        );
        let net: ActorCritic<Net> = model.cast();
        let grads = Grads::zeros(&net);
        Self {
            n_envs,
            obs_dim,
            act_dim,
            obs_norm: ObsNormalizer {
                rms: RunningMeanStd::new(obs_dim),
                enabled: cfg.normalize_obs,
                clip: cfg.obs_clip,
            },
            reward_scaler: RewardScaler::new(n_envs, cfg.gamma, cfg.reward_clip),
            adam_policy: Adam::new(model.policy.params().len(), cfg.adam_eps),
            adam_log_std: Adam::new(act_dim, cfg.adam_eps),
            adam_value: Adam::new(model.value.params().len(), cfg.adam_eps),
            rng_actions: rng_for(seed, Stream::Actions),
            rng_shuffle: rng_for(seed, Stream::Shuffle),
            obs: vec![0.0; batch * obs_dim],
            mean: vec![0.0; n_envs * act_dim],
            actions: vec![0.0; batch * act_dim],
            logp: vec![0.0; batch],
            values: vec![0.0; batch],
            rewards: vec![0.0; batch],
            dones: vec![false; batch],
            advantages: vec![0.0; batch],
            returns: vec![0.0; batch],
            last_values: vec![0.0; n_envs],
            last_obs: vec![0.0; n_envs * obs_dim],
            outcomes: vec![Outcome::Running; n_envs],
            rms_scratch: vec![0.0; 2 * obs_dim],
            policy_ws: MlpWorkspace::new(),
            value_ws: MlpWorkspace::new(),
            rollout_value_ws: MlpWorkspace::new(),
            single_ws: MlpWorkspace::new(),
            single_obs: vec![0.0; obs_dim],
            perm: (0..batch).collect(),
            mb_obs: vec![0.0; mb * obs_dim],
            mb_actions: vec![0.0; mb * act_dim],
            mb_logp: vec![0.0; mb],
            mb_adv: vec![0.0; mb],
            mb_ret: vec![0.0; mb],
            mb_values: vec![0.0; mb],
            loss_ws: LossWorkspace::new(),
            grads,
            net,
            model,
            cfg: cfg.clone(),
        }
    }

    /// Runs `n_steps` steps of every environment, filling the rollout buffers.
    fn collect(&mut self, benv: &mut BatchEnv) -> Result<EpisodeStats, PpoError> {
        let (n, od, ad) = (self.n_envs, self.obs_dim, self.act_dim);
        let mode = self.cfg.time_limit;
        let gamma = self.cfg.gamma;
        let mut episodes = EpisodeStats::default();
        for t in 0..self.cfg.n_steps {
            let raw = benv.observations();
            if self.obs_norm.enabled {
                self.obs_norm.rms.update(raw, &mut self.rms_scratch);
            }
            let obs = &mut self.obs[t * n * od..(t + 1) * n * od];
            self.obs_norm.apply(raw, obs);
            widen(
                self.net.policy.forward(obs, &mut self.policy_ws),
                &mut self.mean,
            );
            let actions = &mut self.actions[t * n * ad..(t + 1) * n * ad];
            gaussian::sample(
                &self.mean,
                &self.net.log_std,
                &mut self.rng_actions,
                actions,
            );
            let logp = &mut self.logp[t * n..(t + 1) * n];
            gaussian::log_prob(&self.mean, &self.net.log_std, actions, logp);

            let infos = benv.step(actions)?;
            self.reward_scaler
                .update(infos.iter().map(|s| (s.reward, s.outcome.is_done())));
            for (i, info) in infos.iter().enumerate() {
                let s = t * n + i;
                let done = info.outcome.is_done();
                self.dones[s] = done;
                self.rewards[s] = if self.cfg.normalize_reward {
                    self.reward_scaler.scale(info.reward)
                } else {
                    info.reward
                };
                self.outcomes[i] = info.outcome;
                if done {
                    episodes.count += 1;
                    episodes.successes += u32::from(info.outcome == Outcome::Success);
                    episodes.return_sum += info.episode_return;
                    episodes.length_sum += f64::from(info.episode_len);
                }
            }
            for i in 0..n {
                let outcome = self.outcomes[i];
                if outcome.is_done() {
                    let (norm, single_obs) = (&self.obs_norm, &mut self.single_obs);
                    let (value, ws) = (&self.net.value, &mut self.single_ws);
                    let final_obs = benv.final_observation(i);
                    self.rewards[t * n + i] =
                        learning_reward(self.rewards[t * n + i], outcome, mode, gamma, || {
                            norm.apply(final_obs, single_obs);
                            f64::from(value.forward(single_obs, ws)[0])
                        });
                }
            }
        }
        // The values of the whole rollout in one pass: the parameters do not
        // change during collection, and one 4096-column product runs faster
        // than 64 of 64 columns.
        let values = self
            .net
            .value
            .forward(&self.obs, &mut self.rollout_value_ws);
        for (dst, v) in self.values.iter_mut().zip(values) {
            *dst = f64::from(*v);
        }
        self.obs_norm.apply(benv.observations(), &mut self.last_obs);
        let v = self.net.value.forward(&self.last_obs, &mut self.value_ws);
        for (dst, v) in self.last_values.iter_mut().zip(v) {
            *dst = f64::from(*v);
        }
        Ok(episodes)
    }

    fn compute_gae(&mut self) {
        gae(
            &Rollout {
                n_envs: self.n_envs,
                rewards: &self.rewards,
                values: &self.values,
                dones: &self.dones,
                last_values: &self.last_values,
            },
            self.cfg.gamma,
            self.cfg.gae_lambda,
            &mut self.advantages,
            &mut self.returns,
        );
    }

    /// 1 - Var(returns - values) / Var(returns) over the rollout.
    fn explained_variance(&self) -> f64 {
        let var = |xs: &mut dyn Iterator<Item = f64>| {
            let (mut n, mut s, mut s2) = (0.0, 0.0, 0.0);
            for x in xs {
                n += 1.0;
                s += x;
                s2 += x * x;
            }
            let m = s / n;
            s2 / n - m * m
        };
        let vr = var(&mut self.returns.iter().copied());
        let vd = var(&mut self.returns.iter().zip(&self.values).map(|(r, v)| r - v));
        if vr > 0.0 {
            1.0 - vd / vr
        } else {
            0.0
        }
    }

    /// Minibatch epochs over the rollout; returns the mean loss statistics.
    fn optimize(&mut self, lr: f64) -> LossStats {
        let (od, ad) = (self.obs_dim, self.act_dim);
        let mbs = self.cfg.minibatch_size;
        let coefs = LossCoefs {
            clip_range: self.cfg.clip_range,
            clip_range_vf: self.cfg.clip_range_vf,
            vf_coef: self.cfg.vf_coef,
            ent_coef: self.cfg.ent_coef,
        };
        let mut sum = LossStats::default();
        let mut n_mb = 0.0;
        for _ in 0..self.cfg.epochs {
            self.perm.shuffle(&mut self.rng_shuffle);
            let mut epoch_kl = 0.0;
            let mut epoch_mb = 0.0;
            for chunk in self.perm.chunks_exact(mbs) {
                for (k, &s) in chunk.iter().enumerate() {
                    self.mb_obs[k * od..(k + 1) * od]
                        .copy_from_slice(&self.obs[s * od..(s + 1) * od]);
                    self.mb_actions[k * ad..(k + 1) * ad]
                        .copy_from_slice(&self.actions[s * ad..(s + 1) * ad]);
                    self.mb_logp[k] = self.logp[s];
                    self.mb_adv[k] = self.advantages[s];
                    self.mb_ret[k] = self.returns[s];
                    self.mb_values[k] = self.values[s];
                }
                if self.cfg.normalize_advantages {
                    normalize_in_place(&mut self.mb_adv);
                }
                let mb = Minibatch {
                    obs: &self.mb_obs,
                    actions: &self.mb_actions,
                    old_logp: &self.mb_logp,
                    advantages: &self.mb_adv,
                    returns: &self.mb_ret,
                    old_values: &self.mb_values,
                };
                let stats = ppo_loss(
                    &self.net,
                    &mb,
                    &coefs,
                    &mut self.loss_ws,
                    Some(&mut self.grads),
                );
                let scale = self.grads.clip_scale(self.cfg.max_grad_norm);
                self.adam_policy.step(
                    self.model.policy.params_mut(),
                    &self.grads.policy,
                    scale,
                    lr,
                );
                self.adam_log_std
                    .step(&mut self.model.log_std, &self.grads.log_std, scale, lr);
                self.adam_value
                    .step(self.model.value.params_mut(), &self.grads.value, scale, lr);
                self.net.copy_from(&self.model);
                sum.total += stats.total;
                sum.policy_loss += stats.policy_loss;
                sum.value_loss += stats.value_loss;
                sum.entropy += stats.entropy;
                sum.approx_kl += stats.approx_kl;
                sum.clip_fraction += stats.clip_fraction;
                n_mb += 1.0;
                epoch_kl += stats.approx_kl;
                epoch_mb += 1.0;
            }
            if let Some(target) = self.cfg.target_kl {
                if epoch_kl / epoch_mb > target {
                    break;
                }
            }
        }
        LossStats {
            total: sum.total / n_mb,
            policy_loss: sum.policy_loss / n_mb,
            value_loss: sum.value_loss / n_mb,
            entropy: sum.entropy / n_mb,
            approx_kl: sum.approx_kl / n_mb,
            clip_fraction: sum.clip_fraction / n_mb,
        }
    }
}

/// A rollout's rewards, values and episode ends, sample `s = t * n_envs + i`.
pub struct Rollout<'a> {
    /// Environments per time step.
    pub n_envs: usize,
    /// (Scaled) rewards; a truncation's bootstrap is already folded in.
    pub rewards: &'a [f64],
    /// Value estimates of the observations the actions were taken in.
    pub values: &'a [f64],
    /// Whether the transition ended its episode (any outcome).
    pub dones: &'a [bool],
    /// Value of each environment's observation after the last step.
    pub last_values: &'a [f64],
}

/// GAE(lambda) advantages and returns (`advantage + value`). An episode end
/// stops the recursion and the bootstrap from the next observation (which
/// belongs to the next episode).
pub fn gae(r: &Rollout<'_>, gamma: f64, lambda: f64, advantages: &mut [f64], returns: &mut [f64]) {
    let n = r.n_envs;
    let steps = r.rewards.len() / n;
    for i in 0..n {
        let mut acc = 0.0;
        for t in (0..steps).rev() {
            let s = t * n + i;
            let next_value = if t + 1 == steps {
                r.last_values[i]
            } else {
                r.values[s + n]
            };
            let not_done = if r.dones[s] { 0.0 } else { 1.0 };
            let delta = r.rewards[s] + gamma * next_value * not_done - r.values[s];
            acc = delta + gamma * lambda * not_done * acc;
            advantages[s] = acc;
            returns[s] = acc + r.values[s];
        }
    }
}

/// The reward a transition learns from: its (scaled) reward, plus, when the
/// time limit is a truncation, the discounted value of the final
/// observation. Success and fail are true terminals: never bootstrapped.
pub fn learning_reward(
    reward: f64,
    outcome: Outcome,
    mode: TimeLimit,
    gamma: f64,
    final_value: impl FnOnce() -> f64,
) -> f64 {
    if outcome == Outcome::Truncated && mode == TimeLimit::Truncate {
        reward + gamma * final_value()
    } else {
        reward
    }
}

/// Shifts and scales to mean 0, standard deviation 1 (population sd + 1e-8).
fn normalize_in_place(xs: &mut [f64]) {
    let n = xs.len() as f64;
    let mean = xs.iter().sum::<f64>() / n;
    let var = xs.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / n;
    let inv = 1.0 / (var.sqrt() + 1e-8);
    xs.iter_mut().for_each(|x| *x = (*x - mean) * inv);
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)] // index loops read clearer in checks
mod tests {
    use super::*;

    #[test]
    fn gae_matches_a_hand_worked_three_step_rollout() {
        // One env, steps 0..3, episode ends after step 1 (done), then a new
        // episode runs past the rollout (bootstrapped by last_values).
        let r = Rollout {
            n_envs: 1,
            rewards: &[1.0, 2.0, 3.0],
            values: &[0.5, 1.0, 1.5],
            dones: &[false, true, false],
            last_values: &[2.0],
        };
        let (g, l) = (0.9, 0.8);
        let mut adv = [0.0; 3];
        let mut ret = [0.0; 3];
        gae(&r, g, l, &mut adv, &mut ret);
        let d2 = 3.0 + g * 2.0 - 1.5; // 3.3
        let d1 = 2.0 - 1.0; // terminal: no bootstrap
        let d0 = 1.0 + g * 1.0 - 0.5; // 1.4
        let a2 = d2;
        let a1 = d1;
        let a0 = d0 + g * l * a1;
        for (got, want) in adv.iter().zip([a0, a1, a2]) {
            assert!((got - want).abs() < 1e-12, "{got} vs {want}");
        }
        assert!((ret[0] - (a0 + 0.5)).abs() < 1e-12);
    }

    #[test]
    fn gae_keeps_environments_apart() {
        // Two envs interleaved; env 1 mirrors env 0's single-env result.
        let r = Rollout {
            n_envs: 2,
            rewards: &[1.0, 1.0, 0.0, 0.0],
            values: &[0.0, 0.0, 0.0, 0.0],
            dones: &[false, false, true, true],
            last_values: &[5.0, 5.0],
        };
        let mut adv = [0.0; 4];
        let mut ret = [0.0; 4];
        gae(&r, 0.5, 1.0, &mut adv, &mut ret);
        assert_eq!(adv, [1.0, 1.0, 0.0, 0.0]);
    }

    #[test]
    fn truncation_bootstraps_but_termination_does_not() {
        let v = || 10.0;
        let g = 0.9;
        let tr = TimeLimit::Truncate;
        assert_eq!(learning_reward(1.0, Outcome::Truncated, tr, g, v), 10.0);
        assert_eq!(learning_reward(1.0, Outcome::Success, tr, g, v), 1.0);
        assert_eq!(learning_reward(1.0, Outcome::Fail, tr, g, v), 1.0);
        assert_eq!(learning_reward(1.0, Outcome::Running, tr, g, v), 1.0);
        let term = TimeLimit::Terminal;
        assert_eq!(learning_reward(1.0, Outcome::Truncated, term, g, v), 1.0);
    }

    #[test]
    fn advantage_normalization_gives_zero_mean_unit_sd() {
        let mut xs = [1.0, 2.0, 3.0, 10.0];
        normalize_in_place(&mut xs);
        let m = xs.iter().sum::<f64>() / 4.0;
        let sd = (xs.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / 4.0).sqrt();
        assert!(m.abs() < 1e-12 && (sd - 1.0).abs() < 1e-7);
    }
}
