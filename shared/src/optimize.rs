//! A solver-independent reference for the task: the best open-loop action
//! sequence from the noise-free squat, found by the cross-entropy method
//! (docs/science.md#optimal-reference).
//!
//! PPO learns a feedback policy from noisy starts and may stop short of the
//! best movement; grid search infers w1 as if it did not. This module answers
//! "what is the best movement this reward allows?" without a learner: the
//! model is deterministic without initial noise, so an open-loop sequence of
//! `max_steps` actions is a complete plan, and its return is the true
//! objective. The optimum found this way bounds what any policy can earn from
//! the squat (up to the optimizer's own gap, which restarts expose).

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use crate::env::{EnvConfig, EnvError, Episode, Outcome, Task};

/// Actions per control step: one normalized torque per joint.
const ACTION_DIM: usize = 3;

/// Cross-entropy method settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OptimizeConfig {
    /// Candidate sequences per iteration.
    pub population: usize,
    /// Best candidates the next distribution is fitted to.
    pub elites: usize,
    /// Iterations per restart.
    pub iterations: usize,
    /// Independent restarts from the same broad distribution; the best wins.
    pub restarts: usize,
    /// Initial per-coordinate standard deviation of the actions.
    pub init_std: f64,
    /// Initial standard deviation of restarts from a given sequence.
    pub warm_std: f64,
    /// Floor of the per-coordinate standard deviation, so the search never
    /// collapses before the last iteration.
    pub min_std: f64,
    /// Weight of the new elite statistics against the old ones (1 = none of
    /// the old).
    pub smoothing: f64,
    /// Seed of the candidate noise.
    pub seed: u64,
    /// Threads evaluating candidates (0 = all cores). The result does not
    /// depend on it.
    pub threads: usize,
    /// Start every other restart from the best sequence of the same task at
    /// w1 = 0 (continuation). From the origin, a large torque weight makes a
    /// cheap fall look better than the first clumsy stand-ups the search
    /// samples, and the method settles on falling; the w1 = 0 optimum is a
    /// stand-up to begin from.
    pub warm_start: bool,
}

impl Default for OptimizeConfig {
    fn default() -> Self {
        Self {
            population: 256,
            elites: 24,
            iterations: 250,
            restarts: 4,
            init_std: 0.6,
            warm_std: 0.15,
            min_std: 0.01,
            smoothing: 0.7,
            seed: 0,
            threads: 0,
            warm_start: true,
        }
    }
}

impl OptimizeConfig {
    /// Rejects settings the method cannot run with.
    pub fn validate(&self) -> Result<(), EnvError> {
        let bad = |m: String| Err(EnvError::InvalidConfig(m));
        if self.population < 2 || self.population > 100_000 {
            return bad(format!(
                "population must be in 2..=100000 (got {})",
                self.population
            ));
        }
        if self.elites == 0 || self.elites >= self.population {
            return bad(format!(
                "elites must be in 1..population (got {})",
                self.elites
            ));
        }
        if self.iterations == 0 || self.restarts == 0 {
            return bad("iterations and restarts must be at least 1".into());
        }
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !positive(self.init_std) || !positive(self.warm_std) || !positive(self.min_std) {
            return bad("init_std, warm_std and min_std must be positive".into());
        }
        if !(self.smoothing > 0.0 && self.smoothing <= 1.0) {
            return bad(format!(
                "smoothing must be in (0, 1] (got {})",
                self.smoothing
            ));
        }
        Ok(())
    }
}

