//! Checks of the body model against independent references: the numbers
//! of docs/science.md#body-model, energy conservation, and a numeric Euler-Lagrange derivation from
//! segment positions written out separately here.
#![allow(clippy::needless_range_loop)] // index loops mirror the matrix formulas

use super::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn model() -> Model {
    Model::new(&SimConfig::default()).unwrap()
}

fn random_state(rng: &mut ChaCha8Rng, vel: f64) -> State {
    let mut s = [0.0; 6];
    for v in &mut s[..3] {
        *v = rng.gen_range(-2.0..2.0);
    }
    for v in &mut s[3..] {
        *v = rng.gen_range(-vel..=vel);
    }
    s
}

#[test]
fn standing_com_height_is_spec_value() {
    let m = model();
    assert!((m.h_stand() - 0.98239).abs() < 5e-6, "{}", m.h_stand());
    let c = m.com(&[0.0; 6]);
    assert!((c.z - m.h_stand()).abs() < 1e-15 && c.x.abs() < 1e-15);
    assert!((m.total_mass() - 67.97).abs() < 1e-9);
}

#[test]
fn squat_com_is_above_ankle_at_62_percent_height() {
    let m = model();
    let cfg = SimConfig::default();
    let c = m.com(&[cfg.q0[0], cfg.q0[1], cfg.q0[2], 0.0, 0.0, 0.0]);
    let frac = c.z / m.h_stand();
    assert!((0.58..0.66).contains(&frac), "squat height fraction {frac}");
    assert!(c.x.abs() < 0.05, "squat COM x {}", c.x);
}

/// Largest |E(t) - E(0)| over a zero-torque, zero-pull 2 s fall from the
/// squat, integrated with sub-step `dt_s`, and the largest kinetic energy.
fn fall_energy_drift(dt_s: f64) -> (f64, f64) {
    let cfg = SimConfig {
        perturbation_gain: 0.0,
        dt_s,
        substeps: (0.05 / dt_s).round() as u32,
        ..SimConfig::default()
    };
    let m = Model::new(&cfg).unwrap();
    let mut s: State = [cfg.q0[0], cfg.q0[1], cfg.q0[2], 0.0, 0.0, 0.0];
    let energy = |s: &State| m.kinetic_energy(s) + m.potential_energy(&s[..3]);
    let e0 = energy(&s);
    let (mut drift, mut kinetic) = (0.0_f64, 0.0_f64);
    for _ in 0..40 {
        m.control_step(&mut s, &[0.0; 3], |s| {
            drift = drift.max((energy(s) - e0).abs());
            kinetic = kinetic.max(m.kinetic_energy(s));
        });
    }
    (drift, kinetic)
}

/// Zero torque, zero pull: total mechanical energy over a 2 s fall from the
/// squat. Without joint stops the chain whips round at up to ~53 rad/s, so
/// RK4 at the default 5 ms drifts by 3.3 J (5.1e-3 of m g h_stand = 655 J);
/// halving the step cuts the drift ~16-30x, the fourth order of RK4, which
/// shows the drift is integration error and not a modelling error.
#[test]
fn energy_is_conserved_in_a_zero_torque_fall() {
    let scale = 67.97 * 9.81 * 0.98239;
    let (d5, kinetic) = fall_energy_drift(0.005);
    let (d25, _) = fall_energy_drift(0.0025);
    let (d125, _) = fall_energy_drift(0.00125);
    // The fall is violent (about 1 kJ of kinetic energy at its peak), so a
    // conserved total is a real check, not a body at rest.
    assert!(kinetic > 500.0, "max kinetic {kinetic}");
    assert!(d5 / scale < 1e-2, "relative drift at 5 ms {:e}", d5 / scale);
    assert!(
        d125 / scale < 2e-5,
        "relative drift at 1.25 ms {:e}",
        d125 / scale
    );
    assert!(d25 / d125 > 10.0, "RK4 order lost: {d25:e} -> {d125:e}");
}

/// Over the first half second of the fall (moderate speeds) RK4 at the
/// default step conserves energy to 5.2e-6 relative (measured).
#[test]
fn energy_is_conserved_tightly_at_moderate_speed() {
    let cfg = SimConfig {
        perturbation_gain: 0.0,
        ..SimConfig::default()
    };
    let m = Model::new(&cfg).unwrap();
    let mut s: State = [cfg.q0[0], cfg.q0[1], cfg.q0[2], 0.0, 0.0, 0.0];
    let energy = |s: &State| m.kinetic_energy(s) + m.potential_energy(&s[..3]);
    let e0 = energy(&s);
    for _ in 0..10 {
        m.control_step(&mut s, &[0.0; 3], |_| {});
    }
    assert!(m.kinetic_energy(&s) > 10.0);
    let rel = (energy(&s) - e0).abs() / e0.abs();
    assert!(rel < 1e-5, "relative drift {rel:e}");
}

