//! The blur's opacity compensation (`SplatConfig::compensate_blur`): what a splat covers no
//! longer depends on the blur; its factor; gradients against finite differences; stiff inputs.

use burn::tensor::{DType, Device};
use gtsr_render_kernels::antialias::MIN_COMPENSATION;
use gtsr_render_kernels::scenes::{
    HostScene, RandomSceneSpec, axis_camera, random_scene, stiff_cases,
    weighted_loss_gradients_through, weighted_loss_gradients_with,
};
use gtsr_render_kernels::{
    AlphaCutoff, BLUR_PX2, PIXEL_BOX_BLUR_PX2, SplatConfig, SplatInputs, blur_compensation, render,
};

use crate::common::{INPUT_NAMES, check_against_finite_differences, host, loss_weights};

/// One Gaussian seen by an on-axis camera (focal 80 px, image 48 x 48), its mean on the centre of
/// pixel (24, 24).
fn single(scales: [f64; 3], quat: [f64; 4], opacity: f64) -> HostScene {
    HostScene {
        means: vec![0.0, 0.0, 4.0],
        quats: quat.to_vec(),
        scales: scales.to_vec(),
        opacities: vec![opacity],
        features: vec![1.0],
        xy_offsets: vec![0.0, 0.0],
        channels: 1,
        background: vec![0.0],
        camera: axis_camera(48, 48, 80.0),
    }
}

fn config(scene: &HostScene, cutoff: AlphaCutoff, blur: f64, compensate: bool) -> SplatConfig {
    SplatConfig {
        blur_px2: blur,
        compensate_blur: compensate,
        ..scene.config(cutoff)
    }
}

fn factor(scene: &HostScene, blur: f64) -> f64 {
    let inp = scene.inputs(&Device::ndarray(), DType::F64);
    let cfg = config(scene, AlphaCutoff::Hard, blur, true);
    host(blur_compensation(&inp.means, &inp.quats, &inp.scales, &cfg))[0]
}

#[test]
fn the_blur_no_longer_changes_what_a_splat_covers() {
    // Isotropic, 0.5 px standard deviation on screen (f s / z = 80 * 0.025 / 4).
    let scene = single([0.025; 3], [1.0, 0.0, 0.0, 0.0], 0.6);
    let sigma2 = 0.25;
    let covered = |blur: f64, compensate: bool| {
        let cfg = config(&scene, AlphaCutoff::Hard, blur, compensate);
        let out = render(scene.inputs(&Device::ndarray(), DType::F64), &cfg).unwrap();
        let alpha = host(out.alpha);
        (alpha.iter().sum::<f64>(), alpha[24 * 48 + 24])
    };
    // The Gaussian's own integral: o 2 pi sqrt(det Sigma).
    let want = 0.6 * 2.0 * std::f64::consts::PI * sigma2;
    for blur in [PIXEL_BOX_BLUR_PX2, BLUR_PX2] {
        let (sum, centre) = covered(blur, true);
        assert!(
            (sum / want - 1.0).abs() < 0.03,
            "blur {blur}: {sum} vs {want}"
        );
        // At the centre: o sqrt(det Sigma / det(Sigma + b I)) = o sigma^2 / (sigma^2 + b).
        let c = sigma2 / (sigma2 + blur);
        assert!((centre - 0.6 * c).abs() < 1e-9, "blur {blur}: {centre}");
        assert!((factor(&scene, blur) - c).abs() < 1e-12);
        // Without the compensation the blur adds to the coverage by (sigma^2 + b) / sigma^2.
        let (plain, _) = covered(blur, false);
        let grown = (sigma2 + blur) / sigma2;
        assert!((plain / sum / grown - 1.0).abs() < 0.03, "{plain} / {sum}");
    }
}

#[test]
fn the_factor_is_one_for_wide_splats_and_small_for_thin_ones() {
    let face_on = single([0.5, 0.5, 1e-7], [1.0, 0.0, 0.0, 0.0], 0.8);
    let f = factor(&face_on, PIXEL_BOX_BLUR_PX2);
    assert!(f > 0.99 && f <= 1.0, "{f}");
    assert_eq!(factor(&face_on, 0.0), 1.0);
    // Thin along y: 4 px by 0.04 px on screen, det Sigma = 16 * 0.0016.
    let thin = single([0.2, 0.002, 1e-7], [1.0, 0.0, 0.0, 0.0], 0.8);
    let b = PIXEL_BOX_BLUR_PX2;
    let want = (16.0 * 0.0016 / ((16.0 + b) * (0.0016 + b))).sqrt();
    assert!(
        (factor(&thin, b) - want).abs() < 1e-9,
        "{}",
        factor(&thin, b)
    );
    // A flat splat seen edge-on (its flat axis turned to camera x): clamped at the floor.
    let h = std::f64::consts::FRAC_1_SQRT_2;
    let edge_on = single([0.5, 0.5, 1e-7], [h, 0.0, h, 0.0], 0.8);
    let f = factor(&edge_on, b);
    assert!((f - MIN_COMPENSATION).abs() < 1e-12, "{f}");
}

