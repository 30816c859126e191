//! Batched multilayer perceptron: tanh hidden layers, linear output layer.
//!
//! All parameters live in one flat `Vec<f64>` (per layer: the weight matrix
//! `W` of shape `out x in`, column-major, then the bias `b`), so that Adam and
//! the global gradient-norm clipping work on plain slices. A batch is a
//! column-major `dim x batch` block: one sample per column, which is exactly
//! the row-major `n * dim` layout of the environment's observation buffer.
//! Forward and backward passes are matrix-matrix products (`linalg`: the
//! `gemm` crate in f32, `matrixmultiply` in f64) into preallocated
//! workspaces, so nothing is allocated per sample or per call once the
//! workspace has seen its batch size.

use super::linalg::MatRef;
use super::real::{on_widest, Real};
use nalgebra::DMatrix;
use rand::Rng;
use rand_distr::StandardNormal;

/// A fully connected network `sizes[0] -> sizes[1] -> ... -> sizes[L]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Mlp<T: Real = f64> {
    sizes: Vec<usize>,
    params: Vec<T>,
}

/// Activations (and backward scratch) for one batch size.
#[derive(Debug, Clone, Default)]
pub struct MlpWorkspace<T: Real = f64> {
    batch: usize,
    /// Output of every layer (`sizes[l + 1] x batch`, column-major); hidden
    /// ones after tanh.
    acts: Vec<Vec<T>>,
    /// Gradient of the loss wrt the pre-activation of each layer.
    deltas: Vec<Vec<T>>,
}

/// Number of parameters of a network with these layer sizes.
pub fn param_count(sizes: &[usize]) -> usize {
    sizes.windows(2).map(|w| w[1] * w[0] + w[1]).sum()
}

impl<T: Real> Mlp<T> {
    /// A network with all parameters zero. `sizes` must have at least two
    /// entries, all non-zero (checked by the callers' config validation).
    pub fn zeros(sizes: &[usize]) -> Self {
        Self {
            sizes: sizes.to_vec(),
            params: vec![T::ZERO; param_count(sizes)],
        }
    }

    /// Orthogonal initialization (Saxe et al.), as in the PPO reference
    /// implementations: each weight matrix is a random (semi-)orthogonal
    /// matrix times `hidden_gain` (hidden layers) or `output_gain` (last
    /// layer); biases are zero.
    pub fn orthogonal<R: Rng>(
        sizes: &[usize],
        hidden_gain: f64,
        output_gain: f64,
        rng: &mut R,
    ) -> Self {
        let mut net = Self::zeros(sizes);
        let n_layers = net.n_layers();
        for l in 0..n_layers {
            let gain = if l + 1 == n_layers {
                output_gain
            } else {
                hidden_gain
            };
            let (rows, cols) = (sizes[l + 1], sizes[l]);
            let q = orthogonal_matrix(rows, cols, rng);
            let (w_off, _) = net.layer_offsets(l);
            for (dst, src) in net.params[w_off..w_off + rows * cols]
                .iter_mut()
                .zip(q.as_slice())
            {
                *dst = T::from_f64(gain * src);
            }
        }
        net
    }

    /// Rebuilds a network from its layer sizes and flat parameters; `None`
    /// when the lengths do not match.
    pub fn from_parts(sizes: Vec<usize>, params: Vec<T>) -> Option<Self> {
        if sizes.len() < 2 || sizes.contains(&0) || params.len() != param_count(&sizes) {
            return None;
        }
        Some(Self { sizes, params })
    }

    /// The same network in another precision (rounding when narrowing).
    pub fn cast<U: Real>(&self) -> Mlp<U> {
        Mlp {
            sizes: self.sizes.clone(),
            params: self
                .params
                .iter()
                .map(|p| U::from_f64(p.to_f64()))
                .collect(),
        }
    }

    /// Layer sizes, input first.
    pub fn sizes(&self) -> &[usize] {
        &self.sizes
    }

    /// Input dimension.
    pub fn in_dim(&self) -> usize {
        self.sizes[0]
    }

    /// Output dimension.
    pub fn out_dim(&self) -> usize {
        self.sizes[self.sizes.len() - 1]
    }

    /// Number of weight layers.
    pub fn n_layers(&self) -> usize {
        self.sizes.len() - 1
    }

    /// The flat parameter vector.
    pub fn params(&self) -> &[T] {
        &self.params
    }

    /// The flat parameter vector, mutable (for the optimizer).
    pub fn params_mut(&mut self) -> &mut [T] {
        &mut self.params
    }

