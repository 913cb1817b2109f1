//! The extraction recipe on spheres, dents and lit scenes.

use super::*;
use glam::Vec3;

/// `n` cameras of `size` pixels square on a Fibonacci sphere of radius 4, looking at the
/// origin.
fn sphere_cameras(n: usize, size: u32) -> Vec<Camera> {
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    (0..n)
        .map(|k| {
            let y = 1.0 - 2.0 * (k as f32 + 0.5) / n as f32;
            let r = (1.0 - y * y).sqrt();
            let a = golden * k as f32;
            let eye = 4.0 * Vec3::new(r * a.cos(), y, r * a.sin());
            let up = if y.abs() > 0.9 { Vec3::X } else { Vec3::Y };
            Camera::look_at(eye, Vec3::ZERO, up, 0.69, size, size)
        })
        .collect()
}

/// Coverage masks of a sphere (8 x 8 samples a pixel), from [`sphere_cameras`].
fn sphere_masks(n: usize, size: u32, radius: f32) -> Vec<(Camera, Vec<f32>)> {
    (sphere_cameras(n, size).into_iter())
        .map(|cam| {
            let s = 8;
            let mut mask = vec![0.0f32; (size * size) as usize];
            for j in 0..size {
                for i in 0..size {
                    let mut hits = 0;
                    for sj in 0..s {
                        for si in 0..s {
                            let u = i as f32 + (si as f32 + 0.5) / s as f32;
                            let v = j as f32 + (sj as f32 + 0.5) / s as f32;
                            let (o, d) = cam.ray(u, v);
                            let b = o.dot(d);
                            hits += (b * b - (o.length_squared() - radius * radius) >= 0.0) as u32;
                        }
                    }
                    mask[(j * size + i) as usize] = hits as f32 / (s * s) as f32;
                }
            }
            (cam, mask)
        })
        .collect()
}

/// Each view's z-depth of the sphere at its pixel centres (where the mask is at least 0.5
/// and the ray meets it), passed through `at(z, camera)`; 0 elsewhere.
fn sphere_depth_maps(
    masks: &MasksAlone,
    radius: f32,
    at: impl Fn(f32, &Camera) -> f32,
) -> Vec<Vec<f32>> {
    (masks.views.iter())
        .map(|(cam, mask)| {
            let size = cam.width;
            let mut depth = vec![0.0f32; mask.len()];
            for j in 0..size {
                for i in 0..size {
                    let k = (j * size + i) as usize;
                    let (o, d) = cam.pixel_ray(i, j);
                    let b = o.dot(d);
                    let disc = b * b - (o.length_squared() - radius * radius);
                    if mask[k] >= 0.5 && disc >= 0.0 {
                        let hit = o + d * (-b - disc.sqrt());
                        depth[k] = at(cam.world_to_camera.transform_point3(hit).z, cam);
                    }
                }
            }
            depth
        })
        .collect()
}

/// The mean distance of a mesh's vertices from the origin-centred sphere of `radius`.
fn mean_radial_error(m: &TriMesh, radius: f32) -> f32 {
    m.positions
        .iter()
        .map(|p| (p.length() - radius).abs())
        .sum::<f32>()
        / m.positions.len() as f32
}

/// The pixel footprint of [`sphere_masks`]' 32 px views at the sphere's centre.
fn sphere_footprint_32() -> f32 {
    4.0 * (0.5f32 * 0.69).tan() * 2.0 / 32.0
}

/// The carving alone on the sphere: no silhouette check, no culling, a 0.03 grid.
fn carving_only() -> MeshConfig {
    MeshConfig {
        carve_max_opened: 1.0,
        cull_unobserved: 0.0,
        carve_voxel: Some(0.03),
        ..MeshConfig::default()
    }
}

/// [`extract_mesh`] under `config` of the sphere's masks and depth maps (one per view),
/// in the box `[-1.2, 1.2]^3`.
fn sphere_extract(
    masks: &MasksAlone,
    maps: &[Vec<f32>],
    config: &MeshConfig,
) -> (TriMesh, Vec<String>) {
    sphere_try_extract(masks, maps, config).unwrap()
}