#[test]
fn gravity_torque_holds_any_pose_at_rest() {
    let m = model();
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    for _ in 0..200 {
        let mut s = random_state(&mut rng, 0.0);
        s[3..].fill(0.0);
        let tau = m.gravity(&s[..3]);
        let qdd = m.accelerations(&s, &tau, m.perturbation(&s));
        for a in qdd {
            assert!(a.abs() < 1e-10, "qdd {qdd:?} at {s:?}");
        }
    }
}

#[test]
fn mass_matrix_is_symmetric_positive_definite() {
    let m = model();
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    for _ in 0..500 {
        let s = random_state(&mut rng, 0.0);
        let mm = m.mass_matrix(&s[..3]);
        for i in 0..3 {
            for j in 0..3 {
                assert_eq!(mm[i][j], mm[j][i]);
            }
        }
        // Sylvester's criterion: all leading minors positive.
        let d1 = mm[0][0];
        let d2 = mm[0][0] * mm[1][1] - mm[0][1] * mm[1][0];
        let d3 = mm[0][0] * (mm[1][1] * mm[2][2] - mm[1][2] * mm[2][1])
            - mm[0][1] * (mm[1][0] * mm[2][2] - mm[1][2] * mm[2][0])
            + mm[0][2] * (mm[1][0] * mm[2][1] - mm[1][1] * mm[2][0]);
        assert!(d1 > 0.0 && d2 > 0.0 && d3 > 0.0, "{mm:?}");
    }
}

#[test]
fn upright_with_zero_torque_is_an_equilibrium() {
    let m = model();
    let d = m.derivative(&[0.0; 6], &[0.0; 3]);
    assert_eq!(d, [0.0; 6]);
    let mut s = [0.0; 6];
    for _ in 0..20 {
        m.control_step(&mut s, &[0.0; 3], |_| {});
    }
    assert_eq!(s, [0.0; 6]);
}

#[test]
fn spd_solver_inverts_mass_matrix() {
    let m = model();
    let mm = m.mass_matrix(&[0.3, -1.0, 1.2]);
    let b = [1.0, -2.0, 3.0];
    let x = solve_spd3(&mm, b);
    for i in 0..3 {
        let r: f64 = (0..3).map(|j| mm[i][j] * x[j]).sum();
        assert!((r - b[i]).abs() < 1e-12);
    }
}

/// Independent kinematics: segment COMs, hip and absolute angles written
/// from docs/science.md#equations-of-motion directly (not through the model's closed forms).
struct Kinematics {
    cfg: SimConfig,
}

impl Kinematics {
    fn points(&self, q: &[f64; 3]) -> [[f64; 2]; 4] {
        let mut th = 0.0;
        let mut base = [0.0, 0.0];
        let mut out = [[0.0; 2]; 4];
        for (i, seg) in self.cfg.segments().iter().enumerate() {
            th += q[i];
            let u = [th.sin(), th.cos()];
            out[i] = [base[0] + seg.com * u[0], base[1] + seg.com * u[1]];
            base = [base[0] + seg.length * u[0], base[1] + seg.length * u[1]];
            if i == 1 {
                out[3] = base; // hip
            }
        }
        out
    }

    /// d point_k / d q_j by central differences.
    fn jacobians(&self, q: &[f64; 3]) -> [[[f64; 3]; 2]; 4] {
        let h = 1e-5;
        let mut jac = [[[0.0; 3]; 2]; 4];
        for j in 0..3 {
            let (mut qp, mut qm) = (*q, *q);
            qp[j] += h;
            qm[j] -= h;
            let (pp, pm) = (self.points(&qp), self.points(&qm));
            for k in 0..4 {
                for c in 0..2 {
                    jac[k][c][j] = (pp[k][c] - pm[k][c]) / (2.0 * h);
                }
            }
        }
        jac
    }

