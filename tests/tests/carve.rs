//! The masks bound, the depth carves: a cube with a pit in its top face, which no silhouette
//! shows and exact depth maps do.

mod common;

use common::cameras_around;
use glam::Vec3;
use gtsr_data::Camera;
use gtsr_eval::score_against_ground_truth;
use gtsr_mesh::carve::{CarveSettings, DepthMap, carve_grid, carve_mesh};
use gtsr_mesh::hull::{hull_slack, masks_mesh};
use gtsr_mesh::hull::{masks_grid, silhouette_distance};
use gtsr_mesh::raycast::MeshRaycaster;

const HALF: f32 = 0.5;
const PIT_RADIUS: f32 = 0.2;
const PIT_FLOOR: f32 = 0.1;

/// Signed distance (an exact bound is enough for sphere tracing) of the cube
/// `[-0.5, 0.5]^3` minus the pit `x^2 + z^2 < 0.2^2, y > 0.1` (open to the top face y = 0.5).
fn sdf(p: Vec3) -> f32 {
    let q = p.abs() - Vec3::splat(HALF);
    let cube = q.max(Vec3::ZERO).length() + q.max_element().min(0.0);
    let radial = (p.x * p.x + p.z * p.z).sqrt() - PIT_RADIUS;
    let floor = PIT_FLOOR - p.y;
    let pit = radial.max(floor);
    cube.max(-pit)
}

/// Z-depth (0 where the ray misses) and mask of the pitted cube, per pixel centre.
fn render(cam: &Camera) -> (Vec<f32>, Vec<f32>) {
    let (w, h) = (cam.width as usize, cam.height as usize);
    let to_world = cam.world_to_camera.inverse();
    let eye = to_world.transform_point3(Vec3::ZERO);
    let mut depth = vec![0.0; w * h];
    let mut mask = vec![0.0; w * h];
    for j in 0..h {
        for i in 0..w {
            let d_cam = cam.camera_direction(i as f32 + 0.5, j as f32 + 0.5);
            let dir = to_world.transform_vector3(d_cam).normalize();
            let mut t = 0.0f32;
            // Rays grazing a face march in tiny steps: a floor on the step keeps every ray
            // converging (to within that floor of the surface).
            for _ in 0..4000 {
                let s = sdf(eye + t * dir);
                if s < 2e-4 {
                    // z-depth: distance along the ray over its length per unit z.
                    depth[j * w + i] = t / d_cam.length();
                    mask[j * w + i] = 1.0;
                    break;
                }
                t += s.max(2e-4);
                if t > 20.0 {
                    break;
                }
            }
        }
    }
    (depth, mask)
}

struct Scene {
    cams: Vec<Camera>,
    depths: Vec<Vec<f32>>,
    masks: Vec<Vec<f32>>,
}

fn scene() -> Scene {
    let cams = cameras_around(Vec3::ZERO, 4.0, 40, 0.6, 96);
    let (depths, masks) = cams.iter().map(render).unzip();
    Scene {
        cams,
        depths,
        masks,
    }
}

fn mask_views(s: &Scene) -> Vec<(Camera, &[f32])> {
    s.cams
        .iter()
        .copied()
        .zip(s.masks.iter().map(|m| &m[..]))
        .collect()
}

fn depth_maps(s: &Scene) -> Vec<DepthMap<'_>> {
    s.cams
        .iter()
        .zip(&s.depths)
        .map(|(camera, depth)| DepthMap {
            camera,
            depth,
            hull_depth: None,
        })
        .collect()
}

/// The masks' own depth per camera of `s`: `hull` ray cast.
fn hull_depths(s: &Scene, hull: &gtsr_data::ply::TriMesh) -> Vec<Vec<f32>> {
    let caster = MeshRaycaster::new(hull, "the masks' mesh").unwrap();
    s.cams.iter().map(|c| caster.render(c).depth).collect()
}

/// `depths` (one per camera of `s`) with the masks' own depth beside them, for the gate.
fn gated_maps<'a>(
    s: &'a Scene,
    depths: &'a [Vec<f32>],
    hulls: &'a [Vec<f32>],
) -> Vec<DepthMap<'a>> {
    s.cams
        .iter()
        .zip(depths)
        .zip(hulls)
        .map(|((camera, depth), hull)| DepthMap {
            camera,
            depth,
            hull_depth: Some(hull),
        })
        .collect()
}

