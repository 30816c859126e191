//! A matrix product with one tiny dimension that the general kernels handle
//! badly: the output layers' weight gradient `delta (m x 256) * H^T (256 x
//! 64)` with `m <= 4` rows (3 for the policy's mean, 1 for the value) and
//! B's rows contiguous. Here C's rows are accumulated in registers while the
//! 256 rows of B stream past: 6-10x faster than `matrixmultiply` (which pads
//! the rows to a 16 x 16 tile) and 4x faster than the `gemm` crate, which
//! takes every other product (see `linalg::sgemm`).
//!
//! Sums run in a fixed order. The FMA builds (AVX-512, AVX2) fuse each
//! multiply-add and the baseline build does not, so results are
//! deterministic per machine, as the `gemm` crate's are.

use super::matref::MatRef;

/// Hidden width the kernel is specialized for.
const W: usize = 64;

/// Whether the kernel takes `A (m x k) * B (k x n)`.
pub(super) fn fits(a: &MatRef<'_, f32>, b: &MatRef<'_, f32>) -> bool {
    (1..=4).contains(&a.rows) && b.cols == W && b.cs == 1
}

/// The compiled copies of the kernel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Path {
    #[cfg(target_arch = "x86_64")]
    Avx512,
    #[cfg(target_arch = "x86_64")]
    Avx2,
    Portable,
}

impl Path {
    fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::is_x86_feature_detected as has;
            if has!("avx512f") && has!("fma") {
                return Path::Avx512;
            }
            if has!("avx2") && has!("fma") {
                return Path::Avx2;
            }
        }
        Path::Portable
    }

    /// Every copy this CPU can run (for tests).
    #[cfg(test)]
    pub(super) fn available() -> Vec<Self> {
        let mut out = vec![Path::Portable];
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::is_x86_feature_detected as has;
            if has!("avx2") && has!("fma") {
                out.push(Path::Avx2);
            }
            if has!("avx512f") && has!("fma") {
                out.push(Path::Avx512);
            }
        }
        out
    }
}

/// `C = alpha * A * B + beta * C` for a product that [`fits`], on the
/// widest path the CPU has.
pub(super) fn run(alpha: f32, a: MatRef<'_, f32>, b: MatRef<'_, f32>, beta: f32, c: &mut [f32]) {
    run_on(Path::detect(), alpha, a, b, beta, c);
}

