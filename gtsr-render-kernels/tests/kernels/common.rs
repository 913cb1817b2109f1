use burn::tensor::{DType, Device, Tensor};
use gtsr_render_kernels::scenes::{HostScene, weighted_loss_gradients};
use gtsr_render_kernels::{AlphaCutoff, render};

/// Reads any float tensor as f64.
pub fn host<const D: usize>(t: Tensor<D>) -> Vec<f64> {
    t.into_data().iter::<f64>().collect()
}

/// Renders through the public API and returns `[H, W, C + 1]` (image channels then alpha).
pub fn render_host(scene: &HostScene, dtype: DType, cutoff: AlphaCutoff) -> Vec<f64> {
    let out = render(
        scene.inputs(&Device::ndarray(), dtype),
        &scene.config(cutoff),
    )
    .unwrap();
    let img = host(out.image);
    let alpha = host(out.alpha);
    let c = scene.channels;
    let mut v = Vec::with_capacity(alpha.len() * (c + 1));
    for (p, a) in alpha.iter().enumerate() {
        v.extend_from_slice(&img[p * c..(p + 1) * c]);
        v.push(*a);
    }
    v
}

pub use gtsr_render_kernels::scenes::{INPUT_NAMES, random_weights as loss_weights};

/// Gradients of all six inputs (order of `INPUT_NAMES`) for `loss = sum(W * [image, alpha])`,
/// and the `[H, W, C + 1]` output.
pub fn autodiff_grads(
    scene: &HostScene,
    dtype: DType,
    cutoff: AlphaCutoff,
    weights: &[f64],
) -> (Vec<Vec<f64>>, Vec<f64>) {
    let r = weighted_loss_gradients(scene, dtype, cutoff, weights).unwrap();
    (r.grads.to_vec(), r.output)
}

/// Mutable access to input `k` of a host scene.
pub fn input_mut(scene: &mut HostScene, k: usize) -> &mut Vec<f64> {
    match k {
        0 => &mut scene.means,
        1 => &mut scene.quats,
        2 => &mut scene.scales,
        3 => &mut scene.opacities,
        4 => &mut scene.features,
        _ => &mut scene.xy_offsets,
    }
}
