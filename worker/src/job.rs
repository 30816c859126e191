//! The body of a job: build the grid point's task, then either train a
//! policy with PPO and sample its trajectories (docs/science.md#sampling),
//! or, for an optimizer variant (docs/inference.md#solver-spread), find the
//! best open-loop movement (docs/science.md#optimal-reference); package the
//! output either way. Runs on a blocking thread; progress goes out through
//! [`JobHooks`], and a raised cancel flag stops training at the next update.

use std::ops::ControlFlow;
use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use anyhow::Context;
use shared::analysis::EpisodeRecord;
use shared::api::{splitmix64, JobOutput, JobPhase, JobSpec, ProgressPoint, SolverSpec};
use shared::env::EnvConfig;
use shared::optimize::{optimize, OptimizeConfig};
use shared::ppo::{train, PpoError, TrainProgress};
use shared::sample::sample;

/// Most progress points buffered between heartbeats (older ones are
/// dropped first if the coordinator stays unreachable).
pub const MAX_BUFFERED_PROGRESS: usize = 1000;

/// Channels between a running job body and its heartbeat task.
#[derive(Debug, Clone, Default)]
pub struct JobHooks {
    /// Raised to stop the job (lease lost, search cancelled, shutdown).
    pub cancel: Arc<AtomicBool>,
    /// Progress points not yet reported.
    pub progress: Arc<Mutex<Vec<ProgressPoint>>>,
    /// 0 = training, 1 = sampling.
    phase: Arc<AtomicU8>,
}

impl JobHooks {
    /// Queues a progress point for the next heartbeat.
    pub fn report(&self, p: ProgressPoint) {
        let mut buf = self.progress.lock().unwrap_or_else(|e| e.into_inner());
        if buf.len() >= MAX_BUFFERED_PROGRESS {
            buf.remove(0);
        }
        buf.push(p);
    }

    /// Takes the queued progress points.
    pub fn take_progress(&self) -> Vec<ProgressPoint> {
        std::mem::take(&mut *self.progress.lock().unwrap_or_else(|e| e.into_inner()))
    }

    /// Puts unsent points back in front (a heartbeat failed).
    pub fn restore_progress(&self, mut pts: Vec<ProgressPoint>) {
        let mut buf = self.progress.lock().unwrap_or_else(|e| e.into_inner());
        pts.append(&mut buf);
        let excess = pts.len().saturating_sub(MAX_BUFFERED_PROGRESS);
        pts.drain(..excess);
        *buf = pts;
    }

    /// Sets the phase.
    pub fn set_phase(&self, phase: JobPhase) {
        self.phase
            .store(u8::from(phase == JobPhase::Sampling), Ordering::Relaxed);
    }

    /// The phase.
    pub fn phase(&self) -> JobPhase {
        if self.phase.load(Ordering::Relaxed) == 1 {
            JobPhase::Sampling
        } else {
            JobPhase::Training
        }
    }

    /// Whether the job should stop.
    pub fn cancelled(&self) -> bool {
        self.cancel.load(Ordering::Relaxed)
    }
}

