//! Task configuration (docs/science.md#task, docs/science.md#reward): reward
//! terms, episode length, initial-state noise and the observation switch.

use serde::{Deserialize, Serialize};

use super::EnvError;
use crate::sim::SimConfig;

/// Which fail penalty to use (docs/science.md#fail-term).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(rename_all = "snake_case")]
pub enum FailPenalty {
    /// -100 - 400 * (1 - h_t): a collapse at the bottom costs most (default).
    #[default]
    HeightDeficit,
    /// -100 - 400 * h_t, as printed in the paper.
    PaperLiteral,
}

/// What the effort term measures (docs/science.md#reward-forms).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(rename_all = "snake_case")]
pub enum EffortTerm {
    /// ||a||_2 of the normalized action, as in the paper (default): holding a
    /// posture costs as much as moving through it.
    #[default]
    Torque,
    /// Mechanical power of the normalized action, sum_i |a_i * dq_i| (rad/s),
    /// averaged over the control step's sub-steps: holding still is free and
    /// fast movements cost, so effort and time trade off.
    Power,
}

/// Reward (docs/science.md#reward). Every coefficient is a named parameter so that a reward
/// grid can search over any of them ([`RewardConfig::set_param`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(default, deny_unknown_fields)]
pub struct RewardConfig {
    /// Torque-cost weight w1: the running reward is
    /// `(h_t - height_offset) - w1 * ||a||_2^effort_exponent`.
    pub w1: f64,
    /// Exponent p of the effort term `||a||_2^p`: 1 as in the paper, 2 for a
    /// quadratic cost that makes slow movements cheaper than impulsive ones
    /// (docs/science.md#reward-forms).
    pub effort_exponent: f64,
    /// Subtracted from the normalized height in the running reward: 0 as in the
    /// paper, 1 so that every step before standing costs (docs/science.md#reward-forms).
    pub height_offset: f64,
    /// What the effort term measures: the action's norm (paper) or its power.
    pub effort_term: EffortTerm,
    /// Success reward: `success_bonus - success_step_cost * t`.
    pub success_bonus: f64,
    /// Per-step decrement of the success reward.
    pub success_step_cost: f64,
    /// Constant part of the fail reward: `-fail_base - fail_height_weight * (..)`.
    pub fail_base: f64,
    /// Height weight of the fail reward.
    pub fail_height_weight: f64,
    /// Which height term the fail reward uses.
    pub fail_penalty: FailPenalty,
    /// Running reward once tall (h_t >= success_height) but still moving.
    pub tall_reward: f64,
    /// Normalized height at and above which the body counts as standing.
    pub success_height: f64,
    /// COM speed (m/s) below which a standing body has succeeded.
    pub success_speed: f64,
    /// Normalized height below which the episode fails.
    pub fail_height: f64,
}

impl Default for RewardConfig {
    fn default() -> Self {
        Self {
            w1: 1.0,
            effort_exponent: 1.0,
            height_offset: 0.0,
            effort_term: EffortTerm::Torque,
            success_bonus: 1000.0,
            success_step_cost: 10.0,
            fail_base: 100.0,
            fail_height_weight: 400.0,
            fail_penalty: FailPenalty::HeightDeficit,
            tall_reward: 1.0,
            success_height: 0.99,
            success_speed: 0.1,
            fail_height: 0.5,
        }
    }
}

impl RewardConfig {
    /// The effort term `m^effort_exponent` of an effort measure `m` (the
    /// action's norm or its power, per `effort_term`). The paper's exponent 1 (and 2) take exact paths so that
    /// the paper's reward stays bit-identical to its form without the parameter.
    pub fn effort(&self, action_norm: f64) -> f64 {
        if self.effort_exponent == 1.0 {
            action_norm
        } else if self.effort_exponent == 2.0 {
            action_norm * action_norm
        } else {
            action_norm.powf(self.effort_exponent)
        }
    }

    /// The names a reward grid may vary.
    pub const PARAMS: [&'static str; 11] = [
        "w1",
        "effort_exponent",
        "height_offset",
        "success_bonus",
        "success_step_cost",
        "fail_base",
        "fail_height_weight",
        "tall_reward",
        "success_height",
        "success_speed",
        "fail_height",
    ];

