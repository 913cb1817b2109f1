//! `gtsr_mesh::consistency`: the multi-view depth filter on exact sphere depth maps.

mod common;

use glam::Vec3;
use gtsr_data::Camera;
use gtsr_mesh::consistency::{ConsistencySettings, DepthView, filter_consistent, nearest_views};

/// A camera at `eye` looking at the origin, 32 x 32 px, 60 degrees across.
fn camera(eye: Vec3) -> Camera {
    Camera::look_at(eye, Vec3::ZERO, Vec3::Y, 60f32.to_radians(), 32, 32)
}

/// The z-depth of the sphere of radius `r` at the origin through each pixel centre.
fn sphere_depth(c: &Camera, r: f32) -> Vec<f32> {
    common::render_sphere(c, Vec3::ZERO, r).0
}

fn ring(n: usize) -> Vec<Camera> {
    (0..n)
        .map(|k| {
            let a = k as f32 / n as f32 * std::f32::consts::TAU;
            camera(Vec3::new(3.0 * a.cos(), 0.5, 3.0 * a.sin()))
        })
        .collect()
}

#[test]
fn exact_depth_is_kept_and_an_outlier_dropped() {
    let cams = ring(12);
    let mut maps: Vec<Vec<f32>> = cams.iter().map(|c| sphere_depth(c, 0.8)).collect();
    // One sample of view 0 far behind the surface, one in front of it.
    let centre = 16 * 32 + 16;
    assert!(maps[0][centre] > 0.0);
    maps[0][centre] += 0.5;
    maps[0][centre + 1] -= 0.3;
    let views: Vec<DepthView> = cams
        .iter()
        .zip(&maps)
        .map(|(camera, depth)| DepthView { camera, depth })
        .collect();
    let settings = ConsistencySettings::default();
    let (out, stats) = filter_consistent(&views, &settings).unwrap();
    assert_eq!(out[0][centre], 0.0, "the far sample is dropped");
    assert_eq!(out[0][centre + 1], 0.0, "the near sample is dropped");
    // Everything else on the sphere is kept but a few grazing samples at the rim.
    assert!(stats.samples > 12 * 150, "{stats:?}");
    assert!(
        (stats.dropped as f32) < 0.1 * stats.samples as f32,
        "too many exact samples dropped: {stats:?}"
    );
    for (a, b) in out.iter().flatten().zip(maps.iter().flatten()) {
        assert!(*a == 0.0 || a == b, "kept samples are unchanged");
    }
    // Order of the views does not matter.
    let reversed: Vec<DepthView> = views.iter().rev().copied().collect();
    let (back, stats_back) = filter_consistent(&reversed, &settings).unwrap();
    assert_eq!(stats, stats_back);
    assert_eq!(back[11], out[0]);
}

#[test]
fn a_shifted_view_disagrees_with_its_neighbours() {
    let cams = ring(12);
    let mut maps: Vec<Vec<f32>> = cams.iter().map(|c| sphere_depth(c, 0.8)).collect();
    for d in maps[3].iter_mut().filter(|d| **d > 0.0) {
        *d += 0.4;
    }
    let views: Vec<DepthView> = cams
        .iter()
        .zip(&maps)
        .map(|(camera, depth)| DepthView { camera, depth })
        .collect();
    let (out, _) = filter_consistent(&views, &ConsistencySettings::default()).unwrap();
    let kept = out[3].iter().filter(|d| **d > 0.0).count();
    let had = maps[3].iter().filter(|d| **d > 0.0).count();
    // Near the rim a sample shifted along its grazing ray stays near the sphere; the rest
    // (the centre included) go.
    assert!(kept * 5 < had, "kept {kept} of {had}");
    assert_eq!(out[3][16 * 32 + 16], 0.0);
}

#[test]
fn neighbours_are_the_nearest_axes() {
    let cams = ring(12);
    let refs: Vec<&Camera> = cams.iter().collect();
    let mut near = nearest_views(&refs, 0, 2);
    near.sort();
    assert_eq!(near, vec![1, 11]);
    assert_eq!(nearest_views(&refs, 5, 4).len(), 4);
}

#[test]
fn bad_settings_and_sizes_are_errors() {
    let cams = ring(3);
    let maps: Vec<Vec<f32>> = cams.iter().map(|c| sphere_depth(c, 0.8)).collect();
    let views: Vec<DepthView> = cams
        .iter()
        .zip(&maps)
        .map(|(camera, depth)| DepthView { camera, depth })
        .collect();
    for bad in [
        ConsistencySettings {
            min_agree: 3,
            neighbours: 2,
            footprints: 1.0,
        },
        ConsistencySettings {
            min_agree: 0,
            ..Default::default()
        },
        ConsistencySettings {
            footprints: f32::NAN,
            ..Default::default()
        },
        ConsistencySettings {
            footprints: 0.0,
            ..Default::default()
        },
    ] {
        assert!(filter_consistent(&views, &bad).is_err(), "{bad:?}");
    }
    let short = [0.0f32; 5];
    let views = [DepthView {
        camera: &cams[0],
        depth: &short,
    }];
    let err = filter_consistent(&views, &ConsistencySettings::default()).unwrap_err();
    assert!(err.to_string().contains("depth map of view 0"), "{err}");
}
