//! The floating-point types the networks run in. Training runs the networks
//! in `f32` (twice the matrix-multiply throughput of `f64`, and a cheaper
//! tanh); the gradient checks run the same code in `f64`. Everything outside
//! the networks (losses, log-densities, normalization, GAE, Adam's master
//! copy of the parameters) stays `f64`.

use std::fmt::Debug;
use std::ops::{Add, AddAssign, Div, Mul, MulAssign, Sub};

use super::linalg::MatRef;

/// A network scalar: `f32` or `f64`.
pub trait Real:
    Copy
    + Default
    + Debug
    + PartialEq
    + PartialOrd
    + Send
    + Sync
    + 'static
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + AddAssign
    + MulAssign
{
    /// 0.
    const ZERO: Self;
    /// 1.
    const ONE: Self;
    /// Nearest value (rounding for `f32`).
    fn from_f64(x: f64) -> Self;
    /// Exact widening.
    fn to_f64(self) -> f64;
    /// `C = alpha * A * B + beta * C`, `C` column-major (see `linalg::gemm`).
    fn gemm(alpha: Self, a: MatRef<'_, Self>, b: MatRef<'_, Self>, beta: Self, c: &mut [Self]);
    /// Elementwise tanh in place.
    fn tanh_in_place(xs: &mut [Self]);
}

impl Real for f64 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
    fn from_f64(x: f64) -> Self {
        x
    }
    fn to_f64(self) -> f64 {
        self
    }
    fn gemm(alpha: Self, a: MatRef<'_, Self>, b: MatRef<'_, Self>, beta: Self, c: &mut [Self]) {
        super::linalg::dgemm(alpha, a, b, beta, c);
    }
    fn tanh_in_place(xs: &mut [Self]) {
        tanh_f64(xs);
    }
}

impl Real for f32 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
    fn from_f64(x: f64) -> Self {
        x as f32
    }
    fn to_f64(self) -> f64 {
        f64::from(self)
    }
    fn gemm(alpha: Self, a: MatRef<'_, Self>, b: MatRef<'_, Self>, beta: Self, c: &mut [Self]) {
        super::linalg::sgemm(alpha, a, b, beta, c);
    }
    fn tanh_in_place(xs: &mut [Self]) {
        tanh_f32(xs);
    }
}

/// Runs a slice kernel in the widest vector unit the CPU has. The kernels
/// are plain loops the compiler vectorizes; Rust never contracts `a * b + c`
/// into FMA on its own, and an explicit `mul_add` is correctly rounded
/// everywhere (one instruction with FMA, a libm call without), so every
/// variant gives bit-identical results.
macro_rules! dispatch {
    ($name:ident, $portable:ident, $t:ty) => {
        fn $name(xs: &mut [$t]) {
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx512f,fma")]
                unsafe fn wide512(xs: &mut [$t]) {
                    $portable(xs);
                }
                #[target_feature(enable = "avx2,fma")]
                unsafe fn wide256(xs: &mut [$t]) {
                    $portable(xs);
                }
                use std::arch::is_x86_feature_detected as has;
                if has!("avx512f") && has!("fma") {
                    // SAFETY: the CPU supports AVX-512F and FMA, checked just above.
                    unsafe { wide512(xs) };
                    return;
                }
                if has!("avx2") && has!("fma") {
                    // SAFETY: the CPU supports AVX2 and FMA, checked just above.
                    unsafe { wide256(xs) };
                    return;
                }
            }
            $portable(xs);
        }
    };
}

/// Runs `f` compiled for the widest vector unit the CPU has, so the plain
/// element-wise loops inside it (inlined into the wrapper) vectorize to
/// 512 or 256 bits instead of the 128-bit baseline. For loops of IEEE
/// operations without fused multiply-adds every width gives the same bits.
#[inline(always)]
pub(crate) fn on_widest<R>(f: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx512f")]
        fn wide512<R>(f: impl FnOnce() -> R) -> R {
            f()
        }
        #[target_feature(enable = "avx2")]
        fn wide256<R>(f: impl FnOnce() -> R) -> R {
            f()
        }
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU supports AVX-512F, checked just above.
            return unsafe { wide512(f) };
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2, checked just above.
            return unsafe { wide256(f) };
        }
    }
    f()
}

dispatch!(tanh_f64, tanh_f64_portable, f64);
dispatch!(tanh_f32, tanh_f32_portable, f32);

/// libm's scalar `tanh` took half of the training time, so this is a
/// branch-free form the compiler vectorizes: `tanh(x) = (e - 1) / (e + 1)`
/// with `e = exp(2x)` from a range-reduced Taylor polynomial. Absolute
/// error below 1e-15; the backward pass uses `1 - y^2` of the value actually
/// produced.
#[inline(always)]
fn tanh_f64_portable(xs: &mut [f64]) {
    for v in xs.iter_mut() {
        let e = exp_f64(2.0 * v.clamp(-20.0, 20.0));
        *v = (e - 1.0) / (e + 1.0);
    }
}

