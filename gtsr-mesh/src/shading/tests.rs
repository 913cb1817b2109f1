use super::*;

/// The views of rendered radiance and depth maps, without masks.
fn unmasked_views<'a>(
    cams: &'a [Camera],
    rads: &'a [Vec<f32>],
    depths: &'a [Vec<f32>],
) -> Vec<ShadingView<'a>> {
    cams.iter()
        .zip(rads)
        .zip(depths)
        .map(|((c, r), d)| ShadingView {
            camera: c,
            radiance: r,
            mask: None,
            mesh_depth: d,
        })
        .collect()
}

/// The trusted tilt follows a face's least vertex slack: the base up to the reference, the
/// steep limit from twice it, the angle linear between.
#[test]
fn the_trusted_tilt_ramps_with_the_least_slack_of_a_face() {
    // Four faces over five vertices; the reference slack is 2.
    let mesh = TriMesh {
        positions: vec![Vec3::ZERO; 5],
        triangles: vec![[0, 1, 2], [1, 2, 3], [2, 3, 4], [1, 2, 4]],
    };
    let slack = [0.5, 9.0, 9.0, 3.0, 4.0];
    let (base, steep) = (30f32.to_radians().sin(), 60f32.to_radians().sin());
    let t = slack_tilt_limits(&mesh, &slack, 2.0, base, steep);
    let deg: Vec<f32> = t.iter().map(|s| s.asin().to_degrees()).collect();
    // Slack 0.5 (under the reference): the base; 3 (halfway to twice it): 45 degrees;
    // 4 (twice it) and beyond: the steep limit.
    for (got, want) in deg.iter().zip([30.0, 45.0, 45.0, 60.0]) {
        assert!((got - want).abs() < 1e-3, "{deg:?}");
    }
    // Never a right angle, whatever the steep limit asked.
    let t = slack_tilt_limits(&mesh, &slack, 2.0, base, 1.0);
    assert!(t.iter().all(|s| *s > 0.0 && *s < 1.0));
}

/// The calibration's root finder: a crossing inside a step, past the old scan's 0.4, none
/// (the least value), and none to find (0).
#[test]
fn the_zero_of_a_falling_function() {
    for root in [0.0123f32, 0.37, 0.52, 0.999] {
        let got = falling_zero(|c| f64::from(root - c) * (1.0 + f64::from(c)));
        assert!((got - root).abs() < 1e-3, "root {root}: got {got}");
    }
    assert_eq!(falling_zero(|c| f64::from(2.0 - c)), 1.0);
    assert_eq!(falling_zero(|c| f64::from(-0.1 - c)), 0.0);
}

/// A flat square facing +z (two faces).
fn square() -> TriMesh {
    TriMesh {
        positions: vec![
            Vec3::new(-0.1, -0.1, 0.0),
            Vec3::new(0.1, -0.1, 0.0),
            Vec3::new(0.1, 0.1, 0.0),
            Vec3::new(-0.1, 0.1, 0.0),
        ],
        triangles: vec![[0, 1, 2], [0, 2, 3]],
    }
}

/// Renders the square as a surface of normal `truth` and albedo 0.7 whose radiance under
/// the light at the camera is `0.7 g(n . w) / r^2`, solves its normals and returns each
/// face's angle to `truth` (degrees).
fn solve(
    cams: &[Camera],
    truth: Vec3,
    g: impl Fn(f32) -> f32,
    settings: &ShadingSettings,
) -> Vec<f32> {
    let mesh = square();
    let (w, h) = (64usize, 64usize);
    let mut rads = Vec::new();
    let mut depths = Vec::new();
    for c in cams {
        let eye = c.centre();
        let mut rad = vec![0.0f32; w * h];
        let mut dep = vec![0.0f32; w * h];
        for j in 0..h {
            for i in 0..w {
                let (o, d) = c.pixel_ray(i as u32, j as u32);
                let t = -o.z / d.z;
                let x = o + d * t;
                if t > 0.0 && x.x.abs() < 0.1 && x.y.abs() < 0.1 {
                    let to = eye - x;
                    let r2 = to.length_squared();
                    rad[j * w + i] = 0.7 * g(truth.dot(to / r2.sqrt()).max(0.0)) / r2;
                    dep[j * w + i] = c.world_to_camera.transform_point3(x).z;
                }
            }
        }
        rads.push(rad);
        depths.push(dep);
    }
    let views = unmasked_views(cams, &rads, &depths);
    let got = shading_normals(&mesh, &views, None, settings)
        .unwrap()
        .normals;
    (0..2)
        .map(|f| {
            assert_eq!(got.weight[f], 1.0);
            got.normal[f]
                .dot(truth)
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees()
        })
        .collect()
}

