use burn::tensor::DType;
use gtsr_render_kernels::AlphaCutoff;
use gtsr_render_kernels::reference::render_reference;
use gtsr_render_kernels::scenes::{HostScene, RandomSceneSpec, axis_camera, random_scene};

use crate::common::render_host;

fn spec(count: usize, size: (u32, u32)) -> RandomSceneSpec {
    RandomSceneSpec {
        count,
        channels: 3,
        size,
        radius: 1.0,
        scale_range: (0.01, 0.4),
        opacity_range: (0.02, 0.99),
        distance: 4.0,
        fov_x: 0.8,
    }
}

fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// Gaussians centred on tile corners and edges, large enough to straddle several tiles.
fn tile_border_scene() -> HostScene {
    let camera = axis_camera(70, 45, 50.0);
    let z = 3.0;
    let mut s = HostScene {
        means: vec![],
        quats: vec![],
        scales: vec![],
        opacities: vec![],
        features: vec![],
        xy_offsets: vec![],
        channels: 2,
        background: vec![0.25, -0.5],
        camera: camera.clone(),
    };
    let mut k = 0.0;
    for &px in &[0.0, 16.0, 32.0, 48.0, 64.0, 70.0] {
        for &py in &[0.0, 16.0, 32.0, 45.0] {
            // World point projecting exactly onto (px, py).
            let x = (px - camera.cx) * z / camera.fx;
            let y = (py - camera.cy) * z / camera.fy;
            s.means.extend([x, y, z + 0.01 * k]);
            s.quats.extend([1.0, 0.1 * k, -0.05 * k, 0.3]);
            s.scales.extend([0.08 + 0.01 * k, 0.05, 0.02]);
            s.opacities.push(0.3 + 0.02 * k);
            s.features.extend([k / 24.0, 1.0 - k / 24.0]);
            s.xy_offsets.extend([0.0, 0.0]);
            k += 1.0;
        }
    }
    s
}

#[test]
fn forward_matches_brute_force_in_f64() {
    let mut cases: Vec<HostScene> = [1usize, 3, 10, 40, 120, 400]
        .iter()
        .enumerate()
        .map(|(i, &n)| random_scene(100 + i as u64, &spec(n, (61, 47))))
        .collect();
    cases.push(tile_border_scene());
    for (i, scene) in cases.iter().enumerate() {
        for cutoff in [AlphaCutoff::Hard, AlphaCutoff::Smooth] {
            let got = render_host(scene, DType::F64, cutoff);
            let want = render_reference(&scene.host(), &scene.config(cutoff));
            let d = max_abs_diff(&got, &want);
            assert!(
                d <= 1e-6,
                "scene {i} ({cutoff:?}): max |tiled - brute force| = {d:e}"
            );
            // The scene must actually draw something.
            let c = scene.channels;
            let covered = want.chunks(c + 1).filter(|p| p[c] > 0.01).count();
            assert!(covered > 0, "scene {i} draws nothing");
        }
    }
}

#[test]
fn forward_f32_is_close_to_f64_reference() {
    for seed in 0..4u64 {
        let scene = random_scene(200 + seed, &spec(60, (64, 48)));
        let got = render_host(&scene, DType::F32, AlphaCutoff::Smooth);
        let want = render_reference(&scene.host(), &scene.config(AlphaCutoff::Smooth));
        let d = max_abs_diff(&got, &want);
        assert!(d <= 1e-4, "seed {seed}: max |f32 - f64 reference| = {d:e}");
    }
}

#[test]
fn tile_border_scene_touches_several_tiles() {
    // Guards the test above: its splats really straddle tile borders.
    let scene = tile_border_scene();
    let out = gtsr_render_kernels::render(
        scene.inputs(&burn::tensor::Device::ndarray(), DType::F64),
        &scene.config(AlphaCutoff::Hard),
    )
    .unwrap();
    let aux = crate::common::host(out.aux);
    let multi = aux.chunks(4).filter(|a| a[3] == 0.0 && a[2] >= 2.0).count();
    assert!(multi >= 10, "only {multi} splats touch two or more tiles");
}
