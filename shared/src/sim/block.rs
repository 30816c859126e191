//! Eight environments' body models stepped together (structure of arrays).
//!
//! The arithmetic mirrors the scalar model in `dynamics.rs` and
//! `integrate.rs` operation for operation, so with libm's trigonometry a
//! block reproduces the scalar path bit for bit (a test checks that). The
//! production path swaps libm for the branch-free polynomial of `lanes.rs`,
//! which vectorizes; it stays within a few ulp of libm per call, and within
//! 1e-12 rad of the scalar path over a 60-step episode (tested).
//!
//! The body is compiled three times, for AVX-512, AVX2 and baseline x86-64
//! (or the target's baseline elsewhere), and the widest one the CPU has is
//! picked once at run time. Rust does not fuse multiply-adds on its own, so
//! the three give identical bits (tested): a job's result does not depend on
//! which machine of a cluster ran it.

use super::dynamics::{BlockConstants, Model};
use super::lanes::{F64s, LibmSinCos, PolySinCos, SinCos, LANES};

/// The joint states of eight environments: `q[j].0[lane]` is joint j of
/// environment `lane`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Block {
    pub q: [F64s; 3],
    pub qd: [F64s; 3],
}

/// Which compiled copy of the block step runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Isa {
    /// 512-bit vectors (one instruction per lane group of eight).
    Avx512,
    /// 256-bit vectors.
    Avx2,
    /// The target's baseline (SSE2 on x86-64).
    Portable,
}

impl Isa {
    /// The widest copy this CPU can run.
    pub fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                return Isa::Avx512;
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                return Isa::Avx2;
            }
        }
        Isa::Portable
    }

    /// Every copy this CPU can run (for tests and benchmarks).
    pub fn available() -> Vec<Self> {
        let mut out = vec![Isa::Portable];
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") {
                out.push(Isa::Avx2);
            }
            if std::arch::is_x86_feature_detected!("avx512f") {
                out.push(Isa::Avx512);
            }
        }
        out
    }
}

/// Steps blocks of eight environments of one model.
#[derive(Clone, Debug)]
pub struct BlockStepper {
    c: BlockConstants,
    isa: Isa,
}

/// What one control step of a block produced besides the new states.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BlockStep {
    /// Sum over sub-steps of sum_i |a_i q'_i| (the power effort before
    /// dividing by the sub-step count; see `EffortTerm::Power`).
    pub power_sum: F64s,
}

impl Model {
    /// A stepper for blocks of this model, using the widest vector unit found.
    pub fn block_stepper(&self) -> BlockStepper {
        BlockStepper {
            c: self.block_constants(),
            isa: Isa::detect(),
        }
    }
}

impl BlockStepper {
    /// Number of environments per block.
    pub const LANES: usize = LANES;

    /// The same stepper forced onto one compiled copy (which must be in
    /// [`Isa::available`]; others fall back to `Portable`).
    pub fn with_isa(mut self, isa: Isa) -> Self {
        self.isa = if Isa::available().contains(&isa) {
            isa
        } else {
            Isa::Portable
        };
        self
    }

    /// The compiled copy in use.
    pub fn isa(&self) -> Isa {
        self.isa
    }

    /// One control step: `substeps` RK4 sub-steps with torques `tau` (and
    /// clipped actions `a`, for the power effort) held. When `com` is given
    /// (length `substeps`), entry k receives the COM (x, z) after sub-step k.
    pub fn control_step(
        &self,
        b: &mut Block,
        tau: &[F64s; 3],
        a: &[F64s; 3],
        com: Option<&mut [[F64s; 2]]>,
    ) -> BlockStep {
        match self.isa {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `isa` is Avx512 only when the CPU reported avx512f.
            Isa::Avx512 => unsafe { step_avx512(&self.c, b, tau, a, com) },
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `isa` is Avx2 only when the CPU reported avx2.
            Isa::Avx2 => unsafe { step_avx2(&self.c, b, tau, a, com) },
            _ => control_step_body::<PolySinCos>(&self.c, b, tau, a, com),
        }
    }

    /// The same step with libm's sine and cosine: bit-identical to the
    /// scalar model, and slower. For tests.
    pub fn control_step_libm(
        &self,
        b: &mut Block,
        tau: &[F64s; 3],
        a: &[F64s; 3],
        com: Option<&mut [[F64s; 2]]>,
    ) -> BlockStep {
        control_step_body::<LibmSinCos>(&self.c, b, tau, a, com)
    }
}