/// A flat square facing +z, seen by cameras around it, shaded by the Lambertian law with
/// a tilted normal: the solve recovers the tilt.
#[test]
fn recovers_a_tilted_lambertian_normal_from_views_with_the_light_at_the_camera() {
    let truth = Vec3::new(0.3, -0.2, 1.0).normalize();
    let cams: Vec<Camera> = (0..12)
        .map(|k| {
            let a = k as f32 * std::f32::consts::TAU / 12.0;
            let eye = Vec3::new(1.5 * a.cos(), 1.5 * a.sin(), 3.0) * (1.0 + 0.05 * k as f32);
            Camera::look_at(eye, Vec3::ZERO, Vec3::Y, 0.3, 64, 64)
        })
        .collect();
    let settings = ShadingSettings {
        ridge: 1e-4,
        ..ShadingSettings::default()
    };
    for (f, angle) in solve(&cams, truth, |c| c, &settings).iter().enumerate() {
        assert!(*angle < 0.5, "face {f}: {angle} degrees off");
    }
}

/// A surface whose shading is flatter than Lambert's cosine (wrap lighting), seen only
/// from one side: Lambert's fit leans towards the eyes, the fitted response does not.
#[test]
fn a_fitted_response_removes_the_lean_of_a_flatter_shading() {
    let truth = Vec3::Z;
    let cams: Vec<Camera> = (0..24)
        .map(|k| {
            let dir = direction(5.0 + 3.0 * k as f32, k as f32 * 7.0);
            Camera::look_at(3.0 * dir, Vec3::ZERO, Vec3::Y, 0.3, 64, 64)
        })
        .collect();
    let wrap = |c: f32| (c + 0.5) / 1.5;
    let lambert = ShadingSettings {
        ridge: 1e-4,
        min_views: 6,
        ..ShadingSettings::default()
    };
    let leaning = solve(&cams, truth, wrap, &lambert);
    assert!(
        leaning.iter().all(|a| *a > 2.0),
        "Lambert's fit: {leaning:?}"
    );
    let fitted = solve(
        &cams,
        truth,
        wrap,
        &ShadingSettings {
            response: 4,
            ..lambert
        },
    );
    assert!(
        fitted.iter().all(|a| *a < 0.5),
        "fitted response: {fitted:?}"
    );
}

/// A floor beside a lit wall, each lit by the other (one bounce): the wall's light adds
/// to the floor's shading in the views that light it, and Lambert's fit leans; with the
/// interreflected light modelled, at the scene's constant (`1 / pi` for Lambertian
/// renders) or at the one calibrated on the images, the floor's normal is recovered.
#[test]
fn modelling_the_light_of_a_facing_wall_removes_its_lean() {
    let k = std::f32::consts::FRAC_1_PI;
    let (leaning, modelled, calibrated, c) = floor_beside_a_wall(k);
    assert!(
        leaning.iter().all(|a| *a > 2.0),
        "Lambert's fit: {leaning:?}"
    );
    assert!(modelled.iter().all(|a| *a < 0.5), "modelled: {modelled:?}");
    assert!(
        calibrated.iter().all(|a| *a < 0.5),
        "calibrated: {calibrated:?}"
    );
    assert!(
        (c / k - 1.0).abs() < 0.2,
        "calibrated c = {c}, the renders' {k}"
    );
}

