//! The body-model parameters (docs/science.md#body-model) as one serde
//! struct whose `Default` is exactly the documented values.

use serde::{Deserialize, Serialize};

use super::SimError;

/// One rigid segment of the planar chain (docs/science.md#segments).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(deny_unknown_fields)]
pub struct Segment {
    /// Mass (kg).
    pub mass: f64,
    /// Length from the lower joint to the upper end (m).
    pub length: f64,
    /// Distance of the segment's centre of mass from its lower joint (m).
    pub com: f64,
    /// Moment of inertia about the segment's own centre of mass (kg m^2).
    pub inertia: f64,
}

/// Everything the simulator needs: body, perturbation, time steps, limits and
/// the initial pose. `Default` equals docs/science.md#body-model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(schemars::JsonSchema))]
#[serde(default, deny_unknown_fields)]
pub struct SimConfig {
    /// Segment 1: shank (both legs).
    pub shank: Segment,
    /// Segment 2: thigh (both legs).
    pub thigh: Segment,
    /// Segment 3: head-arms-trunk.
    pub trunk: Segment,
    /// Gravitational acceleration (m/s^2), acting along -z.
    pub gravity: f64,
    /// Backward pull gain k (N s/m): F_pert = (-k max(0, zdot_com), 0) at the hip.
    pub perturbation_gain: f64,
    /// RK4 sub-step (s).
    pub dt_s: f64,
    /// RK4 sub-steps per control step (zero-order hold of the action).
    pub substeps: u32,
    /// Lower joint limits [ankle, knee, hip] (rad); a task termination test, not a stop.
    pub q_min: [f64; 3],
    /// Upper joint limits [ankle, knee, hip] (rad).
    pub q_max: [f64; 3],
    /// Torque limits (N m): tau = a * tau_max for a normalized action a in [-1, 1]^3.
    pub tau_max: [f64; 3],
    /// Initial joint angles, the squat (rad).
    pub q0: [f64; 3],
    /// Initial joint velocities (rad/s).
    pub qd0: [f64; 3],
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            shank: Segment {
                mass: 6.51,
                length: 0.4305,
                com: 0.24409,
                inertia: 0.11004,
            },
            thigh: Segment {
                mass: 14.0,
                length: 0.42875,
                com: 0.24310,
                inertia: 0.26851,
            },
            trunk: Segment {
                mass: 47.46,
                length: 0.504,
                com: 0.31550,
                inertia: 2.9659,
            },
            gravity: 9.81,
            perturbation_gain: 200.0,
            dt_s: 0.005,
            substeps: 10,
            q_min: [-0.5, -2.4, -0.4],
            q_max: [0.9, 0.1, 2.6],
            tau_max: [200.0, 400.0, 300.0],
            q0: [0.50, -1.85, 2.06],
            qd0: [0.0; 3],
        }
    }
}

impl SimConfig {
    /// Control period (s): `dt_s * substeps` (0.05 s by default).
    pub fn control_dt(&self) -> f64 {
        self.dt_s * f64::from(self.substeps)
    }

    /// The three segments in chain order (shank, thigh, trunk).
    pub fn segments(&self) -> [Segment; 3] {
        [self.shank, self.thigh, self.trunk]
    }

    /// Rejects parameters the model cannot integrate meaningfully.
    pub fn validate(&self) -> Result<(), SimError> {
        for (name, s) in ["shank", "thigh", "trunk"].iter().zip(self.segments()) {
            let ok = s.mass > 0.0
                && s.length > 0.0
                && s.inertia >= 0.0
                && s.com >= 0.0
                && [s.mass, s.length, s.com, s.inertia]
                    .iter()
                    .all(|v| v.is_finite());
            if !ok {
                return Err(SimError::InvalidConfig(format!(
                    "segment {name} needs finite mass > 0, length > 0, com >= 0, inertia >= 0 (got {s:?})"
                )));
            }
        }
        let positive = |name: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(SimError::InvalidConfig(format!(
                    "{name} must be finite and > 0 (got {v})"
                )))
            }
        };
        positive("gravity", self.gravity)?;
        positive("dt_s", self.dt_s)?;
        if self.substeps == 0 {
            return Err(SimError::InvalidConfig("substeps must be >= 1".into()));
        }
        if !(self.perturbation_gain.is_finite() && self.perturbation_gain >= 0.0) {
            return Err(SimError::InvalidConfig(format!(
                "perturbation_gain must be finite and >= 0 (got {})",
                self.perturbation_gain
            )));
        }
        for i in 0..3 {
            positive("tau_max", self.tau_max[i])?;
            if !(self.q_min[i].is_finite() && self.q_max[i].is_finite())
                || self.q_min[i] >= self.q_max[i]
            {
                return Err(SimError::InvalidConfig(format!(
                    "joint {} limits must be finite with q_min < q_max (got {} .. {})",
                    i + 1,
                    self.q_min[i],
                    self.q_max[i]
                )));
            }
            if !(self.q0[i].is_finite() && self.qd0[i].is_finite()) {
                return Err(SimError::InvalidConfig(
                    "initial state must be finite".into(),
                ));
            }
        }
        Ok(())
    }
}
