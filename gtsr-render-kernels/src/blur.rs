//! A separable blur of image planes with a symmetric window and zero padding (SSIM's 11-tap
//! Gaussian, for one), differentiable.
//!
//! [`blur_planes`] blurs `[C, H, W]` planes along W, then along H:
//! `out[c, i, j] = sum_{a, b} w[a] w[b] x[c, i + a - r, j + b - r]`, with `x` zero outside the
//! planes and `r` the window's radius. With a symmetric window this linear map is its own
//! adjoint, so its backward pass is the same blur of the output's gradient.
//!
//! On NdArray it runs as a backend extension ([`BlurBackend`]): a direct loop over the window's
//! taps, `O(C H W (2r + 1))`, parallel over rows. On other devices it is two matrix products
//! with the banded `[W, W]` and `[H, H]` blur matrices, which GPUs do well and which the CPU
//! would spend `W / (2r + 1)` times the work on.

use burn::backend::{Autodiff, Backend, Dispatch, NdArray, backend_extension, tensor::FloatTensor};
use burn::tensor::{Tensor, TensorData};
use burn_autodiff::{
    checkpoint::{base::Checkpointer, strategy::CheckpointStrategy},
    grads::Gradients,
    ops::{Backward, Ops, OpsKind},
};
use burn_ndarray::NdArrayTensor;
use rayon::prelude::*;

use crate::autodiff::backward_step;
use crate::backend::{host_slice, is_f64, on_ndarray, to_nd};
use crate::scalar::Real;

/// A symmetric blur window of odd length.
#[derive(Clone, Debug, PartialEq)]
pub struct BlurWindow {
    weights: Vec<f32>,
}

/// Why a [`BlurWindow`] could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BlurWindowError {
    /// The weights are empty, of even length, not finite, or not symmetric.
    #[error("a blur window needs an odd number of finite, symmetric weights, got {0:?}")]
    Weights(Vec<f32>),
}

impl BlurWindow {
    /// A window from its weights (odd length, finite, `w[k] == w[len - 1 - k]`).
    pub fn new(weights: Vec<f32>) -> Result<Self, BlurWindowError> {
        let n = weights.len();
        let ok = n % 2 == 1
            && weights.iter().all(|w| w.is_finite())
            && (0..n / 2).all(|k| weights[k] == weights[n - 1 - k]);
        if ok {
            Ok(Self { weights })
        } else {
            Err(BlurWindowError::Weights(weights))
        }
    }

    /// The normalised Gaussian of `taps` weights (odd, at least 1) and standard deviation
    /// `sigma` (taps): `exp(-k^2 / (2 sigma^2))` for `k` in `-r..=r`, divided by their sum.
    pub fn gaussian(taps: usize, sigma: f64) -> Result<Self, BlurWindowError> {
        let r = taps / 2;
        let w: Vec<f64> = (0..taps)
            .map(|i| (-(i as f64 - r as f64).powi(2) / (2.0 * sigma * sigma)).exp())
            .collect();
        let sum: f64 = w.iter().sum();
        Self::new(w.iter().map(|v| (v / sum) as f32).collect())
    }

    /// The weights.
    pub fn weights(&self) -> &[f32] {
        &self.weights
    }

    /// The radius `r` (the window has `2 r + 1` weights).
    pub fn radius(&self) -> usize {
        self.weights.len() / 2
    }

    /// The `[n, n]` matrix `B` of this blur on a length-`n` signal with zero padding:
    /// `(B x)[i] = sum_k w[k] x[i + k - r]`; symmetric.
    fn matrix(&self, n: usize) -> Vec<f32> {
        let r = self.radius();
        let mut m = vec![0f32; n * n];
        for i in 0..n {
            for (k, &w) in self.weights.iter().enumerate() {
                if let Some(j) = (i + k).checked_sub(r).filter(|&j| j < n) {
                    m[i * n + j] = w;
                }
            }
        }
        m
    }
}

/// The blur as a backend op (NdArray, and autodiff over it). Use [`blur_planes`], which picks
/// this op or the matrix products by device.
#[backend_extension(Autodiff, NdArray)]
pub trait BlurBackend: Backend {
    /// Blurs `[C, H, W]` planes with `window` along W and H (zero padding).
    fn blur_planes(x: FloatTensor<Self>, window: BlurWindow) -> FloatTensor<Self>;
}