    /// Mass matrix from T = sum 1/2 m |J qd|^2 + 1/2 I (sum of qd up to i)^2.
    fn mass_matrix(&self, q: &[f64; 3]) -> [[f64; 3]; 3] {
        let jac = self.jacobians(q);
        let segs = self.cfg.segments();
        let mut m = [[0.0; 3]; 3];
        for (k, seg) in segs.iter().enumerate() {
            for i in 0..3 {
                for j in 0..3 {
                    let jj: f64 = (0..2).map(|c| jac[k][c][i] * jac[k][c][j]).sum();
                    // Segment k's absolute rate is qd_1 + .. + qd_k.
                    let rot = if i <= k && j <= k { seg.inertia } else { 0.0 };
                    m[i][j] += seg.mass * jj + rot;
                }
            }
        }
        m
    }

    fn potential(&self, q: &[f64; 3]) -> f64 {
        let p = self.points(q);
        let segs = self.cfg.segments();
        (0..3)
            .map(|k| segs[k].mass * self.cfg.gravity * p[k][1])
            .sum()
    }
}

/// The closed-form equations of motion satisfy the Euler-Lagrange equations
/// built numerically from the independent kinematics above:
/// M qdd + (dM/dt) qd - 1/2 d(qd^T M qd)/dq + dV/dq = tau + J_hip^T F.
/// Worst residual measured: 1.5e-4 N m (finite-difference noise) against
/// torques of up to 400 N m.
#[test]
fn equations_of_motion_match_numeric_euler_lagrange() {
    let m = model();
    let kin = Kinematics {
        cfg: SimConfig::default(),
    };
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut worst: f64 = 0.0;
    for _ in 0..50 {
        let s = random_state(&mut rng, 2.0);
        let q = [s[0], s[1], s[2]];
        let qd = [s[3], s[4], s[5]];
        let tau = [
            rng.gen_range(-200.0..200.0),
            rng.gen_range(-400.0..400.0),
            rng.gen_range(-300.0..300.0),
        ];
        let f = m.perturbation(&s);
        let qdd = m.accelerations(&s, &tau, f);

        let e = 1e-3;
        let shift =
            |dir: &[f64; 3], sc: f64| [q[0] + sc * dir[0], q[1] + sc * dir[1], q[2] + sc * dir[2]];
        let mm = kin.mass_matrix(&q);
        let (mp, mn) = (
            kin.mass_matrix(&shift(&qd, e)),
            kin.mass_matrix(&shift(&qd, -e)),
        );
        let quad = |mat: &[[f64; 3]; 3]| -> f64 {
            (0..3)
                .flat_map(|i| (0..3).map(move |j| (i, j)))
                .map(|(i, j)| qd[i] * mat[i][j] * qd[j])
                .sum()
        };
        let jac_hip = kin.jacobians(&q)[3];
        for i in 0..3 {
            let mut unit = [0.0; 3];
            unit[i] = 1.0;
            let dquad = (quad(&kin.mass_matrix(&shift(&unit, e)))
                - quad(&kin.mass_matrix(&shift(&unit, -e))))
                / (2.0 * e);
            let dv =
                (kin.potential(&shift(&unit, e)) - kin.potential(&shift(&unit, -e))) / (2.0 * e);
            let mdot_qd: f64 = (0..3)
                .map(|j| (mp[i][j] - mn[i][j]) / (2.0 * e) * qd[j])
                .sum();
            let m_qdd: f64 = (0..3).map(|j| mm[i][j] * qdd[j]).sum();
            let pull = jac_hip[0][i] * f[0] + jac_hip[1][i] * f[1];
            let residual = m_qdd + mdot_qd - 0.5 * dquad + dv - tau[i] - pull;
            worst = worst.max(residual.abs());
            assert!(
                residual.abs() < 1e-3,
                "joint {i}: residual {residual} N m at {s:?}"
            );
        }
    }
    eprintln!("worst Euler-Lagrange residual {worst:e} N m");
}

#[test]
fn perturbation_pulls_backward_only_while_rising() {
    let m = model();
    // Rising: from the squat with the knee extending fast, zdot_com > 0.
    let rising = [0.5, -1.85, 2.06, 0.0, 2.0, -1.0];
    assert!(m.com(&rising).vz > 0.0);
    let f = m.perturbation(&rising);
    assert!((f[0] + 200.0 * m.com(&rising).vz).abs() < 1e-12 && f[1] == 0.0);
    let sinking = [0.5, -1.85, 2.06, 0.0, -2.0, 1.0];
    assert!(m.com(&sinking).vz < 0.0);
    assert_eq!(m.perturbation(&sinking), [0.0, 0.0]);
}

