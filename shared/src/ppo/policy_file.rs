//! The trained-policy file (`policy.json`): network weights, observation
//! statistics, and the exact configurations that produced it.

use serde::{Deserialize, Serialize};

use super::config::PpoConfig;
use super::mlp::Mlp;
use super::model::{ActorCritic, ObsNormalizer};
use super::normalize::RunningMeanStd;
use super::PpoError;
use crate::env::{BatchEnv, EnvConfig};

/// Value of the `format` field.
pub const POLICY_FORMAT: &str = "irlgrid-ppo-policy";
/// Current file version; files of another version are rejected.
pub const POLICY_VERSION: u32 = 1;

/// One network: layer sizes (input first) and the flat parameters, per
/// layer the weight matrix `out x in` in column-major order, then the bias.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NetworkWeights {
    /// Layer sizes, input first.
    pub sizes: Vec<usize>,
    /// Flat parameters (see the type doc for the layout).
    pub params: Vec<f64>,
}

/// A trained Gaussian policy, self-contained: everything needed to act,
/// evaluate, sample, or reproduce it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainedPolicy {
    /// Always [`POLICY_FORMAT`].
    pub format: String,
    /// Always [`POLICY_VERSION`] when written by this build.
    pub version: u32,
    /// Observation length (6, or 7 with the elapsed-time feature).
    pub obs_dim: usize,
    /// Action length (3).
    pub act_dim: usize,
    /// Policy mean network (tanh hidden layers, linear output).
    pub policy: NetworkWeights,
    /// State-independent log standard deviation of the actions.
    pub log_std: Vec<f64>,
    /// Value network (kept for inspection and warm starts).
    pub value: NetworkWeights,
    /// Observation normalization statistics, frozen at the end of training.
    pub obs_norm: RunningMeanStd,
    /// PPO configuration used (its `normalize_obs` and `obs_clip` apply).
    pub ppo: PpoConfig,
    /// Environment the policy was trained in (incl. w1 and the
    /// observation switch actually used).
    pub env: EnvConfig,
    /// Training seed.
    pub seed: u64,
    /// Environment steps trained.
    pub env_steps: u64,
}

impl TrainedPolicy {
    /// Packs a trained model.
    pub fn new(
        model: ActorCritic,
        obs_norm: RunningMeanStd,
        ppo: PpoConfig,
        env: EnvConfig,
        seed: u64,
        env_steps: u64,
    ) -> Self {
        Self {
            format: POLICY_FORMAT.to_string(),
            version: POLICY_VERSION,
            obs_dim: model.obs_dim(),
            act_dim: model.act_dim(),
            policy: NetworkWeights {
                sizes: model.policy.sizes().to_vec(),
                params: model.policy.params().to_vec(),
            },
            log_std: model.log_std,
            value: NetworkWeights {
                sizes: model.value.sizes().to_vec(),
                params: model.value.params().to_vec(),
            },
            obs_norm,
            ppo,
            env,
            seed,
            env_steps,
        }
    }

    /// Torque weight the policy was trained for.
    pub fn w1(&self) -> f64 {
        self.env.reward.w1
    }

    /// Compact JSON (deterministic: same policy, same bytes).
    pub fn to_json(&self) -> String {
        // Serializing plain data (no maps with non-string keys, no
        // non-finite floats: `validate` rejects them) cannot fail.
        serde_json::to_string(self).unwrap_or_default()
    }