/// Why a job body ended without an output.
#[derive(Debug, thiserror::Error)]
pub enum JobError {
    /// Stopped through [`JobHooks::cancel`].
    #[error("job cancelled")]
    Cancelled,
    /// Anything else; reported to the coordinator as the job's error.
    #[error(transparent)]
    Failed(#[from] anyhow::Error),
}

/// A job body: the real one is [`run_job`]; tests and benchmarks plug in
/// others.
pub type JobBody = Arc<dyn Fn(&JobSpec, &JobHooks) -> Result<JobOutput, JobError> + Send + Sync>;

/// Seed of the sampling rollouts of a job: a splitmix64 step away from the
/// training seed, so the two random streams are unrelated.
pub fn sampling_seed(job_seed: u64) -> u64 {
    splitmix64(job_seed ^ 0x5341_4D50_4C45_0001)
}

fn finite(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

/// A trainer progress row as a wire progress point.
pub fn progress_point(p: &TrainProgress) -> ProgressPoint {
    ProgressPoint {
        env_steps: p.env_steps,
        total_env_steps: p.total_env_steps,
        mean_return: finite(p.mean_return),
        success_rate: finite(p.success_rate).map(|s| s.clamp(0.0, 1.0)),
        mean_episode_length: finite(p.mean_episode_length),
        policy_loss: finite(p.policy_loss),
        value_loss: finite(p.value_loss),
        entropy: finite(p.entropy),
        approx_kl: finite(p.approx_kl),
    }
}

/// The task of a job: the search's environment with the grid point's reward
/// parameters applied.
pub fn job_env(spec: &JobSpec) -> anyhow::Result<EnvConfig> {
    let mut env: EnvConfig = spec.env.clone();
    for (name, &value) in &spec.params {
        env.reward
            .set_param(name, value)
            .with_context(|| format!("reward parameter {name} = {value}"))?;
    }
    Ok(env)
}

/// Trains, samples and packages one job (docs/science.md#sampling). The final success rate
/// is the sampling rollouts' (successes / episodes rolled out): a fresh
/// stochastic evaluation of the trained policy over many episodes.
pub fn run_job(spec: &JobSpec, hooks: &JobHooks) -> Result<JobOutput, JobError> {
    if let Some(SolverSpec::Optimizer { optimizer, .. }) = &spec.solver {
        return run_optimizer_job(spec, optimizer, hooks);
    }
    let training = &spec.training;
    let sampling = &spec.sampling;
    let env = job_env(spec)?;
    hooks.set_phase(JobPhase::Training);
    let t0 = Instant::now();
    let mut on_update = |p: &TrainProgress| {
        hooks.report(progress_point(p));
        if hooks.cancelled() {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    };
    let trained = match train(training, &env, spec.seed, &mut on_update) {
        Ok(t) => t,
        Err(PpoError::Cancelled) => return Err(JobError::Cancelled),
        Err(e) => return Err(anyhow::Error::new(e).context("training").into()),
    };
    let train_secs = t0.elapsed().as_secs_f64();
    if hooks.cancelled() {
        return Err(JobError::Cancelled);
    }
    hooks.set_phase(JobPhase::Sampling);
    let t1 = Instant::now();
    let s = sample(&trained.policy, sampling, sampling_seed(spec.seed)).context("sampling")?;
    Ok(JobOutput {
        final_success_rate: s.success_rate(),
        env_steps: trained.env_steps,
        successes_found: s.successes_found,
        successes_wanted: s.successes_wanted,
        sampling_attempts: s.attempts,
        episodes: s.episodes,
        train_secs,
        sample_secs: t1.elapsed().as_secs_f64(),
    })
}

/// An optimizer variant's job: the cross-entropy optimum of the grid
/// point's task from the noise-free squat, with the job's seed. Its output
/// has the PPO job's shape: the one movement it rolls out is "sampled", and
/// kept when it stands up, so the success rate is 1 or 0.
pub fn run_optimizer_job(
    spec: &JobSpec,
    optimizer: &OptimizeConfig,
    hooks: &JobHooks,
) -> Result<JobOutput, JobError> {
    let env = job_env(spec)?;
    hooks.set_phase(JobPhase::Training);
    let cfg = OptimizeConfig {
        seed: spec.seed,
        ..optimizer.clone()
    };
    let t0 = Instant::now();
    let found = optimize(&env, &cfg).context("optimizing")?;
    if hooks.cancelled() {
        return Err(JobError::Cancelled);
    }
    let best = found.best;
    let stood = best.outcome == "success";
    let rollouts = cfg.evaluations(&[env.reward.w1]);
    Ok(JobOutput {
        final_success_rate: if stood { 1.0 } else { 0.0 },
        // Control steps simulated, the optimizer's counterpart of PPO's
        // environment steps (an upper bound: rollouts end early on a fall).
        env_steps: rollouts.saturating_mul(u64::from(env.max_steps)),
        successes_found: u32::from(stood),
        successes_wanted: 1,
        sampling_attempts: 1,
        episodes: if stood {
            vec![EpisodeRecord {
                com_t: best.com_t,
                com_x: best.com_x,
                com_z: best.com_z,
                ret: best.ret,
                torque_usage: best.torque_usage,
                steps: best.steps,
            }]
        } else {
            Vec::new()
        },
        train_secs: t0.elapsed().as_secs_f64(),
        sample_secs: 0.0,
    })
}

/// A job of grid point w1 = 1, trial 0, seed 7, with the default
/// configurations: the unit tests' job.
#[cfg(test)]
pub(crate) fn test_spec() -> JobSpec {
    JobSpec {
        search_id: "s".into(),
        search_name: "n".into(),
        point_idx: 0,
        params: [("w1".to_string(), 1.0)].into(),
        trial: 0,
        seed: 7,
        attempt: 1,
        training: Default::default(),
        sampling: Default::default(),
        env: Default::default(),
        convergence_threshold: 0.5,
        solver: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(optimizer: OptimizeConfig) -> JobSpec {
        JobSpec {
            solver: Some(SolverSpec::Optimizer {
                name: "cem".into(),
                optimizer,
            }),
            ..test_spec()
        }
    }

    #[test]
    fn an_optimizer_job_uploads_its_one_movement_in_the_ppo_output_shape() {
        let cfg = OptimizeConfig {
            population: 32,
            elites: 4,
            iterations: 20,
            restarts: 1,
            threads: 1,
            warm_start: false,
            stretch: vec![1.25],
            stretch_rounds: 1,
            ..OptimizeConfig::default()
        };
        let out = run_job(&spec(cfg.clone()), &JobHooks::default()).unwrap();
        assert_eq!((out.successes_wanted, out.sampling_attempts), (1, 1));
        assert!(out.episodes.len() <= 1);
        assert_eq!(out.successes_found as usize, out.episodes.len());
        assert_eq!(out.final_success_rate, f64::from(out.successes_found));
        // Budget in control steps: every candidate of every iteration of
        // the restart and the stretched search.
        let max_steps = u64::from(EnvConfig::default().max_steps);
        assert_eq!(out.env_steps, 32 * 20 * 2 * max_steps);
        // The job's seed is the optimizer's: the same job gives the same
        // movement, as the optimizer alone does with that seed.
        let again = run_job(&spec(cfg.clone()), &JobHooks::default()).unwrap();
        assert_eq!(again.episodes, out.episodes);
        let env = job_env(&spec(cfg.clone())).unwrap();
        let direct = optimize(&env, &OptimizeConfig { seed: 7, ..cfg }).unwrap();
        assert_eq!(
            u32::from(direct.best.outcome == "success"),
            out.successes_found
        );
        if let Some(e) = out.episodes.first() {
            assert_eq!(e.ret, direct.best.ret);
            assert_eq!(e.com_x, direct.best.com_x);
        }
    }

    // A lease is read strictly by the typed client (irlgrid_client), so
    // that a worker never runs a job without a setting it does not know.

    /// A lease as the coordinator of this version sends it.
    fn lease_json() -> serde_json::Value {
        let spec = test_spec();
        serde_json::to_value(shared::api::Lease {
            job_id: 3,
            lease_token: "t".into(),
            lease_secs: 60,
            heartbeat_secs: 20,
            spec,
        })
        .unwrap()
    }

    #[test]
    fn a_spec_from_another_version_is_refused_naming_the_unknown_field() {
        let ok = lease_json();
        let lease = irlgrid_client::parse_lease(&ok.to_string()).unwrap();
        assert_eq!(lease.spec.seed, 7);
        // A newer coordinator's setting this worker does not know, in a
        // configuration and in the spec itself: refused, not dropped.
        let mut v = ok.clone();
        v["spec"]["training"]["new_knob"] = serde_json::json!(1);
        let e = irlgrid_client::parse_lease(&v.to_string()).unwrap_err();
        assert!(e.starts_with("spec.training"), "{e}");
        assert!(e.contains("new_knob"), "{e}");
        let mut v = ok.clone();
        v["spec"]["curriculum"] = serde_json::json!("x");
        let e = irlgrid_client::parse_lease(&v.to_string()).unwrap_err();
        assert!(e.contains("curriculum"), "{e}");
        // An older coordinator missing a field is refused too.
        let mut v = ok.clone();
        v["spec"].as_object_mut().unwrap().remove("sampling");
        let e = irlgrid_client::parse_lease(&v.to_string()).unwrap_err();
        assert!(e.contains("sampling"), "{e}");
    }
}