/// Maximizes `objective` over R^dim by the cross-entropy method with a
/// diagonal Gaussian, restarted `cfg.restarts` times. Restart k starts from
/// `starts[k]` when given, else from the origin. Returns the best point seen
/// and its value, and the best value of each restart.
pub fn cross_entropy<F>(
    dim: usize,
    cfg: &OptimizeConfig,
    starts: &[Vec<f64>],
    objective: F,
) -> (Vec<f64>, f64, Vec<f64>)
where
    F: Fn(&[f64]) -> f64 + Sync,
{
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let threads = match cfg.threads {
        0 => std::thread::available_parallelism().map_or(1, |n| n.get()),
        n => n,
    };
    let mut best = (vec![0.0; dim], f64::NEG_INFINITY);
    let mut per_restart = Vec::with_capacity(cfg.restarts);
    let mut candidates = vec![0.0; cfg.population * dim];
    let mut scores = vec![0.0; cfg.population];
    for restart in 0..cfg.restarts {
        let mut mean = starts
            .get(restart)
            .cloned()
            .unwrap_or_else(|| vec![0.0; dim]);
        // A restart from a given sequence searches near it: the broad
        // initial spread would throw most candidates off the stand-up.
        let spread = if restart < starts.len() && starts[restart].iter().any(|&v| v != 0.0) {
            cfg.warm_std
        } else {
            cfg.init_std
        };
        let mut std = vec![spread; dim];
        let mut restart_best = (vec![0.0; dim], f64::NEG_INFINITY);
        for _ in 0..cfg.iterations {
            // The first candidate is the current mean, so an iteration never
            // loses the distribution's centre to sampling noise.
            for (k, c) in candidates.chunks_mut(dim).enumerate() {
                for j in 0..dim {
                    let z: f64 = if k == 0 {
                        0.0
                    } else {
                        StandardNormal.sample(&mut rng)
                    };
                    c[j] = mean[j] + std[j] * z;
                }
            }
            evaluate(&candidates, dim, threads, &objective, &mut scores);
            let mut order: Vec<usize> = (0..cfg.population).collect();
            // NaN scores sort last: a candidate the objective cannot score is
            // never an elite.
            order.sort_by(|&a, &b| {
                let (sa, sb) = (scores[a], scores[b]);
                sb.partial_cmp(&sa)
                    .unwrap_or_else(|| sa.is_nan().cmp(&sb.is_nan()))
            });
            let top = order[0];
            if scores[top] > restart_best.1 {
                restart_best = (candidates[top * dim..(top + 1) * dim].to_vec(), scores[top]);
            }
            let elites = &order[..cfg.elites];
            let n = elites.len() as f64;
            for j in 0..dim {
                let m = elites.iter().map(|&e| candidates[e * dim + j]).sum::<f64>() / n;
                let v = elites
                    .iter()
                    .map(|&e| (candidates[e * dim + j] - m).powi(2))
                    .sum::<f64>()
                    / n;
                mean[j] = (1.0 - cfg.smoothing) * mean[j] + cfg.smoothing * m;
                std[j] =
                    ((1.0 - cfg.smoothing) * std[j] + cfg.smoothing * v.sqrt()).max(cfg.min_std);
            }
        }
        per_restart.push(restart_best.1);
        if restart_best.1 > best.1 {
            best = restart_best;
        }
    }
    (best.0, best.1, per_restart)
}

fn evaluate<F>(candidates: &[f64], dim: usize, threads: usize, objective: &F, scores: &mut [f64])
where
    F: Fn(&[f64]) -> f64 + Sync,
{
    let per = scores.len().div_ceil(threads.max(1));
    std::thread::scope(|s| {
        for (chunk, out) in candidates.chunks(per * dim).zip(scores.chunks_mut(per)) {
            s.spawn(move || {
                for (c, o) in chunk.chunks(dim).zip(out.iter_mut()) {
                    *o = objective(c);
                }
            });
        }
    });
}

/// What an open-loop action sequence does from the noise-free squat.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Rollout {
    /// Undiscounted return.
    #[serde(rename = "return")]
    pub ret: f64,
    /// How the episode ended.
    pub outcome: String,
    /// Control steps taken.
    pub steps: u32,
    /// Duration (s).
    pub duration: f64,
    /// Torque usage: sum of ||tau||_2 * control period (N m s).
    pub torque_usage: f64,
    /// COM path at every RK4 sub-step (200 Hz), the initial state included.
    pub com_t: Vec<f64>,
    /// Forward COM coordinate (m).
    pub com_x: Vec<f64>,
    /// Vertical COM coordinate (m).
    pub com_z: Vec<f64>,
    /// The clamped actions actually applied, one row per control step.
    pub actions: Vec<[f64; ACTION_DIM]>,
}