/// The field's value at the grid point nearest `p`.
fn at(grid: &gtsr_mesh::marching::Grid, p: Vec3) -> f32 {
    let c = ((p - grid.origin) / grid.voxel).round();
    grid.values[grid.index(c.x as usize, c.y as usize, c.z as usize)]
}

/// Grid points carved (field > 0) where the solid's signed distance is below `depth`.
fn carved_below(g: &gtsr_mesh::marching::Grid, depth: f32) -> usize {
    let [nx, ny, nz] = g.dims;
    let mut n = 0;
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                if sdf(g.point(i, j, k)) < depth && g.values[g.index(i, j, k)] > 0.0 {
                    n += 1;
                }
            }
        }
    }
    n
}

const LO: Vec3 = Vec3::splat(-0.7);
const HI: Vec3 = Vec3::splat(0.7);
const VOXEL: f32 = 0.025;

#[test]
fn masks_fill_the_pit_and_depth_carves_it() {
    let s = scene();
    let masks = mask_views(&s);
    let hull = masks_grid(&masks, LO, HI, VOXEL).unwrap();
    let in_pit = Vec3::new(0.0, 0.35, 0.0);
    let in_wall = Vec3::new(0.35, 0.35, 0.0);
    let centre = Vec3::new(0.0, -0.2, 0.0);
    let outside = Vec3::new(0.65, 0.0, 0.0);
    assert!(at(&hull, in_pit) < 0.0, "silhouettes cannot see the pit");
    assert!(silhouette_distance(&masks, outside).unwrap() > 0.0);

    let carved = carve_grid(
        &masks,
        &depth_maps(&s),
        LO,
        HI,
        VOXEL,
        &CarveSettings::default(),
    )
    .unwrap();
    assert!(at(&carved, in_pit) > 0.0, "the depth carves the pit");
    assert!(at(&carved, in_wall) < 0.0, "but not the wall beside it");
    assert!(at(&carved, centre) < 0.0, "nor the body");
    assert!(at(&carved, outside) > 0.0);
    // Carving never adds volume: the field is at least the masks' everywhere.
    for (c, h) in carved.values.iter().zip(&hull.values) {
        assert!(c >= h, "carved {c} below the masks' {h}");
    }
}

#[test]
fn one_wrong_depth_map_does_not_dig_into_the_object() {
    let s = scene();
    let masks = mask_views(&s);
    // One view claims the surface lies far behind everything it sees.
    let mut depths = s.depths.clone();
    for d in depths[0].iter_mut().filter(|d| **d > 0.0) {
        *d += 3.0;
    }
    let maps: Vec<DepthMap> = s
        .cams
        .iter()
        .zip(&depths)
        .map(|(camera, depth)| DepthMap {
            camera,
            depth,
            hull_depth: None,
        })
        .collect();
    let settings = CarveSettings::default();
    let carved = carve_grid(&masks, &maps, LO, HI, VOXEL, &settings).unwrap();
    let honest = carve_grid(&masks, &depth_maps(&s), LO, HI, VOXEL, &settings).unwrap();
    // No point of the solid (deeper than the margin) is carved, and the wrong view changes
    // almost nothing.
    let dug = |g: &gtsr_mesh::marching::Grid| carved_below(g, -0.05);
    assert_eq!(dug(&honest), 0, "carved into the solid by exact depth");
    assert_eq!(dug(&carved), 0, "carved into the solid by one wrong view");
    let changed = carved
        .values
        .iter()
        .zip(&honest.values)
        .filter(|(c, h)| (**c > 0.0) != (**h > 0.0))
        .count();
    assert!(
        changed * 200 < carved.values.len(),
        "{changed} points changed side"
    );
    // With one view enough, the wrong one digs.
    let single = CarveSettings {
        min_views: 1,
        ..settings
    };
    let carved = carve_grid(&masks, &maps, LO, HI, VOXEL, &single).unwrap();
    assert!(dug(&carved) > 0);
}