    /// Offsets of layer `l`'s weight matrix and bias in the flat vector.
    pub fn layer_offsets(&self, l: usize) -> (usize, usize) {
        let mut off = 0;
        for w in self.sizes.windows(2).take(l) {
            off += w[1] * w[0] + w[1];
        }
        (off, off + self.sizes[l + 1] * self.sizes[l])
    }

    /// Weight matrix (`out x in`, column-major) and bias of layer `l`.
    pub fn layer(&self, l: usize) -> (MatRef<'_, T>, &[T]) {
        let (w_off, b_off) = self.layer_offsets(l);
        let (rows, cols) = (self.sizes[l + 1], self.sizes[l]);
        (
            MatRef::col_major(&self.params[w_off..b_off], rows, cols),
            &self.params[b_off..b_off + rows],
        )
    }

    /// Forward pass of a batch `x` (`in_dim x batch`, column-major, so
    /// `x.len() == in_dim * batch`). Returns the output block
    /// (`out_dim x batch`, column-major), which stays in the workspace for
    /// `backward`.
    pub fn forward<'w>(&self, x: &[T], ws: &'w mut MlpWorkspace<T>) -> &'w [T] {
        let batch = x.len() / self.in_dim();
        debug_assert_eq!(x.len(), batch * self.in_dim());
        ws.ensure(&self.sizes, batch);
        let n_layers = self.n_layers();
        for l in 0..n_layers {
            let (w, b) = self.layer(l);
            let (prev, rest) = ws.acts.split_at_mut(l);
            let out = &mut rest[0];
            for col in out.chunks_exact_mut(b.len()) {
                col.copy_from_slice(b);
            }
            let input = if l == 0 { x } else { &prev[l - 1] };
            T::gemm(
                T::ONE,
                w,
                MatRef::col_major(input, w.cols, batch),
                T::ONE,
                out,
            );
            if l + 1 < n_layers {
                T::tanh_in_place(out);
            }
        }
        &ws.acts[n_layers - 1]
    }

    /// Backward pass after `forward(x, ws)`: given `d_out`, the gradient of a
    /// scalar loss wrt the outputs (`out_dim x batch`), writes the gradient
    /// wrt every parameter into `grad` (overwriting it; same layout as
    /// `params`) and, when asked, the gradient wrt the inputs into `d_x`.
    pub fn backward(
        &self,
        x: &[T],
        ws: &mut MlpWorkspace<T>,
        d_out: &[T],
        grad: &mut [T],
        d_x: Option<&mut [T]>,
    ) {
        // The bias sums and tanh derivatives are element-wise loops.
        on_widest(
            #[inline(always)]
            || self.backward_body(x, ws, d_out, grad, d_x),
        );
    }

    #[inline(always)]
    fn backward_body(
        &self,
        x: &[T],
        ws: &mut MlpWorkspace<T>,
        d_out: &[T],
        grad: &mut [T],
        mut d_x: Option<&mut [T]>,
    ) {
        let batch = ws.batch;
        debug_assert_eq!(x.len(), batch * self.in_dim());
        debug_assert_eq!(d_out.len(), batch * self.out_dim());
        debug_assert_eq!(grad.len(), self.params.len());
        let n_layers = self.n_layers();
        ws.deltas[n_layers - 1].copy_from_slice(d_out);
        for l in (0..n_layers).rev() {
            let (rows, cols) = (self.sizes[l + 1], self.sizes[l]);
            let (w_off, b_off) = self.layer_offsets(l);
            let (lower, upper) = ws.deltas.split_at_mut(l);
            let delta = MatRef::col_major(&upper[0], rows, batch);
            let input: &[T] = if l == 0 { x } else { &ws.acts[l - 1] };
            {
                let (gw, gb) = grad[w_off..b_off + rows].split_at_mut(rows * cols);
                // dW = delta * input^T
                T::gemm(
                    T::ONE,
                    delta,
                    MatRef::col_major(input, cols, batch).t(),
                    T::ZERO,
                    gw,
                );
                gb.fill(T::ZERO);
                for col in delta.data.chunks_exact(rows) {
                    for (g, d) in gb.iter_mut().zip(col) {
                        *g += *d;
                    }
                }
            }
            let w_t = MatRef::col_major(&self.params[w_off..b_off], rows, cols).t();
            if l > 0 {
                let prev = &mut lower[l - 1];
                T::gemm(T::ONE, w_t, delta, T::ZERO, prev);
                // tanh'(z) = 1 - tanh(z)^2, with tanh(z) the stored activation.
                for (d, a) in prev.iter_mut().zip(&ws.acts[l - 1]) {
                    *d *= T::ONE - *a * *a;
                }
            } else if let Some(d_x) = d_x.as_deref_mut() {
                T::gemm(T::ONE, w_t, delta, T::ZERO, d_x);
            }
        }
    }
}