/// The polynomial step compiled for one vector extension.
macro_rules! step_for {
    ($name:ident, $features:literal) => {
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = $features)]
        fn $name(
            c: &BlockConstants,
            b: &mut Block,
            tau: &[F64s; 3],
            a: &[F64s; 3],
            com: Option<&mut [[F64s; 2]]>,
        ) -> BlockStep {
            control_step_body::<PolySinCos>(c, b, tau, a, com)
        }
    };
}

step_for!(step_avx512, "avx512f");
step_for!(step_avx2, "avx2");

#[inline(always)]
fn control_step_body<T: SinCos>(
    c: &BlockConstants,
    b: &mut Block,
    tau: &[F64s; 3],
    a: &[F64s; 3],
    mut com: Option<&mut [[F64s; 2]]>,
) -> BlockStep {
    let mut power = F64s::splat(0.0);
    for k in 0..c.substeps as usize {
        rk4_substep::<T>(c, b, tau);
        // Same order as the scalar sum over joints of |a_i q'_i|.
        power =
            power + (((a[0] * b.qd[0]).abs() + (a[1] * b.qd[1]).abs()) + (a[2] * b.qd[2]).abs());
        if let Some(out) = com.as_deref_mut() {
            out[k] = com_xz::<T>(c, &b.q);
        }
    }
    BlockStep { power_sum: power }
}

#[inline(always)]
fn rk4_substep<T: SinCos>(c: &BlockConstants, b: &mut Block, tau: &[F64s; 3]) {
    let h = c.h;
    let half = F64s::splat(0.5 * h);
    let full = F64s::splat(h);
    let stage = |dt: F64s, q: &[F64s; 3], qd: &[F64s; 3], kq: &[F64s; 3], kqd: &[F64s; 3]| {
        let mut sq = *q;
        let mut sqd = *qd;
        for i in 0..3 {
            sq[i] = q[i] + dt * kq[i];
            sqd[i] = qd[i] + dt * kqd[i];
        }
        (sq, sqd)
    };
    let (q, qd) = (b.q, b.qd);
    let k1 = (qd, accelerations::<T>(c, &q, &qd, tau));
    let (q2, qd2) = stage(half, &q, &qd, &k1.0, &k1.1);
    let k2 = (qd2, accelerations::<T>(c, &q2, &qd2, tau));
    let (q3, qd3) = stage(half, &q, &qd, &k2.0, &k2.1);
    let k3 = (qd3, accelerations::<T>(c, &q3, &qd3, tau));
    let (q4, qd4) = stage(full, &q, &qd, &k3.0, &k3.1);
    let k4 = (qd4, accelerations::<T>(c, &q4, &qd4, tau));
    let w = F64s::splat(h / 6.0);
    let two = F64s::splat(2.0);
    for i in 0..3 {
        b.q[i] = b.q[i] + w * (((k1.0[i] + two * k2.0[i]) + two * k3.0[i]) + k4.0[i]);
        b.qd[i] = b.qd[i] + w * (((k1.1[i] + two * k2.1[i]) + two * k3.1[i]) + k4.1[i]);
    }
}

/// Sines and cosines of the absolute segment angles.
#[inline(always)]
fn trig<T: SinCos>(q: &[F64s; 3]) -> ([F64s; 3], [F64s; 3]) {
    let th1 = q[0] + q[1];
    let (s0, c0) = T::sin_cos(q[0]);
    let (s1, c1) = T::sin_cos(th1);
    let (s2, c2) = T::sin_cos(th1 + q[2]);
    ([s0, s1, s2], [c0, c1, c2])
}

#[inline(always)]
fn com_xz<T: SinCos>(c: &BlockConstants, q: &[F64s; 3]) -> [F64s; 2] {
    let (sn, cs) = trig::<T>(q);
    let l = c.lever;
    let x = ((l[0] * sn[0] + l[1] * sn[1]) + l[2] * sn[2]) * F64s::splat(c.inv_mass);
    let z = ((l[0] * cs[0] + l[1] * cs[1]) + l[2] * cs[2]) * F64s::splat(c.inv_mass);
    [x, z]
}