/// The same with a much stronger interreflection (the renders' constant 0.6, as a very
/// translucent object shows): the calibration looks past small constants and removes the
/// lean. (The renders' second bounce, which the model reads from the images as well, is
/// then no longer small, so the constant found lies below the renders'.)
#[test]
fn a_strong_interreflection_is_calibrated_too() {
    let (leaning, _, calibrated, c) = floor_beside_a_wall(0.6);
    assert!(
        leaning.iter().all(|a| *a > 4.0),
        "Lambert's fit: {leaning:?}"
    );
    assert!(
        calibrated.iter().all(|a| *a < 0.5),
        "calibrated: {calibrated:?} at c = {c}"
    );
    assert!(c > 0.4, "calibrated c = {c}");
}

/// Renders the floor and the wall with the interreflected light scaled by `k` (the
/// albedo times `k` times the irradiance) and returns the floor faces' angles to their
/// normal (degrees) under Lambert's fit, the model at `k` and the calibrated model, and
/// the calibrated constant.
fn floor_beside_a_wall(k: f32) -> (Vec<f32>, Vec<f32>, Vec<f32>, f32) {
    let mesh = TriMesh {
        positions: vec![
            Vec3::new(-0.1, -0.1, 0.0),
            Vec3::new(0.1, -0.1, 0.0),
            Vec3::new(0.1, 0.1, 0.0),
            Vec3::new(-0.1, 0.1, 0.0),
            Vec3::new(0.1, -0.1, 0.2),
            Vec3::new(0.1, 0.1, 0.2),
        ],
        // The floor (+z) and the wall at x = 0.1 facing -x.
        triangles: vec![[0, 1, 2], [0, 2, 3], [1, 5, 2], [1, 4, 5]],
    };
    let (rho_floor, rho_wall) = (0.6f32, 0.9f32);
    let wall_n = Vec3::NEG_X;
    let cams: Vec<Camera> = (0..24)
        .map(|k| {
            let dir = direction(
                20.0 + 40.0 * (k % 6) as f32 / 5.0,
                120.0 + 120.0 * (k / 6) as f32 / 3.0,
            );
            Camera::look_at(3.0 * dir, Vec3::new(0.0, 0.0, 0.05), Vec3::Z, 0.2, 64, 64)
        })
        .collect();
    let caster = crate::raycast::MeshRaycaster::new(&mesh, "test scene").unwrap();
    // The wall on a 20 x 20 grid of cells for the floor's irradiance.
    let cells: Vec<Vec3> = (0..400)
        .map(|k| {
            let (a, b) = ((k % 20) as f32 + 0.5, (k / 20) as f32 + 0.5);
            Vec3::new(0.1, -0.1 + 0.01 * a, 0.01 * b)
        })
        .collect();
    let floor: Vec<Vec3> = (0..400)
        .map(|k| {
            let (a, b) = ((k % 20) as f32 + 0.5, (k / 20) as f32 + 0.5);
            Vec3::new(-0.1 + 0.01 * a, -0.1 + 0.01 * b, 0.0)
        })
        .collect();
    let (mut rads, mut depths) = (Vec::new(), Vec::new());
    for c in &cams {
        let eye = c.centre();
        let lit = |y: Vec3, n: Vec3, rho: f32| {
            let to = eye - y;
            let r2 = to.length_squared();
            rho * n.dot(to / r2.sqrt()).max(0.0) / r2
        };
        let mut rad = vec![0.0f32; 64 * 64];
        let mut dep = vec![0.0f32; 64 * 64];
        for j in 0..64u32 {
            for i in 0..64u32 {
                let (o, d) = c.pixel_ray(i, j);
                let Some((t, n)) = caster.first_hit(o, d) else {
                    continue;
                };
                let x = o + t * d;
                let p = (j * 64 + i) as usize;
                dep[p] = c.world_to_camera.transform_point3(x).z;
                // The irradiance at `x` (normal `nx`) from the lit cells of the other
                // plane (normal `ny`, albedo `rho`, 1e-4 each).
                let irradiance = |nx: Vec3, cells: &[Vec3], ny: Vec3, rho: f32| -> f32 {
                    cells
                        .iter()
                        .map(|y| {
                            let to = *y - x;
                            let d2 = to.length_squared();
                            let u = to / d2.sqrt();
                            lit(*y, ny, rho) * nx.dot(u).max(0.0) * (-ny.dot(u)).max(0.0) * 1e-4
                                / d2
                        })
                        .sum()
                };
                rad[p] = if n.z > 0.9 {
                    let e = irradiance(Vec3::Z, &cells, wall_n, rho_wall);
                    lit(x, Vec3::Z, rho_floor) + rho_floor * k * e
                } else {
                    let e = irradiance(wall_n, &floor, Vec3::Z, rho_floor);
                    lit(x, wall_n, rho_wall) + rho_wall * k * e
                };
            }
        }
        rads.push(rad);
        depths.push(dep);
    }
    let views = unmasked_views(&cams, &rads, &depths);
    let around = surroundings(&mesh, 256).unwrap();
    let floor_error = |settings: &ShadingSettings| -> (Vec<f32>, f32) {
        let fit = shading_normals(&mesh, &views, Some(&around), settings).unwrap();
        let angles = (0..2)
            .map(|f| {
                assert_eq!(fit.normals.weight[f], 1.0);
                fit.normals.normal[f]
                    .dot(Vec3::Z)
                    .clamp(-1.0, 1.0)
                    .acos()
                    .to_degrees()
            })
            .collect();
        (angles, fit.interreflection)
    };
    let lambert = ShadingSettings {
        ridge: 1e-4,
        ..ShadingSettings::default()
    };
    let (leaning, _) = floor_error(&lambert);
    let (modelled, _) = floor_error(&ShadingSettings {
        interreflection: true,
        interreflection_c: Some(k),
        ..lambert
    });
    let (calibrated, c) = floor_error(&ShadingSettings {
        interreflection: true,
        ..lambert
    });
    (leaning, modelled, calibrated, c)
}