/// [`sphere_extract`], its error returned.
fn sphere_try_extract(
    masks: &MasksAlone,
    maps: &[Vec<f32>],
    config: &MeshConfig,
) -> Result<(TriMesh, Vec<String>)> {
    sphere_try_extract_as(masks, maps, config, false)
}

/// [`sphere_try_extract`], quicker with `coarse` ([`FusionInputs::coarse`]).
fn sphere_try_extract_as(
    masks: &MasksAlone,
    maps: &[Vec<f32>],
    config: &MeshConfig,
    coarse: bool,
) -> Result<(TriMesh, Vec<String>)> {
    let views: Vec<FusionView<'_>> = (masks.views.iter().zip(maps))
        .map(|((camera, mask), depth)| FusionView {
            camera,
            depth,
            mask,
            normal: &[],
        })
        .collect();
    let cameras: Vec<Camera> = masks.views.iter().map(|(c, _)| *c).collect();
    let inputs = FusionInputs {
        views: &views,
        masked: true,
        masks: Some(masks),
        footprint_cameras: &cameras,
        bounds: (Vec3::splat(-1.2), Vec3::splat(1.2)),
        coarse,
    };
    extract_mesh(config, &inputs)
}

/// Blending in the rendered normals needs a normal map on every view, and a share in
/// [0, 1].
#[test]
fn rendered_normals_need_maps_and_a_share() {
    let masks = MasksAlone::new(sphere_masks(8, 16, 0.8))
        .unwrap()
        .expect("a sphere");
    let maps = vec![Vec::new(); masks.views.len()];
    let config = MeshConfig {
        shading_normals_rendered: 0.5,
        ..MeshConfig::default()
    };
    let err = sphere_try_extract(&masks, &maps, &config)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("shading_normals_rendered") && err.contains("normal map"),
        "{err}"
    );
    for share in [-0.5, 1.5, f32::NAN] {
        let config = MeshConfig {
            shading_normals_rendered: share,
            ..MeshConfig::default()
        };
        let err = config.validate().unwrap_err().to_string();
        assert!(err.contains("shading_normals_rendered"), "{err}");
    }
}

/// Low-resolution coverage masks of a sphere: the cones of the coverage interpolated
/// between pixel centres meet inside the sphere (each view's error on the inner side is
/// the one that counts); the hull of the masks' edges sits on it and is the nearer.
#[test]
fn the_edge_hull_does_not_sink_into_the_object() {
    let radius = 0.8;
    let masks = MasksAlone::new(sphere_masks(40, 24, radius))
        .unwrap()
        .expect("a sphere")
        .with_edge_distance()
        .unwrap();
    let stats = |m: &TriMesh| {
        let n = m.positions.len() as f32;
        let signed: f32 = m.positions.iter().map(|p| p.length() - radius).sum::<f32>() / n;
        let abs: f32 = m
            .positions
            .iter()
            .map(|p| (p.length() - radius).abs())
            .sum::<f32>()
            / n;
        (signed, abs)
    };
    let footprint = 4.0 * (0.5f32 * 0.69).tan() * 2.0 / 24.0;
    let (s_cov, a_cov) = stats(&masks.mesh);
    let (s_edge, a_edge) = stats(masks.bound_mesh());
    // Measured: the coverage hull -0.0039 on average (a thirtieth of a footprint), 0.0052
    // off; the edge hull -0.0012 and 0.0015.
    assert!(
        s_cov < -0.02 * footprint,
        "coverage hull {s_cov} (footprint {footprint})"
    );
    assert!(
        s_edge.abs() < 0.5 * s_cov.abs(),
        "edge hull {s_edge} vs {s_cov}"
    );
    assert!(
        a_edge < 0.5 * a_cov,
        "edge hull {a_edge} vs coverage {a_cov}"
    );
    // The bound is the edge hull's; the masks' own views and mesh stay the baseline.
    let bound = masks.bound();
    assert_eq!(bound.len(), 40);
    assert!(
        bound[0].1.iter().any(|m| *m > 1.0),
        "distances past the edge"
    );
    assert!(masks.views[0].1.iter().all(|m| (0.0..=1.0).contains(m)));
}

