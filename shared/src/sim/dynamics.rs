//! Closed-form rigid-body dynamics of the 3-link chain (docs/science.md#equations-of-motion):
//! M(q) q'' + C(q, q') q' + G(q) = tau + J_hip(q)^T F_pert.
//!
//! The terms are derived in absolute segment angles th = S q (S the lower
//! triangular matrix of ones), where the mass matrix has the simple form
//! `Ma_ij = a_ij cos(th_i - th_j)`, and mapped to the relative joint angles
//! q by M = S^T Ma S, C q' = S^T h, G = S^T Ga. All of it is stack-only
//! arithmetic on `[f64; 3]`, so stepping allocates nothing.
#![allow(clippy::needless_range_loop)] // index loops mirror the matrix formulas

use super::{SimConfig, SimError};

/// Joint-space state [q1, q2, q3, q1', q2', q3'] (rad, rad/s).
pub type State = [f64; 6];

/// A 3x3 matrix, row-major.
pub type Mat3 = [[f64; 3]; 3];

/// Per-model constants of the equations of motion, as `Model` computes them
/// (`Model::block_constants`) for a block of eight environments (`block.rs`).
#[derive(Clone, Debug)]
pub(super) struct BlockConstants {
    pub d: [f64; 3],
    pub a12: f64,
    pub a13: f64,
    pub a23: f64,
    /// -g * gcoef_i (gravity torque per sine of the absolute angle).
    pub neg_g_gcoef: [f64; 3],
    pub shank: f64,
    pub thigh: f64,
    /// Mass-weighted lever arm of each absolute angle on the COM.
    pub lever: [f64; 3],
    pub inv_mass: f64,
    /// -perturbation_gain.
    pub neg_gain: f64,
    /// RK4 sub-step (s).
    pub h: f64,
    pub substeps: u32,
}

/// The body model with every constant of the equations of motion
/// precomputed from a [`SimConfig`].
#[derive(Clone, Debug)]
pub struct Model {
    cfg: SimConfig,
    /// Diagonal of the absolute-angle mass matrix.
    d: [f64; 3],
    /// Off-diagonal coefficients a12, a13, a23 of Ma_ij = a_ij cos(th_i - th_j).
    a12: f64,
    a13: f64,
    a23: f64,
    /// Gravity coefficients: Ga_i = -g * gcoef_i * sin th_i.
    gcoef: [f64; 3],
    /// Segment masses and COM offsets, for the body COM.
    m: [f64; 3],
    total_mass: f64,
    h_stand: f64,
}

/// Body centre of mass and its velocity (m, m/s).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Com {
    pub x: f64,
    pub z: f64,
    pub vx: f64,
    pub vz: f64,
}

impl Com {
    /// Speed |v_com| (m/s).
    pub fn speed(&self) -> f64 {
        self.vx.hypot(self.vz)
    }
}

/// Sines and cosines of the absolute segment angles, computed once per
/// evaluation: trigonometry dominates the cost of a step, and every term of
/// the dynamics needs only these (differences via the angle-sum identities).
#[derive(Clone, Copy)]
struct Trig {
    sn: [f64; 3],
    cs: [f64; 3],
}

impl Trig {
    #[inline]
    fn new(q: &[f64]) -> Self {
        let th = absolute_angles(q);
        let (s0, c0) = th[0].sin_cos();
        let (s1, c1) = th[1].sin_cos();
        let (s2, c2) = th[2].sin_cos();
        Self {
            sn: [s0, s1, s2],
            cs: [c0, c1, c2],
        }
    }

    /// cos(th_i - th_j)
    #[inline]
    fn cos_diff(&self, i: usize, j: usize) -> f64 {
        self.cs[i] * self.cs[j] + self.sn[i] * self.sn[j]
    }

    /// sin(th_i - th_j)
    #[inline]
    fn sin_diff(&self, i: usize, j: usize) -> f64 {
        self.sn[i] * self.cs[j] - self.cs[i] * self.sn[j]
    }
}

#[inline]
fn absolute_angles(q: &[f64]) -> [f64; 3] {
    [q[0], q[0] + q[1], q[0] + q[1] + q[2]]
}