#[test]
fn the_carved_mesh_beats_the_masks_on_the_pit() {
    let s = scene();
    let masks = mask_views(&s);
    let gt = carve_mesh(
        &masks,
        &depth_maps(&s),
        LO,
        HI,
        0.01,
        &CarveSettings {
            min_views: 1,
            margin_footprints: 0.0,
            min_free_ratio: 0.0,
            slope_margin: 0.0,
            bilinear: false,
            concavity_gate: 0.0,
            gate_radius: 0,
        },
    )
    .unwrap();
    let hull = masks_mesh(&masks, Some(VOXEL)).unwrap().expect("a hull");
    let carved = carve_mesh(
        &masks,
        &depth_maps(&s),
        LO,
        HI,
        VOXEL,
        &CarveSettings::default(),
    )
    .unwrap();
    let (h, _) = score_against_ground_truth(&hull, &gt, &s.cams, Some(&hull)).unwrap();
    let (c, _) = score_against_ground_truth(&carved, &gt, &s.cams, Some(&hull)).unwrap();
    let (hb, cb) = (h.hull_blind.unwrap(), c.hull_blind.unwrap());
    // The pit's walls and floor are hull-blind; the masks miss them by their depth.
    assert!(hb.fraction > 0.02, "{hb:?}");
    assert!((hb.blind - hb.hull_on_blind).abs() < 1e-6, "{hb:?}");
    assert!(cb.blind < 0.5 * hb.blind, "carved {cb:?} masks {hb:?}");
    assert!(
        c.chamfer < h.chamfer,
        "carved {} masks {}",
        c.chamfer,
        h.chamfer
    );
}

#[test]
fn carving_checks_its_inputs() {
    let s = scene();
    let masks = mask_views(&s);
    let maps = depth_maps(&s);
    for bad in [
        CarveSettings {
            min_views: 0,
            margin_footprints: 1.0,
            ..CarveSettings::default()
        },
        CarveSettings {
            min_views: 17,
            margin_footprints: 1.0,
            ..CarveSettings::default()
        },
        CarveSettings {
            min_views: 2,
            margin_footprints: f32::NAN,
            ..CarveSettings::default()
        },
        CarveSettings {
            min_views: 2,
            margin_footprints: -1.0,
            ..CarveSettings::default()
        },
        CarveSettings {
            min_free_ratio: 1.5,
            ..CarveSettings::default()
        },
        CarveSettings {
            slope_margin: f32::NAN,
            ..CarveSettings::default()
        },
        CarveSettings {
            slope_margin: -0.5,
            ..CarveSettings::default()
        },
        CarveSettings {
            concavity_gate: f32::INFINITY,
            ..CarveSettings::default()
        },
        // A gate without the hull's depth maps.
        CarveSettings {
            concavity_gate: 3.0,
            ..CarveSettings::default()
        },
    ] {
        assert!(
            carve_grid(&masks, &maps, LO, HI, VOXEL, &bad).is_err(),
            "{bad:?}"
        );
    }
    let ok = CarveSettings::default();
    let short = [DepthMap {
        camera: &s.cams[0],
        depth: &s.depths[0][1..],
        hull_depth: None,
    }];
    assert!(carve_grid(&masks, &short, LO, HI, VOXEL, &ok).is_err());
    assert!(carve_grid(&[], &maps, LO, HI, VOXEL, &ok).is_err());
    assert!(carve_grid(&masks, &maps, HI, LO, VOXEL, &ok).is_err());
    assert!(carve_grid(&masks, &maps, LO, HI, 0.0, &ok).is_err());
}