    /// Parses and validates a policy file.
    pub fn from_json(s: &str) -> Result<Self, PpoError> {
        // Check the header first so an incompatible file gets that message
        // rather than a field-level parse error.
        let header: serde_json::Value =
            serde_json::from_str(s).map_err(|e| PpoError::MalformedPolicy(e.to_string()))?;
        match header.get("format").and_then(|f| f.as_str()) {
            Some(POLICY_FORMAT) => {}
            Some(other) => {
                return Err(PpoError::IncompatiblePolicy(format!(
                    "format is {other:?}, expected {POLICY_FORMAT:?}"
                )))
            }
            None => {
                return Err(PpoError::MalformedPolicy(format!(
                    "missing \"format\": {POLICY_FORMAT:?} (not a policy file?)"
                )))
            }
        }
        match header.get("version").and_then(|v| v.as_u64()) {
            Some(v) if v == u64::from(POLICY_VERSION) => {}
            Some(v) => {
                return Err(PpoError::IncompatiblePolicy(format!(
                    "version {v}, this build reads version {POLICY_VERSION}"
                )))
            }
            None => {
                return Err(PpoError::MalformedPolicy(
                    "missing or non-integer \"version\"".into(),
                ))
            }
        }
        let p: Self =
            serde_json::from_value(header).map_err(|e| PpoError::MalformedPolicy(e.to_string()))?;
        p.validate()?;
        Ok(p)
    }

    /// Checks that the parts fit together and every number is finite.
    pub fn validate(&self) -> Result<(), PpoError> {
        let bad = |msg: String| Err(PpoError::IncompatiblePolicy(msg));
        self.ppo.validate()?;
        self.env.validate()?;
        if self.act_dim != BatchEnv::ACT_DIM {
            return bad(format!(
                "act_dim is {}, the task has {}",
                self.act_dim,
                BatchEnv::ACT_DIM
            ));
        }
        if self.obs_dim != self.env.obs_dim() {
            return bad(format!(
                "obs_dim is {} but its environment observes {} values",
                self.obs_dim,
                self.env.obs_dim()
            ));
        }
        for (name, net, out) in [
            ("policy", &self.policy, self.act_dim),
            ("value", &self.value, 1),
        ] {
            if net.sizes.len() < 2
                || net.sizes[0] != self.obs_dim
                || net.sizes[net.sizes.len() - 1] != out
            {
                return bad(format!(
                    "{name} network sizes {:?} do not map {} observations to {out} outputs",
                    net.sizes, self.obs_dim
                ));
            }
            if net.sizes.len() > 10 || net.sizes.iter().any(|&n| n == 0 || n > 4096) {
                return bad(format!(
                    "{name} network sizes {:?} are out of range",
                    net.sizes
                ));
            }
            let need = super::mlp::param_count(&net.sizes);
            if net.params.len() != need {
                return bad(format!(
                    "{name} network has {} parameters, sizes {:?} need {need}",
                    net.params.len(),
                    net.sizes
                ));
            }
            if let Some(i) = net.params.iter().position(|p| !p.is_finite()) {
                return bad(format!("{name} parameter {i} is not finite"));
            }
        }
        if self.log_std.len() != self.act_dim || self.log_std.iter().any(|l| !l.is_finite()) {
            return bad(format!("log_std must be {} finite values", self.act_dim));
        }
        if self.obs_norm.dim() != self.obs_dim
            || self.obs_norm.var.len() != self.obs_dim
            || !self.obs_norm.is_valid()
        {
            return bad(format!(
                "observation statistics must be {} finite means and non-negative variances",
                self.obs_dim
            ));
        }
        Ok(())
    }

    /// The networks, rebuilt (the file must have passed `validate`).
    pub fn model(&self) -> Result<ActorCritic, PpoError> {
        let net = |w: &NetworkWeights, name: &str| {
            Mlp::from_parts(w.sizes.clone(), w.params.clone()).ok_or_else(|| {
                PpoError::IncompatiblePolicy(format!(
                    "{name} network has {} parameters, sizes {:?} need {}",
                    w.params.len(),
                    w.sizes,
                    super::mlp::param_count(&w.sizes)
                ))
            })
        };
        Ok(ActorCritic {
            policy: net(&self.policy, "policy")?,
            log_std: self.log_std.clone(),
            value: net(&self.value, "value")?,
        })
    }

    /// The observation preprocessing the policy expects.
    pub fn obs_normalizer(&self) -> ObsNormalizer {
        ObsNormalizer {
            rms: self.obs_norm.clone(),
            enabled: self.ppo.normalize_obs,
            clip: self.ppo.obs_clip,
        }
    }
}