/// A depth that is not a surface yet (here: a sphere's true depth pushed a radius
/// back, as an untrained model renders) carves into the object and opens the
/// silhouettes: the carving is refused and the mesh is the masks' bound. The true depth
/// carves nothing and opens nothing.
#[test]
fn a_carving_that_opens_the_silhouettes_is_refused() {
    let radius = 0.8;
    let masks = MasksAlone::new(sphere_masks(24, 24, radius))
        .unwrap()
        .expect("a sphere");
    let depth_maps = |behind: f32| sphere_depth_maps(&masks, radius, |z, _| z + behind);
    let extract = |maps: &[Vec<f32>], max_opened: f32| {
        let config = MeshConfig {
            carve_max_opened: max_opened,
            // The depth as given: moved back by its offset from the bound, this one would
            // carve nothing (the next test).
            carve_debias: false,
            cull_unobserved: 0.0,
            // A coarse grid keeps the test quick; the bound keeps its own.
            carve_voxel: Some(0.04),
            ..MeshConfig::default()
        };
        sphere_extract(&masks, maps, &config)
    };
    let hull = masks.bound_mesh().triangles.len();
    let (truth, notes) = extract(&depth_maps(0.0), DEFAULT_CARVE_MAX_OPENED);
    assert!(
        !notes.iter().any(|n| n.starts_with("carving refused")),
        "{notes:?}"
    );
    assert!(
        notes.iter().any(|n| n.contains("(0.000 %")),
        "the true depth opens nothing: {notes:?}"
    );
    let behind = depth_maps(radius);
    let (unguarded, _) = extract(&behind, 1.0);
    assert!(
        unguarded.triangles.len() < truth.triangles.len() / 2,
        "the pushed-back depth carves most of the sphere away: {} faces left of {}",
        unguarded.triangles.len(),
        truth.triangles.len()
    );
    let (guarded, notes) = extract(&behind, DEFAULT_CARVE_MAX_OPENED);
    assert_eq!(guarded.triangles.len(), hull, "{notes:?}");
    assert!(
        notes.iter().any(|n| n.starts_with("carving refused")),
        "{notes:?}"
    );
}

/// A depth that runs 4.5 footprints behind the surface over the whole object (as a model
/// without its interior set renders), past the concavity gate, carves the sphere inward
/// (the silhouette check, which would refuse it here, is off: on a sphere every point lies
/// on some view's contour, on amber_ingot's dome and slab most do not). Its median offset
/// from the masks' bound is its bias: moved forward by it, the depth carves nothing and
/// the mesh is the bound's.
#[test]
fn a_depth_biased_over_the_whole_object_is_moved_back_onto_the_bound() {
    let radius = 0.8;
    let masks = MasksAlone::new(sphere_masks(24, 32, radius))
        .unwrap()
        .expect("a sphere");
    let maps = sphere_depth_maps(&masks, radius, |z, cam| z * (1.0 + 4.5 / cam.fx));
    let extract = |debias: bool| {
        let config = MeshConfig {
            carve_debias: debias,
            ..carving_only()
        };
        sphere_extract(&masks, &maps, &config)
    };
    let mean_error = |m: &TriMesh| mean_radial_error(m, radius);
    let footprint = sphere_footprint_32();
    let (biased, _) = extract(false);
    let (debiased, notes) = extract(true);
    let moved: f32 = notes
        .iter()
        .find_map(|n| n.strip_prefix("carving: the depth maps moved "))
        .and_then(|n| n.split(' ').next()?.parse().ok())
        .unwrap_or_else(|| panic!("{notes:?}"));
    // The bound lies a little outside the sphere, so a little less than the bias.
    assert!((4.0..=4.5).contains(&moved), "{notes:?}");
    let (e_biased, e_debiased) = (mean_error(&biased), mean_error(&debiased));
    let e_bound = mean_error(masks.bound_mesh());
    assert!(
        e_biased > e_bound + 0.5 * footprint,
        "the biased depth carves: {e_biased} against the bound's {e_bound} (footprint {footprint})"
    );
    assert!(
        e_debiased < e_bound + 0.05 * footprint,
        "moved back, it carves nothing: {e_debiased} against the bound's {e_bound}"
    );
}

