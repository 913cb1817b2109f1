use burn::tensor::{DType, Device};
use gtsr_render_kernels::scenes::{HostScene, axis_camera};
use gtsr_render_kernels::{AlphaCutoff, render};

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
    for dtype in [DType::F64, DType::F32] {
        let out = render(
            scene.inputs(&Device::ndarray(), dtype),
            &scene.config(AlphaCutoff::Hard),
        )
        .unwrap();
        let alpha = host(out.alpha);
        // The mean projects onto the centre of pixel (w/2, h/2).
        let (ci, cj) = ((w / 2) as usize, (h / 2) as usize);
        let centre = alpha[cj * w as usize + ci];
        assert!(
            (centre - o).abs() < 1e-6,
            "{dtype:?}: alpha at centre {centre} != {o}"
        );
        // sigma^2 in pixels: (f s / z)^2 plus the 0.3 px^2 low-pass filter.
        let sigma2 = (f * s / z).powi(2) + 0.3;
        let mut checked = 0;
        for j in 0..h as usize {
            for i in 0..w as usize {
                let r2 = (i as f64 - ci as f64).powi(2) + (j as f64 - cj as f64).powi(2);
                let want = o * (-r2 / (2.0 * sigma2)).exp();
                let got = alpha[j * w as usize + i];
                if want >= 1.0 / 255.0 {
                    assert!(
                        (got - want).abs() <= 1e-4,
                        "{dtype:?}: alpha at r^2 = {r2}: {got} vs {want}"
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