/// Plays `actions` (rows of `ACTION_DIM`, at least `max_steps` rows' worth)
/// from the squat without initial noise. Returns the return, and with
/// `record` the whole path.
pub fn rollout(task: &Task, actions: &[f64], record: bool) -> Rollout {
    let cfg = task.config();
    let model = task.model();
    let mut state = [0.0; 6];
    state[..3].copy_from_slice(&cfg.sim.q0);
    state[3..].copy_from_slice(&cfg.sim.qd0);
    let mut ep = Episode::new(state);
    let sub_dt = cfg.sim.control_dt() / f64::from(cfg.sim.substeps);
    let mut out = Rollout {
        ret: 0.0,
        outcome: Outcome::Running.as_str().to_string(),
        steps: 0,
        duration: 0.0,
        torque_usage: 0.0,
        com_t: Vec::new(),
        com_x: Vec::new(),
        com_z: Vec::new(),
        actions: Vec::new(),
    };
    if record {
        let c = model.com(&ep.state);
        out.com_t.push(0.0);
        out.com_x.push(c.x);
        out.com_z.push(c.z);
    }
    for row in actions.chunks(ACTION_DIM).take(cfg.max_steps as usize) {
        let mut n = 0u32;
        let t0 = f64::from(ep.t) * cfg.sim.control_dt();
        let info = task.step(&mut ep, row, |s| {
            if record {
                n += 1;
                let c = model.com(s);
                out.com_t.push(t0 + f64::from(n) * sub_dt);
                out.com_x.push(c.x);
                out.com_z.push(c.z);
            }
        });
        if record {
            let (_, a) = model.torque(row);
            out.actions.push(a);
        }
        if info.outcome.is_done() {
            out.outcome = info.outcome.as_str().to_string();
            break;
        }
    }
    out.ret = ep.ret;
    out.steps = ep.t;
    out.duration = f64::from(ep.t) * cfg.sim.control_dt();
    out.torque_usage = ep.torque_usage;
    out
}

/// The optimizer's answer for one task.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Optimum {
    /// The task optimized (noise-free start regardless of `init_noise`).
    pub env: EnvConfig,
    /// Settings used.
    pub optimizer: OptimizeConfig,
    /// Best return of each restart: their spread is the optimizer's own
    /// uncertainty.
    pub restart_returns: Vec<f64>,
    /// The best sequence found, played back.
    pub best: Rollout,
}

/// Finds the best open-loop action sequence for `env` from the noise-free
/// squat: [`optimize_ladder`] over w1 = 0 and `env`'s own w1.
pub fn optimize(env: &EnvConfig, cfg: &OptimizeConfig) -> Result<Optimum, EnvError> {
    let mut all = optimize_ladder(env, &[env.reward.w1], cfg)?;
    Ok(all.remove(0))
}