#[test]
fn the_extraction_recipe_carves_with_masks_and_fuses_a_tsdf_without() {
    use gtsr_mesh::{Fusion, FusionInputs, FusionView, MasksAlone, MeshConfig, extract_mesh};
    let s = scene();
    let views: Vec<FusionView> = s
        .cams
        .iter()
        .zip(s.depths.iter().zip(&s.masks))
        .map(|(camera, (depth, mask))| FusionView {
            camera,
            depth,
            mask,
            normal: &[],
        })
        .collect();
    let alone = MasksAlone::new(s.cams.iter().copied().zip(s.masks.clone()).collect())
        .unwrap()
        .expect("a hull");
    let inputs = FusionInputs {
        views: &views,
        masked: true,
        masks: Some(&alone),
        footprint_cameras: &s.cams,
        bounds: (LO, HI),
        coarse: false,
    };
    // The default without its culling: the depth moved forward by its median offset from the
    // masks' mesh, then the masks carved where a view looks into a concavity, exactly
    // `carve_mesh` on the masks' own grid with the masks' mesh ray cast as the hull's depth.
    let closed = MeshConfig {
        cull_unobserved: 0.0,
        ..MeshConfig::default()
    };
    let (carved, notes) = extract_mesh(&closed, &inputs).unwrap();
    let hulls = hull_depths(&s, &alone.mesh);
    let offset =
        gtsr_mesh::carve::hull_offset(&gated_maps(&s, &s.depths, &hulls)).expect("samples")[1];
    let moved: Vec<Vec<f32>> = (s.cams.iter().zip(&s.depths))
        .map(|(camera, depth)| {
            let mut depth = depth.clone();
            if offset > 0.0 {
                gtsr_mesh::carve::debias_depth(camera, &mut depth, offset);
            }
            depth
        })
        .collect();
    let maps = gated_maps(&s, &moved, &hulls);
    let direct = carve_mesh(
        &alone.borrowed(),
        &maps,
        LO,
        HI,
        alone.voxel,
        &closed.carve(),
    )
    .unwrap();
    assert!(
        carved == direct,
        "{} against {} triangles",
        carved.triangles.len(),
        direct.triangles.len()
    );
    assert!(
        notes.iter().any(|n| n.contains("concavity gate")),
        "{notes:?}"
    );
    assert!(
        at(
            &carve_grid(&alone.borrowed(), &maps, LO, HI, VOXEL, &closed.carve()).unwrap(),
            Vec3::new(0.0, 0.35, 0.0)
        ) > 0.0,
        "the default carves the pit"
    );
    // The default culls the carved walls no depth map observes: a subset of those faces.
    let (culled, notes) = extract_mesh(&MeshConfig::default(), &inputs).unwrap();
    assert!(notes.iter().any(|n| n.contains("culled")), "{notes:?}");
    let faces: std::collections::HashSet<[u32; 3]> = carved.triangles.iter().copied().collect();
    assert!(culled.positions == carved.positions);
    assert!(culled.triangles.iter().all(|t| faces.contains(t)));
    // TSDF fusion of the same depth with the masks' hull (at a truncation short enough for
    // the pit), and of the masks alone: the depth reaches the pit, the masks alone fill it.
    let tsdf = MeshConfig {
        fusion: Fusion::Tsdf,
        voxel: Some(VOXEL),
        truncation_footprints: Some(3.0),
        ..MeshConfig::default()
    };
    let (fused, notes) = extract_mesh(&tsdf, &inputs).unwrap();
    assert!(notes.is_empty());
    let masks_only = MeshConfig {
        fuse_depth: false,
        ..tsdf.clone()
    };
    let (hull, _) = extract_mesh(&masks_only, &inputs).unwrap();
    let (f, _) = score_against_ground_truth(&fused, &direct, &s.cams, Some(&alone.mesh)).unwrap();
    let (h, _) = score_against_ground_truth(&hull, &direct, &s.cams, Some(&alone.mesh)).unwrap();
    let (fb, hb) = (f.hull_blind.unwrap(), h.hull_blind.unwrap());
    assert!(fb.blind < 0.5 * hb.blind, "fused {fb:?} masks {hb:?}");
    // Settings that cannot work are refused, named.
    let bad = MeshConfig {
        depth_crossing: Some(2.0),
        ..tsdf
    };
    let e = extract_mesh(&bad, &inputs).unwrap_err().to_string();
    assert!(e.contains("depth_crossing"), "{e}");
}

#[test]
fn depth_preparation_keeps_only_what_fusion_may_trust() {
    use gtsr_mesh::{DepthGeometry, prepare_depth};
    let cam = Camera {
        world_to_camera: glam::Affine3A::IDENTITY,
        fx: 4.0,
        fy: 4.0,
        cx: 2.0,
        cy: 1.0,
        width: 4,
        height: 2,
    };
    let n = 8;
    let mut depth = vec![2.0f32; n];
    depth[3] = f32::NAN;
    let mut normal: Vec<f32> = (0..n).flat_map(|_| [0.0, 0.0, -1.0]).collect();
    normal[3 * 5..3 * 5 + 3].copy_from_slice(&[1.0, 0.0, 0.0]); // grazing
    let rays: Vec<f32> = (0..n).flat_map(|_| [0.0, 0.0, 1.0]).collect();
    let plane = vec![2.0f32; n];
    let mut coverage = vec![1.0f32; n];
    coverage[6] = 0.2;
    let mut mask = vec![1.0f32; n];
    mask[1] = 0.0;
    let geometry = DepthGeometry {
        normal: &normal,
        plane: &plane,
        rays: &rays,
        coverage: Some(&coverage),
    };
    prepare_depth(&cam, &mut depth, &geometry, &mask, false).unwrap();
    assert_eq!(depth, [2.0, 0.0, 2.0, 0.0, 2.0, 0.0, 0.0, 2.0]);
    let short = DepthGeometry {
        normal: &normal[..6],
        ..geometry
    };
    let e = prepare_depth(&cam, &mut depth, &short, &mask, false)
        .unwrap_err()
        .to_string();
    assert!(e.contains("normal"), "{e}");
}