/// A depth still scattered about the surface (blocks of pixels 8 footprints behind it, 40 %
/// of them, different in every view) digs pits into a sphere through the concavity gate
/// without opening a silhouette; its offsets from the bound spread over 8 footprints
/// between their quartiles, so the spread check refuses the carving. The sphere's own depth
/// is carved as before.
#[test]
fn a_scattered_depth_is_refused_by_the_spread_of_its_offsets() {
    let radius = 0.8;
    let masks = MasksAlone::new(sphere_masks(24, 32, radius))
        .unwrap()
        .expect("a sphere");
    let exact = sphere_depth_maps(&masks, radius, |z, _| z);
    let scattered: Vec<Vec<f32>> = (exact.iter().zip(&masks.views).enumerate())
        .map(|(v, (depth, (cam, _)))| {
            (depth.iter().enumerate())
                .map(|(k, z)| {
                    let (i, j) = (k % 32 / 4, k / 32 / 4);
                    let hash = (v * 131 + j * 17 + i * 7) * 2_654_435_761 % 1000;
                    if *z > 0.0 && hash < 400 {
                        z * (1.0 + 8.0 / cam.fx)
                    } else {
                        *z
                    }
                })
                .collect()
        })
        .collect();
    let extract = |maps: &[Vec<f32>], max_spread: f32| {
        let config = MeshConfig {
            carve_max_spread: max_spread,
            ..carving_only()
        };
        sphere_extract(&masks, maps, &config)
    };
    let refused = |notes: &[String]| {
        notes
            .iter()
            .any(|n| n.starts_with("carving refused: the depth's offsets"))
    };
    let mean_error = |m: &TriMesh| mean_radial_error(m, radius);
    let footprint = sphere_footprint_32();
    let e_bound = mean_error(masks.bound_mesh());
    let (dug, notes) = extract(&scattered, 0.0);
    assert!(!refused(&notes), "{notes:?}");
    assert!(
        mean_error(&dug) > e_bound + 0.25 * footprint,
        "unchecked, the scattered depth digs: {} against the bound's {e_bound} (footprint \
         {footprint})",
        mean_error(&dug)
    );
    let (kept, notes) = extract(&scattered, DEFAULT_CARVE_MAX_SPREAD);
    assert!(refused(&notes), "{notes:?}");
    assert_eq!(&kept, masks.bound_mesh());
    let (_, notes) = extract(&exact, DEFAULT_CARVE_MAX_SPREAD);
    assert!(!refused(&notes), "{notes:?}");
    let bad = MeshConfig {
        carve_max_spread: -1.0,
        ..MeshConfig::default()
    };
    assert!(bad.validate().is_err());
}

/// One view of [`mesh_views`].
struct MeshView {
    camera: Camera,
    mask: Vec<f32>,
    depth: Vec<f32>,
    radiance: Vec<f32>,
}