/// A grid over `[-0.2, 0.2]^2` with `n` cells a side, at height `z(x, y)`.
fn height_grid(n: usize, z: impl Fn(f32, f32) -> f32) -> TriMesh {
    crate::mesh::height_grid(n, glam::Vec2::splat(-0.2), glam::Vec2::splat(0.2), z)
}

/// The unit direction at `polar` from +z and `azimuth` about it (degrees).
fn direction(polar: f32, azimuth: f32) -> Vec3 {
    let (p, a) = (polar.to_radians(), azimuth.to_radians());
    Vec3::new(p.sin() * a.cos(), p.sin() * a.sin(), p.cos())
}

/// The bowl of depth `BOWL.0` and radius `BOWL.1` in a flat floor.
const BOWL: (f32, f32) = (0.02, 0.12);

fn bowl(x: f32, y: f32) -> f32 {
    let (depth, radius) = BOWL;
    -depth * (1.0 - (x * x + y * y) / (radius * radius)).max(0.0)
}

/// A flat lid over [`bowl`] refined by the bowl's Lambertian shading (the light at each
/// of 24 cameras, 96 px), each pixel's radiance scaled by `1 + noise u` with `u` uniform
/// in `[-1, 1)` (seeded).
fn refine_lid_over_bowl(noise: f32, settings: &ShadingRefinement) -> (TriMesh, ShadingRefined) {
    refine_lid_over_bowl_with_prior(noise, settings, None)
}