    /// Sets a numeric reward parameter by name (for a grid point).
    pub fn set_param(&mut self, name: &str, value: f64) -> Result<(), EnvError> {
        let slot = match name {
            "w1" => &mut self.w1,
            "effort_exponent" => &mut self.effort_exponent,
            "height_offset" => &mut self.height_offset,
            "success_bonus" => &mut self.success_bonus,
            "success_step_cost" => &mut self.success_step_cost,
            "fail_base" => &mut self.fail_base,
            "fail_height_weight" => &mut self.fail_height_weight,
            "tall_reward" => &mut self.tall_reward,
            "success_height" => &mut self.success_height,
            "success_speed" => &mut self.success_speed,
            "fail_height" => &mut self.fail_height,
            _ => {
                return Err(EnvError::InvalidConfig(format!(
                    "unknown reward parameter {name:?} (known: {})",
                    Self::PARAMS.join(", ")
                )))
            }
        };
        *slot = value;
        self.validate()
    }

    /// Rejects non-finite coefficients and a negative torque weight.
    pub fn validate(&self) -> Result<(), EnvError> {
        let values = [
            ("w1", self.w1),
            ("effort_exponent", self.effort_exponent),
            ("height_offset", self.height_offset),
            ("success_bonus", self.success_bonus),
            ("success_step_cost", self.success_step_cost),
            ("fail_base", self.fail_base),
            ("fail_height_weight", self.fail_height_weight),
            ("tall_reward", self.tall_reward),
            ("success_height", self.success_height),
            ("success_speed", self.success_speed),
            ("fail_height", self.fail_height),
        ];
        if let Some((name, v)) = values.iter().find(|(_, v)| !v.is_finite()) {
            return Err(EnvError::InvalidConfig(format!(
                "reward parameter {name} must be finite (got {v})"
            )));
        }
        if self.w1 < 0.0 {
            return Err(EnvError::InvalidConfig(format!(
                "w1 must be >= 0 (got {})",
                self.w1
            )));
        }
        if !(0.5..=4.0).contains(&self.effort_exponent) {
            return Err(EnvError::InvalidConfig(format!(
                "effort_exponent must be in [0.5, 4] (got {})",
                self.effort_exponent
            )));
        }
        if self.success_speed <= 0.0 || self.fail_height >= self.success_height {
            return Err(EnvError::InvalidConfig(
                "need success_speed > 0 and fail_height < success_height".into(),
            ));
        }
        Ok(())
    }
}

/// The whole task: body model, reward, episode length, initial noise and
/// observation features. `Default` equals docs/science.md#body-model and
/// docs/science.md#reward-parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(default, deny_unknown_fields)]
pub struct EnvConfig {
    /// Body model and integration.
    pub sim: SimConfig,
    /// Reward terms, including w1.
    pub reward: RewardConfig,
    /// Half-width (rad) of the uniform noise added to each initial joint angle.
    pub init_noise: f64,
    /// Episode time limit in control steps (60 = 3 s).
    pub max_steps: u32,
    /// Append the elapsed-time fraction t / max_steps to the observation.
    pub observe_time: bool,
}

impl Default for EnvConfig {
    fn default() -> Self {
        Self {
            sim: SimConfig::default(),
            reward: RewardConfig::default(),
            init_noise: 0.02,
            max_steps: 60,
            observe_time: false,
        }
    }
}

impl EnvConfig {
    /// The default task with torque weight `w1`.
    pub fn with_w1(w1: f64) -> Self {
        let mut cfg = Self::default();
        cfg.reward.w1 = w1;
        cfg
    }

    /// Observation length: 6, or 7 with the time feature.
    pub fn obs_dim(&self) -> usize {
        if self.observe_time {
            7
        } else {
            6
        }
    }

    /// Checks every part of the configuration.
    pub fn validate(&self) -> Result<(), EnvError> {
        self.sim.validate()?;
        self.reward.validate()?;
        if !(self.init_noise.is_finite() && self.init_noise >= 0.0 && self.init_noise < 0.5) {
            return Err(EnvError::InvalidConfig(format!(
                "init_noise must be in [0, 0.5) rad (got {})",
                self.init_noise
            )));
        }
        if self.max_steps == 0 || self.max_steps > 100_000 {
            return Err(EnvError::InvalidConfig(format!(
                "max_steps must be in 1..=100000 (got {})",
                self.max_steps
            )));
        }
        Ok(())
    }
}
