//! The f32 lane kernels (`cpu::BlendPath`): every instruction set gives bit-identical renders
//! and gradients, and they agree with the per-pixel code and the f64 reference.

use gtsr_render_kernels::cpu::{self, BlendPath, HostGradients};
use gtsr_render_kernels::reference::render_reference;
use gtsr_render_kernels::scenes::{
    HostScene, RandomSceneSpec, random_scene, random_weights, stiff_cases,
};
use gtsr_render_kernels::{AlphaCutoff, SplatConfig};

/// Forward and backward (loss = sum of weights * output) on one path.
fn run(scene: &HostScene, path: BlendPath, weights: &[f64]) -> (Vec<f32>, HostGradients<f32>, u64) {
    let h = scene.to_f32();
    let cfg: SplatConfig = scene.config(AlphaCutoff::Hard);
    let out = cpu::forward_with(&h.host(), &cfg, path);
    let grad: Vec<f32> = weights.iter().map(|&w| w as f32).collect();
    let g = cpu::backward(&h.host(), &cfg, &out.state, &grad);
    (out.image, g, out.evaluations)
}

fn grads_flat(g: &HostGradients<f32>) -> Vec<f32> {
    g.clone().into_parts().concat()
}

fn scenes() -> Vec<(String, HostScene)> {
    let mut out = Vec::new();
    for (i, &(n, w, h)) in [(40usize, 61u32, 47u32), (400, 96, 80), (3000, 128, 112)]
        .iter()
        .enumerate()
    {
        let spec = RandomSceneSpec {
            count: n,
            channels: [3, 1, 7][i],
            size: (w, h),
            radius: 1.0,
            scale_range: (0.005, 0.4),
            opacity_range: (0.02, 0.999),
            distance: 4.0,
            fov_x: 0.8,
        };
        out.push((format!("random {n}"), random_scene(300 + i as u64, &spec)));
    }
    for case in stiff_cases() {
        out.push((format!("stiff: {}", case.name), case.scene));
    }
    out
}

#[test]
fn every_instruction_set_gives_bit_identical_renders_and_gradients() {
    let paths: Vec<BlendPath> = [BlendPath::LanesAvx2, BlendPath::LanesAvx512]
        .into_iter()
        .filter(|p| p.available())
        .collect();
    eprintln!("lane paths compared with the portable build: {paths:?}");
    for (name, scene) in scenes() {
        let (w, h) = (scene.camera.width as usize, scene.camera.height as usize);
        let weights = random_weights(5, w * h * (scene.channels + 1));
        let (img0, g0, e0) = run(&scene, BlendPath::LanesScalar, &weights);
        let g0 = grads_flat(&g0);
        for &p in &paths {
            let (img, g, e) = run(&scene, p, &weights);
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&img), bits(&img0), "{name}: {p:?} render differs");
            assert_eq!(
                bits(&grads_flat(&g)),
                bits(&g0),
                "{name}: {p:?} gradients differ"
            );
            assert_eq!(e, e0, "{name}: {p:?} evaluation count differs");
        }
    }
}

fn max_abs_diff(a: &[f32], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(&x, &y)| (f64::from(x) - y).abs())
        .fold(0.0, f64::max)
}

#[test]
fn lanes_agree_with_the_per_pixel_code_and_the_f64_reference() {
    for (name, scene) in scenes().into_iter().take(3) {
        let (w, h) = (scene.camera.width as usize, scene.camera.height as usize);
        let weights = random_weights(6, w * h * (scene.channels + 1));
        let (img_l, g_l, e_l) = run(&scene, BlendPath::best(), &weights);
        let (img_p, g_p, e_p) = run(&scene, BlendPath::PerPixel, &weights);
        assert!(
            img_l.iter().any(|&v| v != 0.0),
            "{name}: the scene draws nothing"
        );
        assert_eq!(e_l, e_p, "{name}: the lanes visit other pixels");
        let reference = render_reference(&scene.host(), &scene.config(AlphaCutoff::Hard));
        let d_ref = max_abs_diff(&img_l, &reference);
        assert!(
            d_ref <= 1e-4,
            "{name}: max |lanes - f64 reference| = {d_ref:e}"
        );
        let img_p64: Vec<f64> = img_p.iter().map(|&x| f64::from(x)).collect();
        let d = max_abs_diff(&img_l, &img_p64);
        assert!(d <= 1e-5, "{name}: max |lanes - per-pixel| = {d:e}");
        // Gradients: relative to the largest of each input's gradients.
        for (k, (a, b)) in [
            (&g_l.means, &g_p.means),
            (&g_l.quats, &g_p.quats),
            (&g_l.scales, &g_p.scales),
            (&g_l.opacities, &g_p.opacities),
            (&g_l.features, &g_p.features),
        ]
        .into_iter()
        .enumerate()
        {
            let scale = b.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-12);
            let worst = a
                .iter()
                .zip(b.iter())
                .map(|(x, y)| (x - y).abs() / scale)
                .fold(0f32, f32::max);
            assert!(
                worst <= 1e-3,
                "{name}: input {k}: gradients differ by {worst:e} of their largest"
            );
        }
    }
}
