//! Stiff and extreme inputs: outputs and gradients stay finite; non-finite parameters are
//! culled (status 2) and get zero gradients.

use burn::tensor::DType;
use gtsr_render_kernels::AlphaCutoff;
use gtsr_render_kernels::config::status;
use gtsr_render_kernels::scenes::stiff_cases;

use crate::common::{INPUT_NAMES, autodiff_grads, loss_weights};

#[test]
fn stiff_cases_stay_finite_in_f32_and_f64() {
    for case in stiff_cases() {
        let s = &case.scene;
        let (h, w) = (s.camera.height as usize, s.camera.width as usize);
        let weights = loss_weights(5, h * w * (s.channels + 1));
        for dtype in [DType::F32, DType::F64] {
            for cutoff in [AlphaCutoff::Hard, AlphaCutoff::Smooth] {
                let (grads, out) = autodiff_grads(s, dtype, cutoff, &weights);
                let bad = out.iter().filter(|v| !v.is_finite()).count();
                assert_eq!(
                    bad, 0,
                    "{} {dtype:?} {cutoff:?}: {bad} non-finite outputs",
                    case.name
                );
                for (g, name) in grads.iter().zip(INPUT_NAMES) {
                    let bad = g.iter().filter(|v| !v.is_finite()).count();
                    assert_eq!(
                        bad, 0,
                        "{} {dtype:?} {cutoff:?}: {bad} non-finite gradients of {name}",
                        case.name
                    );
                }
                // Alpha stays a probability.
                let c = s.channels;
                assert!(
                    out.chunks(c + 1).all(|p| (0.0..=1.0).contains(&p[c])),
                    "{}: alpha outside [0, 1]",
                    case.name
                );
            }
        }
    }
}

fn aux_of(case_name: &str) -> (Vec<f64>, gtsr_render_kernels::scenes::HostScene) {
    let case = stiff_cases()
        .into_iter()
        .find(|c| c.name == case_name)
        .unwrap();
    let out = gtsr_render_kernels::render(
        case.scene
            .inputs(&burn::tensor::Device::ndarray(), DType::F32),
        &case.scene.config(AlphaCutoff::Hard),
    )
    .unwrap();
    (crate::common::host(out.aux), case.scene)
}

#[test]
fn non_finite_parameters_are_culled_with_zero_gradients() {
    let (aux, scene) = aux_of("NaN / Inf parameters");
    let n = scene.len();
    // The last five Gaussians carry a NaN or an infinity each.
    for i in n - 5..n {
        assert_eq!(
            aux[4 * i + 3],
            f64::from(status::NON_FINITE),
            "Gaussian {i}"
        );
        assert_eq!(aux[4 * i], 0.0);
    }
    assert!(
        aux[..4 * (n - 5)]
            .chunks(4)
            .any(|a| a[3] == f64::from(status::VISIBLE))
    );
    let (h, w) = (scene.camera.height as usize, scene.camera.width as usize);
    let weights = loss_weights(3, h * w * 4);
    let (grads, _) = autodiff_grads(&scene, DType::F32, AlphaCutoff::Hard, &weights);
    for (g, name) in grads.iter().zip(INPUT_NAMES) {
        let per = g.len() / n;
        assert!(
            g[per * (n - 5)..].iter().all(|v| *v == 0.0),
            "{name}: culled Gaussians must have zero gradient"
        );
    }
}

#[test]
fn clipping_and_degenerate_statuses() {
    let (aux, _) = aux_of("behind the camera");
    assert_eq!(aux[3], f64::from(status::CLIPPED));
    let (aux, _) = aux_of("near-zero quaternion (1e-5)");
    assert_eq!(aux[aux.len() - 1], f64::from(status::DEGENERATE));
    let (aux, _) = aux_of("far outside the frustum");
    assert_eq!(aux[3], f64::from(status::NOT_ON_SCREEN));
    let (aux, _) = aux_of("huge scales (1e3)");
    assert_eq!(aux[3], f64::from(status::VISIBLE));
    let (aux, _) = aux_of("edge-on flat (scale 1e-6)");
    assert_eq!(aux[3], f64::from(status::VISIBLE));
}

#[test]
fn ten_thousand_splats_on_one_pixel_saturate() {
    let (aux, scene) = aux_of("10,000 splats on one pixel");
    assert_eq!(scene.len(), 10_000);
    assert!(aux.chunks(4).all(|a| a[3] == f64::from(status::VISIBLE)));
    let out = crate::common::render_host(&scene, DType::F32, AlphaCutoff::Hard);
    let (w, h) = (scene.camera.width as usize, scene.camera.height as usize);
    let centre = (h / 2) * w + w / 2;
    let alpha = out[centre * 4 + 3];
    // Blending stops once transmittance would drop below 1e-4.
    assert!(alpha > 0.999 && alpha <= 1.0 - 1e-4 + 1e-6, "alpha {alpha}");
}