/// [`refine_lid_over_bowl`], with the lid's own (flat) normals rendered in every view as a
/// [`NormalPrior`] of this share.
fn refine_lid_over_bowl_with_prior(
    noise: f32,
    settings: &ShadingRefinement,
    prior_share: Option<f32>,
) -> (TriMesh, ShadingRefined) {
    let truth = height_grid(48, bowl);
    let lid = height_grid(24, |_, _| 0.0);
    let cams: Vec<Camera> = (0..24)
        .map(|k| {
            let dir = direction(10.0 + 40.0 * (k % 4) as f32 / 3.0, k as f32 * 15.0 + 7.0);
            Camera::look_at(1.5 * dir, Vec3::ZERO, Vec3::Z, 0.35, 96, 96)
        })
        .collect();
    let caster = crate::raycast::MeshRaycaster::new(&truth, "the bowl").unwrap();
    let mut rng = crate::mesh::SplitMix64::new(0);
    let rads: Vec<Vec<f32>> = (cams.iter())
        .map(|c| {
            let eye = c.centre();
            (0..96 * 96u32)
                .map(|p| {
                    let (o, d) = c.pixel_ray(p % 96, p / 96);
                    let u = 2.0 * rng.next_f64() as f32 - 1.0;
                    caster.first_hit(o, d).map_or(0.0, |(t, n)| {
                        let to = eye - (o + t * d);
                        let r2 = to.length_squared();
                        0.7 * n.dot(to / r2.sqrt()).max(0.0) / r2 * (1.0 + noise * u)
                    })
                })
                .collect()
        })
        .collect();
    let images: Vec<ShadingImage<'_>> = cams
        .iter()
        .zip(&rads)
        .map(|(camera, radiance)| ShadingImage {
            camera,
            radiance,
            mask: None,
        })
        .collect();
    let lid_caster = crate::raycast::MeshRaycaster::new(&lid, "the lid").unwrap();
    let flat: Vec<Vec<f32>> = (cams.iter())
        .map(|c| {
            let n = c.world_to_camera.transform_vector3(Vec3::Z);
            (0..96 * 96u32)
                .flat_map(|p| {
                    let (o, d) = c.pixel_ray(p % 96, p / 96);
                    let hit = lid_caster.first_hit(o, d).is_some();
                    if hit { n.to_array() } else { [0.0; 3] }
                })
                .collect()
        })
        .collect();
    let maps: Vec<(&Camera, &[f32])> = cams.iter().zip(&flat).map(|(c, n)| (c, &n[..])).collect();
    let prior = prior_share.map(|share| NormalPrior {
        views: &maps,
        share,
    });
    let refined = refine_by_shading(&lid, &images, None, prior, settings).unwrap();
    (lid, refined)
}

/// The lid's own flat normals as a prior hold it: at share 1 the bowl's shading moves
/// nothing, at one half the centre sinks part of the way; a share outside [0, 1] is refused.
#[test]
fn a_prior_of_flat_normals_holds_the_lid_by_its_share() {
    let settings = ShadingRefinement {
        anchor: 0.5,
        ..ShadingRefinement::default()
    };
    let centre = |r: &ShadingRefined, lid: &TriMesh| {
        let k = (lid.positions.iter().enumerate())
            .min_by(|a, b| a.1.length().total_cmp(&b.1.length()))
            .map(|(k, _)| k)
            .unwrap();
        r.moves[k]
    };
    let (lid, none) = refine_lid_over_bowl_with_prior(0.0, &settings, None);
    let (_, zero) = refine_lid_over_bowl_with_prior(0.0, &settings, Some(0.0));
    let (_, half) = refine_lid_over_bowl_with_prior(0.0, &settings, Some(0.5));
    let (_, all) = refine_lid_over_bowl_with_prior(0.0, &settings, Some(1.0));
    let (d0, dz, dh, d1) = (
        centre(&none, &lid),
        centre(&zero, &lid),
        centre(&half, &lid),
        centre(&all, &lid),
    );
    assert!((d0 - dz).abs() < 1e-6, "share 0: {dz} against {d0}");
    assert!(d0 < -0.5 * BOWL.0, "no prior: {d0}");
    assert!(d1.abs() < 0.05 * BOWL.0, "share 1: {d1}");
    assert!(
        dh < 0.8 * d1 + 0.2 * d0 && dh > 0.9 * d0,
        "share 0.5: {dh} ({d0} .. {d1})"
    );
    let cam = Camera::look_at(1.5 * Vec3::Z, Vec3::ZERO, Vec3::Y, 0.35, 8, 8);
    let (rad, normal) = (vec![0.5f32; 64], vec![0.0f32; 192]);
    let images = [ShadingImage {
        camera: &cam,
        radiance: &rad,
        mask: None,
    }];
    let maps = [(&cam, &normal[..])];
    for share in [-0.1, 1.5, f32::NAN] {
        let prior = Some(NormalPrior {
            views: &maps,
            share,
        });
        let err = refine_by_shading(&square(), &images, None, prior, &settings).unwrap_err();
        assert!(err.to_string().contains("share"), "{err}");
    }
}

