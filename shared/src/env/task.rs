//! One environment's episode logic (docs/science.md#task): observation,
//! clipped actions, the fail / success / continue checks in the documented
//! order, and the reward (docs/science.md#reward).

use rand::Rng;

use super::{EffortTerm, EnvConfig, EnvError, FailPenalty};
use crate::sim::{Model, State};

/// How a control step ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// The episode goes on.
    Running,
    /// Standing still: h_t >= 0.99 and |v_com| < 0.1 m/s (true terminal).
    Success,
    /// A joint limit was exceeded or h_t < 0.5 (true terminal).
    Fail,
    /// The time limit was reached without a terminal state.
    Truncated,
}

impl Outcome {
    /// Whether the episode is over.
    pub fn is_done(self) -> bool {
        self != Outcome::Running
    }

    /// Lower-case name, as printed by the CLI.
    pub fn as_str(self) -> &'static str {
        match self {
            Outcome::Running => "running",
            Outcome::Success => "success",
            Outcome::Fail => "fail",
            Outcome::Truncated => "truncated",
        }
    }
}

/// What one control step produced. The `episode_*` fields describe the whole
/// episode and are meaningful when `outcome` is not `Running`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepInfo {
    /// Reward of this step.
    pub reward: f64,
    /// How the step ended.
    pub outcome: Outcome,
    /// Undiscounted return of the episode so far (including this step).
    pub episode_return: f64,
    /// Control steps taken in the episode so far.
    pub episode_len: u32,
    /// Torque usage so far: sum of ||tau||_2 * control period (N m s, docs/science.md#sampling).
    pub episode_torque_usage: f64,
}

/// The running state of one episode.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Episode {
    /// Joint state.
    pub state: State,
    /// Control steps taken.
    pub t: u32,
    /// Return so far.
    pub ret: f64,
    /// Torque usage so far (N m s).
    pub torque_usage: f64,
}

impl Episode {
    /// A fresh episode starting in `state`.
    pub fn new(state: State) -> Self {
        Self {
            state,
            t: 0,
            ret: 0.0,
            torque_usage: 0.0,
        }
    }
}

/// The task: a body model plus the rules of docs/science.md#task. Immutable and shared by
/// every environment of a batch.
#[derive(Clone, Debug)]
pub struct Task {
    model: Model,
    cfg: EnvConfig,
}

impl Task {
    /// Builds the task after validating the configuration.
    pub fn new(cfg: &EnvConfig) -> Result<Self, EnvError> {
        cfg.validate()?;
        Ok(Self {
            model: Model::new(&cfg.sim)?,
            cfg: cfg.clone(),
        })
    }

    /// The body model.
    pub fn model(&self) -> &Model {
        &self.model
    }

    /// The configuration.
    pub fn config(&self) -> &EnvConfig {
        &self.cfg
    }

    /// The squat plus uniform noise of +-`init_noise` on each joint angle.
    pub fn initial_state<R: Rng>(&self, rng: &mut R) -> State {
        let sim = &self.cfg.sim;
        let mut s = [0.0; 6];
        for i in 0..3 {
            let noise = if self.cfg.init_noise > 0.0 {
                rng.gen_range(-self.cfg.init_noise..=self.cfg.init_noise)
            } else {
                0.0
            };
            s[i] = sim.q0[i] + noise;
            s[3 + i] = sim.qd0[i];
        }
        s
    }

    /// Writes the observation of `ep` into `out` (length `obs_dim`).
    pub fn observe(&self, ep: &Episode, out: &mut [f64]) {
        out[..6].copy_from_slice(&ep.state);
        if self.cfg.observe_time {
            out[6] = f64::from(ep.t) / f64::from(self.cfg.max_steps);
        }
    }

    /// Advances `ep` by one control step with normalized `action`, calling
    /// `on_substep` after every RK4 sub-step, and scores the result.
    pub fn step(
        &self,
        ep: &mut Episode,
        action: &[f64],
        on_substep: impl FnMut(&State),
    ) -> StepInfo {
        let (tau, a) = self.model.torque(action);
        let mut on_substep = on_substep;
        let mut power = 0.0;
        self.model.control_step(&mut ep.state, &tau, |s| {
            power += ((a[0] * s[3]).abs() + (a[1] * s[4]).abs()) + (a[2] * s[5]).abs();
            on_substep(s);
        });
        let effort = self.effort(a, power);
        self.finish_step(ep, tau, effort)
    }

    /// The effort measure of a control step from its clipped action `a` and
    /// the sum over its sub-steps of sum_i |a_i q'_i| (`power_sum`, used by
    /// [`EffortTerm::Power`] only).
    pub fn effort(&self, a: [f64; 3], power_sum: f64) -> f64 {
        match self.cfg.reward.effort_term {
            EffortTerm::Torque => norm(a),
            EffortTerm::Power => power_sum / f64::from(self.cfg.sim.substeps),
        }
    }

    /// Books a control step whose dynamics already moved `ep.state` (with
    /// torque `tau` and effort measure `effort`): counts it, adds its torque
    /// usage, and scores it. [`Task::step`] is this after the scalar
    /// dynamics; the batch calls it after stepping a block.
    pub fn finish_step(&self, ep: &mut Episode, tau: [f64; 3], effort: f64) -> StepInfo {
        ep.t += 1;
        ep.torque_usage += norm(tau) * self.cfg.sim.control_dt();
        let (reward, outcome) = self.score(&ep.state, ep.t, effort);
        ep.ret += reward;
        StepInfo {
            reward,
            outcome,
            episode_return: ep.ret,
            episode_len: ep.t,
            episode_torque_usage: ep.torque_usage,
        }
    }

    /// Reward and outcome of arriving in `state` after `t` control steps with
    /// effort measure `effort` (the action's norm, or its power; see
    /// [`EffortTerm`]) (docs/science.md#termination, checks in that order).
    pub fn score(&self, state: &State, t: u32, effort: f64) -> (f64, Outcome) {
        let r = &self.cfg.reward;
        let sim = &self.cfg.sim;
        let com = self.model.com(state);
        let h = com.z / self.model.h_stand();
        // A non-finite state (only reachable with extreme custom parameters)
        // counts as a fall rather than leaking NaN into learning.
        let finite = state.iter().all(|v| v.is_finite());
        let out_of_limits = (0..3).any(|i| state[i] < sim.q_min[i] || state[i] > sim.q_max[i]);
        if !finite || out_of_limits || h < r.fail_height {
            let h = if finite { h } else { 0.0 };
            let height_term = match r.fail_penalty {
                FailPenalty::HeightDeficit => 1.0 - h,
                FailPenalty::PaperLiteral => h,
            };
            return (
                -r.fail_base - r.fail_height_weight * height_term,
                Outcome::Fail,
            );
        }
        if h >= r.success_height && com.speed() < r.success_speed {
            return (
                r.success_bonus - r.success_step_cost * f64::from(t),
                Outcome::Success,
            );
        }
        let reward = if h >= r.success_height {
            r.tall_reward
        } else {
            (h - r.height_offset) - r.w1 * r.effort(effort)
        };
        let outcome = if t >= self.cfg.max_steps {
            Outcome::Truncated
        } else {
            Outcome::Running
        };
        (reward, outcome)
    }
}

/// Euclidean norm of a 3-vector.
fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}