/// exp(x) for |x| <= 40: x = k ln2 + r with |r| <= ln2 / 2, exp(r) by a
/// degree-13 Taylor polynomial (truncation error < 2e-17 relative), and 2^k
/// assembled from its exponent bits.
#[inline(always)]
fn exp_f64(x: f64) -> f64 {
    const LN2_HI: f64 = 6.931_471_803_691_238e-1;
    const LN2_LO: f64 = 1.908_214_929_270_587_7e-10;
    // Round to nearest by the 1.5 * 2^52 trick (vectorizes on plain SSE2,
    // unlike `f64::round`); the integer lands in the low mantissa bits.
    const MAGIC: f64 = 6_755_399_441_055_744.0;
    let kf = x * std::f64::consts::LOG2_E + MAGIC;
    let ki = (kf.to_bits() as i64).wrapping_sub(MAGIC.to_bits() as i64);
    let k = kf - MAGIC;
    let r = (x - k * LN2_HI) - k * LN2_LO;
    let mut p = 1.0 / 6_227_020_800.0; // 1/13!
    for c in [
        1.0 / 479_001_600.0,
        1.0 / 39_916_800.0,
        1.0 / 3_628_800.0,
        1.0 / 362_880.0,
        1.0 / 40_320.0,
        1.0 / 5_040.0,
        1.0 / 720.0,
        1.0 / 120.0,
        1.0 / 24.0,
        1.0 / 6.0,
        0.5,
        1.0,
        1.0,
    ] {
        p = p * r + c;
    }
    p * f64::from_bits(((ki + 1023) as u64) << 52)
}

/// `f32` version: a rational minimax approximation (odd degree-13
/// numerator over even degree-6 denominator, the coefficients Eigen uses),
/// with |x| clamped to 7.9 where it reaches 1 in f32, the polynomials by
/// fused multiply-adds. One division and no
/// exponential: cheaper than `(e - 1) / (e + 1)`, which it replaced (tanh
/// was an eighth of the training time). Absolute error below 3e-7 (5 f32
/// ulp near 1; most of it is 1 - tanh(7.9) at the clamp).
#[inline(always)]
fn tanh_f32_portable(xs: &mut [f32]) {
    const CLAMP: f32 = 7.905_311;
    const NUM: [f32; 7] = [
        -2.760_768_5e-16,
        2.000_188e-13,
        -8.604_672e-11,
        5.122_297e-8,
        1.485_722_4e-5,
        6.372_619_3e-4,
        4.893_524_6e-3,
    ];
    const DEN: [f32; 4] = [1.198_258_4e-6, 1.185_347_1e-4, 2.268_434_7e-3, 4.893_525e-3];
    for v in xs.iter_mut() {
        let x = v.clamp(-CLAMP, CLAMP);
        let x2 = x * x;
        let mut p = NUM[0];
        for &c in &NUM[1..] {
            p = p.mul_add(x2, c);
        }
        let mut q = DEN[0];
        for &c in &DEN[1..] {
            q = q.mul_add(x2, c);
        }
        *v = x * p / q;
    }
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)] // index loops read clearer in checks
mod tests {
    use super::*;

    fn grid() -> Vec<f64> {
        (-4000..=4000)
            .map(|i| f64::from(i) * 0.00731)
            .chain([0.0, 1e-300, -25.0, 700.0, -700.0, 9.99, -10.5])
            .collect()
    }

    #[test]
    fn fast_tanh_f64_matches_libm() {
        let xs = grid();
        let mut ys = xs.clone();
        f64::tanh_in_place(&mut ys);
        let worst = xs
            .iter()
            .zip(&ys)
            .map(|(x, y)| (y - x.tanh()).abs())
            .fold(0.0, f64::max);
        assert!(worst < 1e-15, "worst abs error {worst}");
    }

    #[test]
    fn fast_tanh_f32_matches_libm() {
        let xs: Vec<f32> = grid().iter().map(|&x| x as f32).collect();
        let mut ys = xs.clone();
        f32::tanh_in_place(&mut ys);
        let worst = xs
            .iter()
            .zip(&ys)
            .map(|(x, y)| (f64::from(*y) - f64::from(*x).tanh()).abs())
            .fold(0.0, f64::max);
        assert!(worst < 3e-7, "worst abs error {worst}");
    }

    #[test]
    fn every_vector_width_gives_identical_bits() {
        let xs = grid();
        let mut a = xs.clone();
        let mut b = xs.clone();
        f64::tanh_in_place(&mut a);
        tanh_f64_portable(&mut b);
        assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
        let xs: Vec<f32> = xs.iter().map(|&x| x as f32).collect();
        let mut a = xs.clone();
        let mut b = xs;
        f32::tanh_in_place(&mut a);
        tanh_f32_portable(&mut b);
        assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
    }
}
