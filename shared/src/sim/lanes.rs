//! Eight f64 lanes with element-wise arithmetic, for stepping eight
//! environments at once (structure of arrays).
//!
//! Every operation is a loop over a fixed-size array marked
//! `#[inline(always)]`, so it compiles to vector instructions of whatever
//! width the enclosing function is built for (AVX-512, AVX2, or baseline
//! SSE2; see `block.rs`). Rust never contracts `a * b + c` into a fused
//! multiply-add, so all widths give the same bits, and lanes never interact.
#![allow(clippy::needless_range_loop)] // lane loops are what vectorizes
#![allow(clippy::excessive_precision)] // constants as published (fdlibm, Cephes)

use std::ops::{Add, Div, Mul, Neg, Sub};

/// Lanes per block.
pub const LANES: usize = 8;

/// Eight f64 values, one per environment of a block.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(align(64))]
pub struct F64s(pub [f64; LANES]);

impl F64s {
    /// Every lane `v`.
    #[inline(always)]
    pub fn splat(v: f64) -> Self {
        Self([v; LANES])
    }

    #[inline(always)]
    fn map(self, f: impl Fn(f64) -> f64) -> Self {
        let mut out = [0.0; LANES];
        for i in 0..LANES {
            out[i] = f(self.0[i]);
        }
        Self(out)
    }

    #[inline(always)]
    fn zip(self, o: Self, f: impl Fn(f64, f64) -> f64) -> Self {
        let mut out = [0.0; LANES];
        for i in 0..LANES {
            out[i] = f(self.0[i], o.0[i]);
        }
        Self(out)
    }

    /// Lane-wise square root (IEEE, correctly rounded like `f64::sqrt`).
    #[inline(always)]
    pub fn sqrt(self) -> Self {
        self.map(f64::sqrt)
    }

    /// Lane-wise `f64::max` (a NaN lane gives `o`).
    #[inline(always)]
    pub fn max(self, o: Self) -> Self {
        self.zip(o, f64::max)
    }

    /// Lane-wise absolute value.
    #[inline(always)]
    pub fn abs(self) -> Self {
        self.map(f64::abs)
    }
}

impl Add for F64s {
    type Output = Self;
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        self.zip(o, |a, b| a + b)
    }
}

impl Sub for F64s {
    type Output = Self;
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        self.zip(o, |a, b| a - b)
    }
}

impl Mul for F64s {
    type Output = Self;
    #[inline(always)]
    fn mul(self, o: Self) -> Self {
        self.zip(o, |a, b| a * b)
    }
}

impl Div for F64s {
    type Output = Self;
    #[inline(always)]
    fn div(self, o: Self) -> Self {
        self.zip(o, |a, b| a / b)
    }
}

impl Neg for F64s {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {
        self.map(|a| -a)
    }
}

/// Scalar times lanes, so formulas read like their scalar originals.
impl Mul<F64s> for f64 {
    type Output = F64s;
    #[inline(always)]
    fn mul(self, o: F64s) -> F64s {
        F64s::splat(self) * o
    }
}

/// How a block evaluates sine and cosine: the branch-free polynomial that
/// vectorizes ([`PolySinCos`]), or libm lane by lane ([`LibmSinCos`]), which
/// makes a block bit-identical to the scalar model (used to test that the
/// block mirrors the scalar arithmetic operation for operation).
pub trait SinCos {
    /// (sin x, cos x) per lane.
    fn sin_cos(x: F64s) -> (F64s, F64s);
}

/// libm's `sin_cos`, one lane at a time (does not vectorize).
pub struct LibmSinCos;

impl SinCos for LibmSinCos {
    #[inline(always)]
    fn sin_cos(x: F64s) -> (F64s, F64s) {
        let (mut s, mut c) = ([0.0; LANES], [0.0; LANES]);
        for i in 0..LANES {
            (s[i], c[i]) = x.0[i].sin_cos();
        }
        (F64s(s), F64s(c))
    }
}

/// Branch-free sine and cosine: Cody-Waite reduction by pi/2 with pi/2 split
/// into three parts (exact products for |x| < 2^20), then the Cephes minimax
/// polynomials on [-pi/4, pi/4] (error about 1 ulp), and the quadrant chosen
/// by bit selects. Meant for joint angles (|x| well under 1e5); non-finite
/// input gives NaN.
pub struct PolySinCos;

// 2/pi, and pi/2 = PIO2_1 + PIO2_2 + PIO2_3 (fdlibm's 33-bit split).
const TWO_OVER_PI: f64 = std::f64::consts::FRAC_2_PI;
const PIO2_1: f64 = 1.570_796_326_734_125_614_17e+00;
const PIO2_2: f64 = 6.077_100_506_303_965_976_60e-11;
const PIO2_3: f64 = 2.022_266_248_711_166_455_80e-21;
// Adding and subtracting 1.5 * 2^52 rounds to the nearest integer (ties to
// even) for |v| < 2^51, and leaves that integer in the low mantissa bits.
const ROUND_MAGIC: f64 = 6_755_399_441_055_744.0;