/// [`sphere_cameras`] looking at `mesh`: per view its mask (4x4 rays a pixel), its
/// z-depth where the mask is at least 0.5, and its Lambertian radiance under a light at the
/// camera.
fn mesh_views(mesh: &TriMesh, n: usize, size: u32) -> Vec<MeshView> {
    let caster = MeshRaycaster::new(mesh, "the test mesh").unwrap();
    (sphere_cameras(n, size).into_iter())
        .map(|cam| {
            let eye = cam.centre();
            let mut mask = vec![0.0f32; (size * size) as usize];
            let mut radiance = vec![0.0f32; mask.len()];
            for j in 0..size {
                for i in 0..size {
                    let k = (j * size + i) as usize;
                    let mut hits = 0;
                    for s in 0..16 {
                        let u = i as f32 + (s % 4) as f32 / 4.0 + 0.125;
                        let v = j as f32 + (s / 4) as f32 / 4.0 + 0.125;
                        let (o, d) = cam.ray(u, v);
                        hits += u32::from(caster.first_hit(o, d).is_some());
                    }
                    mask[k] = hits as f32 / 16.0;
                    let (o, d) = cam.pixel_ray(i, j);
                    if let Some((t, nrm)) = caster.first_hit(o, d) {
                        let to = eye - (o + t * d);
                        let r2 = to.length_squared();
                        radiance[k] = 0.7 * nrm.dot(to / r2.sqrt()).max(0.0) / r2;
                    }
                }
            }
            let mut depth = caster.render(&cam).depth;
            for (z, m) in depth.iter_mut().zip(&mask) {
                if *m < 0.5 {
                    *z = 0.0;
                }
            }
            MeshView {
                camera: cam,
                mask,
                depth,
                radiance,
            }
        })
        .collect()
}

/// A sphere of `radius` with a smooth dent `depth` deep in its cap within 25 degrees of
/// each of the `poles` (unit; the masks see a dent down to the plane of its rim only).
fn dented_sphere(radius: f32, depth: f32, poles: &[Vec3]) -> TriMesh {
    let mut m = crate::mesh::icosphere(Vec3::ZERO, radius, 5);
    let c0 = 25f32.to_radians().cos();
    for p in &mut m.positions {
        let dir = *p / p.length();
        for pole in poles {
            let t = ((dir.dot(*pole) - c0) / (1.0 - c0)).clamp(0.0, 1.0);
            *p *= 1.0 - depth * t * t * (3.0 - 2.0 * t) / radius;
        }
    }
    m
}

/// The masks and radiance of `images`.
fn lit_masks(images: &[MeshView]) -> MasksAlone {
    let masks = (images.iter())
        .map(|v| (v.camera, v.mask.clone()))
        .collect();
    MasksAlone::new(masks)
        .unwrap()
        .expect("a sphere")
        .with_radiance(images.iter().map(|v| v.radiance.clone()).collect())
        .unwrap()
}

/// The carving (no shading refinement, voxel 0.03, `min_lid` for
/// [`MeshConfig::carve_min_lid_departure`]) of the masks and radiance of `images` by the
/// depth of `depth`: the mesh, the masks' bound and the notes.
fn lit_extract(
    images: &[MeshView],
    depth: &[MeshView],
    min_lid: f32,
) -> (TriMesh, TriMesh, Vec<String>) {
    let masks = lit_masks(images);
    let maps: Vec<Vec<f32>> = depth.iter().map(|v| v.depth.clone()).collect();
    let config = MeshConfig {
        carve_voxel: Some(0.03),
        shading_anchor: 0.0,
        carve_min_lid_departure: min_lid,
        // The images here come from a shading model, not from light transport; the hollow
        // search reads no hollow from them (`a_shading_models_dark_pixels_read_no_hollow`)
        // and is left out for time.
        hollow_search: false,
        ..MeshConfig::default()
    };
    let (mesh, notes) = sphere_extract(&masks, &maps, &config);
    (mesh, masks.bound_mesh().clone(), notes)
}

