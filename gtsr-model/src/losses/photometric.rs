//! L1 and SSIM (11x11 Gaussian window, sigma 1.5, zero padding, as 3DGS), differentiable.

use burn::tensor::module::conv2d;
use burn::tensor::ops::ConvOptions;
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

/// Separable Gaussian blur of `[1, C, H, W]` with zero padding.
fn blur(x: Tensor<4>) -> Tensor<4> {
    let c = x.dims()[1];
    let device = x.device();
    let g = gaussian_window();
    let taps: Vec<f32> = (0..c).flat_map(|_| g.iter().copied()).collect();
    let kv = Tensor::<4>::from_data(TensorData::new(taps.clone(), [c, 1, WINDOW, 1]), &device)
        .cast(x.dtype());
    let kh =
        Tensor::<4>::from_data(TensorData::new(taps, [c, 1, 1, WINDOW]), &device).cast(x.dtype());
    let p = WINDOW / 2;
    let y = conv2d(x, kv, None, ConvOptions::new([1, 1], [p, 0], [1, 1], c));
    conv2d(y, kh, None, ConvOptions::new([1, 1], [0, p], [1, 1], c))
}

/// The per-pixel SSIM map `[H, W]` (mean over channels) of two `[H, W, C]` images.
pub fn ssim_map(a: Tensor<3>, b: Tensor<3>) -> Tensor<2> {
    let [h, w, c] = a.dims();
    let to4 = |t: Tensor<3>| t.permute([2, 0, 1]).reshape([1, c, h, w]);
    let (a, b) = (to4(a), to4(b));
    let mu_a = blur(a.clone());
    let mu_b = blur(b.clone());
    let s_aa = blur(a.clone() * a.clone()) - mu_a.clone() * mu_a.clone();
    let s_bb = blur(b.clone() * b.clone()) - mu_b.clone() * mu_b.clone();
    let s_ab = blur(a * b) - mu_a.clone() * mu_b.clone();
    let num = (mu_a.clone() * mu_b.clone() * 2.0 + C1) * (s_ab * 2.0 + C2);
    let den = (mu_a.clone() * mu_a + mu_b.clone() * mu_b + C1) * (s_aa + s_bb + C2);
    (num / den).mean_dim(1).reshape([h, w])
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
