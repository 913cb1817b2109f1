//! The forward-only crossing render (`render_crossing`): against the brute-force reference, on
//! analytic two-layer cases, and its input checks.

use burn::tensor::{DType, Device, Tensor};
use gtsr_render_kernels::reference::crossing_reference;
use gtsr_render_kernels::scenes::{HostScene, RandomSceneSpec, axis_camera, random_scene};
use gtsr_render_kernels::{AlphaCutoff, RenderError, SplatConfig, SplatInputs, render_crossing};

use crate::common::{host, render_host};

fn spec(count: usize) -> RandomSceneSpec {
    RandomSceneSpec {
        count,
        channels: 2,
        size: (53, 41),
        radius: 1.0,
        scale_range: (0.02, 0.4),
        opacity_range: (0.05, 0.99),
        distance: 4.0,
        fov_x: 0.8,
    }
}

#[test]
fn crossing_matches_brute_force_in_f64() {
    let mut checked = 0;
    for (i, &n) in [5usize, 40, 200].iter().enumerate() {
        let scene = random_scene(300 + i as u64, &spec(n));
        for cutoff in [AlphaCutoff::Hard, AlphaCutoff::Smooth] {
            let cfg = scene.config(cutoff);
            let mut seen_before = n;
            for threshold in [0.2, 0.5, 0.9] {
                let out = render_crossing(
                    scene.inputs(&Device::ndarray(), DType::F64),
                    &cfg,
                    threshold,
                )
                .unwrap();
                let (want_f, want_found, want_obs) =
                    crossing_reference(&scene.host(), &cfg, threshold);
                assert_eq!(
                    out.observed, want_obs,
                    "scene {i} ({cutoff:?}, T = {threshold}): observed Gaussians differ"
                );
                let seen = want_obs.iter().filter(|o| **o).count();
                if n == 200 {
                    // Some Gaussians are blended in front of the crossing, some only behind it.
                    assert!(seen > 0 && seen < n, "scene {i}: {seen} of {n} observed");
                }
                // A higher threshold observes a subset.
                assert!(
                    seen <= seen_before,
                    "scene {i}: {seen} observed after {seen_before}"
                );
                seen_before = seen;
                let got_f = host(out.features);
                let got_found = host(out.found);
                assert_eq!(
                    got_found, want_found,
                    "scene {i} ({cutoff:?}, T = {threshold}): crossing pixels differ"
                );
                let d = got_f
                    .iter()
                    .zip(&want_f)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max);
                assert!(d == 0.0, "scene {i}: features differ by {d:e}");
                // Both outcomes must occur, or the comparison shows little.
                let hits = got_found.iter().filter(|f| **f > 0.5).count();
                if n >= 40 {
                    assert!(hits > 0 && hits < got_found.len(), "scene {i}: {hits} hits");
                }
                // The alpha is the ordinary render's.
                let plain = render_host(&scene, DType::F64, cutoff);
                let c = scene.channels;
                let alpha = host(out.alpha);
                for (p, a) in alpha.iter().enumerate() {
                    assert!((a - plain[p * (c + 1) + c]).abs() < 1e-12);
                }
                checked += hits;
            }
        }
    }
    assert!(checked > 1000, "only {checked} crossing pixels checked");
}

/// Two flat discs facing the camera on its axis, at depths 3.5 and 4.5, whose single feature
/// is their depth. The back disc is the smaller, so that wherever it is blended the front one
/// is near its peak opacity.
fn two_discs(front: f64, back: f64) -> (SplatInputs, SplatConfig) {
    let device = Device::ndarray();
    let scene = HostScene {
        means: vec![0.0, 0.0, 3.5, 0.0, 0.0, 4.5],
        quats: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
        scales: vec![0.8, 0.8, 1e-4, 0.25, 0.25, 1e-4],
        opacities: vec![front, back],
        features: vec![3.5, 4.5],
        xy_offsets: vec![0.0; 4],
        channels: 1,
        background: vec![0.0],
        camera: axis_camera(32, 32, 40.0),
    };
    (
        scene.inputs(&device, DType::F64),
        scene.config(AlphaCutoff::Hard),
    )
}

fn centre(t: Tensor<3>) -> f64 {
    let v = host(t);
    v[16 * 32 + 16]
}

#[test]
fn crossing_takes_the_layer_where_transmittance_falls() {
    // An opaque front layer: T = 0.1 after it.
    let (inputs, cfg) = two_discs(0.9, 0.9);
    assert_eq!(
        centre(render_crossing(inputs, &cfg, 0.5).unwrap().features),
        3.5
    );
    // A faint front layer (T = 0.7 after it) hands the median to the back one ...
    let (inputs, cfg) = two_discs(0.3, 0.9);
    assert_eq!(
        centre(render_crossing(inputs, &cfg, 0.5).unwrap().features),
        4.5
    );
    // ... but not a threshold it already crosses.
    let (inputs, cfg) = two_discs(0.3, 0.9);
    assert_eq!(
        centre(render_crossing(inputs, &cfg, 0.8).unwrap().features),
        3.5
    );
    // The opaque front layer hides the back one from the median; a faint one does not.
    let (inputs, cfg) = two_discs(0.9, 0.9);
    assert_eq!(
        render_crossing(inputs, &cfg, 0.5).unwrap().observed,
        [true, false]
    );
    let (inputs, cfg) = two_discs(0.3, 0.9);
    assert_eq!(
        render_crossing(inputs, &cfg, 0.5).unwrap().observed,
        [true, true]
    );
    // Two faint layers never reach 0.5 (T = 0.7 * 0.8): nothing found.
    let (inputs, cfg) = two_discs(0.3, 0.2);
    let out = render_crossing(inputs, &cfg, 0.5).unwrap();
    assert_eq!(centre(out.features), 0.0);
    assert_eq!(host(out.found)[16 * 32 + 16], 0.0);
}

#[test]
fn crossing_f32_agrees_with_f64() {
    let scene = random_scene(77, &spec(120));
    let cfg = scene.config(AlphaCutoff::Hard);
    let a = render_crossing(scene.inputs(&Device::ndarray(), DType::F32), &cfg, 0.5).unwrap();
    let b = render_crossing(scene.inputs(&Device::ndarray(), DType::F64), &cfg, 0.5).unwrap();
    assert_eq!(a.features.dtype(), DType::F32);
    let (fa, fb) = (host(a.found), host(b.found));
    // A pixel whose transmittance lands within f32 rounding of 0.5 may flip; no more than a few.
    let flips = fa.iter().zip(&fb).filter(|(x, y)| x != y).count();
    assert!(flips <= 3, "{flips} pixels differ between f32 and f64");
    assert!(fb.iter().filter(|f| **f > 0.5).count() > 100);
}

#[test]
fn crossing_refuses_thresholds_outside_0_1() {
    for t in [0.0, 1.0, -0.5, 2.0, f64::NAN, f64::INFINITY] {
        let (inputs, cfg) = two_discs(0.9, 0.9);
        match render_crossing(inputs, &cfg, t) {
            Err(RenderError::Threshold(_)) => {}
            other => panic!("threshold {t}: expected Threshold, got {other:?}"),
        }
    }
}