impl BlurBackend for NdArray {
    fn blur_planes(x: FloatTensor<Self>, window: BlurWindow) -> FloatTensor<Self> {
        if is_f64(&x) {
            nd_blur::<f64>(&x, &window)
        } else {
            nd_blur::<f32>(&x, &window)
        }
    }
}

/// [`blur_host`] on an NdArray tensor, in `F`.
fn nd_blur<F: Real + burn::tensor::Element>(
    x: &NdArrayTensor,
    window: &BlurWindow,
) -> NdArrayTensor {
    let shape = burn::backend::TensorMetadata::shape(x).to_vec();
    let w: Vec<F> = window.weights.iter().map(|&w| F::c(f64::from(w))).collect();
    to_nd(blur_host(&host_slice::<F>(x), &shape, &w), &shape)
}

#[derive(Debug)]
struct BlurBackward;

impl<B: BlurBackend> Backward<B, 1> for BlurBackward {
    type State = BlurWindow;

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        // The blur is self-adjoint: its window is symmetric and its padding zero.
        backward_step::<B, _, 1>(ops, grads, |window, grad| [B::blur_planes(grad, window)]);
    }
}

impl<B: BlurBackend, C: CheckpointStrategy> BlurBackend for Autodiff<B, C> {
    fn blur_planes(x: FloatTensor<Self>, window: BlurWindow) -> FloatTensor<Self> {
        let guard = [x.node()];
        let out = B::blur_planes(x.into_primitive(), window.clone());
        match BlurBackward.prepare::<C>(guard).compute_bound().stateful() {
            OpsKind::Tracked(prep) => prep.finish(window, out),
            OpsKind::UnTracked(prep) => prep.finish(out),
        }
    }
}

/// The blur of `[C, H, W]` planes (row-major `x`) with `w` along W, then along H.
pub(crate) fn blur_host<F: Real>(x: &[F], shape: &[usize], w: &[F]) -> Vec<F> {
    let [c, h, wd] = [shape[0], shape[1], shape[2]];
    assert_eq!(x.len(), c * h * wd, "blur_planes: data and shape disagree");
    let r = w.len() / 2;
    if x.is_empty() {
        return Vec::new();
    }
    // Along W: each row on its own, one tap at a time over the outputs it reaches (each
    // output still sums its taps in order).
    let mut rows = vec![F::zero(); x.len()];
    rows.par_chunks_mut(wd)
        .zip(x.par_chunks(wd))
        .for_each(|(out, row)| {
            for (k, &wk) in w.iter().enumerate() {
                let lo = r.saturating_sub(k);
                let hi = (wd + r).saturating_sub(k).min(wd);
                if lo >= hi {
                    continue;
                }
                let src = &row[lo + k - r..hi + k - r];
                for (a, &b) in out[lo..hi].iter_mut().zip(src) {
                    *a = *a + wk * b;
                }
            }
        });
    // Along H: each output row a weighted sum of whole input rows of its plane.
    let mut out = vec![F::zero(); x.len()];
    out.par_chunks_mut(wd)
        .enumerate()
        .for_each(|(row_index, o)| {
            let (plane, i) = (row_index / h, row_index % h);
            let base = plane * h;
            for (k, &wk) in w.iter().enumerate() {
                let Some(src) = (i + k).checked_sub(r).filter(|&s| s < h) else {
                    continue;
                };
                let src = &rows[(base + src) * wd..(base + src + 1) * wd];
                for (a, &b) in o.iter_mut().zip(src) {
                    *a = *a + wk * b;
                }
            }
        });
    out
}