#[test]
fn com_velocity_matches_finite_difference_of_position() {
    let m = model();
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    for _ in 0..50 {
        let s = random_state(&mut rng, 2.0);
        let h = 1e-6;
        let mut sp = s;
        let mut sm = s;
        for i in 0..3 {
            sp[i] += h * s[3 + i];
            sm[i] -= h * s[3 + i];
        }
        let c = m.com(&s);
        let vx = (m.com(&sp).x - m.com(&sm).x) / (2.0 * h);
        let vz = (m.com(&sp).z - m.com(&sm).z) / (2.0 * h);
        assert!((c.vx - vx).abs() < 1e-7 && (c.vz - vz).abs() < 1e-7);
    }
}

#[test]
fn invalid_config_is_rejected() {
    let mut cfg = SimConfig::default();
    cfg.trunk.mass = -1.0;
    assert!(matches!(Model::new(&cfg), Err(SimError::InvalidConfig(_))));
    let cfg = SimConfig {
        substeps: 0,
        ..SimConfig::default()
    };
    assert!(Model::new(&cfg).is_err());
    let cfg = SimConfig {
        dt_s: f64::NAN,
        ..SimConfig::default()
    };
    assert!(Model::new(&cfg).is_err());
}

#[test]
fn config_round_trips_through_json() {
    let cfg = SimConfig::default();
    let json = serde_json::to_string(&cfg).unwrap();
    let back: SimConfig = serde_json::from_str(&json).unwrap();
    assert_eq!(cfg, back);
    let partial: SimConfig = serde_json::from_str(r#"{"perturbation_gain": 0}"#).unwrap();
    assert_eq!(partial.perturbation_gain, 0.0);
    assert_eq!(partial.q0, cfg.q0);
}

/// Eight squat-like starts under a gravity-compensating PD controller that
/// rises part way, for the block checks: the same closed loop run through
/// the scalar model and through a block. (Open-loop torques would tumble the
/// chain, which is chaotic: any two integrators part there, whatever their
/// precision. A policy is a feedback controller too.)
struct BlockCase {
    model: Model,
    starts: [State; LANES],
}

type Trace = Vec<([State; LANES], [f64; LANES], Vec<[f64; 2]>)>;

impl BlockCase {
    fn new() -> Self {
        let cfg = SimConfig::default();
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let starts = std::array::from_fn(|_| {
            let mut s = [0.0; 6];
            for i in 0..3 {
                s[i] = cfg.q0[i] + rng.gen_range(-0.05..0.05);
                s[3 + i] = rng.gen_range(-0.2..0.2);
            }
            s
        });
        Self {
            model: Model::new(&cfg).unwrap(),
            starts,
        }
    }

    /// Torque and clipped action at control step `k` in state `s`.
    fn input(&self, k: usize, s: &State) -> ([f64; 3], [f64; 3]) {
        let cfg = self.model.config();
        let (kp, kd) = ([300.0, 500.0, 400.0], [60.0, 80.0, 70.0]);
        let stand = [0.02, -0.08, 0.05];
        // Rise half way over 30 steps (the pull acts while the COM goes up),
        // then hold: the saturating torques of this simple PD cannot hold a
        // full stand-up against the pull.
        let blend = 1.0 - (k as f64 / 60.0).min(0.5);
        let g = self.model.gravity(&s[..3]);
        let a: [f64; 3] = std::array::from_fn(|i| {
            let target = cfg.q0[i] * blend + stand[i] * (1.0 - blend);
            (g[i] - kp[i] * (s[i] - target) - kd[i] * s[3 + i]) / cfg.tau_max[i]
        });
        self.model.torque(&a)
    }

    /// Scalar states, power sums and last-lane COM (x, z) per control step.
    fn scalar(&self, steps: usize) -> Trace {
        let mut s = self.starts;
        (0..steps)
            .map(|k| {
                let mut power = [0.0; LANES];
                let mut com = Vec::new();
                for lane in 0..LANES {
                    let (tau, a) = self.input(k, &s[lane]);
                    self.model.control_step(&mut s[lane], &tau, |st| {
                        power[lane] +=
                            ((a[0] * st[3]).abs() + (a[1] * st[4]).abs()) + (a[2] * st[5]).abs();
                        if lane == LANES - 1 {
                            let c = self.model.com(st);
                            com.push([c.x, c.z]);
                        }
                    });
                }
                (s, power, com)
            })
            .collect()
    }

    /// The same through a block; `libm` picks libm's trigonometry.
    fn block(&self, stepper: &BlockStepper, libm: bool, steps: usize) -> Trace {
        let lanes = |f: &dyn Fn(usize) -> f64| F64s(std::array::from_fn(f));
        let mut b = Block {
            q: std::array::from_fn(|j| lanes(&|l| self.starts[l][j])),
            qd: std::array::from_fn(|j| lanes(&|l| self.starts[l][3 + j])),
        };
        let substeps = self.model.config().substeps as usize;
        let mut com = vec![[F64s::splat(0.0); 2]; substeps];
        let states = |b: &Block| -> [State; LANES] {
            std::array::from_fn(|l| {
                std::array::from_fn(|j| if j < 3 { b.q[j].0[l] } else { b.qd[j - 3].0[l] })
            })
        };
        (0..steps)
            .map(|k| {
                let inputs: Vec<_> = states(&b).iter().map(|s| self.input(k, s)).collect();
                let tau = std::array::from_fn(|j| lanes(&|l| inputs[l].0[j]));
                let a = std::array::from_fn(|j| lanes(&|l| inputs[l].1[j]));
                let out = if libm {
                    stepper.control_step_libm(&mut b, &tau, &a, Some(&mut com))
                } else {
                    stepper.control_step(&mut b, &tau, &a, Some(&mut com))
                };
                let last = com
                    .iter()
                    .map(|xz| [xz[0].0[LANES - 1], xz[1].0[LANES - 1]]);
                (states(&b), out.power_sum.0, last.collect())
            })
            .collect()
    }
}

#[test]
fn block_with_libm_trig_is_bit_identical_to_the_scalar_model() {
    // This pins the block's arithmetic to the scalar model's, operation for
    // operation: any reordering or fused operation would change some bits.
    let case = BlockCase::new();
    let stepper = case.model.block_stepper();
    let want = case.scalar(60);
    let got = case.block(&stepper, true, 60);
    for (k, (w, g)) in want.iter().zip(&got).enumerate() {
        assert_eq!(w, g, "control step {k}");
    }
}

#[test]
fn block_stays_within_1e12_rad_of_the_scalar_model_for_an_episode() {
    let case = BlockCase::new();
    let want = case.scalar(60);
    // The closed loop keeps every lane upright for the whole 60-step episode
    // (inside the joint limits), so the comparison covers a full episode.
    let cfg = case.model.config();
    for (lane, s) in want[59].0.iter().enumerate() {
        let inside = (0..3).all(|j| (cfg.q_min[j]..=cfg.q_max[j]).contains(&s[j]));
        assert!(inside, "lane {lane} left the joint limits: {s:?}");
    }
    let mut runs = Vec::new();
    for isa in Isa::available() {
        let stepper = case.model.block_stepper().with_isa(isa);
        assert_eq!(stepper.isa(), isa);
        let got = case.block(&stepper, false, 60);
        let mut worst = 0.0f64;
        for (w, g) in want.iter().zip(&got) {
            for lane in 0..LANES {
                for j in 0..3 {
                    worst = worst.max((w.0[lane][j] - g.0[lane][j]).abs());
                }
            }
        }
        eprintln!("{isa:?}: worst angle difference {worst:e} rad over 60 control steps");
        assert!(worst <= 1e-12, "{isa:?}: angles differ by {worst:e} rad");
        // The polynomial is not libm: the paths must differ somewhere, or
        // this test is not looking at the vector path at all.
        assert!(worst > 0.0, "{isa:?}: no difference at all from libm");
        // Powers and COM paths agree closely too.
        for (w, g) in want.iter().zip(&got) {
            for lane in 0..LANES {
                assert!((w.1[lane] - g.1[lane]).abs() <= 1e-9 * w.1[lane].max(1.0));
            }
            for (a, b) in w.2.iter().zip(&g.2) {
                assert!((a[0] - b[0]).abs() < 1e-12 && (a[1] - b[1]).abs() < 1e-12);
            }
        }
        runs.push((isa, got));
    }
    // Every compiled copy gives the same bits, so a job's result does not
    // depend on which worker's CPU ran it.
    for (isa, got) in &runs[1..] {
        assert_eq!(got, &runs[0].1, "{isa:?} differs from {:?}", runs[0].0);
    }
}