const SIN_COEF: [f64; 6] = [
    1.589_623_015_765_465_680_60e-10,
    -2.505_074_776_285_780_728_66e-8,
    2.755_731_362_138_572_452_13e-6,
    -1.984_126_982_958_953_859_96e-4,
    8.333_333_333_322_118_588_78e-3,
    -1.666_666_666_666_663_072_95e-1,
];
const COS_COEF: [f64; 6] = [
    -1.135_853_652_138_768_173_00e-11,
    2.087_570_084_197_473_167_78e-9,
    -2.755_731_417_929_673_881_12e-7,
    2.480_158_728_885_170_453_48e-5,
    -1.388_888_888_887_305_641_16e-3,
    4.166_666_666_666_659_292_18e-2,
];

#[inline(always)]
fn horner(z: f64, c: &[f64; 6]) -> f64 {
    let mut p = c[0];
    for &ci in &c[1..] {
        p = p * z + ci;
    }
    p
}

/// (sin x, cos x) of one value by the polynomial; the lane loop of
/// [`PolySinCos`] calls it, and the tests compare it with libm.
#[inline(always)]
pub fn poly_sin_cos(x: f64) -> (f64, f64) {
    let t = x * TWO_OVER_PI + ROUND_MAGIC;
    let quadrant = t.to_bits();
    let k = t - ROUND_MAGIC;
    let r = ((x - k * PIO2_1) - k * PIO2_2) - k * PIO2_3;
    let z = r * r;
    let s = r + r * z * horner(z, &SIN_COEF);
    let c = (1.0 - 0.5 * z) + z * z * horner(z, &COS_COEF);
    // x = k pi/2 + r: quadrant 1 is (cos r, -sin r), 2 (-sin r, -cos r),
    // 3 (-cos r, sin r). The low bits of `quadrant` are k mod 4.
    let swap = quadrant & 1 != 0;
    let (s, c) = if swap { (c, s) } else { (s, c) };
    let s_sign = (quadrant & 2) << 62;
    let c_sign = (quadrant.wrapping_add(1) & 2) << 62;
    (
        f64::from_bits(s.to_bits() ^ s_sign),
        f64::from_bits(c.to_bits() ^ c_sign),
    )
}

impl SinCos for PolySinCos {
    #[inline(always)]
    fn sin_cos(x: F64s) -> (F64s, F64s) {
        let (mut s, mut c) = ([0.0; LANES], [0.0; LANES]);
        for i in 0..LANES {
            (s[i], c[i]) = poly_sin_cos(x.0[i]);
        }
        (F64s(s), F64s(c))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Within 2 ulp of libm (at least 2^-53 absolute near zeros of the
    /// function) on a dense grid over several periods.
    #[test]
    fn poly_sin_cos_matches_libm() {
        let n = 200_000;
        let mut worst = 0.0f64;
        for i in 0..=n {
            let x = -20.0 + 40.0 * f64::from(i) / f64::from(n);
            let (s, c) = poly_sin_cos(x);
            let (rs, rc) = x.sin_cos();
            for (got, want) in [(s, rs), (c, rc)] {
                let tol = 2.0 * f64::EPSILON * want.abs().max(0.5);
                let err = (got - want).abs();
                worst = worst.max(err / tol);
                assert!(err <= tol, "x = {x}: {got} vs libm {want}");
            }
        }
        assert!(worst > 0.0, "the comparison must have looked at something");
    }

    #[test]
    fn poly_sin_cos_exact_points_and_symmetry() {
        assert_eq!(poly_sin_cos(0.0), (0.0, 1.0));
        for x in [0.1, 0.7, 1.3, 2.9, 4.4, 7.0] {
            let (s, c) = poly_sin_cos(x);
            let (sn, cn) = poly_sin_cos(-x);
            assert_eq!(sn, -s, "sin is odd at {x}");
            assert_eq!(cn, c, "cos is even at {x}");
            assert!((s * s + c * c - 1.0).abs() < 4.0 * f64::EPSILON);
        }
        let (s, c) = poly_sin_cos(f64::NAN);
        assert!(s.is_nan() && c.is_nan());
    }

    #[test]
    fn lane_ops_are_element_wise() {
        let a = F64s([1.0, -2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0]);
        let b = F64s::splat(2.0);
        assert_eq!((a + b).0[1], 0.0);
        assert_eq!((a - b).0[0], -1.0);
        assert_eq!((a * b).0[7], 16.0);
        assert_eq!((a / b).0[2], 1.5);
        assert_eq!((-a).0[1], 2.0);
        assert_eq!(a.abs().0[1], 2.0);
        assert_eq!(a.max(F64s::splat(0.0)).0[1], 0.0);
        assert_eq!(F64s::splat(9.0).sqrt(), F64s::splat(3.0));
    }
}
