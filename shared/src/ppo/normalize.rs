//! Running statistics for observation normalization and reward scaling.

use serde::{Deserialize, Serialize};

use super::real::Real;

/// Added to the variance before taking the square root.
const VAR_EPS: f64 = 1e-8;

/// Per-dimension running mean and variance, merged batch by batch with the
/// parallel (Chan et al.) update, as in the usual `RunningMeanStd`. Starts
/// from a tiny pseudo-count so the first batch dominates.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunningMeanStd {
    /// Running mean per dimension.
    pub mean: Vec<f64>,
    /// Running (population) variance per dimension.
    pub var: Vec<f64>,
    /// Number of samples merged so far (plus the initial pseudo-count).
    pub count: f64,
}

impl RunningMeanStd {
    /// Mean 0, variance 1, pseudo-count 1e-4.
    pub fn new(dim: usize) -> Self {
        Self {
            mean: vec![0.0; dim],
            var: vec![1.0; dim],
            count: 1e-4,
        }
    }

    /// Dimension.
    pub fn dim(&self) -> usize {
        self.mean.len()
    }

    /// Merges a row-major batch (`n * dim` values). `scratch` must have
    /// length `2 * dim` (it holds the batch mean and variance).
    pub fn update(&mut self, batch: &[f64], scratch: &mut [f64]) {
        let dim = self.dim();
        let n = batch.len() / dim;
        if n == 0 {
            return;
        }
        let (b_mean, b_var) = scratch.split_at_mut(dim);
        b_mean.fill(0.0);
        b_var.fill(0.0);
        for row in batch.chunks_exact(dim) {
            for (m, x) in b_mean.iter_mut().zip(row) {
                *m += x;
            }
        }
        let inv_n = 1.0 / n as f64;
        b_mean.iter_mut().for_each(|m| *m *= inv_n);
        for row in batch.chunks_exact(dim) {
            for ((v, m), x) in b_var.iter_mut().zip(b_mean.iter()).zip(row) {
                *v += (x - m) * (x - m);
            }
        }
        b_var.iter_mut().for_each(|v| *v *= inv_n);
        let n = n as f64;
        let total = self.count + n;
        for j in 0..dim {
            let delta = b_mean[j] - self.mean[j];
            let m2 =
                self.var[j] * self.count + b_var[j] * n + delta * delta * self.count * n / total;
            self.mean[j] += delta * n / total;
            self.var[j] = m2 / total;
        }
        self.count = total;
    }

    /// Merges a single scalar sample (for `dim == 1`).
    pub fn update_scalar(&mut self, x: f64) {
        let total = self.count + 1.0;
        let delta = x - self.mean[0];
        let m2 = self.var[0] * self.count + delta * delta * self.count / total;
        self.mean[0] += delta / total;
        self.var[0] = m2 / total;
        self.count = total;
    }

    /// Normalizes a row-major batch in place of `out`:
    /// `clip((x - mean) / sqrt(var + 1e-8), -clip, clip)`.
    pub fn normalize<T: Real>(&self, batch: &[f64], clip: f64, out: &mut [T]) {
        let dim = self.dim();
        for (o_row, row) in out.chunks_exact_mut(dim).zip(batch.chunks_exact(dim)) {
            for j in 0..dim {
                let z = (row[j] - self.mean[j]) / (self.var[j] + VAR_EPS).sqrt();
                o_row[j] = T::from_f64(z.clamp(-clip, clip));
            }
        }
    }

    /// True when every statistic is finite and the variances non-negative.
    pub fn is_valid(&self) -> bool {
        self.mean.iter().all(|m| m.is_finite())
            && self.var.iter().all(|v| v.is_finite() && *v >= 0.0)
            && self.count.is_finite()
            && self.count > 0.0
    }
}

/// Reward scaling by the running standard deviation of the discounted
/// return (the `VecNormalize` scheme): each env keeps
/// `ret = gamma * ret + r` (reset at episode end), the running variance of
/// `ret` is tracked, and rewards are divided by its standard deviation (not
/// centred, so the sign of the reward is kept).
#[derive(Debug, Clone)]
pub struct RewardScaler {
    gamma: f64,
    clip: f64,
    returns: Vec<f64>,
    stats: RunningMeanStd,
}

impl RewardScaler {
    /// One discounted-return accumulator per env.
    pub fn new(n_envs: usize, gamma: f64, clip: f64) -> Self {
        Self {
            gamma,
            clip,
            returns: vec![0.0; n_envs],
            stats: RunningMeanStd::new(1),
        }
    }

    /// Folds in one step's rewards (one per env) and the episode-end flags.
    pub fn update(&mut self, rewards: impl Iterator<Item = (f64, bool)>) {
        for (ret, (r, done)) in self.returns.iter_mut().zip(rewards) {
            *ret = *ret * self.gamma + r;
            self.stats.update_scalar(*ret);
            if done {
                *ret = 0.0;
            }
        }
    }

    /// Scaled reward `clip(r / sqrt(var + 1e-8), -clip, clip)`.
    pub fn scale(&self, r: f64) -> f64 {
        (r / (self.stats.var[0] + VAR_EPS).sqrt()).clamp(-self.clip, self.clip)
    }
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)] // index loops read clearer in checks
mod tests {
    use super::*;

    #[test]
    fn batched_updates_match_the_two_pass_moments() {
        let data: Vec<f64> = (0..40)
            .map(|i| ((i * 7919) % 31) as f64 * 0.37 - 3.0)
            .collect();
        let mut rms = RunningMeanStd::new(2);
        let mut scratch = [0.0; 4];
        for chunk in data.chunks(10) {
            rms.update(chunk, &mut scratch);
        }
        for j in 0..2 {
            let col: Vec<f64> = data.iter().skip(j).step_by(2).copied().collect();
            let mean = col.iter().sum::<f64>() / col.len() as f64;
            let var = col.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / col.len() as f64;
            // The 1e-4 pseudo-count perturbs the moments by ~1e-5 relative.
            assert!((rms.mean[j] - mean).abs() < 1e-4 * (1.0 + mean.abs()));
            assert!((rms.var[j] - var).abs() < 1e-4 * (1.0 + var));
        }
    }

    #[test]
    fn scalar_updates_match_batched_updates() {
        let mut a = RunningMeanStd::new(1);
        let mut b = RunningMeanStd::new(1);
        let xs = [1.0, 4.0, -2.0, 8.0, 0.5];
        for x in xs {
            a.update_scalar(x);
        }
        for x in xs {
            b.update(&[x], &mut [0.0; 2]);
        }
        assert!((a.mean[0] - b.mean[0]).abs() < 1e-12);
        assert!((a.var[0] - b.var[0]).abs() < 1e-12);
    }

    #[test]
    fn normalize_centres_scales_and_clips() {
        let rms = RunningMeanStd {
            mean: vec![1.0, -1.0],
            var: vec![4.0, 1.0],
            count: 10.0,
        };
        let mut out = [0.0f64; 2];
        rms.normalize(&[3.0, 100.0], 5.0, &mut out);
        assert!((out[0] - 1.0).abs() < 1e-8);
        assert_eq!(out[1], 5.0);
    }

    #[test]
    fn reward_scaler_divides_by_return_std() {
        let mut s = RewardScaler::new(1, 0.0, 100.0);
        // gamma 0: returns are the rewards themselves, alternating +-2.
        for i in 0..1000 {
            let r = if i % 2 == 0 { 2.0 } else { -2.0 };
            s.update(std::iter::once((r, false)));
        }
        assert!((s.scale(2.0) - 1.0).abs() < 1e-3);
    }
}