/// Half and half of two observed normals is their bisector; a face only one set observes
/// keeps that one's normal at its share of the weight.
#[test]
fn blended_face_normals_mix_by_the_share() {
    let a = FaceNormals {
        normal: vec![Vec3::X, Vec3::X, Vec3::ZERO],
        weight: vec![1.0, 1.0, 0.0],
    };
    let b = FaceNormals {
        normal: vec![Vec3::Y, Vec3::ZERO, Vec3::Z],
        weight: vec![1.0, 0.0, 0.8],
    };
    let m = blend_face_normals(&a, &b, 0.5);
    assert!((m.normal[0] - Vec3::new(1.0, 1.0, 0.0).normalize()).length() < 1e-6);
    assert!((m.weight[0] - 1.0).abs() < 1e-6);
    assert_eq!((m.normal[1], m.weight[1]), (Vec3::X, 0.5));
    assert_eq!((m.normal[2], m.weight[2]), (Vec3::Z, 0.4));
    let only_a = blend_face_normals(&a, &b, 0.0);
    assert_eq!(only_a.normal[0], Vec3::X);
    assert_eq!((only_a.normal[2], only_a.weight[2]), (Vec3::ZERO, 0.0));
}

/// Holding the vertices by their slack needs a positive reference and the masks; the
/// steep tilt it allows must be a sine in (0, 1).
#[test]
fn the_slack_needs_masks_and_a_positive_reference() {
    let mesh = square();
    let cam = Camera::look_at(1.5 * Vec3::Z, Vec3::ZERO, Vec3::Y, 0.35, 8, 8);
    let rad = vec![0.5f32; 64];
    let images = [ShadingImage {
        camera: &cam,
        radiance: &rad,
        mask: None,
    }];
    let with = |slack_reference| ShadingRefinement {
        slack_reference,
        ..ShadingRefinement::default()
    };
    for r in [0.0, -1.0, f32::NAN, f32::INFINITY] {
        assert!(refine_by_shading(&mesh, &images, None, None, &with(Some(r))).is_err());
    }
    let err = refine_by_shading(&mesh, &images, None, None, &with(Some(0.1))).unwrap_err();
    assert!(err.to_string().contains("masks"), "{err}");
    // The steep limit is the sine of a tilt short of a right angle.
    for steep_tilt in [0.0, 1.0, -0.5, f32::NAN] {
        let settings = ShadingRefinement {
            steep_tilt,
            ..ShadingRefinement::default()
        };
        let err = refine_by_shading(&mesh, &images, None, None, &settings).unwrap_err();
        assert!(err.to_string().contains("steep tilt"), "{err}");
    }
}

/// A bowl the silhouettes cannot see, under a lid: the lid refined by the shading of the
/// bowl (Lambertian, the light at each camera) sinks to the bowl's depth in the middle and
/// stays where the surface is flat.
#[test]
fn the_shading_of_a_hidden_bowl_sinks_the_lid_over_it() {
    let (depth, radius) = BOWL;
    let settings = ShadingRefinement {
        anchor: 0.5,
        ..ShadingRefinement::default()
    };
    let (lid, refined) = refine_lid_over_bowl(0.0, &settings);
    assert!(
        refined.solved > lid.triangles.len() / 2,
        "{}",
        refined.solved
    );
    // Clean images: the shrinkage keeps nearly all of each correction.
    assert!(refined.confidence > 0.99, "{}", refined.confidence);
    for (v, d) in lid.positions.iter().zip(&refined.moves) {
        let want = bowl(v.x, v.y);
        let r = v.truncate().length();
        if r < 0.2 * radius {
            assert!(*d < 0.7 * want, "centre {v}: moved {d}, the bowl at {want}");
        }
        if r > 1.3 * radius && v.x.abs() < 0.18 && v.y.abs() < 0.18 {
            assert!(d.abs() < 0.2 * depth, "flat {v}: moved {d}");
        }
    }
    // Inward only, up to the default's zero outward bound.
    assert!(refined.moves.iter().all(|d| *d <= 0.0));
}

