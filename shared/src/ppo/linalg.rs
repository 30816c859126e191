//! A safe, bounds-checked front to the matrix-product kernels on strided
//! slices: `matrixmultiply` for f64 (the gradient checks), the `gemm` crate
//! and `skinny.rs` for f32 (training). nalgebra's `gemm` hands large
//! dynamic products to `matrixmultiply`, but its small-dimension fallback
//! mishandles strided (transposed) views, and the MLP's output layers are
//! small (1 or 3 rows), so the network calls the kernels directly:
//! transposes cost nothing, just strides.

pub use super::matref::MatRef;

macro_rules! gemm_fn {
    ($name:ident, $kernel:path, $t:ty) => {
        /// `C = alpha * A * B + beta * C` with `C` column-major
        /// `a.rows x b.cols` in `c`. Panics only on a programming error
        /// (shapes that do not fit).
        pub fn $name(alpha: $t, a: MatRef<'_, $t>, b: MatRef<'_, $t>, beta: $t, c: &mut [$t]) {
            let (m, k, n) = (a.rows, a.cols, b.cols);
            assert!(b.rows == k && a.fits() && b.fits() && c.len() == m * n);
            if m == 0 || n == 0 {
                return;
            }
            if k == 0 {
                c.iter_mut().for_each(|v| *v *= beta);
                return;
            }
            // SAFETY: the assertion above keeps every strided access of A
            // and B inside their slices, and C is exactly m x n column-major
            // and unaliased (a distinct &mut slice).
            unsafe {
                $kernel(
                    m,
                    k,
                    n,
                    alpha,
                    a.data.as_ptr(),
                    a.rs as isize,
                    a.cs as isize,
                    b.data.as_ptr(),
                    b.rs as isize,
                    b.cs as isize,
                    beta,
                    c.as_mut_ptr(),
                    1,
                    m as isize,
                );
            }
        }
    };
}

gemm_fn!(dgemm, matrixmultiply::dgemm, f64);

/// `C = alpha * A * B + beta * C` in `f32` (the training precision) with `C`
/// column-major. The networks' products are small (64 x 64 weights, batches
/// of 64 or 256), where the `gemm` crate's kernels, which skip packing for
/// small operands and handle 1- and 3-row products without padding them to
/// a 16 x 16 tile, beat `matrixmultiply` by 1.3x to 10x per shape; the
/// output layers' weight gradient goes to a kernel of its own (`skinny.rs`).
/// Single-threaded, so deterministic.
pub fn sgemm(alpha: f32, a: MatRef<'_, f32>, b: MatRef<'_, f32>, beta: f32, c: &mut [f32]) {
    let (m, k, n) = (a.rows, a.cols, b.cols);
    assert!(b.rows == k && a.fits() && b.fits() && c.len() == m * n);
    if m == 0 || n == 0 {
        return;
    }
    if super::skinny::fits(&a, &b) {
        return super::skinny::run(alpha, a, b, beta, c);
    }
    // SAFETY: the assertion above keeps every strided access of A and B
    // inside their slices; C is exactly m x n column-major and unaliased.
    // (`gemm` computes dst = alpha * dst + beta * lhs * rhs, reading dst
    // only when asked: our beta is its alpha and the other way round.)
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            c.as_mut_ptr(),
            m as isize,
            1,
            beta != 0.0,
            a.data.as_ptr(),
            a.cs as isize,
            a.rs as isize,
            b.data.as_ptr(),
            b.cs as isize,
            b.rs as isize,
            beta,
            alpha,
            false,
            false,
            false,
            gemm::Parallelism::None,
        );
    }
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)] // index loops read clearer in checks
mod tests {
    use super::*;

    #[test]
    fn transposed_views_multiply_correctly() {
        // A = [[1, 2, 3], [4, 5, 6]] (2 x 3) column-major.
        let a = [1.0, 4.0, 2.0, 5.0, 3.0, 6.0];
        let a = MatRef::col_major(&a, 2, 3);
        let mut c = [0.0; 4];
        dgemm(1.0, a, a.t(), 0.0, &mut c); // A A^T
        assert_eq!(c, [14.0, 32.0, 32.0, 77.0]);
        let mut c = [1.0; 9];
        dgemm(2.0, a.t(), a, 1.0, &mut c); // 2 A^T A + 1
        assert_eq!(c, [35.0, 45.0, 55.0, 45.0, 59.0, 73.0, 55.0, 73.0, 91.0]);
        let a32 = [1.0f32, 4.0, 2.0, 5.0, 3.0, 6.0];
        let a32 = MatRef::col_major(&a32, 2, 3);
        let mut c = [0.0f32; 4];
        sgemm(1.0, a32, a32.t(), 0.0, &mut c);
        assert_eq!(c, [14.0, 32.0, 32.0, 77.0]);
    }
}