/// A dent that the depth maps hold alike in every view and the images do not show (a
/// model stopped mid-schedule): it opens no silhouette and spreads the offsets little,
/// so only the shading check refuses its carving; the images' shading finds the sphere's
/// bound to be the surface over it. Where the images show the same dent, the carving
/// stands.
#[test]
fn a_dent_the_images_do_not_show_is_refused_by_the_shading() {
    let (radius, size) = (0.8, 64);
    let footprint = 0.5 * sphere_footprint_32();
    let dent = dented_sphere(radius, 6.0 * footprint, &[Vec3::NEG_Y]);
    let round = crate::mesh::icosphere(Vec3::ZERO, radius, 5);
    let dented_views = mesh_views(&dent, 24, size);
    let round_views = mesh_views(&round, 24, size);
    // The images (masks, radiance) of one object, the depth of the dented one.
    let extract = |images: &[MeshView], min_lid: f32| lit_extract(images, &dented_views, min_lid);
    let refused = |notes: &[String]| notes.iter().any(|n| n.starts_with("carving refused"));
    let by_shading = |notes: &[String]| {
        (notes.iter()).any(|n| n.starts_with("carving refused: the images' shading"))
    };
    // Unchecked, the depth's dent is carved into the round object.
    let (dug, bound, notes) = extract(&round_views, 0.0);
    assert!(!refused(&notes), "{notes:?}");
    let inside = |m: &TriMesh| {
        (m.positions.iter())
            .filter(|p| p.length() < radius - 2.0 * footprint)
            .count()
    };
    assert!(
        inside(&dug) > 20,
        "{} vertices dug in; {notes:?}",
        inside(&dug)
    );
    // Checked, the shading refuses it: the bound goes on alone.
    let (kept, _, notes) = extract(&round_views, DEFAULT_CARVE_MIN_LID_DEPARTURE);
    assert!(by_shading(&notes), "{notes:?}");
    assert_eq!(kept, bound);
    // The images show the dent: the carving stands.
    let (carved, _, notes) = extract(&dented_views, DEFAULT_CARVE_MIN_LID_DEPARTURE);
    assert!(!refused(&notes), "{notes:?}");
    assert!(inside(&carved) > 20, "{notes:?}");
    let bad = MeshConfig {
        carve_min_lid_departure: f32::NAN,
        ..MeshConfig::default()
    };
    assert!(bad.validate().is_err());
}

/// A carving of two dents, of which the images show one (a true concavity and a model's
/// wrong dent at once): the shading judges each carved region by the lid over it, keeps
/// the true one and restores the bound over the other.
#[test]
fn the_shading_judges_each_carved_region_by_its_own_lid() {
    let (radius, size) = (0.8, 64);
    let footprint = 0.5 * sphere_footprint_32();
    let shown = mesh_views(
        &dented_sphere(radius, 6.0 * footprint, &[Vec3::NEG_Y]),
        24,
        size,
    );
    let depth = mesh_views(
        &dented_sphere(radius, 6.0 * footprint, &[Vec3::NEG_Y, Vec3::Y]),
        24,
        size,
    );
    let (mesh, _, notes) = lit_extract(&shown, &depth, DEFAULT_CARVE_MIN_LID_DEPARTURE);
    assert!(
        !notes.iter().any(|n| n.starts_with("carving refused")),
        "{notes:?}"
    );
    assert!(
        notes
            .iter()
            .any(|n| n.contains("2 carved regions, 2 judged") && n.ends_with("1 refused")),
        "{notes:?}"
    );
    // Vertices dug in under each pole's cap.
    let dug = |pole: Vec3| {
        (mesh.positions.iter())
            .filter(|p| p.length() < radius - 2.0 * footprint && p.dot(pole) > 0.0)
            .count()
    };
    assert!(
        dug(Vec3::NEG_Y) > 20,
        "{} dug in; {notes:?}",
        dug(Vec3::NEG_Y)
    );
    assert_eq!(dug(Vec3::Y), 0, "{notes:?}");
}

/// The masks and Lambertian images of 24 views at 64 px of a sphere of radius 0.8 with a
/// dent 6 half footprints deep at -Y, and the views.
fn lambert_dent() -> (MasksAlone, Vec<MeshView>) {
    let footprint = 0.5 * sphere_footprint_32();
    let views = mesh_views(&dented_sphere(0.8, 6.0 * footprint, &[Vec3::NEG_Y]), 24, 64);
    (lit_masks(&views), views)
}