/// Optimizes `env` at each of `w1s` (any order; answered in that order) by
/// continuation up the sorted values. With `warm_start`, every other restart
/// at a value starts from the best sequence of the next lower value (w1 = 0
/// below the first): from the origin a large torque weight makes a cheap fall
/// look better than the first clumsy stand-ups the search samples, and the
/// method settles on falling, while the neighbour's optimum is a stand-up to
/// begin from and usually close to the answer.
pub fn optimize_ladder(
    env: &EnvConfig,
    w1s: &[f64],
    cfg: &OptimizeConfig,
) -> Result<Vec<Optimum>, EnvError> {
    cfg.validate()?;
    let dim = env.max_steps as usize * ACTION_DIM;
    let at = |w1: f64| -> Result<Task, EnvError> {
        let mut e = env.clone();
        e.reward.set_param("w1", w1)?;
        Task::new(&e)
    };
    let mut order: Vec<usize> = (0..w1s.len()).collect();
    order.sort_by(|&a, &b| w1s[a].total_cmp(&w1s[b]));
    let mut previous: Option<Vec<f64>> = None;
    if cfg.warm_start && w1s.iter().any(|&w| w != 0.0) {
        let free = at(0.0)?;
        previous = Some(cross_entropy(dim, cfg, &[], |a| rollout(&free, a, false).ret).0);
    }
    let mut out: Vec<Option<Optimum>> = vec![None; w1s.len()];
    for i in order {
        let task = at(w1s[i])?;
        let starts: Vec<Vec<f64>> = match (&previous, cfg.warm_start) {
            (Some(x0), true) => (0..cfg.restarts)
                .map(|k| {
                    if k % 2 == 0 {
                        x0.clone()
                    } else {
                        vec![0.0; dim]
                    }
                })
                .collect(),
            _ => Vec::new(),
        };
        let (x, _, restart_returns) =
            cross_entropy(dim, cfg, &starts, |a| rollout(&task, a, false).ret);
        out[i] = Some(Optimum {
            env: task.config().clone(),
            optimizer: cfg.clone(),
            restart_returns,
            best: rollout(&task, &x, true),
        });
        previous = Some(x);
    }
    Ok(out.into_iter().flatten().collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quick() -> OptimizeConfig {
        OptimizeConfig {
            population: 64,
            elites: 8,
            iterations: 60,
            restarts: 2,
            threads: 1,
            ..OptimizeConfig::default()
        }
    }

    #[test]
    fn finds_the_maximum_of_a_concave_quadratic() {
        // Closed form: -sum (x_j - c_j)^2 peaks at c with value 0.
        let c = [0.3, -1.2, 2.0, 0.0, -0.7];
        let (x, f, _) = cross_entropy(5, &quick(), &[], |x| {
            -x.iter().zip(&c).map(|(a, b)| (a - b).powi(2)).sum::<f64>()
        });
        for (a, b) in x.iter().zip(&c) {
            assert!((a - b).abs() < 0.02, "{x:?}");
        }
        assert!(f > -1e-3, "{f}");
    }

    #[test]
    fn result_does_not_depend_on_the_thread_count() {
        let env = EnvConfig {
            max_steps: 4,
            ..EnvConfig::with_w1(1.0)
        };
        let one = optimize(&env, &quick()).unwrap();
        let two = optimize(
            &env,
            &OptimizeConfig {
                threads: 2,
                ..quick()
            },
        )
        .unwrap();
        assert_eq!(one.best, two.best);
        assert_eq!(one.restart_returns, two.restart_returns);
    }

    #[test]
    fn matches_brute_force_over_a_one_step_horizon() {
        // With one control step the return is a function of three numbers in
        // [-1, 1]; an exhaustive 41^3 grid bounds the optimum from below to
        // within the grid's resolution.
        let env = EnvConfig {
            max_steps: 1,
            ..EnvConfig::with_w1(2.0)
        };
        let task = Task::new(&env).unwrap();
        let mut brute = f64::NEG_INFINITY;
        let k = 41;
        let v = |i: usize| -1.0 + 2.0 * i as f64 / (k - 1) as f64;
        for i in 0..k {
            for j in 0..k {
                for l in 0..k {
                    brute = brute.max(rollout(&task, &[v(i), v(j), v(l)], false).ret);
                }
            }
        }
        let found = optimize(&env, &quick()).unwrap();
        assert!(
            found.best.ret >= brute - 1e-3,
            "CEM {} below brute force {brute}",
            found.best.ret
        );
        // And it is a real sequence: replaying its actions gives its return.
        let flat: Vec<f64> = found.best.actions.iter().flatten().copied().collect();
        assert_eq!(rollout(&task, &flat, false).ret, found.best.ret);
    }

    #[test]
    fn rollout_records_the_200_hz_path_and_usage() {
        let env = EnvConfig::with_w1(1.0);
        let task = Task::new(&env).unwrap();
        let zeros = vec![0.0; env.max_steps as usize * ACTION_DIM];
        let r = rollout(&task, &zeros, true);
        // Without torque the body collapses: a fall, with no torque used.
        assert_eq!(r.outcome, "fail");
        assert_eq!(r.torque_usage, 0.0);
        let n = r.steps as usize * env.sim.substeps as usize + 1;
        assert_eq!((r.com_t.len(), r.com_x.len(), r.com_z.len()), (n, n, n));
        assert!((r.com_t[1] - 0.005).abs() < 1e-12, "{}", r.com_t[1]);
    }
}
