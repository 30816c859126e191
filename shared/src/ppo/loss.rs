//! The PPO loss on one minibatch and its exact gradient wrt every parameter:
//! clipped surrogate, (optionally clipped) value error, entropy bonus.
//!
//! `total = -mean(min(r A, clip(r, 1 - eps, 1 + eps) A))
//!          + vf_coef * mean(L_v) - ent_coef * H`, with `r = exp(logp -
//! logp_old)`, `L_v = (V - R)^2` or, with value clipping,
//! `max((V - R)^2, (V_old + clip(V - V_old, -c, c) - R)^2)`.

use super::gaussian;
use super::mlp::MlpWorkspace;
use super::model::widen;
use super::model::ActorCritic;
use super::real::{on_widest, Real};

/// One minibatch, column-major per sample (`dim x m`).
#[derive(Debug, Clone, Copy)]
pub struct Minibatch<'a, T: Real = f64> {
    /// Normalized observations, `obs_dim x m`, in the networks' precision.
    pub obs: &'a [T],
    /// Actions taken, `act_dim x m`.
    pub actions: &'a [f64],
    /// Log-density of the actions under the rollout policy.
    pub old_logp: &'a [f64],
    /// Advantages (already normalized if asked).
    pub advantages: &'a [f64],
    /// Value targets (GAE returns).
    pub returns: &'a [f64],
    /// Values predicted during the rollout.
    pub old_values: &'a [f64],
}

/// Loss coefficients.
#[derive(Debug, Clone, Copy)]
pub struct LossCoefs {
    /// Ratio clip epsilon.
    pub clip_range: f64,
    /// Value clip, if any.
    pub clip_range_vf: Option<f64>,
    /// Value-loss weight.
    pub vf_coef: f64,
    /// Entropy-bonus weight.
    pub ent_coef: f64,
}

/// Scalars of one loss evaluation.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LossStats {
    /// The full objective that is minimized.
    pub total: f64,
    /// Clipped-surrogate part (already negated).
    pub policy_loss: f64,
    /// Mean (possibly clipped) squared value error.
    pub value_loss: f64,
    /// Policy entropy.
    pub entropy: f64,
    /// Mean of `(r - 1) - ln r`, a low-variance estimate of KL(old || new).
    pub approx_kl: f64,
    /// Fraction of samples whose ratio left `[1 - eps, 1 + eps]`.
    pub clip_fraction: f64,
}

/// Gradients, same layouts as the parameters (networks in precision `T`).
#[derive(Debug, Clone)]
pub struct Grads<T: Real = f64> {
    /// Policy network.
    pub policy: Vec<T>,
    /// Log-std.
    pub log_std: Vec<f64>,
    /// Value network.
    pub value: Vec<T>,
}

impl<T: Real> Grads<T> {
    /// Zero gradients shaped like `model`.
    pub fn zeros(model: &ActorCritic<T>) -> Self {
        Self {
            policy: vec![T::ZERO; model.policy.params().len()],
            log_std: vec![0.0; model.log_std.len()],
            value: vec![T::ZERO; model.value.params().len()],
        }
    }

    /// Global L2 norm over all gradients (accumulated in `f64`).
    pub fn norm(&self) -> f64 {
        // Eight running sums in a fixed order, combined at the end: one
        // sum would chain every addition on the previous one, and this ran
        // once per minibatch over ten thousand gradients.
        let sq = |v: &[T]| {
            on_widest(
                #[inline(always)]
                || {
                    let mut acc = [0.0f64; 8];
                    let chunks = v.chunks_exact(8);
                    let tail: f64 = chunks
                        .remainder()
                        .iter()
                        .map(|g| g.to_f64() * g.to_f64())
                        .sum();
                    for c in chunks {
                        for (a, g) in acc.iter_mut().zip(c) {
                            *a += g.to_f64() * g.to_f64();
                        }
                    }
                    acc.iter().sum::<f64>() + tail
                },
            )
        };
        let sq_log_std = self.log_std.iter().map(|g| g * g).sum::<f64>();
        (sq(&self.policy) + sq_log_std + sq(&self.value)).sqrt()
    }