/// `sum(W * [image, alpha])` through the public render, compensated, smooth cut-off, f64.
fn loss(scene: &HostScene, w: &[f64]) -> f64 {
    let cfg = config(scene, AlphaCutoff::Smooth, BLUR_PX2, true);
    let out = render(scene.inputs(&Device::ndarray(), DType::F64), &cfg).unwrap();
    let (img, alpha) = (host(out.image), host(out.alpha));
    let c = scene.channels;
    alpha
        .iter()
        .enumerate()
        .map(|(p, a)| {
            let colour: f64 = (0..c).map(|k| img[p * c + k] * w[p * (c + 1) + k]).sum();
            colour + a * w[p * (c + 1) + c]
        })
        .sum()
}

#[test]
fn compensated_backward_matches_finite_differences() {
    for (i, &n) in [1usize, 4, 12].iter().enumerate() {
        let spec = RandomSceneSpec {
            count: n,
            channels: 2,
            size: (32, 24),
            radius: 0.6,
            // Small splats, some thinner than the blur on screen, where the factor matters.
            scale_range: (0.004, 0.1),
            opacity_range: (0.1, 0.9),
            distance: 4.0,
            fov_x: 0.9,
        };
        let scene = random_scene(700 + i as u64, &spec);
        let weights = loss_weights(40 + i as u64, 32 * 24 * 3);
        let cfg = config(&scene, AlphaCutoff::Smooth, BLUR_PX2, true);
        let grads =
            weighted_loss_gradients_with(&Device::ndarray(), &scene, DType::F64, &cfg, &weights)
                .unwrap()
                .grads;
        let what = format!("{n} Gaussians, compensated");
        check_against_finite_differences(&scene, &grads, |s| loss(s, &weights), &what);
    }
}

#[test]
fn the_kernels_compensate_as_the_burn_expression_does() {
    // The projection's own factor and its gradient against the opacities scaled by
    // `blur_compensation` upstream (uncompensated kernels, Burn's autodiff through the factor).
    let spec = RandomSceneSpec {
        count: 300,
        channels: 3,
        size: (64, 48),
        radius: 1.0,
        scale_range: (0.001, 0.2),
        opacity_range: (0.05, 0.95),
        distance: 4.0,
        fov_x: 0.8,
    };
    let mut thin = 0;
    for (seed, blur) in [(31, BLUR_PX2), (32, PIXEL_BOX_BLUR_PX2), (33, 1.5)] {
        let scene = random_scene(seed, &spec);
        let weights = loss_weights(seed, 64 * 48 * 4);
        let device = Device::ndarray();
        let on = config(&scene, AlphaCutoff::Smooth, blur, true);
        let off = SplatConfig {
            compensate_blur: false,
            ..on.clone()
        };
        let inp = scene.inputs(&device, DType::F64);
        let f = host(blur_compensation(&inp.means, &inp.quats, &inp.scales, &on));
        thin += f.iter().filter(|v| **v < 0.5).count();
        let kernels =
            weighted_loss_gradients_with(&device, &scene, DType::F64, &on, &weights).unwrap();
        let expression =
            weighted_loss_gradients_through(&device, &scene, DType::F64, &off, &weights, |i| {
                let c = blur_compensation(&i.means, &i.quats, &i.scales, &on);
                SplatInputs {
                    opacities: i.opacities.clone() * c,
                    ..i
                }
            })
            .unwrap();
        let close = |a: &[f64], b: &[f64], what: &str| {
            let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-12);
            for (k, (x, y)) in a.iter().zip(b).enumerate() {
                assert!(
                    (x - y).abs() <= 1e-9 * scale,
                    "blur {blur}, {what}[{k}]: kernels {x}, expression {y}"
                );
            }
        };
        close(&kernels.output, &expression.output, "output");
        for ((a, b), name) in kernels.grads.iter().zip(&expression.grads).zip(INPUT_NAMES) {
            close(a, b, name);
        }
    }
    assert!(thin > 30, "only {thin} splats thinner than the blur");
}

#[test]
fn compensated_stiff_cases_stay_finite() {
    for case in stiff_cases() {
        let s = &case.scene;
        let (h, w) = (s.camera.height as usize, s.camera.width as usize);
        let weights = loss_weights(5, h * w * (s.channels + 1));
        for dtype in [DType::F32, DType::F64] {
            let cfg = config(s, AlphaCutoff::Hard, PIXEL_BOX_BLUR_PX2, true);
            let r =
                weighted_loss_gradients_with(&Device::ndarray(), s, dtype, &cfg, &weights).unwrap();
            let bad = r.output.iter().filter(|v| !v.is_finite()).count();
            assert_eq!(bad, 0, "{} {dtype:?}: {bad} non-finite outputs", case.name);
            for (g, name) in r.grads.iter().zip(INPUT_NAMES) {
                let bad = g.iter().filter(|v| !v.is_finite()).count();
                assert_eq!(bad, 0, "{} {dtype:?}: {bad} non-finite {name}", case.name);
            }
        }
    }
}
