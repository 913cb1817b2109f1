//! L1 and SSIM (11x11 Gaussian window, sigma 1.5, zero padding, as 3DGS), differentiable.

use burn::tensor::Tensor;
use gtsr_render_kernels::{BlurWindow, blur_planes};

const WINDOW: usize = 11;
const SIGMA: f64 = 1.5;
const C1: f64 = 0.01 * 0.01;
const C2: f64 = 0.03 * 0.03;

/// Mean absolute difference.
pub fn l1<const D: usize>(a: Tensor<D>, b: Tensor<D>) -> Tensor<1> {
    (a - b).abs().mean()
}

/// SSIM's window: the normalised 11-tap Gaussian of sigma 1.5.
fn window() -> BlurWindow {
    BlurWindow::gaussian(WINDOW, SIGMA).expect("an odd, symmetric window")
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

/// The per-pixel SSIM map `[H, W]` (mean over channels) of two `[H, W, C]` images. The
/// window's means are [`gtsr_render_kernels::blur_planes`] (a direct kernel on the CPU, matrix
/// products elsewhere).
pub fn ssim_map(a: Tensor<3>, b: Tensor<3>) -> Tensor<2> {
    let [h, w, _] = a.dims();
    let (a, b) = (planes(a), planes(b));
    let m = window();
    let mu_a = blur_planes(a.clone(), &m);
    let mu_b = blur_planes(b.clone(), &m);
    let s_aa = blur_planes(a.clone() * a.clone(), &m) - mu_a.clone() * mu_a.clone();
    let s_bb = blur_planes(b.clone() * b.clone(), &m) - mu_b.clone() * mu_b.clone();
    let s_ab = blur_planes(a * b, &m) - mu_a.clone() * mu_b.clone();
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
