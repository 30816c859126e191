//! Diagonal Gaussian policy head with a state-independent log standard
//! deviation: log-density, entropy and their gradients.
//!
//! Batches are column-major `act_dim x batch` blocks (one sample per
//! column), the layout the MLP produces. `act_dim` is at most [`MAX_DIM`].

use rand::Rng;
use rand_distr::StandardNormal;

/// Largest action dimension supported (the task has 3).
pub const MAX_DIM: usize = 16;

/// 0.5 * ln(2 pi).
const HALF_LN_2PI: f64 = 0.918_938_533_204_672_8;

/// Log-density of each sample: `out[s] = log N(actions[:, s]; mean[:, s],
/// diag(exp(log_std))^2)`.
pub fn log_prob(mean: &[f64], log_std: &[f64], actions: &[f64], out: &mut [f64]) {
    let d = log_std.len();
    let norm: f64 = log_std.iter().sum::<f64>() + d as f64 * HALF_LN_2PI;
    let mut inv_std = [0.0; MAX_DIM];
    for (s, l) in inv_std.iter_mut().zip(log_std) {
        *s = (-l).exp();
    }
    for ((o, mu), a) in out
        .iter_mut()
        .zip(mean.chunks_exact(d))
        .zip(actions.chunks_exact(d))
    {
        let mut q = 0.0;
        for j in 0..d {
            let z = (a[j] - mu[j]) * inv_std[j];
            q += z * z;
        }
        *o = -0.5 * q - norm;
    }
}

/// Entropy of the distribution (the same for every state):
/// `sum_j (0.5 + 0.5 ln(2 pi) + log_std_j)`. Its gradient wrt each
/// `log_std_j` is 1.
pub fn entropy(log_std: &[f64]) -> f64 {
    log_std.iter().map(|l| 0.5 + HALF_LN_2PI + l).sum()
}

/// Backpropagates `d_logp[s]` (the loss gradient wrt each sample's
/// log-density) to the means (`d_mean`, overwritten, `act_dim x batch`) and
/// accumulates into `d_log_std`:
/// `dlogp/dmu_j = (a_j - mu_j) / sigma_j^2`,
/// `dlogp/dlog_std_j = ((a_j - mu_j) / sigma_j)^2 - 1`.
pub fn log_prob_backward(
    mean: &[f64],
    log_std: &[f64],
    actions: &[f64],
    d_logp: &[f64],
    d_mean: &mut [f64],
    d_log_std: &mut [f64],
) {
    let d = log_std.len();
    let mut inv_var = [0.0; MAX_DIM];
    for (s, l) in inv_var.iter_mut().zip(log_std) {
        *s = (-2.0 * l).exp();
    }
    for (((dm, mu), a), &g) in d_mean
        .chunks_exact_mut(d)
        .zip(mean.chunks_exact(d))
        .zip(actions.chunks_exact(d))
        .zip(d_logp)
    {
        for j in 0..d {
            let diff = a[j] - mu[j];
            dm[j] = g * diff * inv_var[j];
            d_log_std[j] += g * (diff * diff * inv_var[j] - 1.0);
        }
    }
}

/// Samples actions `mean + exp(log_std) * eps`, eps ~ N(0, I), in place of
/// `out` (same layout as `mean`).
pub fn sample<R: Rng>(mean: &[f64], log_std: &[f64], rng: &mut R, out: &mut [f64]) {
    let d = log_std.len();
    let mut std = [0.0; MAX_DIM];
    for (s, l) in std.iter_mut().zip(log_std) {
        *s = l.exp();
    }
    for (o, mu) in out.chunks_exact_mut(d).zip(mean.chunks_exact(d)) {
        for j in 0..d {
            let eps: f64 = rng.sample(StandardNormal);
            o[j] = mu[j] + std[j] * eps;
        }
    }
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)] // index loops read clearer in checks
mod tests {
    use super::*;

    #[test]
    fn log_prob_of_standard_normal_at_zero() {
        let mut out = [0.0];
        log_prob(&[0.0, 0.0, 0.0], &[0.0; 3], &[0.0; 3], &mut out);
        assert!((out[0] + 3.0 * HALF_LN_2PI).abs() < 1e-15);
        // One-dimensional, sigma = 2, one sigma away.
        log_prob(&[1.0], &[2f64.ln()], &[3.0], &mut out);
        let expected = -0.5 - 2f64.ln() - HALF_LN_2PI;
        assert!((out[0] - expected).abs() < 1e-14);
    }

    #[test]
    fn entropy_closed_form() {
        let h = entropy(&[0.0, 2f64.ln()]);
        let expected = 2.0 * (0.5 + HALF_LN_2PI) + 2f64.ln();
        assert!((h - expected).abs() < 1e-14);
    }

    #[test]
    fn gradients_match_central_differences() {
        let mean = [0.3, -0.2, 0.9, 0.1, 0.5, -0.7];
        let log_std = [-0.5, 0.2, -1.1];
        let actions = [0.1, 0.4, 0.2, -0.3, 0.6, -0.1];
        let d_logp = [0.7, -1.3];
        let loss = |mean: &[f64], log_std: &[f64]| {
            let mut lp = [0.0; 2];
            log_prob(mean, log_std, &actions, &mut lp);
            lp[0] * d_logp[0] + lp[1] * d_logp[1]
        };
        let mut d_mean = [0.0; 6];
        let mut d_log_std = [0.0; 3];
        log_prob_backward(
            &mean,
            &log_std,
            &actions,
            &d_logp,
            &mut d_mean,
            &mut d_log_std,
        );
        let h = 1e-6;
        for i in 0..6 {
            let (mut up, mut down) = (mean, mean);
            up[i] += h;
            down[i] -= h;
            let fd = (loss(&up, &log_std) - loss(&down, &log_std)) / (2.0 * h);
            assert!(
                (fd - d_mean[i]).abs() < 1e-7,
                "mean {i}: {fd} vs {}",
                d_mean[i]
            );
        }
        for j in 0..3 {
            let (mut up, mut down) = (log_std, log_std);
            up[j] += h;
            down[j] -= h;
            let fd = (loss(&mean, &up) - loss(&mean, &down)) / (2.0 * h);
            assert!(
                (fd - d_log_std[j]).abs() < 1e-7,
                "log_std {j}: {fd} vs {}",
                d_log_std[j]
            );
            let fd_h = (entropy(&up) - entropy(&down)) / (2.0 * h);
            assert!((fd_h - 1.0).abs() < 1e-8);
        }
    }

    #[test]
    fn samples_have_the_requested_moments() {
        use rand::SeedableRng;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let n = 20000;
        let mean: Vec<f64> = (0..n).flat_map(|_| [1.0, -2.0]).collect();
        let mut out = vec![0.0; 2 * n];
        sample(&mean, &[0.0, (0.5f64).ln()], &mut rng, &mut out);
        let m1 = out.iter().step_by(2).sum::<f64>() / n as f64;
        let s2 = (out
            .iter()
            .skip(1)
            .step_by(2)
            .map(|a| (a + 2.0).powi(2))
            .sum::<f64>()
            / n as f64)
            .sqrt();
        assert!((m1 - 1.0).abs() < 0.03);
        assert!((s2 - 0.5).abs() < 0.02);
    }
}