    /// The factor that brings the global norm down to `max_norm` (1 when it
    /// is already below): the optimizer applies it to every gradient.
    pub fn clip_scale(&self, max_norm: f64) -> f64 {
        let norm = self.norm();
        if norm > max_norm {
            max_norm / (norm + 1e-6)
        } else {
            1.0
        }
    }
}

/// Scratch buffers for the loss.
#[derive(Debug, Clone, Default)]
pub struct LossWorkspace<T: Real = f64> {
    policy: MlpWorkspace<T>,
    value: MlpWorkspace<T>,
    mean: Vec<f64>,
    values: Vec<f64>,
    logp: Vec<f64>,
    d_logp: Vec<f64>,
    d_mean: Vec<f64>,
    d_mean_t: Vec<T>,
    d_value: Vec<T>,
}

impl<T: Real> LossWorkspace<T> {
    /// Empty; sizes itself on first use.
    pub fn new() -> Self {
        Self {
            policy: MlpWorkspace::new(),
            value: MlpWorkspace::new(),
            mean: Vec::new(),
            values: Vec::new(),
            logp: Vec::new(),
            d_logp: Vec::new(),
            d_mean: Vec::new(),
            d_mean_t: Vec::new(),
            d_value: Vec::new(),
        }
    }
}

/// Evaluates the loss on `mb` and, when `grads` is given, writes its
/// gradient (overwriting).
pub fn ppo_loss<T: Real>(
    model: &ActorCritic<T>,
    mb: &Minibatch<'_, T>,
    coefs: &LossCoefs,
    ws: &mut LossWorkspace<T>,
    grads: Option<&mut Grads<T>>,
) -> LossStats {
    let m = mb.old_logp.len();
    let inv_m = 1.0 / m as f64;
    let eps = coefs.clip_range;
    ws.logp.resize(m, 0.0);
    ws.d_logp.resize(m, 0.0);
    ws.d_value.resize(m, T::ZERO);
    ws.d_mean.resize(mb.actions.len(), 0.0);
    ws.d_mean_t.resize(mb.actions.len(), T::ZERO);

    // Policy part (the Gaussian in f64 whatever the network precision).
    widen(model.policy.forward(mb.obs, &mut ws.policy), &mut ws.mean);
    gaussian::log_prob(&ws.mean, &model.log_std, mb.actions, &mut ws.logp);
    let (mut pg, mut kl, mut clipped) = (0.0, 0.0, 0usize);
    for s in 0..m {
        let log_ratio = ws.logp[s] - mb.old_logp[s];
        let ratio = log_ratio.exp();
        let a = mb.advantages[s];
        let surr1 = ratio * a;
        let surr2 = ratio.clamp(1.0 - eps, 1.0 + eps) * a;
        pg -= surr1.min(surr2);
        // The gradient flows only through the unclipped term when it is the
        // minimum (inside the clip range both terms coincide).
        ws.d_logp[s] = if surr1 <= surr2 {
            -a * ratio * inv_m
        } else {
            0.0
        };
        kl += (ratio - 1.0) - log_ratio;
        if (ratio - 1.0).abs() > eps {
            clipped += 1;
        }
    }
    let entropy = gaussian::entropy(&model.log_std);

    // Value part.
    widen(model.value.forward(mb.obs, &mut ws.value), &mut ws.values);
    let mut vl = 0.0;
    for s in 0..m {
        let (v, r) = (ws.values[s], mb.returns[s]);
        let l1 = (v - r) * (v - r);
        let (l, dl) = match coefs.clip_range_vf {
            Some(c) => {
                let v_old = mb.old_values[s];
                let vc = v_old + (v - v_old).clamp(-c, c);
                let l2 = (vc - r) * (vc - r);
                if l1 >= l2 {
                    (l1, 2.0 * (v - r))
                } else {
                    (l2, 0.0)
                }
            }
            None => (l1, 2.0 * (v - r)),
        };
        vl += l;
        ws.d_value[s] = T::from_f64(coefs.vf_coef * dl * inv_m);
    }
    let stats = LossStats {
        policy_loss: pg * inv_m,
        value_loss: vl * inv_m,
        entropy,
        approx_kl: kl * inv_m,
        clip_fraction: clipped as f64 * inv_m,
        total: pg * inv_m + coefs.vf_coef * vl * inv_m - coefs.ent_coef * entropy,
    };

    if let Some(g) = grads {
        g.log_std.fill(-coefs.ent_coef);
        gaussian::log_prob_backward(
            &ws.mean,
            &model.log_std,
            mb.actions,
            &ws.d_logp,
            &mut ws.d_mean,
            &mut g.log_std,
        );
        for (d, s) in ws.d_mean_t.iter_mut().zip(&ws.d_mean) {
            *d = T::from_f64(*s);
        }
        model
            .policy
            .backward(mb.obs, &mut ws.policy, &ws.d_mean_t, &mut g.policy, None);
        model
            .value
            .backward(mb.obs, &mut ws.value, &ws.d_value, &mut g.value, None);
    }
    stats
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)] // index loops read clearer in checks
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::StandardNormal;

    struct Data {
        obs: Vec<f64>,
        actions: Vec<f64>,
        old_logp: Vec<f64>,
        adv: Vec<f64>,
        ret: Vec<f64>,
        old_v: Vec<f64>,
    }

    fn setup(m: usize) -> (ActorCritic, Data) {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut model = ActorCritic::new(7, 3, &[8, 8], -0.3, &mut rng);
        // Move away from the tiny-output initialization so every term matters.
        for p in model.policy.params_mut() {
            *p += 0.2 * rng.sample::<f64, _>(StandardNormal);
        }
        let mut n = |k: usize, s: f64| -> Vec<f64> {
            (0..k)
                .map(|_| s * rng.sample::<f64, _>(StandardNormal))
                .collect()
        };
        let obs = n(7 * m, 1.0);
        let actions = n(3 * m, 0.8);
        let adv = n(m, 1.0);
        let ret = n(m, 2.0);
        // Old log-probs near the current ones so ratios straddle the clip
        // range; old values likewise around the current values.
        let mut ws = MlpWorkspace::new();
        let mean = model.policy.forward(&obs, &mut ws).to_vec();
        let mut logp = vec![0.0; m];
        gaussian::log_prob(&mean, &model.log_std, &actions, &mut logp);
        let jitter = n(m, 0.3);
        let old_logp = logp.iter().zip(&jitter).map(|(l, j)| l + j).collect();
        let v = model.value.forward(&obs, &mut ws).to_vec();
        let jitter = n(m, 0.5);
        let old_v = v.iter().zip(&jitter).map(|(v, j)| v + j).collect();
        (
            model,
            Data {
                obs,
                actions,
                old_logp,
                adv,
                ret,
                old_v,
            },
        )
    }

    #[test]
    fn ppo_loss_gradient_matches_central_differences() {
        let m = 12;
        let (model, d) = setup(m);
        let mb = Minibatch {
            obs: &d.obs,
            actions: &d.actions,
            old_logp: &d.old_logp,
            advantages: &d.adv,
            returns: &d.ret,
            old_values: &d.old_v,
        };
        for clip_range_vf in [None, Some(0.2)] {
            let coefs = LossCoefs {
                clip_range: 0.2,
                clip_range_vf,
                vf_coef: 0.5,
                ent_coef: 0.01,
            };
            let mut ws = LossWorkspace::new();
            let mut g = Grads::zeros(&model);
            let stats = ppo_loss(&model, &mb, &coefs, &mut ws, Some(&mut g));
            assert!(stats.clip_fraction > 0.0 && stats.clip_fraction < 1.0);
            let h = 1e-6;
            let total =
                |m: &ActorCritic| ppo_loss(m, &mb, &coefs, &mut LossWorkspace::new(), None).total;
            let check = |fd: f64, an: f64, what: &str| {
                assert!(
                    (fd - an).abs() < 1e-6 * (1.0 + fd.abs()),
                    "{what}: fd {fd} vs analytic {an}"
                );
            };
            for i in 0..model.policy.params().len() {
                let mut p = model.clone();
                p.policy.params_mut()[i] += h;
                let up = total(&p);
                p.policy.params_mut()[i] -= 2.0 * h;
                check(
                    (up - total(&p)) / (2.0 * h),
                    g.policy[i],
                    &format!("policy {i}"),
                );
            }
            for i in 0..model.value.params().len() {
                let mut p = model.clone();
                p.value.params_mut()[i] += h;
                let up = total(&p);
                p.value.params_mut()[i] -= 2.0 * h;
                check(
                    (up - total(&p)) / (2.0 * h),
                    g.value[i],
                    &format!("value {i}"),
                );
            }
            for j in 0..3 {
                let mut p = model.clone();
                p.log_std[j] += h;
                let up = total(&p);
                p.log_std[j] -= 2.0 * h;
                check(
                    (up - total(&p)) / (2.0 * h),
                    g.log_std[j],
                    &format!("log_std {j}"),
                );
            }
        }
    }

    #[test]
    fn unchanged_policy_has_zero_kl_and_no_clipping() {
        let m = 8;
        let (model, mut d) = setup(m);
        let mut ws = MlpWorkspace::new();
        let mean = model.policy.forward(&d.obs, &mut ws).to_vec();
        gaussian::log_prob(&mean, &model.log_std, &d.actions, &mut d.old_logp);
        let mb = Minibatch {
            obs: &d.obs,
            actions: &d.actions,
            old_logp: &d.old_logp,
            advantages: &d.adv,
            returns: &d.ret,
            old_values: &d.old_v,
        };
        let coefs = LossCoefs {
            clip_range: 0.2,
            clip_range_vf: None,
            vf_coef: 0.5,
            ent_coef: 0.0,
        };
        let s = ppo_loss(&model, &mb, &coefs, &mut LossWorkspace::new(), None);
        assert!(s.approx_kl.abs() < 1e-15);
        assert_eq!(s.clip_fraction, 0.0);
        let mean_adv = d.adv.iter().sum::<f64>() / m as f64;
        assert!((s.policy_loss + mean_adv).abs() < 1e-12);
    }

    #[test]
    fn grad_norm_clipping_scales_to_the_limit() {
        let (model, _) = setup(2);
        let mut g = Grads::zeros(&model);
        g.policy[0] = 3.0;
        g.value[0] = 4.0;
        assert_eq!(g.norm(), 5.0);
        assert_eq!(g.clip_scale(10.0), 1.0);
        assert!((g.clip_scale(1.0) * 5.0 - 1.0).abs() < 1e-6);
    }

    #[test]
    fn f32_loss_matches_f64_loss() {
        let m = 12;
        let (model, d) = setup(m);
        let obs32: Vec<f32> = d.obs.iter().map(|&x| x as f32).collect();
        let coefs = LossCoefs {
            clip_range: 0.2,
            clip_range_vf: Some(0.2),
            vf_coef: 0.5,
            ent_coef: 0.01,
        };
        let mb = Minibatch {
            obs: &d.obs[..],
            actions: &d.actions,
            old_logp: &d.old_logp,
            advantages: &d.adv,
            returns: &d.ret,
            old_values: &d.old_v,
        };
        let mb32 = Minibatch {
            obs: &obs32[..],
            actions: &d.actions,
            old_logp: &d.old_logp,
            advantages: &d.adv,
            returns: &d.ret,
            old_values: &d.old_v,
        };
        let model32: ActorCritic<f32> = model.cast();
        let mut g = Grads::zeros(&model);
        let mut g32 = Grads::zeros(&model32);
        let a = ppo_loss(&model, &mb, &coefs, &mut LossWorkspace::new(), Some(&mut g));
        let b = ppo_loss(
            &model32,
            &mb32,
            &coefs,
            &mut LossWorkspace::new(),
            Some(&mut g32),
        );
        assert!((a.total - b.total).abs() < 1e-5, "{a:?} vs {b:?}");
        for (x, y) in g.policy.iter().zip(&g32.policy) {
            assert!((x - f64::from(*y)).abs() < 1e-4 * (1.0 + x.abs()));
        }
    }
}