/// S^T x: a vector of absolute-angle generalized forces to joint space.
#[inline]
fn st_mul(x: [f64; 3]) -> [f64; 3] {
    [x[0] + x[1] + x[2], x[1] + x[2], x[2]]
}

impl Model {
    /// Precomputes the model; fails on parameters that [`SimConfig::validate`] rejects.
    pub fn new(cfg: &SimConfig) -> Result<Self, SimError> {
        cfg.validate()?;
        let [s1, s2, s3] = cfg.segments();
        let (m1, m2, m3) = (s1.mass, s2.mass, s3.mass);
        let (l1, l2) = (s1.length, s2.length);
        let (c1, c2, c3) = (s1.com, s2.com, s3.com);
        let total_mass = m1 + m2 + m3;
        let h_stand = (m1 * c1 + m2 * (l1 + c2) + m3 * (l1 + l2 + c3)) / total_mass;
        Ok(Self {
            cfg: cfg.clone(),
            d: [
                s1.inertia + m1 * c1 * c1 + (m2 + m3) * l1 * l1,
                s2.inertia + m2 * c2 * c2 + m3 * l2 * l2,
                s3.inertia + m3 * c3 * c3,
            ],
            a12: (m2 * c2 + m3 * l2) * l1,
            a13: m3 * c3 * l1,
            a23: m3 * c3 * l2,
            gcoef: [m1 * c1 + (m2 + m3) * l1, m2 * c2 + m3 * l2, m3 * c3],
            m: [m1, m2, m3],
            total_mass,
            h_stand,
        })
    }

    /// The constants a block of eight environments needs (`block.rs`), each
    /// computed by the same expression as in the scalar methods below so the
    /// two paths round alike.
    pub(super) fn block_constants(&self) -> BlockConstants {
        let [s1, s2, s3] = self.cfg.segments();
        let g = self.cfg.gravity;
        BlockConstants {
            d: self.d,
            a12: self.a12,
            a13: self.a13,
            a23: self.a23,
            neg_g_gcoef: [-g * self.gcoef[0], -g * self.gcoef[1], -g * self.gcoef[2]],
            shank: self.cfg.shank.length,
            thigh: self.cfg.thigh.length,
            lever: [
                self.m[0] * s1.com + (self.m[1] + self.m[2]) * s1.length,
                self.m[1] * s2.com + self.m[2] * s2.length,
                self.m[2] * s3.com,
            ],
            inv_mass: 1.0 / self.total_mass,
            neg_gain: -self.cfg.perturbation_gain,
            h: self.cfg.dt_s,
            substeps: self.cfg.substeps,
        }
    }

    /// The configuration this model was built from.
    pub fn config(&self) -> &SimConfig {
        &self.cfg
    }

    /// Standing COM height h_stand: the COM height at q = 0 (docs/science.md#segments).
    pub fn h_stand(&self) -> f64 {
        self.h_stand
    }

    /// Total mass of the three segments (kg).
    pub fn total_mass(&self) -> f64 {
        self.total_mass
    }

    fn mass_matrix_abs(&self, tr: &Trig) -> Mat3 {
        let m12 = self.a12 * tr.cos_diff(0, 1);
        let m13 = self.a13 * tr.cos_diff(0, 2);
        let m23 = self.a23 * tr.cos_diff(1, 2);
        [
            [self.d[0], m12, m13],
            [m12, self.d[1], m23],
            [m13, m23, self.d[2]],
        ]
    }

    /// Joint-space mass matrix M(q) = S^T Ma(S q) S.
    pub fn mass_matrix(&self, q: &[f64]) -> Mat3 {
        self.mass_matrix_t(&Trig::new(q))
    }