/// Blurs `[C, H, W]` planes with `window` along W and along H, with zero padding (see the
/// module docs); differentiable on an autodiff device.
///
/// ```
/// use burn::tensor::{Device, Tensor};
/// use gtsr_render_kernels::{BlurWindow, blur_planes};
///
/// let window = BlurWindow::gaussian(11, 1.5)?;
/// let x = Tensor::<3>::ones([3, 32, 32], &Device::ndarray());
/// let y = blur_planes(x, &window);
/// assert_eq!(y.dims(), [3, 32, 32]);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn blur_planes(x: Tensor<3>, window: &BlurWindow) -> Tensor<3> {
    let device = x.device();
    let float = matches!(
        x.dtype(),
        burn::tensor::DType::F32 | burn::tensor::DType::F64
    );
    if float && on_ndarray(&device) {
        return Tensor::from_dispatch(<Dispatch as BlurBackend>::blur_planes(
            x.into_dispatch(),
            window.clone(),
        ));
    }
    blur_planes_by_products(x, window)
}

/// [`blur_planes`] as two matrix products with the blur matrices (any backend).
pub fn blur_planes_by_products(x: Tensor<3>, window: &BlurWindow) -> Tensor<3> {
    let [c, h, w] = x.dims();
    let (device, dtype) = (x.device(), x.dtype());
    let along_w =
        Tensor::<2>::from_data(TensorData::new(window.matrix(w), [w, w]), &device).cast(dtype);
    let bh = window.matrix(h);
    let bh: Vec<f32> = (0..c).flat_map(|_| bh.iter().copied()).collect();
    let along_h = Tensor::<3>::from_data(TensorData::new(bh, [c, h, h]), &device).cast(dtype);
    // Along W: `X B_w^T`, and `B_w^T = B_w`; along H: `B_h X` per plane.
    let y = x.reshape([c * h, w]).matmul(along_w).reshape([c, h, w]);
    along_h.matmul(y)
}

#[cfg(test)]
mod tests {
    use burn::tensor::Device;

    use super::*;
    use burn::tensor::DType::{self, F32, F64};
    use rand::{RngExt, SeedableRng};

    fn random(shape: [usize; 3], seed: u64, scale: f64) -> Vec<f64> {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        (0..shape.iter().product::<usize>())
            .map(|_| scale * (rng.random::<f64>() * 2.0 - 1.0))
            .collect()
    }

    fn tensor(v: Vec<f64>, shape: [usize; 3], device: &Device, dtype: DType) -> Tensor<3> {
        Tensor::<3>::from_data(TensorData::new(v, shape), (device, dtype))
    }

    fn host(t: Tensor<3>) -> Vec<f64> {
        t.cast(DType::F64).into_data().to_vec::<f64>().unwrap()
    }

    #[test]
    fn windows_must_be_odd_finite_and_symmetric() {
        assert!(BlurWindow::new(vec![0.25, 0.5, 0.25]).is_ok());
        assert!(BlurWindow::new(vec![0.5, 0.5]).is_err());
        assert!(BlurWindow::new(vec![]).is_err());
        assert!(BlurWindow::new(vec![0.2, 0.5, 0.3]).is_err());
        assert!(BlurWindow::new(vec![f32::NAN]).is_err());
        let g = BlurWindow::gaussian(11, 1.5).unwrap();
        assert_eq!(g.radius(), 5);
        assert!((g.weights().iter().sum::<f32>() - 1.0).abs() < 1e-6);
    }

    #[test]
    fn the_cpu_op_equals_the_matrix_products_on_planes_smaller_and_larger_than_the_window() {
        let device = Device::ndarray();
        let window = BlurWindow::gaussian(11, 1.5).unwrap();
        for (k, shape) in [[3, 17, 23], [2, 4, 3], [1, 1, 1], [3, 40, 11]]
            .into_iter()
            .enumerate()
        {
            let v = random(shape, 7 + k as u64, 1.0);
            let op = host(blur_planes(tensor(v.clone(), shape, &device, F64), &window));
            let products = host(blur_planes_by_products(
                tensor(v, shape, &device, F64),
                &window,
            ));
            for (a, b) in op.iter().zip(&products) {
                assert!((a - b).abs() < 1e-12, "{shape:?}: {a} against {b}");
            }
        }
        // f32 on the default device, against the f64 result.
        let shape = [3, 19, 21];
        let v = random(shape, 3, 1.0);
        let f32_out = host(blur_planes(tensor(v.clone(), shape, &device, F32), &window));
        let f64_out = host(blur_planes(tensor(v, shape, &device, F64), &window));
        for (a, b) in f32_out.iter().zip(&f64_out) {
            assert!((a - b).abs() < 1e-6, "{a} against {b}");
        }
    }

