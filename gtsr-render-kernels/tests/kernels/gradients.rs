//! Backward pass against central finite differences in f64 (smooth alpha cut-off).

use burn::tensor::DType;
use gtsr_render_kernels::AlphaCutoff;
use gtsr_render_kernels::cpu;
use gtsr_render_kernels::scenes::{HostScene, RandomSceneSpec, random_scene};

use crate::common::{INPUT_NAMES, autodiff_grads, input_mut, loss_weights};

fn loss(scene: &HostScene, w: &[f64]) -> f64 {
    let out = cpu::forward(&scene.host(), &scene.config(AlphaCutoff::Smooth));
    out.image.iter().zip(w).map(|(a, b)| a * b).sum()
}

/// Checks every parameter of every input; returns the worst relative error.
fn check_scene(scene: &HostScene, seed: u64) -> f64 {
    let (h, w) = (scene.camera.height as usize, scene.camera.width as usize);
    let weights = loss_weights(seed, h * w * (scene.channels + 1));
    let (grads, _) = autodiff_grads(scene, DType::F64, AlphaCutoff::Smooth, &weights);
    let mut worst: f64 = 0.0;
    for (k, name) in INPUT_NAMES.iter().enumerate() {
        let analytic = &grads[k];
        let scale = analytic.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let mut probe = scene.clone();
        for (i, &a) in analytic.iter().enumerate() {
            let x = input_mut(&mut probe, k)[i];
            let step = 1e-6 * x.abs().max(1.0);
            input_mut(&mut probe, k)[i] = x + step;
            let up = loss(&probe, &weights);
            input_mut(&mut probe, k)[i] = x - step;
            let down = loss(&probe, &weights);
            input_mut(&mut probe, k)[i] = x;
            let fd = (up - down) / (2.0 * step);
            // Relative error, with a floor so that entries that are zero up to rounding do not
            // divide by ~0.
            let denom = a.abs().max(fd.abs()).max(1e-3 * scale).max(1e-9);
            let rel = (a - fd).abs() / denom;
            assert!(
                rel <= 1e-4,
                "{name}[{i}]: autodiff {a:e} vs finite difference {fd:e} (rel {rel:e})"
            );
            worst = worst.max(rel);
        }
        assert!(scale > 0.0, "{name}: all gradients are zero");
    }
    worst
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
