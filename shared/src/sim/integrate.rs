//! Classic fixed-step RK4 with a zero-order-hold action (docs/science.md#integration).

use super::dynamics::{Model, State};

#[inline]
fn axpy(s: &State, h: f64, k: &State) -> State {
    let mut out = *s;
    for i in 0..6 {
        out[i] += h * k[i];
    }
    out
}

impl Model {
    /// One RK4 sub-step of `dt_s` with torque `tau` held; the perturbation is
    /// re-evaluated in every stage from that stage's own state.
    #[inline]
    pub fn rk4_substep(&self, s: &mut State, tau: &[f64; 3]) {
        let h = self.config().dt_s;
        let k1 = self.derivative(s, tau);
        let k2 = self.derivative(&axpy(s, 0.5 * h, &k1), tau);
        let k3 = self.derivative(&axpy(s, 0.5 * h, &k2), tau);
        let k4 = self.derivative(&axpy(s, h, &k3), tau);
        for i in 0..6 {
            s[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
        }
    }

    /// One control step: `substeps` RK4 sub-steps with `tau` held constant.
    /// `on_substep` sees the state after every sub-step (for 200 Hz COM paths).
    #[inline]
    pub fn control_step(&self, s: &mut State, tau: &[f64; 3], mut on_substep: impl FnMut(&State)) {
        for _ in 0..self.config().substeps {
            self.rk4_substep(s, tau);
            on_substep(s);
        }
    }

    /// Torque for a normalized action: clip to [-1, 1], scale by tau_max.
    /// Returns the torque and the clipped action.
    #[inline]
    pub fn torque(&self, action: &[f64]) -> ([f64; 3], [f64; 3]) {
        let mut a = [0.0; 3];
        let mut tau = [0.0; 3];
        for i in 0..3 {
            // A NaN action is treated as zero rather than poisoning the state.
            a[i] = if action[i].is_nan() {
                0.0
            } else {
                action[i].clamp(-1.0, 1.0)
            };
            tau[i] = a[i] * self.config().tau_max[i];
        }
        (tau, a)
    }
}
