//! Regularisers: edge-aware material smoothness, flattening, and mask supervision.

use burn::tensor::Tensor;

/// Edge-aware smoothness (Relightable 3DGS): mean over pixel pairs inside the mask of
/// `|grad M| * exp(-|grad I_gt|)`, with precomputed `[H, W-1]` / `[H-1, W]` weights (the
/// exponential times the mask of both pixels). `map` is `[H, W, C]`.
pub fn edge_aware_smoothness(map: &Tensor<3>, wx: &Tensor<2>, wy: &Tensor<2>) -> Tensor<1> {
    let [h, w, c] = map.dims();
    let gx = (map.clone().slice([0..h, 1..w, 0..c]) - map.clone().slice([0..h, 0..w - 1, 0..c]))
        .abs()
        .mean_dim(2)
        .reshape([h, w - 1]);
    let gy = (map.clone().slice([1..h, 0..w, 0..c]) - map.clone().slice([0..h - 1, 0..w, 0..c]))
        .abs()
        .mean_dim(2)
        .reshape([h - 1, w]);
    let count = (wx.clone().sum() + wy.clone().sum()).clamp_min(1.0);
    ((gx * wx.clone()).sum() + (gy * wy.clone()).sum()) / count
}

/// PGSR flattening: the mean of each Gaussian's smallest scale.
pub fn flatten(scales: &Tensor<2>) -> Tensor<1> {
    scales.clone().min_dim(1).mean()
}

/// Mean `|alpha - mask|`.
pub fn mask_l1(alpha: &Tensor<2>, mask: &Tensor<2>) -> Tensor<1> {
    (alpha.clone() - mask.clone()).abs().mean()
}
