//! Backward pass against central finite differences in f64 (smooth alpha cut-off).

use burn::tensor::DType;
use gtsr_render_kernels::AlphaCutoff;
use gtsr_render_kernels::cpu;
use gtsr_render_kernels::scenes::{HostScene, RandomSceneSpec, random_scene};

use crate::common::{autodiff_grads, check_against_finite_differences, loss_weights};

fn loss(scene: &HostScene, w: &[f64]) -> f64 {
    let out = cpu::forward(&scene.host(), &scene.config(AlphaCutoff::Smooth));
    out.image.iter().zip(w).map(|(a, b)| a * b).sum()
}

/// Checks every parameter of every input; returns the worst relative error.
fn check_scene(scene: &HostScene, seed: u64) -> f64 {
    let (h, w) = (scene.camera.height as usize, scene.camera.width as usize);
    let weights = loss_weights(seed, h * w * (scene.channels + 1));
    let (grads, _) = autodiff_grads(scene, DType::F64, AlphaCutoff::Smooth, &weights);
    let what = format!("{} Gaussians", scene.len());
    check_against_finite_differences(scene, &grads, |s| loss(s, &weights), &what)
}

#[test]
fn backward_matches_finite_differences() {
    for (i, &n) in [1usize, 2, 5, 13, 30, 50].iter().enumerate() {
        let spec = RandomSceneSpec {
            count: n,
            channels: 3,
            size: (40, 30),
            radius: 0.6,
            scale_range: (0.03, 0.3),
            opacity_range: (0.05, 0.9),
            distance: 4.0,
            fov_x: 0.9,
        };
        let scene = random_scene(300 + i as u64, &spec);
        let worst = check_scene(&scene, 900 + i as u64);
        eprintln!("{n} Gaussians: worst relative error {worst:e}");
    }
}
