//! L1 and SSIM (11x11 Gaussian window, sigma 1.5, zero padding, as 3DGS), differentiable.

use burn::tensor::{Tensor, TensorData};

const WINDOW: usize = 11;
const SIGMA: f64 = 1.5;
const C1: f64 = 0.01 * 0.01;
const C2: f64 = 0.03 * 0.03;

/// Mean absolute difference.
pub fn l1<const D: usize>(a: Tensor<D>, b: Tensor<D>) -> Tensor<1> {
    (a - b).abs().mean()
}

fn gaussian_window() -> Vec<f32> {
    let half = (WINDOW / 2) as f64;
    let w: Vec<f64> = (0..WINDOW)
        .map(|i| (-(i as f64 - half).powi(2) / (2.0 * SIGMA * SIGMA)).exp())
        .collect();
    let s: f64 = w.iter().sum();
    w.iter().map(|v| (v / s) as f32).collect()
}

/// `[n, n]` matrix `B` of the 1-D Gaussian blur with zero padding on a length-`n` signal:
/// `(B x)[i] = sum_k g[k] x[i + k - p]`, with `p = WINDOW / 2` and `x` zero outside `[0, n)`.
fn blur_matrix(n: usize) -> Vec<f32> {
    let g = gaussian_window();
    let p = WINDOW / 2;
    let mut m = vec![0f32; n * n];
    for i in 0..n {
        for (k, &gk) in g.iter().enumerate() {
            if let Some(j) = (i + k).checked_sub(p).filter(|&j| j < n) {
                m[i * n + j] = gk;
            }
        }
    }
    m
}

/// The blur matrices of [`blur`] for `[C, H, W]` planes: `B_w` `[W, W]` and `B_h` repeated
/// per plane `[C, H, H]`.
struct BlurMatrices {
    along_w: Tensor<2>,
    along_h: Tensor<3>,
}

impl BlurMatrices {
    fn new(dims: [usize; 3], like: &Tensor<3>) -> Self {
        let [c, h, w] = dims;
        let (device, dtype) = (like.device(), like.dtype());
        let bh = blur_matrix(h);
        let bh: Vec<f32> = (0..c).flat_map(|_| bh.iter().copied()).collect();
        Self {
            along_w: Tensor::<2>::from_data(TensorData::new(blur_matrix(w), [w, w]), &device)
                .cast(dtype),
            along_h: Tensor::<3>::from_data(TensorData::new(bh, [c, h, h]), &device).cast(dtype),
        }
    }
}

/// Separable Gaussian blur of `[C, H, W]` planes with zero padding, as two matrix products
/// (along W: `X B_w^T`, and `B_w^T = B_w` because the window is symmetric; along H: `B_h X`
/// per plane). On the CPU backend this is several times faster than a grouped convolution,
/// forward and backward.
fn blur(x: Tensor<3>, m: &BlurMatrices) -> Tensor<3> {
    let [c, h, w] = x.dims();
    let y = x
        .reshape([c * h, w])
        .matmul(m.along_w.clone())
        .reshape([c, h, w]);
    m.along_h.clone().matmul(y)
}

/// `[H, W, C]` to `[C, H, W]` planes, contiguous.
fn planes(t: Tensor<3>) -> Tensor<3> {
    let [h, w, c] = t.dims();
    let rows = t.reshape([h * w, c]);
    let planes = (0..c)
        .map(|k| crate::layout::pick_cols(&rows, &[k]).reshape([1, h, w]))
        .collect();
    Tensor::cat(planes, 0)
}

/// The per-pixel SSIM map `[H, W]` (mean over channels) of two `[H, W, C]` images.
pub fn ssim_map(a: Tensor<3>, b: Tensor<3>) -> Tensor<2> {
    let [h, w, _] = a.dims();
    let (a, b) = (planes(a), planes(b));
    let m = BlurMatrices::new(a.dims(), &a);
    let mu_a = blur(a.clone(), &m);
    let mu_b = blur(b.clone(), &m);
    let s_aa = blur(a.clone() * a.clone(), &m) - mu_a.clone() * mu_a.clone();
    let s_bb = blur(b.clone() * b.clone(), &m) - mu_b.clone() * mu_b.clone();
    let s_ab = blur(a * b, &m) - mu_a.clone() * mu_b.clone();
    let num = (mu_a.clone() * mu_b.clone() * 2.0 + C1) * (s_ab * 2.0 + C2);
    let den = (mu_a.clone() * mu_a + mu_b.clone() * mu_b + C1) * (s_aa + s_bb + C2);
    (num / den).mean_dim(0).reshape([h, w])
}

/// Mean SSIM of two `[H, W, C]` images.
pub fn ssim(a: Tensor<3>, b: Tensor<3>) -> Tensor<1> {
    ssim_map(a, b).mean()
}

/// `lambda1 * L1 + (1 - lambda1) * (1 - SSIM)`, the paper's photometric loss for one render.
pub fn photometric(render: Tensor<3>, target: Tensor<3>, lambda_l1: f64) -> Tensor<1> {
    l1(render.clone(), target.clone()) * lambda_l1
        + (ssim(render, target).neg() + 1.0) * (1.0 - lambda_l1)
}

/// [`photometric`] with the pixels where `keep` (`[H, W]`, 0 or 1) is 0 left out of both its
/// L1 and its SSIM parts; still the mean over every pixel, so that the term's scale does not
/// depend on how many are left out. With `keep` all ones it equals [`photometric`]. The
/// trainer leaves out the pixels beside each view's silhouette with it
/// ([`crate::config::LossWeights::photometric_band`], [`crate::losses::outside_band`]), so
/// that a diagnosis can tell which pixels an image term's gradient comes from.
pub fn photometric_masked(
    render: Tensor<3>,
    target: Tensor<3>,
    lambda_l1: f64,
    keep: &Tensor<2>,
) -> Tensor<1> {
    let [h, w, _] = render.dims();
    let l1_map = (render.clone() - target.clone())
        .abs()
        .mean_dim(2)
        .reshape([h, w]);
    let dssim_map = ssim_map(render, target).neg() + 1.0;
    (l1_map * lambda_l1 + dssim_map * (1.0 - lambda_l1))
        .mul(keep.clone())
        .mean()
}
