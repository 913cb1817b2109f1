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

/// Checks `grads` (of the six inputs, order of `INPUT_NAMES`) against central finite
/// differences of `loss` at every parameter of `scene`, to a relative error of 1e-4 (with a
/// floor of 1e-3 of the input's largest gradient); returns the worst relative error. `what`
/// names the case in failures.
pub fn check_against_finite_differences(
    scene: &HostScene,
    grads: &[Vec<f64>],
    loss: impl Fn(&HostScene) -> f64,
    what: &str,
) -> f64 {
    let mut worst: f64 = 0.0;
    for (k, name) in INPUT_NAMES.iter().enumerate() {
        let analytic = &grads[k];
        let scale = analytic.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let mut probe = scene.clone();
        for (i, &a) in analytic.iter().enumerate() {
            let x = input_mut(&mut probe, k)[i];
            let step = 1e-6 * x.abs().max(1.0);
            input_mut(&mut probe, k)[i] = x + step;
            let up = loss(&probe);
            input_mut(&mut probe, k)[i] = x - step;
            let down = loss(&probe);
            input_mut(&mut probe, k)[i] = x;
            let fd = (up - down) / (2.0 * step);
            // Relative error, with a floor so that entries that are zero up to rounding do not
            // divide by ~0.
            let denom = a.abs().max(fd.abs()).max(1e-3 * scale).max(1e-9);
            let rel = (a - fd).abs() / denom;
            assert!(
                rel <= 1e-4,
                "{what}: {name}[{i}]: autodiff {a:e} vs finite difference {fd:e} (rel {rel:e})"
            );
            worst = worst.max(rel);
        }
        assert!(scale > 0.0, "{what}: {name}: all gradients are zero");
    }
    worst
}