/// Joint accelerations with the perturbation evaluated from the state itself
/// (`Model::derivative`, lane-wise).
#[inline(always)]
fn accelerations<T: SinCos>(
    c: &BlockConstants,
    q: &[F64s; 3],
    qd: &[F64s; 3],
    tau: &[F64s; 3],
) -> [F64s; 3] {
    let (sn, cs) = trig::<T>(q);
    let cos_diff = |i: usize, j: usize| cs[i] * cs[j] + sn[i] * sn[j];
    let sin_diff = |i: usize, j: usize| sn[i] * cs[j] - cs[i] * sn[j];

    // Mass matrix: M = S^T Ma S with Ma_ij = a_ij cos(th_i - th_j).
    let (d0, d1, d2) = (
        F64s::splat(c.d[0]),
        F64s::splat(c.d[1]),
        F64s::splat(c.d[2]),
    );
    let m12 = c.a12 * cos_diff(0, 1);
    let m13 = c.a13 * cos_diff(0, 2);
    let m23 = c.a23 * cos_diff(1, 2);
    // Sums over the lower-right blocks of Ma in row-major order, as the
    // scalar `mass_matrix_t` adds them.
    let mm00 = (((((((d0 + m12) + m13) + m12) + d1) + m23) + m13) + m23) + d2;
    let mm01 = ((((m12 + m13) + d1) + m23) + m23) + d2;
    let mm02 = (m13 + m23) + d2;
    let mm11 = ((d1 + m23) + m23) + d2;
    let mm12 = m23 + d2;
    let mm22 = d2;

    // Velocity-product terms, in absolute angular velocities w.
    let w0 = qd[0];
    let w1 = qd[0] + qd[1];
    let w2 = w1 + qd[2];
    let (s12, s13, s23) = (sin_diff(0, 1), sin_diff(0, 2), sin_diff(1, 2));
    let h0 = c.a12 * s12 * w1 * w1 + c.a13 * s13 * w2 * w2;
    let h1 = -c.a12 * s12 * w0 * w0 + c.a23 * s23 * w2 * w2;
    let h2 = -c.a13 * s13 * w0 * w0 - c.a23 * s23 * w1 * w1;
    let cor = [(h0 + h1) + h2, h1 + h2, h2];

    // Gravity.
    let g0 = c.neg_g_gcoef[0] * sn[0];
    let g1 = c.neg_g_gcoef[1] * sn[1];
    let g2 = c.neg_g_gcoef[2] * sn[2];
    let grav = [(g0 + g1) + g2, g1 + g2, g2];

    // The pull at the hip: -gain * max(vz_com, 0) horizontally, none vertically.
    let l = c.lever;
    let zero = F64s::splat(0.0);
    let vz = (((zero - l[0] * sn[0] * w0) - l[1] * sn[1] * w1) - l[2] * sn[2] * w2)
        * F64s::splat(c.inv_mass);
    let fx = c.neg_gain * vz.max(zero);
    let fz = zero;
    let p0 = c.shank * (fx * cs[0] - fz * sn[0]);
    let p1 = c.thigh * (fx * cs[1] - fz * sn[1]);
    let pull = [(p0 + p1) + zero, p1 + zero, zero];

    let rhs = [
        ((tau[0] + pull[0]) - cor[0]) - grav[0],
        ((tau[1] + pull[1]) - cor[1]) - grav[1],
        ((tau[2] + pull[2]) - cor[2]) - grav[2],
    ];

    // Cholesky solve, as `solve_spd3`.
    let l11 = mm00.sqrt();
    let l21 = mm01 / l11;
    let l31 = mm02 / l11;
    let l22 = (mm11 - l21 * l21).sqrt();
    let l32 = (mm12 - l31 * l21) / l22;
    let l33 = ((mm22 - l31 * l31) - l32 * l32).sqrt();
    let y1 = rhs[0] / l11;
    let y2 = (rhs[1] - l21 * y1) / l22;
    let y3 = ((rhs[2] - l31 * y1) - l32 * y2) / l33;
    let x3 = y3 / l33;
    let x2 = (y2 - l32 * x3) / l22;
    let x1 = ((y1 - l21 * x2) - l31 * x3) / l11;
    [x1, x2, x3]
}