pub(super) fn run_on(
    path: Path,
    alpha: f32,
    a: MatRef<'_, f32>,
    b: MatRef<'_, f32>,
    beta: f32,
    c: &mut [f32],
) {
    let out = Out { alpha, beta };
    match path {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `Path::Avx512` is only detected on CPUs with AVX-512F and FMA.
        Path::Avx512 => unsafe { run_avx512(out, a, b, c) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `Path::Avx2` is only detected on CPUs with AVX2 and FMA.
        Path::Avx2 => unsafe { run_avx2(out, a, b, c) },
        Path::Portable => dispatch::<false>(out, a, b, c),
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,fma")]
fn run_avx512(out: Out, a: MatRef<'_, f32>, b: MatRef<'_, f32>, c: &mut [f32]) {
    dispatch::<true>(out, a, b, c);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn run_avx2(out: Out, a: MatRef<'_, f32>, b: MatRef<'_, f32>, c: &mut [f32]) {
    dispatch::<true>(out, a, b, c);
}

/// `C = alpha * (A B) + beta * C`; `beta = 0` ignores C's old contents (as
/// in BLAS, so a NaN there does not leak).
#[derive(Clone, Copy)]
struct Out {
    alpha: f32,
    beta: f32,
}

impl Out {
    #[inline(always)]
    fn put(self, c: &mut f32, s: f32) {
        *c = if self.beta == 0.0 {
            self.alpha * s
        } else {
            self.alpha * s + self.beta * *c
        };
    }
}

#[inline(always)]
fn madd<const FMA: bool>(x: f32, y: f32, acc: f32) -> f32 {
    if FMA {
        x.mul_add(y, acc)
    } else {
        acc + x * y
    }
}

/// Monomorphizes the kernel over the row count, so its accumulators are
/// fixed-size arrays the compiler keeps in registers.
#[inline(always)]
fn dispatch<const FMA: bool>(out: Out, a: MatRef<'_, f32>, b: MatRef<'_, f32>, c: &mut [f32]) {
    match a.rows {
        1 => rows::<1, FMA>(out, a, b, c),
        2 => rows::<2, FMA>(out, a, b, c),
        3 => rows::<3, FMA>(out, a, b, c),
        4 => rows::<4, FMA>(out, a, b, c),
        _ => unreachable!("`fits` admits one to four rows"),
    }
}

/// `M` rows, `n = 64`, B's rows contiguous: C[i, :] = sum_p A[i, p] B[p, :].
#[inline(always)]
fn rows<const M: usize, const FMA: bool>(
    out: Out,
    a: MatRef<'_, f32>,
    b: MatRef<'_, f32>,
    c: &mut [f32],
) {
    let mut acc = [[0f32; W]; M];
    for p in 0..a.cols {
        let bp: &[f32; W] = b.data[p * b.rs..p * b.rs + W].try_into().unwrap();
        for (i, acc) in acc.iter_mut().enumerate() {
            let x = a.data[i * a.rs + p * a.cs];
            for t in 0..W {
                acc[t] = madd::<FMA>(x, bp[t], acc[t]);
            }
        }
    }
    for (i, acc) in acc.iter().enumerate() {
        for (t, &s) in acc.iter().enumerate() {
            out.put(&mut c[t * M + i], s);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Every kernel, on every compiled path, against an f64 triple loop, for
    /// the shapes (and transposed views) the networks use.
    #[test]
    fn kernels_match_a_reference_on_every_path() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        // (m, k, n, A transposed, B transposed)
        let cases = [
            (3, 256, 64, false, true),
            (1, 256, 64, false, true),
            (2, 7, 64, true, true),
            (4, 1, 64, false, true),
        ];
        let mut checked = 0;
        for (m, k, n, ta, tb) in cases {
            let ad: Vec<f32> = (0..m * k).map(|_| rng.gen_range(-1.0..1.0)).collect();
            let bd: Vec<f32> = (0..k * n).map(|_| rng.gen_range(-1.0..1.0)).collect();
            let a = if ta {
                MatRef::col_major(&ad, k, m).t()
            } else {
                MatRef::col_major(&ad, m, k)
            };
            let b = if tb {
                MatRef::col_major(&bd, n, k).t()
            } else {
                MatRef::col_major(&bd, k, n)
            };
            assert!(fits(&a, &b), "{m}x{k}x{n}");
            let c0: Vec<f32> = (0..m * n).map(|_| rng.gen_range(-1.0..1.0)).collect();
            for path in Path::available() {
                for (alpha, beta) in [(1.0f32, 1.0f32), (0.5, 0.0), (-2.0, 0.25)] {
                    let mut c = c0.clone();
                    if beta == 0.0 {
                        c.fill(f32::NAN);
                    }
                    run_on(path, alpha, a, b, beta, &mut c);
                    for j in 0..n {
                        for i in 0..m {
                            let ab: f64 = (0..k)
                                .map(|p| {
                                    f64::from(a.data[i * a.rs + p * a.cs])
                                        * f64::from(b.data[p * b.rs + j * b.cs])
                                })
                                .sum();
                            let old = if beta == 0.0 {
                                0.0
                            } else {
                                f64::from(c0[j * m + i])
                            };
                            let want = f64::from(alpha) * ab + f64::from(beta) * old;
                            let got = f64::from(c[j * m + i]);
                            assert!(
                                (got - want).abs() < 1e-5 * (k as f64).sqrt(),
                                "{path:?} {m}x{k}x{n} ({i}, {j}): {got} vs {want}"
                            );
                            checked += 1;
                        }
                    }
                }
            }
        }
        assert!(checked > 1_000);
    }

    #[test]
    fn other_shapes_are_left_to_the_gemm_crate() {
        let d = vec![0f32; 64 * 256];
        let w = MatRef::col_major(&d[..3 * 64], 3, 64);
        let h = MatRef::col_major(&d, 64, 256);
        assert!(!fits(&w, &h), "a forward pass (B's columns contiguous)");
        let delta = MatRef::col_major(&d[..5 * 256], 5, 256);
        let ht = MatRef::col_major(&d, 64, 256).t();
        assert!(!fits(&delta, &ht), "five rows is past the kernel");
        let ht32 = MatRef::col_major(&d[..32 * 256], 32, 256).t();
        let delta3 = MatRef::col_major(&d[..3 * 256], 3, 256);
        assert!(
            fits(&delta3, &ht) && !fits(&delta3, &ht32),
            "other hidden widths"
        );
    }
}
