//! The actor-critic: a Gaussian MLP policy with a state-independent log-std
//! and a separate MLP value function, plus the stochastic actor used by
//! training rollouts, evaluation and sampling.

use rand::Rng;

use super::gaussian;
use super::mlp::{Mlp, MlpWorkspace};
use super::normalize::RunningMeanStd;
use super::real::Real;

/// Orthogonal-init gain of hidden layers (sqrt 2, for tanh/ReLU nets).
pub const HIDDEN_GAIN: f64 = std::f64::consts::SQRT_2;
/// Orthogonal-init gain of the policy's output layer: near-zero initial
/// means, so early actions are the exploration noise alone.
pub const POLICY_OUTPUT_GAIN: f64 = 0.01;
/// Orthogonal-init gain of the value output layer.
pub const VALUE_OUTPUT_GAIN: f64 = 1.0;

/// Policy mean network, log-std and value network, the networks in
/// precision `T` (the log-std is always `f64`).
#[derive(Debug, Clone, PartialEq)]
pub struct ActorCritic<T: Real = f64> {
    /// obs -> action mean (linear output; the environment clips actions).
    pub policy: Mlp<T>,
    /// State-independent log standard deviation per action component.
    pub log_std: Vec<f64>,
    /// obs -> state value (in scaled-reward units).
    pub value: Mlp<T>,
}

impl ActorCritic<f64> {
    /// Orthogonally initialized networks (policy output gain 0.01, value
    /// 1.0, hidden sqrt 2; zero biases) and a constant initial log-std.
    pub fn new<R: Rng>(
        obs_dim: usize,
        act_dim: usize,
        hidden: &[usize],
        init_log_std: f64,
        rng: &mut R,
    ) -> Self {
        let sizes = |out: usize| {
            let mut s = Vec::with_capacity(hidden.len() + 2);
            s.push(obs_dim);
            s.extend_from_slice(hidden);
            s.push(out);
            s
        };
        let policy = Mlp::orthogonal(&sizes(act_dim), HIDDEN_GAIN, POLICY_OUTPUT_GAIN, rng);
        let value = Mlp::orthogonal(&sizes(1), HIDDEN_GAIN, VALUE_OUTPUT_GAIN, rng);
        Self {
            policy,
            log_std: vec![init_log_std; act_dim],
            value,
        }
    }
}

impl<T: Real> ActorCritic<T> {
    /// Observation dimension.
    pub fn obs_dim(&self) -> usize {
        self.policy.in_dim()
    }

    /// Action dimension.
    pub fn act_dim(&self) -> usize {
        self.log_std.len()
    }

    /// The same model with its networks in precision `U`.
    pub fn cast<U: Real>(&self) -> ActorCritic<U> {
        ActorCritic {
            policy: self.policy.cast(),
            log_std: self.log_std.clone(),
            value: self.value.cast(),
        }
    }

    /// Overwrites this model's parameters with `master`'s (same shapes),
    /// without allocating.
    pub fn copy_from(&mut self, master: &ActorCritic<f64>) {
        for (dst, src) in [
            (self.policy.params_mut(), master.policy.params()),
            (self.value.params_mut(), master.value.params()),
        ] {
            for (d, s) in dst.iter_mut().zip(src) {
                *d = T::from_f64(*s);
            }
        }
        self.log_std.copy_from_slice(&master.log_std);
    }

    /// Whether every parameter is finite.
    pub fn is_finite(&self) -> bool {
        self.policy.params().iter().all(|p| p.to_f64().is_finite())
            && self.value.params().iter().all(|p| p.to_f64().is_finite())
            && self.log_std.iter().all(|p| p.is_finite())
    }
}

/// Observation preprocessing: running-statistics normalization with a clip,
/// or the identity.
#[derive(Debug, Clone, PartialEq)]
pub struct ObsNormalizer {
    /// The statistics (frozen outside training).
    pub rms: RunningMeanStd,
    /// Whether to normalize at all.
    pub enabled: bool,
    /// Clip of normalized values.
    pub clip: f64,
}

impl ObsNormalizer {
    /// Writes the preprocessed row-major batch `raw` into `out`.
    pub fn apply<T: Real>(&self, raw: &[f64], out: &mut [T]) {
        if self.enabled {
            self.rms.normalize(raw, self.clip, out);
        } else {
            for (o, r) in out.iter_mut().zip(raw) {
                *o = T::from_f64(*r);
            }
        }
    }
}

/// Samples actions from a (frozen) policy for a batch of raw observations,
/// with preallocated buffers.
#[derive(Debug, Clone, Default)]
pub struct Actor<T: Real = f64> {
    obs: Vec<T>,
    mean: Vec<f64>,
    ws: MlpWorkspace<T>,
}

impl<T: Real> Actor<T> {
    /// A fresh actor; buffers size themselves on first use.
    pub fn new() -> Self {
        Self {
            obs: Vec::new(),
            mean: Vec::new(),
            ws: MlpWorkspace::new(),
        }
    }

    /// Normalizes `raw` (row-major `n * obs_dim`) and samples `actions`
    /// (`n * act_dim`) from the Gaussian policy.
    pub fn act<R: Rng>(
        &mut self,
        model: &ActorCritic<T>,
        norm: &ObsNormalizer,
        raw: &[f64],
        rng: &mut R,
        actions: &mut [f64],
    ) {
        self.obs.resize(raw.len(), T::ZERO);
        norm.apply(raw, &mut self.obs);
        let mean = model.policy.forward(&self.obs, &mut self.ws);
        widen(mean, &mut self.mean);
        gaussian::sample(&self.mean, &model.log_std, rng, actions);
    }
}

/// Copies `src` into `dst` as `f64`, resizing `dst` to fit.
pub fn widen<T: Real>(src: &[T], dst: &mut Vec<f64>) {
    dst.resize(src.len(), 0.0);
    for (d, s) in dst.iter_mut().zip(src) {
        *d = s.to_f64();
    }
}