/// A dented sphere's images from a shading model (Lambert's, not light transport): the
/// dent's darkest pixels make the path-traced search rank a hollow above the lid, which
/// explains little of the pixels beside them, and the band test refuses it.
#[test]
fn a_shading_models_dark_pixels_read_no_hollow() {
    let (masks, _) = lambert_dent();
    let reading = masks.hollow_reading().unwrap().expect("images");
    assert!(reading.pixels[2] > 0, "{:?}", reading.pixels);
    assert!(reading.best.is_some(), "{:?}", reading.candidates);
    let least = crate::hollow::HollowSettings::default().min_band_share;
    assert!(reading.band_share < least, "{}", reading.band_share);
    assert_eq!(reading.pick, None);
}

/// A quicker extraction (`coarse`, an evaluation during training) still refines the mesh
/// by the shading, in the rounds its settings ask ([`MeshConfig::with_shading_rounds`]),
/// and leaves the carved bound as it is with none: on a dented sphere's Lambertian images
/// one round sinks the dent the masks cannot see, and the later rounds further.
#[test]
fn a_coarse_extraction_refines_by_the_shading_in_its_rounds() {
    let (radius, size) = (0.8, 64);
    let footprint = 0.5 * sphere_footprint_32();
    let (masks, views) = lambert_dent();
    // No depth: nothing is carved (the bound is remeshed on the carving's grid), and the
    // refinement alone moves it.
    let empty = vec![vec![0.0f32; (size * size) as usize]; views.len()];
    let extract =
        |config: &MeshConfig| sphere_try_extract_as(&masks, &empty, config, true).unwrap();
    let config = MeshConfig {
        carve_voxel: Some(0.03),
        // Lambertian images, from which the hollow search reads no hollow
        // (`a_shading_models_dark_pixels_read_no_hollow`): left out for time.
        hollow_search: false,
        ..MeshConfig::default()
    };
    let (bound, notes) = extract(&config.with_shading_rounds(0));
    assert!(!notes.iter().any(|n| n.contains("round(s)")), "{notes:?}");
    let bound = &bound;
    let one = config.with_shading_rounds(1);
    assert_eq!(one.shading_anchor, config.shading_anchor);
    let (refined, notes) = extract(&one);
    assert!(notes.iter().any(|n| n.contains(" 1 round(s)")), "{notes:?}");
    // The vertices over the dent's centre, deepest on the truth, sink.
    let under_dent = |m: &TriMesh| {
        let depths: Vec<f32> = (m.positions.iter())
            .filter(|p| p.dot(Vec3::NEG_Y) > 0.97 * p.length())
            .map(|p| radius - p.length())
            .collect();
        depths.iter().sum::<f32>() / depths.len().max(1) as f32
    };
    let (all, _) = extract(&config);
    assert!(
        under_dent(&refined) > under_dent(bound) + 0.05 * footprint
            && under_dent(&all) > under_dent(&refined) + 0.01 * footprint,
        "the dent {} deep after one round, {} after all, {} on the bound (footprint \
         {footprint}); {notes:?}",
        under_dent(&refined),
        under_dent(&all),
        under_dent(bound)
    );
}

/// Three identical 8x8 views of a centred 4x4 square mask, as masks.
fn three_square_views() -> MasksAlone {
    let camera = Camera::look_at(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, Vec3::Y, 0.5, 8, 8);
    let mut mask = vec![0.0f32; 64];
    for y in 2..6 {
        for x in 2..6 {
            mask[y * 8 + x] = 1.0;
        }
    }
    let views: Vec<(Camera, Vec<f32>)> = (0..3).map(|_| (camera, mask.clone())).collect();
    MasksAlone::new(views).unwrap().expect("a cube of views")
}

