use burn::tensor::{DType, Device};
use gtsr_render_kernels::scenes::{HostScene, axis_camera};
use gtsr_render_kernels::{AlphaCutoff, BLUR_PX2, PIXEL_BOX_BLUR_PX2, render};

use crate::common::host;

#[test]
fn isotropic_gaussian_alpha_profile() {
    let (w, h, f, z, s, o) = (64u32, 64u32, 80.0, 4.0, 0.1, 0.7);
    let camera = axis_camera(w, h, f);
    let scene = HostScene {
        means: vec![0.0, 0.0, z],
        quats: vec![0.3, 0.5, -0.2, 0.7], // any rotation: the Gaussian is isotropic
        scales: vec![s; 3],
        opacities: vec![o],
        features: vec![1.0],
        xy_offsets: vec![0.0, 0.0],
        channels: 1,
        background: vec![0.0],
        camera: camera.clone(),
    };
    for (dtype, blur) in [
        (DType::F64, BLUR_PX2),
        (DType::F32, BLUR_PX2),
        (DType::F64, PIXEL_BOX_BLUR_PX2),
        (DType::F32, 0.0),
    ] {
        let mut cfg = scene.config(AlphaCutoff::Hard);
        cfg.blur_px2 = blur;
        let out = render(scene.inputs(&Device::ndarray(), dtype), &cfg).unwrap();
        let alpha = host(out.alpha);
        // The mean projects onto the centre of pixel (w/2, h/2).
        let (ci, cj) = ((w / 2) as usize, (h / 2) as usize);
        let centre = alpha[cj * w as usize + ci];
        assert!(
            (centre - o).abs() < 1e-6,
            "{dtype:?}: alpha at centre {centre} != {o}"
        );
        // sigma^2 in pixels: (f s / z)^2 plus the low-pass filter.
        let sigma2 = (f * s / z).powi(2) + blur;
        let mut checked = 0;
        for j in 0..h as usize {
            for i in 0..w as usize {
                let r2 = (i as f64 - ci as f64).powi(2) + (j as f64 - cj as f64).powi(2);
                let want = o * (-r2 / (2.0 * sigma2)).exp();
                let got = alpha[j * w as usize + i];
                if want >= 1.0 / 255.0 {
                    assert!(
                        (got - want).abs() <= 1e-4,
                        "{dtype:?}, blur {blur}: alpha at r^2 = {r2}: {got} vs {want}"
                    );
                    checked += 1;
                } else {
                    assert_eq!(got, 0.0, "{dtype:?}: alpha below the cut-off must be 0");
                }
            }
        }
        assert!(checked > 50, "profile covers only {checked} pixels");
    }
}

/// An edge-on splat is as wide on screen as the blur: its alpha across the edge falls off with
/// variance `blur_px2`, so 3DGS's 0.3 px^2 spreads it over more pixels than the pixel box's 1/12.
#[test]
fn edge_on_splat_is_as_wide_as_the_blur() {
    let (w, h, f, z, o) = (33u32, 33u32, 80.0, 4.0, 0.9);
    // A splat thin along y (long along x), seen edge-on, its mean half a pixel below the centre
    // of pixel row h/2.
    let scene = HostScene {
        means: vec![0.0, 0.5 * z / f, z],
        quats: vec![1.0, 0.0, 0.0, 0.0],
        scales: vec![0.2, 1e-7, 1e-7],
        opacities: vec![o],
        features: vec![1.0],
        xy_offsets: vec![0.0, 0.0],
        channels: 1,
        background: vec![0.0],
        camera: axis_camera(w, h, f),
    };
    let (ci, cj) = ((w / 2) as usize, (h / 2) as usize);
    let mut half_px_off = Vec::new();
    for blur in [BLUR_PX2, PIXEL_BOX_BLUR_PX2] {
        let mut cfg = scene.config(AlphaCutoff::Hard);
        cfg.blur_px2 = blur;
        let out = render(scene.inputs(&Device::ndarray(), DType::F64), &cfg).unwrap();
        let alpha = host(out.alpha);
        let got = alpha[cj * w as usize + ci];
        let want = o * (-0.125 / blur).exp();
        assert!(
            (got - want).abs() <= 1e-6 * o,
            "blur {blur}: alpha half a pixel across the edge {got} vs {want}"
        );
        half_px_off.push(got);
    }
    assert!(half_px_off[0] > 2.0 * half_px_off[1], "{half_px_off:?}");
}
