//! Adam optimizer (Kingma and Ba) over a flat `f64` parameter slice (the
//! master copy; gradients may come in the networks' precision).

use super::real::{on_widest, Real};

/// Adam state for one flat parameter vector.
#[derive(Debug, Clone)]
pub struct Adam {
    m: Vec<f64>,
    v: Vec<f64>,
    t: i32,
    beta1: f64,
    beta2: f64,
    eps: f64,
}

impl Adam {
    /// Fresh state for `n` parameters with the usual betas (0.9, 0.999) and
    /// the given epsilon (PPO implementations use 1e-5).
    pub fn new(n: usize, eps: f64) -> Self {
        Self {
            m: vec![0.0; n],
            v: vec![0.0; n],
            t: 0,
            beta1: 0.9,
            beta2: 0.999,
            eps,
        }
    }

    /// One descent step with gradient `scale * grad`:
    /// `params -= lr * m_hat / (sqrt(v_hat) + eps)`.
    pub fn step<G: Real>(&mut self, params: &mut [f64], grad: &[G], scale: f64, lr: f64) {
        debug_assert_eq!(params.len(), self.m.len());
        debug_assert_eq!(grad.len(), self.m.len());
        self.t = self.t.saturating_add(1);
        let (b1, b2) = (self.beta1, self.beta2);
        let bc1 = 1.0 - b1.powi(self.t);
        let bc2 = 1.0 - b2.powi(self.t);
        let step = lr / bc1;
        let inv_sqrt_bc2 = 1.0 / bc2.sqrt();
        let eps = self.eps;
        // A square root and a division per parameter: worth the widest
        // vectors (same bits at every width).
        on_widest(|| {
            for (((p, g), m), v) in params
                .iter_mut()
                .zip(grad)
                .zip(&mut self.m)
                .zip(&mut self.v)
            {
                let g = scale * g.to_f64();
                *m = b1 * *m + (1.0 - b1) * g;
                *v = b2 * *v + (1.0 - b2) * g * g;
                *p -= step * *m / (v.sqrt() * inv_sqrt_bc2 + eps);
            }
        });
    }
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)] // index loops read clearer in checks
mod tests {
    use super::*;

    #[test]
    fn first_step_moves_each_parameter_by_lr_against_its_gradient_sign() {
        let mut adam = Adam::new(3, 1e-12);
        let mut p = vec![1.0, 2.0, 3.0];
        adam.step(&mut p, &[0.5, -4.0, 0.0], 1.0, 0.1);
        assert!((p[0] - 0.9).abs() < 1e-9);
        assert!((p[1] - 2.1).abs() < 1e-9);
        assert_eq!(p[2], 3.0);
    }

    #[test]
    fn minimizes_a_quadratic() {
        let mut adam = Adam::new(2, 1e-8);
        let mut p = vec![3.0, -2.0];
        for _ in 0..2000 {
            let g = [2.0 * (p[0] - 1.0), 20.0 * (p[1] + 0.5)];
            adam.step(&mut p, &g, 1.0, 0.01);
        }
        assert!((p[0] - 1.0).abs() < 1e-3 && (p[1] + 0.5).abs() < 1e-3);
    }
}