#[test]
fn the_slope_margin_keeps_single_views_from_eroding_the_edges() {
    let s = scene();
    let masks = mask_views(&s);
    let single = |slope_margin| CarveSettings {
        min_views: 1,
        margin_footprints: 0.0,
        min_free_ratio: 0.0,
        slope_margin,
        bilinear: false,
        concavity_gate: 0.0,
        gate_radius: 0,
    };
    // Points of the solid carved by exact depth maps (with no margin, only a depth read at
    // the wrong place along a grazing pixel can put them in front of the surface).
    let dug = |g: &gtsr_mesh::marching::Grid| carved_below(g, 0.0);
    let plain = carve_grid(&masks, &depth_maps(&s), LO, HI, VOXEL, &single(0.0)).unwrap();
    let sloped = carve_grid(&masks, &depth_maps(&s), LO, HI, VOXEL, &single(1.0)).unwrap();
    let (d_plain, d_sloped) = (dug(&plain), dug(&sloped));
    assert!(
        d_plain > 0,
        "nearest-pixel depth at grazing pixels digs: {d_plain}"
    );
    assert_eq!(d_sloped, 0, "with the slope margin ({d_plain} without)");
    assert!(
        at(&sloped, Vec3::new(0.0, 0.35, 0.0)) > 0.0,
        "the pit is still carved"
    );
}

#[test]
fn bilinear_depth_keeps_single_views_from_eroding_the_edges() {
    let s = scene();
    let masks = mask_views(&s);
    let single = |margin_footprints, bilinear| CarveSettings {
        min_views: 1,
        margin_footprints,
        min_free_ratio: 0.0,
        slope_margin: 0.0,
        bilinear,
        concavity_gate: 0.0,
        gate_radius: 0,
    };
    let maps = depth_maps(&s);
    let dug = |settings: CarveSettings| {
        let g = carve_grid(&masks, &maps, LO, HI, VOXEL, &settings).unwrap();
        let pit = at(&g, Vec3::new(0.0, 0.35, 0.0));
        (carved_below(&g, 0.0), pit)
    };
    // Exact depth, a single view enough: the nearest pixel's depth at grazing pixels digs
    // into the solid, the bilinear depth (measured: about a sixth as much) only where it
    // interpolates across a crease of the depth map. The pit is carved either way.
    let (n0, _) = dug(single(0.0, false));
    let (b0, pit0) = dug(single(0.0, true));
    let (n1, _) = dug(single(0.25, false));
    let (b1, pit1) = dug(single(0.25, true));
    eprintln!("dug at margin 0 / 0.25: nearest {n0} / {n1}, bilinear {b0} / {b1}");
    assert!(b0 * 4 < n0, "bilinear {b0} against nearest {n0}");
    assert!(b1 * 4 < n1.max(1), "bilinear {b1} against nearest {n1}");
    assert!(pit0 > 0.0 && pit1 > 0.0, "the pit is still carved");
}