/// A round that moves nothing is a fixed point: no view sees the mesh, so no normal is
/// solved, nothing moves, and the later rounds are not run.
#[test]
fn rounds_stop_at_a_fixed_point() {
    let mesh = square();
    // Behind the square's plane, looking away from it.
    let cam = Camera::look_at(-1.5 * Vec3::Z, -3.0 * Vec3::Z, Vec3::Y, 0.35, 8, 8);
    let rad = vec![0.5f32; 64];
    let images = [ShadingImage {
        camera: &cam,
        radiance: &rad,
        mask: None,
    }];
    let settings = ShadingRefinement {
        rounds: 4,
        ..ShadingRefinement::default()
    };
    let refined = refine_by_shading(&mesh, &images, None, None, &settings).unwrap();
    assert_eq!(refined.solved, 0);
    assert!(refined.moves.iter().all(|d| *d == 0.0));
    assert!(
        refined.round_changes.is_empty(),
        "{:?}",
        refined.round_changes
    );
}

/// Rounds observe the normals again where the lid has sunk: over the hidden bowl the
/// centre sinks deeper than after one round, and each later round reports how much it
/// changed the moves, less each time.
#[test]
fn later_rounds_sink_the_lid_deeper_and_report_their_changes() {
    let one = ShadingRefinement {
        anchor: 0.5,
        ..ShadingRefinement::default()
    };
    let three = ShadingRefinement { rounds: 3, ..one };
    let centre = |refined: &ShadingRefined, lid: &TriMesh| -> f32 {
        let (mut sum, mut n) = (0.0f32, 0usize);
        for (v, d) in lid.positions.iter().zip(&refined.moves) {
            if v.truncate().length() < 0.3 * BOWL.1 {
                sum += d;
                n += 1;
            }
        }
        sum / n as f32
    };
    let (lid, first) = refine_lid_over_bowl(0.0, &one);
    let (_, last) = refine_lid_over_bowl(0.0, &three);
    assert!(first.round_changes.is_empty());
    assert_eq!(last.round_changes.len(), 2);
    let c = &last.round_changes;
    assert!(c.iter().all(|x| x.is_finite() && *x >= 0.0), "{c:?}");
    assert!(c[1] <= c[0], "{c:?}");
    let (a, b) = (centre(&first, &lid), centre(&last, &lid));
    assert!(b < a - 0.05 * BOWL.0, "one round {a}, three {b}");
}

/// The same bowl under noisy images (each pixel off by up to 30 %): shrinking each face's
/// normal by its uncertainty (`ShadingSettings::shrink`) keeps the flat floor much flatter
/// than the plain solve does, and the lid still sinks over the bowl, if less deep.
#[test]
fn shrinking_noisy_normals_keeps_the_flat_floor_flat() {
    let shrunk = ShadingRefinement {
        anchor: 0.5,
        ..ShadingRefinement::default()
    };
    assert!(shrunk.shading.shrink);
    let plain = ShadingRefinement {
        shading: ShadingSettings {
            shrink: false,
            ..shrunk.shading
        },
        ..shrunk
    };
    let (depth, radius) = BOWL;
    // Per run: the RMS move on the flat floor, the mean move at the bowl's centre and the
    // share of the corrections kept.
    let score = |settings: &ShadingRefinement| -> (f32, f32, f32) {
        let (lid, refined) = refine_lid_over_bowl(0.3, settings);
        let (mut flat, mut nf, mut centre, mut nc) = (0.0f32, 0usize, 0.0f32, 0usize);
        for (v, d) in lid.positions.iter().zip(&refined.moves) {
            let r = v.truncate().length();
            if r > 1.3 * radius && v.x.abs() < 0.18 && v.y.abs() < 0.18 {
                flat += d * d;
                nf += 1;
            }
            if r < 0.3 * radius {
                centre += d;
                nc += 1;
            }
        }
        (
            (flat / nf as f32).sqrt(),
            centre / nc as f32,
            refined.confidence,
        )
    };
    let (flat_plain, _, kept_plain) = score(&plain);
    let (flat_shrunk, centre, kept) = score(&shrunk);
    assert_eq!(kept_plain, 1.0);
    assert!(kept > 0.1 && kept < 0.9, "share kept {kept}");
    assert!(
        flat_shrunk < 0.5 * flat_plain,
        "RMS move on the floor: shrunk {flat_shrunk}, plain {flat_plain}"
    );
    assert!(centre < -0.25 * depth, "the centre moved {centre}");
}