impl<T: Real> MlpWorkspace<T> {
    /// An empty workspace; it sizes itself on first use.
    pub fn new() -> Self {
        Self::default()
    }

    /// Output block of the last forward pass (empty before the first).
    pub fn output(&self) -> &[T] {
        self.acts.last().map_or(&[], |a| a.as_slice())
    }

    fn ensure(&mut self, sizes: &[usize], batch: usize) {
        let n_layers = sizes.len() - 1;
        let fits = self.batch == batch
            && self.acts.len() == n_layers
            && self
                .acts
                .iter()
                .zip(&sizes[1..])
                .all(|(a, &s)| a.len() == s * batch);
        if !fits {
            self.batch = batch;
            self.acts = sizes[1..]
                .iter()
                .map(|&s| vec![T::ZERO; s * batch])
                .collect();
            self.deltas = self.acts.clone();
        }
    }
}

/// A `rows x cols` matrix with orthonormal columns (rows >= cols) or rows
/// (rows < cols), from the QR decomposition of a Gaussian matrix with the
/// sign of R's diagonal folded in, so the result is uniformly distributed.
fn orthogonal_matrix<R: Rng>(rows: usize, cols: usize, rng: &mut R) -> DMatrix<f64> {
    let (tall, short) = (rows.max(cols), rows.min(cols));
    let a = DMatrix::<f64>::from_fn(tall, short, |_, _| rng.sample(StandardNormal));
    let qr = a.qr();
    let mut q = qr.q();
    let r = qr.r();
    for j in 0..short {
        if r[(j, j)] < 0.0 {
            q.column_mut(j).neg_mut();
        }
    }
    if rows >= cols {
        q
    } else {
        q.transpose()
    }
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)] // index loops read clearer in checks
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn random_net(sizes: &[usize], seed: u64) -> Mlp {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut net = Mlp::orthogonal(sizes, 2f64.sqrt(), 1.0, &mut rng);
        // Non-zero biases so their gradients are exercised too.
        for p in net.params_mut() {
            *p += 0.1 * rng.sample::<f64, _>(StandardNormal);
        }
        net
    }

    fn random_vec(n: usize, seed: u64) -> Vec<f64> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..n).map(|_| rng.sample(StandardNormal)).collect()
    }

    /// Scalar test loss sum(g .* net(x)).
    fn loss(net: &Mlp, x: &[f64], g: &[f64]) -> f64 {
        let mut ws = MlpWorkspace::new();
        let y = net.forward(x, &mut ws);
        y.iter().zip(g).map(|(a, b)| a * b).sum()
    }

    #[test]
    fn forward_matches_per_sample_reference() {
        let sizes = [4, 7, 5, 3];
        let net = random_net(&sizes, 1);
        let batch = 9;
        let x = random_vec(4 * batch, 2);
        let mut ws = MlpWorkspace::new();
        let y = net.forward(&x, &mut ws).to_vec();
        for s in 0..batch {
            let mut h: Vec<f64> = x[s * 4..s * 4 + 4].to_vec();
            for l in 0..net.n_layers() {
                let (w, b) = net.layer(l);
                let mut out: Vec<f64> = (0..w.rows)
                    .map(|i| {
                        b[i] + (0..w.cols)
                            .map(|j| w.data[i + j * w.rows] * h[j])
                            .sum::<f64>()
                    })
                    .collect();
                if l + 1 < net.n_layers() {
                    out.iter_mut().for_each(|v| *v = v.tanh());
                }
                h = out;
            }
            for i in 0..3 {
                assert!((y[i + 3 * s] - h[i]).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn gradients_match_central_differences() {
        for (sizes, batch) in [(vec![6, 8, 8, 3], 11), (vec![7, 64, 64, 1], 9)] {
            let net = random_net(&sizes, 3);
            let in_dim = sizes[0];
            let x = random_vec(in_dim * batch, 4);
            let g = random_vec(net.out_dim() * batch, 5);
            let mut ws = MlpWorkspace::new();
            net.forward(&x, &mut ws);
            let mut grad = vec![0.0; net.params().len()];
            let mut dx = vec![0.0; x.len()];
            net.backward(&x, &mut ws, &g, &mut grad, Some(&mut dx));
            let h = 1e-6;
            for i in 0..net.params().len() {
                let mut p = net.clone();
                p.params_mut()[i] += h;
                let up = loss(&p, &x, &g);
                p.params_mut()[i] -= 2.0 * h;
                let down = loss(&p, &x, &g);
                let fd = (up - down) / (2.0 * h);
                assert!(
                    (fd - grad[i]).abs() < 1e-6 * (1.0 + fd.abs()),
                    "param {i}: fd {fd} vs analytic {}",
                    grad[i]
                );
            }
            for i in 0..x.len() {
                let mut xp = x.clone();
                xp[i] += h;
                let up = loss(&net, &xp, &g);
                xp[i] -= 2.0 * h;
                let down = loss(&net, &xp, &g);
                let fd = (up - down) / (2.0 * h);
                assert!(
                    (fd - dx[i]).abs() < 1e-6 * (1.0 + fd.abs()),
                    "input {i}: fd {fd} vs analytic {}",
                    dx[i]
                );
            }
        }
    }

    #[test]
    fn orthogonal_init_is_orthogonal_with_gain() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let net = Mlp::orthogonal(&[6, 64, 64, 3], 2f64.sqrt(), 0.01, &mut rng);
        let (w0, b0) = net.layer(0); // 64 x 6: orthonormal columns * sqrt 2
        let w0 = DMatrix::from_column_slice(64, 6, w0.data);
        let gram = w0.transpose() * &w0;
        assert!((gram - DMatrix::identity(6, 6) * 2.0).abs().max() < 1e-12);
        assert!(b0.iter().all(|&b| b == 0.0));
        let (w2, _) = net.layer(2); // 3 x 64: orthonormal rows * 0.01
        let w2 = DMatrix::from_column_slice(3, 64, w2.data);
        let gram = &w2 * w2.transpose();
        assert!((gram - DMatrix::identity(3, 3) * 1e-4).abs().max() < 1e-15);
    }

    #[test]
    fn f32_network_matches_f64_network() {
        // The f32 products run on the `gemm` crate and the output-gradient
        // kernel (`skinny.rs`), the f64 ones on matrixmultiply: the policy
        // and value shapes at an odd batch and at the minibatch size.
        for (sizes, batch) in [(vec![7, 64, 64, 3], 33), (vec![6, 64, 64, 1], 256)] {
            let (din, dout) = (sizes[0], sizes[3]);
            let net = random_net(&sizes, 5);
            let net32: Mlp<f32> = net.cast();
            let x = random_vec(din * batch, 6);
            let x32: Vec<f32> = x.iter().map(|&v| v as f32).collect();
            let g = random_vec(dout * batch, 7);
            let g32: Vec<f32> = g.iter().map(|&v| v as f32).collect();
            let (mut ws, mut ws32) = (MlpWorkspace::new(), MlpWorkspace::new());
            let y = net.forward(&x, &mut ws).to_vec();
            let y32 = net32.forward(&x32, &mut ws32).to_vec();
            for (a, b) in y.iter().zip(&y32) {
                assert!((a - f64::from(*b)).abs() < 1e-5, "{a} vs {b}");
            }
            let mut grad = vec![0.0; net.params().len()];
            let mut grad32 = vec![0.0f32; net.params().len()];
            net.backward(&x, &mut ws, &g, &mut grad, None);
            net32.backward(&x32, &mut ws32, &g32, &mut grad32, None);
            let scale = (batch as f64).sqrt();
            for (a, b) in grad.iter().zip(&grad32) {
                assert!(
                    (a - f64::from(*b)).abs() < 1e-4 * scale * (1.0 + a.abs()),
                    "{a} vs {b}"
                );
            }
        }
    }

    #[test]
    fn workspace_resizes_between_batch_sizes() {
        let net = random_net(&[3, 5, 2], 9);
        let mut ws = MlpWorkspace::new();
        let x = random_vec(3 * 8, 1);
        let big = net.forward(&x, &mut ws).to_vec();
        let small = net.forward(&x[..6], &mut ws).to_vec();
        assert_eq!(small.len(), 4);
        for (a, b) in small.iter().zip(&big[..4]) {
            assert!((a - b).abs() < 1e-12);
        }
    }

    #[test]
    fn from_parts_rejects_wrong_lengths() {
        assert!(Mlp::from_parts(vec![2, 3], vec![0.0; 9]).is_some());
        assert!(Mlp::from_parts(vec![2, 3], vec![0.0; 8]).is_none());
        assert!(Mlp::<f64>::from_parts(vec![2], vec![]).is_none());
        assert!(Mlp::from_parts(vec![2, 0, 1], vec![0.0; 1]).is_none());
    }
}