    #[inline]
    fn mass_matrix_t(&self, tr: &Trig) -> Mat3 {
        let ma = self.mass_matrix_abs(tr);
        // (S^T Ma S)_ij = sum_{k >= i, l >= j} Ma_kl.
        // Computed for j >= i and mirrored, so M is exactly symmetric.
        let mut m = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in i..3 {
                let sum: f64 = ma[i..].iter().flat_map(|row| &row[j..]).sum();
                m[i][j] = sum;
                m[j][i] = sum;
            }
        }
        m
    }

    /// Velocity-product terms C(q, q') q' (Coriolis and centrifugal).
    pub fn coriolis(&self, q: &[f64], qd: &[f64]) -> [f64; 3] {
        self.coriolis_t(&Trig::new(q), qd)
    }

    #[inline]
    fn coriolis_t(&self, tr: &Trig, qd: &[f64]) -> [f64; 3] {
        let w = absolute_angles(qd);
        let s12 = tr.sin_diff(0, 1);
        let s13 = tr.sin_diff(0, 2);
        let s23 = tr.sin_diff(1, 2);
        // h_i = sum_j a_ij sin(th_i - th_j) w_j^2 (Euler-Lagrange of Ma).
        st_mul([
            self.a12 * s12 * w[1] * w[1] + self.a13 * s13 * w[2] * w[2],
            -self.a12 * s12 * w[0] * w[0] + self.a23 * s23 * w[2] * w[2],
            -self.a13 * s13 * w[0] * w[0] - self.a23 * s23 * w[1] * w[1],
        ])
    }

    /// Gravity terms G(q) = dV/dq.
    pub fn gravity(&self, q: &[f64]) -> [f64; 3] {
        self.gravity_t(&Trig::new(q))
    }

    #[inline]
    fn gravity_t(&self, tr: &Trig) -> [f64; 3] {
        let g = self.cfg.gravity;
        st_mul([
            -g * self.gcoef[0] * tr.sn[0],
            -g * self.gcoef[1] * tr.sn[1],
            -g * self.gcoef[2] * tr.sn[2],
        ])
    }

    /// J_hip(q)^T F for a force F = (fx, fz) applied at the hip.
    pub fn hip_force_to_joint(&self, q: &[f64], f: [f64; 2]) -> [f64; 3] {
        self.hip_force_t(&Trig::new(q), f)
    }

    #[inline]
    fn hip_force_t(&self, tr: &Trig, f: [f64; 2]) -> [f64; 3] {
        let (l1, l2) = (self.cfg.shank.length, self.cfg.thigh.length);
        // d hip / d th_i = L_i (cos th_i, -sin th_i) for i = 1, 2; 0 for the trunk.
        let p = |l: f64, i: usize| l * (f[0] * tr.cs[i] - f[1] * tr.sn[i]);
        st_mul([p(l1, 0), p(l2, 1), 0.0])
    }

    /// Hip position (m).
    pub fn hip(&self, q: &[f64]) -> [f64; 2] {
        let th = absolute_angles(q);
        let (l1, l2) = (self.cfg.shank.length, self.cfg.thigh.length);
        [
            l1 * th[0].sin() + l2 * th[1].sin(),
            l1 * th[0].cos() + l2 * th[1].cos(),
        ]
    }

    /// Positions of the three segment centres of mass (m).
    pub fn segment_coms(&self, q: &[f64]) -> [[f64; 2]; 3] {
        let th = absolute_angles(q);
        let [s1, s2, s3] = self.cfg.segments();
        let u = |t: f64| [t.sin(), t.cos()];
        let (u1, u2, u3) = (u(th[0]), u(th[1]), u(th[2]));
        let knee = [s1.length * u1[0], s1.length * u1[1]];
        let hip = [knee[0] + s2.length * u2[0], knee[1] + s2.length * u2[1]];
        [
            [s1.com * u1[0], s1.com * u1[1]],
            [knee[0] + s2.com * u2[0], knee[1] + s2.com * u2[1]],
            [hip[0] + s3.com * u3[0], hip[1] + s3.com * u3[1]],
        ]
    }

    /// Body COM position and velocity for a state.
    pub fn com(&self, s: &State) -> Com {
        self.com_t(&Trig::new(&s[..3]), &s[3..])
    }

    #[inline]
    fn com_t(&self, tr: &Trig, qd: &[f64]) -> Com {
        let w = absolute_angles(qd);
        let [s1, s2, s3] = self.cfg.segments();
        let (sn, cs) = (tr.sn, tr.cs);
        // Mass-weighted lever arm of each absolute angle on the COM.
        let lever = [
            self.m[0] * s1.com + (self.m[1] + self.m[2]) * s1.length,
            self.m[1] * s2.com + self.m[2] * s2.length,
            self.m[2] * s3.com,
        ];
        let mut c = Com {
            x: 0.0,
            z: 0.0,
            vx: 0.0,
            vz: 0.0,
        };
        for i in 0..3 {
            c.x += lever[i] * sn[i];
            c.z += lever[i] * cs[i];
            c.vx += lever[i] * cs[i] * w[i];
            c.vz -= lever[i] * sn[i] * w[i];
        }
        let inv = 1.0 / self.total_mass;
        c.x *= inv;
        c.z *= inv;
        c.vx *= inv;
        c.vz *= inv;
        c
    }

    /// The perturbation force at the hip for a state (docs/science.md#the-pull).
    pub fn perturbation(&self, s: &State) -> [f64; 2] {
        self.perturbation_t(&Trig::new(&s[..3]), &s[3..])
    }

    #[inline]
    fn perturbation_t(&self, tr: &Trig, qd: &[f64]) -> [f64; 2] {
        let vz = self.com_t(tr, qd).vz;
        [-self.cfg.perturbation_gain * vz.max(0.0), 0.0]
    }

    /// Joint accelerations q'' for joint torques `tau` and hip force `f_hip`.
    pub fn accelerations(&self, s: &State, tau: &[f64; 3], f_hip: [f64; 2]) -> [f64; 3] {
        self.accelerations_t(&Trig::new(&s[..3]), &s[3..], tau, f_hip)
    }

    #[inline]
    fn accelerations_t(&self, tr: &Trig, qd: &[f64], tau: &[f64; 3], f_hip: [f64; 2]) -> [f64; 3] {
        let m = self.mass_matrix_t(tr);
        let c = self.coriolis_t(tr, qd);
        let g = self.gravity_t(tr);
        let p = self.hip_force_t(tr, f_hip);
        let rhs = [
            tau[0] + p[0] - c[0] - g[0],
            tau[1] + p[1] - c[1] - g[1],
            tau[2] + p[2] - c[2] - g[2],
        ];
        solve_spd3(&m, rhs)
    }

    /// The state derivative with the perturbation evaluated from `s` itself.
    #[inline]
    pub fn derivative(&self, s: &State, tau: &[f64; 3]) -> State {
        let tr = Trig::new(&s[..3]);
        let qd = &s[3..];
        let qdd = self.accelerations_t(&tr, qd, tau, self.perturbation_t(&tr, qd));
        [s[3], s[4], s[5], qdd[0], qdd[1], qdd[2]]
    }

    /// Kinetic energy (J).
    pub fn kinetic_energy(&self, s: &State) -> f64 {
        let m = self.mass_matrix(&s[..3]);
        let qd = &s[3..];
        let mut t = 0.0;
        for i in 0..3 {
            for j in 0..3 {
                t += 0.5 * qd[i] * m[i][j] * qd[j];
            }
        }
        t
    }

    /// Potential energy (J), zero at the ankle height.
    pub fn potential_energy(&self, q: &[f64]) -> f64 {
        self.cfg.gravity * self.total_mass * self.com(&[q[0], q[1], q[2], 0.0, 0.0, 0.0]).z
    }
}

/// Solves M x = b for a symmetric positive definite 3x3 M by Cholesky.
#[inline]
pub fn solve_spd3(m: &Mat3, b: [f64; 3]) -> [f64; 3] {
    let l11 = m[0][0].sqrt();
    let l21 = m[1][0] / l11;
    let l31 = m[2][0] / l11;
    let l22 = (m[1][1] - l21 * l21).sqrt();
    let l32 = (m[2][1] - l31 * l21) / l22;
    let l33 = (m[2][2] - l31 * l31 - l32 * l32).sqrt();
    let y1 = b[0] / l11;
    let y2 = (b[1] - l21 * y1) / l22;
    let y3 = (b[2] - l31 * y1 - l32 * y2) / l33;
    let x3 = y3 / l33;
    let x2 = (y2 - l32 * x3) / l22;
    let x1 = (y1 - l21 * x2 - l31 * x3) / l11;
    [x1, x2, x3]
}