#[test]
fn the_concavity_gate_carves_the_pit_and_leaves_the_faces_to_the_masks() {
    let s = scene();
    let masks = mask_views(&s);
    let hull = masks_mesh(&masks, Some(VOXEL)).unwrap().expect("a hull");
    let hulls = hull_depths(&s, &hull);
    // Rendered depth lies behind the surface: two footprints here.
    let behind: Vec<Vec<f32>> = s
        .cams
        .iter()
        .zip(&s.depths)
        .map(|(c, d)| d.iter().map(|&z| z + 2.0 * z / c.fx).collect())
        .collect();
    let maps = gated_maps(&s, &behind, &hulls);
    let single = |concavity_gate| CarveSettings {
        min_views: 1,
        margin_footprints: 0.0,
        min_free_ratio: 0.0,
        concavity_gate,
        ..CarveSettings::default()
    };
    // Solid points carved away from the pit (more than 0.1 from its walls and floor).
    let dug_away = |g: &gtsr_mesh::marching::Grid| {
        let [nx, ny, nz] = g.dims;
        let mut n = 0;
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    let p = g.point(i, j, k);
                    let near_pit =
                        (p.x * p.x + p.z * p.z).sqrt() < PIT_RADIUS + 0.1 && p.y > PIT_FLOOR - 0.1;
                    if !near_pit && sdf(p) < 0.0 && g.values[g.index(i, j, k)] > 0.0 {
                        n += 1;
                    }
                }
            }
        }
        n
    };
    let open = carve_grid(&masks, &maps, LO, HI, VOXEL, &single(0.0)).unwrap();
    let gated = carve_grid(&masks, &maps, LO, HI, VOXEL, &single(3.0)).unwrap();
    let (d_open, d_gated) = (dug_away(&open), dug_away(&gated));
    eprintln!(
        "solid points dug away from the pit: {d_open} open, {d_gated} gated; anywhere {} / {}",
        carved_below(&open, 0.0),
        carved_below(&gated, 0.0)
    );
    assert!(d_open > 100, "depth behind the surface erodes the faces");
    assert_eq!(d_gated, 0, "the gated rule leaves them to the masks");
    for p in [Vec3::new(0.0, 0.35, 0.0), Vec3::new(0.1, 0.2, 0.05)] {
        assert!(at(&gated, p) > 0.0, "the pit is carved at {p}");
    }
    // Depth that agrees with the hull carves nothing.
    let flat = gated_maps(&s, &hulls, &hulls);
    let none = carve_grid(&masks, &flat, LO, HI, VOXEL, &single(3.0)).unwrap();
    let by_masks = masks_grid(&masks, LO, HI, VOXEL).unwrap();
    let changed = none
        .values
        .iter()
        .zip(&by_masks.values)
        .filter(|(a, b)| (**a > 0.0) != (**b > 0.0))
        .count();
    assert_eq!(changed, 0, "the hull's own depth changed {changed} points");
}

#[test]
fn the_hull_slack_bounds_how_far_the_hull_lies_from_the_object() {
    let s = scene();
    let masks = mask_views(&s);
    let hull = masks_mesh(&masks, Some(VOXEL)).unwrap().expect("a hull");
    let footprint = 4.0 / s.cams[0].fx;
    let slack = hull_slack(&masks, &hull.positions, 0.25 * footprint, 1.5).unwrap();
    // The bound: the object lies within the slack of every point of the hull (up to the
    // masks' pixel and the search's step).
    let mut worst = f32::NEG_INFINITY;
    for (p, s) in hull.positions.iter().zip(&slack) {
        worst = worst.max(sdf(*p).abs() - s);
    }
    assert!(
        worst < 2.0 * footprint,
        "the object lies {worst} beyond a slack"
    );
    // Over the pit, which no silhouette shows, the slack is at least the pit's radius (so it
    // is on the cube's flat faces, which the grazing rays run along).
    let mut lid = f32::INFINITY;
    for (p, s) in hull.positions.iter().zip(&slack) {
        if p.x * p.x + p.z * p.z < 0.05 * 0.05 && p.y > HALF - 0.02 {
            lid = lid.min(*s);
        }
    }
    assert!(lid >= PIT_RADIUS - footprint, "slack over the pit {lid}");
    // A sphere's hull is held everywhere.
    let spheres = common::sphere_masks(&s.cams, Vec3::ZERO, 0.4);
    let views = common::as_views(&spheres);
    let ball = masks_mesh(&views, Some(VOXEL)).unwrap().expect("a hull");
    let slack = hull_slack(&views, &ball.positions, 0.25 * footprint, 1.5).unwrap();
    let mut sorted = slack.clone();
    sorted.sort_by(f32::total_cmp);
    let (median, most) = (sorted[sorted.len() / 2], sorted[sorted.len() - 1]);
    eprintln!("slack on the sphere: median {median}, most {most}; over the pit {lid}");
    assert!(
        median < 0.25 * lid && most < 0.5 * 0.4,
        "slack on a sphere of radius 0.4: median {median}, most {most}"
    );
    // Bad input is refused.
    assert!(hull_slack(&masks, &hull.positions, 0.0, 1.0).is_err());
    assert!(hull_slack(&masks, &hull.positions, 0.1, 0.05).is_err());
    let short = [(s.cams[0], &s.masks[0][..10])];
    assert!(hull_slack(&short, &hull.positions, 0.01, 0.1).is_err());
}