/// The radiance given for the shading refinement must match the masks view for view.
#[test]
fn radiance_of_the_wrong_size_is_refused() {
    let masks = three_square_views();
    let e = masks
        .clone()
        .with_radiance(vec![vec![0.5; 64]; 2])
        .unwrap_err();
    assert!(e.to_string().contains("radiance views"), "{e}");
    let e = masks
        .clone()
        .with_radiance(vec![vec![0.5; 63]; 3])
        .unwrap_err();
    assert!(e.to_string().contains("radiance"), "{e}");
    let mut nan = vec![vec![0.5; 64]; 3];
    nan[1][7] = f32::NAN;
    let e = masks.clone().with_radiance(nan).unwrap_err();
    assert!(e.to_string().contains("non-finite"), "{e}");
    let ok = masks.with_radiance(vec![vec![0.5; 64]; 3]).unwrap();
    assert_eq!(ok.radiance.map(|r| r.len()), Some(3));
}

/// The shading's images blended with a model's renders: `(1 - share)` of each image and
/// `share` of its render, pixel by pixel; the bad blends are refused by name.
#[test]
fn rendered_radiance_is_blended_by_its_share() {
    let masks = three_square_views();
    let renders: Vec<Vec<f32>> = (0..3)
        .map(|k| (0..64).map(|p| 0.01 * (p + k) as f32).collect())
        .collect();
    let e = masks
        .clone()
        .with_rendered_radiance(&renders, 0.5)
        .unwrap_err();
    assert!(e.to_string().contains("needs the images"), "{e}");
    let lit = masks.with_radiance(vec![vec![0.2; 64]; 3]).unwrap();
    for share in [0.0f32, 0.25, 1.0] {
        let blended = lit.clone().with_rendered_radiance(&renders, share).unwrap();
        for (image, render) in blended.radiance.as_ref().unwrap().iter().zip(&renders) {
            for (b, r) in image.iter().zip(render) {
                let want = 0.2 * (1.0 - share) + r * share;
                assert!((b - want).abs() < 1e-6, "share {share}: {b} against {want}");
            }
        }
    }
    let e = lit
        .clone()
        .with_rendered_radiance(&renders, 1.5)
        .unwrap_err();
    assert!(e.to_string().contains("[0, 1]"), "{e}");
    let e = (lit.clone())
        .with_rendered_radiance(&renders[..2], 0.5)
        .unwrap_err();
    assert!(e.to_string().contains("rendered radiance views"), "{e}");
    let mut short = renders.clone();
    short[2].pop();
    let e = lit.clone().with_rendered_radiance(&short, 0.5).unwrap_err();
    assert!(e.to_string().contains("rendered radiance"), "{e}");
    let mut nan = renders;
    nan[0][9] = f32::NAN;
    let e = lit.with_rendered_radiance(&nan, 0.5).unwrap_err();
    assert!(e.to_string().contains("non-finite"), "{e}");
}

/// The hollow search runs once for a set of masks and images: a clone (a run's in-run and
/// final extractions) shares the reading, and other images make a new one.
#[test]
fn the_hollow_reading_is_shared_by_clones_and_renewed_with_the_images() {
    let sphere = crate::mesh::icosphere(Vec3::ZERO, 0.5, 3);
    let views = mesh_views(&sphere, 6, 24);
    let masks = lit_masks(&views);
    let first: *const _ = masks
        .hollow_reading()
        .unwrap()
        .expect("the masks carry images");
    let clone = masks.clone();
    let again = clone.hollow_reading().unwrap().unwrap();
    assert!(std::ptr::eq(first, again), "a clone reads the same search");
    let brighter = (views.iter())
        .map(|v| v.radiance.iter().map(|r| 2.0 * r).collect())
        .collect();
    let renewed = clone.with_radiance(brighter).unwrap();
    let other = renewed.hollow_reading().unwrap().unwrap();
    assert!(!std::ptr::eq(first, other), "new images, a new search");
    let bare = MasksAlone::new(views.iter().map(|v| (v.camera, v.mask.clone())).collect())
        .unwrap()
        .unwrap();
    assert!(
        bare.hollow_reading().unwrap().is_none(),
        "no images, no reading"
    );
}