    /// The blur written out per output, summing the taps in the kernel's order (along W, then
    /// along H, each in increasing tap order).
    fn direct(x: &[f32], [c, h, w]: [usize; 3], win: &[f32]) -> Vec<f32> {
        let r = win.len() / 2;
        let at = |p: usize, i: isize, j: isize| -> Option<f32> {
            (i >= 0 && j >= 0 && (i as usize) < h && (j as usize) < w)
                .then(|| x[(p * h + i as usize) * w + j as usize])
        };
        let mut out = vec![0f32; x.len()];
        for p in 0..c {
            for i in 0..h {
                for j in 0..w {
                    let mut s = 0f32;
                    for (b, &wb) in win.iter().enumerate() {
                        let ii = i as isize + b as isize - r as isize;
                        if at(p, ii, 0).is_none() {
                            continue;
                        }
                        let mut row = 0f32;
                        for (a, &wa) in win.iter().enumerate() {
                            if let Some(v) = at(p, ii, j as isize + a as isize - r as isize) {
                                row += wa * v;
                            }
                        }
                        s += wb * row;
                    }
                    out[(p * h + i) * w + j] = s;
                }
            }
        }
        out
    }

    #[test]
    fn the_kernel_equals_the_blur_written_out_per_output_bit_for_bit() {
        let window = BlurWindow::gaussian(11, 1.5).unwrap();
        for (k, shape) in [[3, 33, 29], [1, 4, 7], [2, 12, 12]]
            .into_iter()
            .enumerate()
        {
            let x: Vec<f32> = random(shape, 40 + k as u64, 1.0)
                .iter()
                .map(|&v| v as f32)
                .collect();
            let kernel = blur_host(&x, &shape, window.weights());
            assert_eq!(kernel, direct(&x, shape, window.weights()), "{shape:?}");
        }
    }

    #[test]
    fn the_gradient_matches_central_differences_in_f64() {
        let device = Device::ndarray().autodiff();
        let window = BlurWindow::gaussian(5, 1.0).unwrap();
        let shape = [2, 7, 9];
        let x0 = random(shape, 11, 1.0);
        // A loss that weighs each output differently: sum(blur(x) * u).
        let u = random(shape, 12, 1.0);
        let loss = |x: Vec<f64>| -> f64 {
            let y = host(blur_planes(
                tensor(x, shape, &Device::ndarray(), F64),
                &window,
            ));
            y.iter().zip(&u).map(|(a, b)| a * b).sum()
        };
        let x = tensor(x0.clone(), shape, &device, F64).require_grad();
        let y = blur_planes(x.clone(), &window);
        let l = (y * tensor(u.clone(), shape, &device, F64)).sum();
        let grads = l.backward();
        let g = host(x.grad(&grads).unwrap());
        let eps = 1e-6;
        for k in (0..x0.len()).step_by(5) {
            let (mut p, mut m) = (x0.clone(), x0.clone());
            p[k] += eps;
            m[k] -= eps;
            let fd = (loss(p) - loss(m)) / (2.0 * eps);
            assert!((g[k] - fd).abs() < 1e-8, "input {k}: {} against {fd}", g[k]);
        }
    }

    #[test]
    fn stiff_inputs_give_finite_outputs_and_gradients() {
        let device = Device::ndarray().autodiff();
        let window = BlurWindow::gaussian(11, 1.5).unwrap();
        let shape = [3, 16, 16];
        let mut v = random(shape, 5, 1e30);
        v[0] = 3e38;
        v[1] = -3e38;
        v[2] = 1e-38;
        let x = tensor(v, shape, &device, F32).require_grad();
        let y = blur_planes(x.clone(), &window);
        let out = host(y.clone());
        assert!(out.iter().all(|v| v.is_finite()));
        let grads = (y * 1e-30).sum().backward();
        let g = host(x.grad(&grads).unwrap());
        assert!(g.iter().all(|v| v.is_finite()));
    }
}
