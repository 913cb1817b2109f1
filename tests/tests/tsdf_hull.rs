mod common;

use glam::Vec3;
use gtsr_eval::chamfer;
use gtsr_mesh::MeshError;
use gtsr_mesh::hull::visual_hull;
use gtsr_mesh::mesh::{component_sizes, icosphere, is_closed};
use gtsr_mesh::pixels::median_pixel_footprint;
use gtsr_mesh::tsdf::{TsdfVolume, default_voxel, default_voxel_for_radius};
use gtsr_mesh::tsdf::{default_truncation, drop_depth_edges, faces_ray, snap_to_hull};

#[test]
fn fused_sphere_depths_give_the_sphere() {
    let (centre, r) = (Vec3::new(0.05, -0.02, 0.03), 0.5);
    let voxel = 0.01;
    let mut vol = TsdfVolume::new(
        centre - Vec3::splat(0.6),
        centre + Vec3::splat(0.6),
        voxel,
        4.0 * voxel,
    )
    .unwrap();
    let cams = common::cameras_around(centre, 2.0, 20, 40f32.to_radians(), 160);
    for cam in &cams {
        let (depth, mask) = common::render_sphere(cam, centre, r);
        vol.integrate(cam, &depth, Some(&mask)).unwrap();
    }
    let m = vol.extract_mesh();
    assert!(is_closed(&m), "TSDF sphere is not closed");
    assert_eq!(component_sizes(&m).len(), 1);
    let reference = icosphere(centre, r, 6);
    let cd = chamfer(&m, &reference, 50_000, voxel, 0).unwrap();
    assert!(cd.chamfer < 0.25 * voxel as f64, "{cd:?}");
    assert!(cd.fscore > 0.95, "{cd:?}");
    assert!(m.volume() > 0.0);
    // Deep inside is never observed (behind the surface by more than the truncation).
    let g = vol.grid();
    let c = ((centre - g.origin) / g.voxel).round();
    assert!(!g.observed[g.index(c.x as usize, c.y as usize, c.z as usize)]);
}

#[test]
fn masked_pixels_carve_free_space_and_unmasked_missing_depth_does_not() {
    let voxel = 0.05;
    let cams = common::cameras_around(Vec3::ZERO, 2.0, 1, 40f32.to_radians(), 64);
    let cam = &cams[0];
    let n = 64 * 64;
    let depth = vec![0.0f32; n];
    // No depth, no mask: nothing observed.
    let mut a = TsdfVolume::new(Vec3::splat(-0.3), Vec3::splat(0.3), voxel, 0.1).unwrap();
    a.integrate(cam, &depth, None).unwrap();
    assert!(a.grid().observed.iter().all(|&o| !o));
    // Mask 0 everywhere: everything in view is free space at +truncation.
    let mut b = TsdfVolume::new(Vec3::splat(-0.3), Vec3::splat(0.3), voxel, 0.1).unwrap();
    b.integrate(cam, &depth, Some(&vec![0.0; n])).unwrap();
    let observed = b.grid().observed.iter().filter(|&&o| o).count();
    assert_eq!(observed, b.grid().values.len(), "the box is fully in view");
    assert!(b.grid().values.iter().all(|&v| v == 0.1));
    assert!(b.weights().iter().all(|&w| w == 1.0));
    assert!(b.extract_mesh().triangles.is_empty());
}

#[test]
fn integrate_checks_sizes_and_new_checks_arguments() {
    let cams = common::cameras_around(Vec3::ZERO, 2.0, 1, 0.7, 32);
    let mut v = TsdfVolume::new(Vec3::splat(-0.5), Vec3::splat(0.5), 0.1, 0.3).unwrap();
    assert!(matches!(
        v.integrate(&cams[0], &[1.0; 10], None),
        Err(MeshError::SizeMismatch { .. })
    ));
    assert!(matches!(
        v.integrate(&cams[0], &[1.0; 32 * 32], Some(&[1.0; 3])),
        Err(MeshError::SizeMismatch { .. })
    ));
    assert!(TsdfVolume::new(Vec3::ONE, Vec3::ZERO, 0.1, 0.3).is_err());
    assert!(TsdfVolume::new(Vec3::ZERO, Vec3::ONE, 0.0, 0.3).is_err());
    assert!(TsdfVolume::new(Vec3::ZERO, Vec3::ONE, 1e-6, 0.3).is_err());
    assert!((default_voxel_for_radius(1.0) - 1.0 / 256.0).abs() < 1e-9);
}

/// The default voxel is the radius's, except where a quarter footprint is coarser: images of
/// a few dozen pixels get a grid their depth can fill.
#[test]
fn the_default_voxel_is_no_finer_than_a_quarter_footprint() {
    let by_radius = default_voxel_for_radius(1.0);
    // 256 px of a unit object: a footprint of about 0.01, the radius's voxel stays.
    assert_eq!(default_voxel(1.0, 0.01), by_radius);
    // 24 px: a footprint of 0.1, a voxel of 0.025.
    assert!((default_voxel(1.0, 0.1) - 0.025).abs() < 1e-9);
    // No footprint (no camera, or a degenerate one): the radius's voxel.
    for f in [0.0, -1.0, f32::NAN, f32::INFINITY] {
        assert_eq!(default_voxel(1.0, f), by_radius);
    }
}

#[test]
fn visual_hull_of_a_sphere_contains_it_and_is_close() {
    let (centre, r) = (Vec3::new(0.0, 0.1, 0.0), 0.5);
    let cams = common::cameras_around(centre, 2.5, 60, 35f32.to_radians(), 200);
    let masks = common::sphere_masks(&cams, centre, r);
    let views = common::as_views(&masks);
    let res = 96;
    let (lo, hi) = (centre - Vec3::splat(0.7), centre + Vec3::splat(0.7));
    let hull = visual_hull(&views, lo, hi, res).unwrap();
    let voxel = 1.4 / res as f32;
    assert!(is_closed(&hull));
    assert_eq!(component_sizes(&hull).len(), 1);
    // Contains the sphere: no hull vertex inside it (beyond a pixel/interpolation slack).
    let min_r = hull
        .positions
        .iter()
        .map(|p| (*p - centre).length())
        .fold(f32::INFINITY, f32::min);
    assert!(min_r > r - 0.5 * voxel, "hull vertex at radius {min_r}");
    let cd = chamfer(&hull, &icosphere(centre, r, 6), 30_000, voxel, 0).unwrap();
    // Binary masks carve to within a fraction of a voxel (measured 0.0014, 0.1 voxel).
    assert!(cd.chamfer < 0.25 * voxel as f64, "{cd:?}");
    // A view whose mask is empty carves everything.
    let empty = vec![0.0; masks[0].1.len()];
    let mut with_empty = views.clone();
    with_empty.push((cams[0], &empty));
    assert!(
        visual_hull(&with_empty, lo, hi, 32)
            .unwrap()
            .triangles
            .is_empty()
    );
    // Errors.
    assert!(visual_hull(&[], lo, hi, 32).is_err());
    assert!(matches!(
        visual_hull(&[(cams[0], &[1.0; 5][..])], lo, hi, 32),
        Err(MeshError::SizeMismatch { .. })
    ));
}

#[test]
fn hull_box_holds_the_object_and_little_more() {
    // The object fills much of each frame, as in the shared scenes: a point that only a few
    // cameras see (say near one camera, behind the object for the opposite one) is carved
    // only by those, and a small object in narrow frusta leaves such points inside the hull.
    let (centre, r) = (Vec3::new(0.3, -0.2, 0.1), 0.8);
    let cams = common::cameras_around(centre, 3.0, 40, 50f32.to_radians(), 96);
    let masks = common::sphere_masks(&cams, centre, r);
    let views = common::as_views(&masks);
    let (lo, hi) = gtsr_mesh::hull::hull_box(&views).unwrap().unwrap();
    // The carving voxel: the cameras' cube (side 2 * 3.0 around their mean, which is near the
    // sphere's centre) over HULL_BOX_RESOLUTION.
    let voxel = 6.0 / gtsr_mesh::hull::HULL_BOX_RESOLUTION as f32;
    for axis in 0..3 {
        let (a, b) = (lo[axis], hi[axis]);
        let (c, cmin, cmax) = (centre[axis], centre[axis] - r, centre[axis] + r);
        assert!(
            a < cmin && b > cmax,
            "axis {axis}: box [{a}, {b}] cuts the sphere at {c}"
        );
        // Padded by two carving voxels, plus up to one more and the hull's slack.
        assert!(
            cmin - a < 4.0 * voxel && b - cmax < 4.0 * voxel,
            "axis {axis}: box [{a}, {b}] is loose around [{cmin}, {cmax}]"
        );
    }
    // An empty mask leaves nothing inside every mask; no views is an error.
    let empty = vec![0.0; masks[0].1.len()];
    let mut with_empty = views.clone();
    with_empty.push((cams[0], &empty));
    assert!(gtsr_mesh::hull::hull_box(&with_empty).unwrap().is_none());
    assert!(gtsr_mesh::hull::hull_box(&[]).is_err());
}

#[test]
fn silhouette_carving_keeps_the_surface_inside_every_mask() {
    // Images of 32 px (a pixel is 0.045 wide at the sphere, 4.5 voxels), as coarse as training.
    let (voxel, trunc) = (0.01, 0.12);
    let cams = common::cameras_around(Vec3::ZERO, 2.0, 24, 40f32.to_radians(), 32);
    let fuse = |depth_r: f32, mask_r: f32, carve: bool| {
        let mut v = TsdfVolume::new(Vec3::splat(-0.7), Vec3::splat(0.7), voxel, trunc).unwrap();
        if carve {
            v = v.with_silhouette_carving();
        }
        for cam in &cams {
            let (depth, _) = common::render_sphere(cam, Vec3::ZERO, depth_r);
            let (_, mask) = common::render_sphere(cam, Vec3::ZERO, mask_r);
            v.integrate(cam, &depth, Some(&mask)).unwrap();
        }
        v.extract_mesh()
    };
    let max_radius = |m: &gtsr_data::ply::TriMesh| {
        m.positions
            .iter()
            .map(|p| p.length())
            .fold(0.0f32, f32::max)
    };
    let sphere = icosphere(Vec3::ZERO, 0.4, 5);
    // Exact depth and masks: carving costs nothing (the hull field is placed between pixels as
    // the hull is, and the masked-out pixels no longer vote +truncation into the average).
    let carved = fuse(0.4, 0.4, true);
    let plain = fuse(0.4, 0.4, false);
    let cd = chamfer(&carved, &sphere, 20_000, voxel, 0).unwrap();
    let cd_plain = chamfer(&plain, &sphere, 20_000, voxel, 0).unwrap();
    assert!(cd.chamfer < 0.5 * voxel as f64, "{cd:?}");
    assert!(
        cd.chamfer <= cd_plain.chamfer,
        "{cd:?} against {cd_plain:?}"
    );
    // Depth of a sphere of radius 0.5 but masks of one of radius 0.4: the surface stays inside
    // the masks' hull.
    let carved = fuse(0.5, 0.4, true);
    assert!(!carved.triangles.is_empty());
    let masks = common::sphere_masks(&cams, Vec3::ZERO, 0.4);
    let views = common::as_views(&masks);
    let hull = visual_hull(&views, Vec3::splat(-0.7), Vec3::splat(0.7), 140).unwrap();
    let (r_carved, r_hull, r_plain) = (
        max_radius(&carved),
        max_radius(&hull),
        max_radius(&fuse(0.5, 0.4, false)),
    );
    assert!(
        r_carved < r_hull + voxel,
        "{r_carved} against the hull's {r_hull}"
    );
    assert!(
        r_plain > r_hull + voxel,
        "{r_plain} against the hull's {r_hull}"
    );
}

#[test]
fn hull_depth_bounds_the_sphere_and_snapping_keeps_only_what_lies_deeper() {
    let (voxel, trunc) = (0.01, 0.12);
    let r = 0.4;
    let cams = common::cameras_around(Vec3::ZERO, 2.0, 24, 40f32.to_radians(), 32);
    let plain = TsdfVolume::new(Vec3::splat(-0.7), Vec3::splat(0.7), voxel, trunc).unwrap();
    assert!(plain.hull_depth(&cams[0]).is_none(), "no carving, no hull");
    let mut v = plain.with_silhouette_carving();
    for cam in &cams {
        let (_, mask) = common::render_sphere(cam, Vec3::ZERO, r);
        v.integrate(cam, &vec![0.0; mask.len()], Some(&mask))
            .unwrap();
    }
    let cam = &cams[3];
    let (truth, mask) = common::render_sphere(cam, Vec3::ZERO, r);
    let hull = v.hull_depth(cam).unwrap();
    let footprint = 2.0 / cam.fx;
    let (mut compared, mut gap) = (0, 0.0);
    let interior = |p: usize| {
        [p, p - 1, p + 1, p - 32, p + 32]
            .iter()
            .all(|&q| mask[q] > 0.5)
    };
    for p in 33..32 * 31 {
        let (t, hd) = (truth[p], hull[p]);
        if mask[p] < 0.5 {
            continue;
        }
        // Inside the mask the ray enters the hull. Off the rim (where a grazing ray's depth
        // changes fast) in front of the sphere, which the hull holds up to the masks' own
        // error: their 0.5 level, bilinear between binary pixels, lies up to half a footprint
        // inside the true silhouette.
        assert!(hd > 0.0, "a ray inside the mask misses the hull");
        if !interior(p) {
            continue;
        }
        assert!(
            hd <= t + 0.5 * footprint + voxel,
            "the hull at {hd} lies behind the sphere at {t}"
        );
        // And not far in front: the hull of 24 views bulges between their cones.
        assert!(
            t - hd < 0.1,
            "the hull at {hd} lies far in front of the sphere at {t}"
        );
        gap += t - hd;
        compared += 1;
    }
    assert!(compared > 100, "{compared}");
    assert!(
        gap / (compared as f32) < footprint,
        "mean gap {}",
        gap / compared as f32
    );
    let centre = 16 * 32 + 16;
    assert!(
        (truth[centre] - hull[centre]).abs() < footprint,
        "centre: sphere {} hull {}",
        truth[centre],
        hull[centre]
    );
    // No ray outside the masks' union can meet the hull beyond the rim's pixels.
    assert_eq!(hull[0], 0.0);

    // Snapping: 0.5 footprint behind the hull snaps, 3 behind stays, in front snaps, no depth
    // stays none, a ray that misses the hull keeps its depth.
    let h = hull[centre];
    let fp = |d: f32| d / cam.fx;
    let mut depth = vec![h + 0.5 * fp(h), h + 3.0 * fp(h), h - 0.1, 0.0, 1.7];
    let hulls = [h, h, h, h, 0.0];
    let snapped = snap_to_hull(&mut depth, &hulls, cam.fx, 2.0).unwrap();
    assert_eq!(snapped, 2);
    assert_eq!(depth[0], h);
    assert!(depth[1] > h + 2.9 * fp(h));
    assert_eq!(depth[2], h);
    assert_eq!(depth[3], 0.0);
    assert_eq!(depth[4], 1.7);
    assert!(snap_to_hull(&mut depth, &hulls[..4], cam.fx, 2.0).is_err());
    assert!(snap_to_hull(&mut depth, &hulls, cam.fx, f32::NAN).is_err());
    assert!(snap_to_hull(&mut depth, &hulls, cam.fx, -1.0).is_err());
}

#[test]
fn the_hulls_own_distance_inside_places_the_surface_between_voxels() {
    // Masks alone, fine images (128 px: a pixel is 0.011 wide at the sphere, about a voxel).
    let (voxel, trunc) = (0.01, 0.3);
    let cams = common::cameras_around(Vec3::ZERO, 2.0, 40, 40f32.to_radians(), 128);
    let fuse = |soft: bool| {
        let mut v = TsdfVolume::new(Vec3::splat(-0.7), Vec3::splat(0.7), voxel, trunc)
            .unwrap()
            .with_silhouette_carving();
        if soft {
            v = v.with_hull_inside_distance();
        }
        for cam in &cams {
            let (_, mask) = common::render_sphere(cam, Vec3::ZERO, 0.4);
            v.integrate(cam, &vec![0.0; mask.len()], Some(&mask))
                .unwrap();
        }
        let m = v.extract_mesh();
        chamfer(&m, &icosphere(Vec3::ZERO, 0.4, 6), 50_000, voxel, 0).unwrap()
    };
    let (hard, soft) = (fuse(false), fuse(true));
    // -truncation inside puts every crossing at the outside voxel: a staircase one voxel
    // wide whose normals follow the grid (the hull of 40 views, a polyhedron around the
    // sphere, is most of either's distance: 2.0e-3 against 2.35e-3 here).
    assert!(
        soft.chamfer < hard.chamfer,
        "soft {soft:?} against hard {hard:?}"
    );
    assert!(
        soft.normal_consistency > hard.normal_consistency + 0.05,
        "soft {soft:?} against hard {hard:?}"
    );
}

#[test]
fn default_truncation_follows_the_radius_or_the_training_pixel() {
    let cam = |size: u32| {
        gtsr_data::Camera::look_at(
            Vec3::new(0.0, 0.0, 4.0),
            Vec3::ZERO,
            Vec3::Y,
            0.7,
            size,
            size,
        )
    };
    let (c16, c64) = (cam(16), cam(64));
    let f64px = median_pixel_footprint([&c64, &c64, &c64], Vec3::ZERO);
    assert!((f64px - 4.0 / c64.fx).abs() < 1e-6, "{f64px}");
    // The median view decides; no cameras, no footprint.
    assert_eq!(
        median_pixel_footprint([&c16, &c64, &c64], Vec3::ZERO),
        f64px
    );
    assert_eq!(
        median_pixel_footprint([] as [&gtsr_data::Camera; 0], Vec3::ZERO),
        0.0
    );
    // A unit object: the radius decides.
    let t = default_truncation(1.0, f64px, true);
    assert!((t - 0.75).abs() < 1e-6, "{t}");
    // A small object in coarse images: six pixel footprints.
    let t = default_truncation(0.01, f64px, true);
    assert!((t - 6.0 * 4.0 / c64.fx).abs() < 1e-4, "{t}");
    // Without free-space votes, two footprints, whatever the radius.
    let t = default_truncation(1.0, f64px, false);
    assert!((t - 2.0 * 4.0 / c64.fx).abs() < 1e-4, "{t}");
}

#[test]
fn grazing_depth_is_not_fused() {
    let ray = Vec3::new(0.0, 0.0, -2.0);
    // Facing the ray, at any length; at the cut (cos 0.2) still fused.
    assert!(faces_ray(Vec3::new(0.0, 0.0, 3.0), ray));
    let at_cut = Vec3::new((1.0f32 - 0.2 * 0.2).sqrt(), 0.0, 0.2 + 1e-6);
    assert!(faces_ray(at_cut, ray));
    // Edge-on, facing away, zero and NaN normals: not fused.
    assert!(!faces_ray(Vec3::new(1.0, 0.0, 0.1), ray));
    assert!(!faces_ray(Vec3::new(0.0, 0.0, -1.0), ray));
    assert!(!faces_ray(Vec3::ZERO, ray));
    assert!(!faces_ray(Vec3::new(f32::NAN, 0.0, 1.0), ray));
}

/// Rays `((x + 0.5 - c) / f, (y + 0.5 - c) / f, 1)` of a `w x w` image.
fn rays(w: usize, f: f32) -> Vec<f32> {
    let c = 0.5 * w as f32;
    (0..w * w)
        .flat_map(|p| {
            let (x, y) = ((p % w) as f32, (p / w) as f32);
            [(x + 0.5 - c) / f, (y + 0.5 - c) / f, 1.0]
        })
        .collect()
}

/// Depth, normal and plane maps of the plane `n . X = -plane` seen along `rays`.
fn plane_maps(rays: &[f32], n: [f32; 3], plane: f32) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let k = rays.len() / 3;
    let depth = (0..k)
        .map(|p| {
            let r = &rays[3 * p..3 * p + 3];
            plane / -(n[0] * r[0] + n[1] * r[1] + n[2] * r[2])
        })
        .collect();
    (depth, n.repeat(k), vec![plane; k])
}

#[test]
fn depth_edges_drop_occlusion_boundaries_and_keep_slanted_surfaces() {
    let (w, f) = (16, 20.0);
    let r = rays(w, f);
    // A plane slanted at 60 degrees: continuous, nothing dropped.
    let s = 60f32.to_radians();
    let n = [s.sin(), 0.0, -s.cos()];
    let (mut depth, normal, plane) = plane_maps(&r, n, 2.0);
    let before = depth.clone();
    drop_depth_edges(&mut depth, &normal, &plane, &r, w, w, f).unwrap();
    assert_eq!(depth, before);
    // A fronto-parallel plane at 2 with its right half at 3 (behind): the two columns
    // along the step are dropped, every other pixel kept; empty pixels are not edges.
    let (mut depth, normal, mut plane) = plane_maps(&r, [0.0, 0.0, -1.0], 2.0);
    for y in 0..w {
        for x in w / 2..w {
            depth[y * w + x] = 3.0;
            plane[y * w + x] = 3.0;
        }
        depth[y * w] = 0.0;
    }
    drop_depth_edges(&mut depth, &normal, &plane, &r, w, w, f).unwrap();
    for y in 0..w {
        for x in 0..w {
            let d = depth[y * w + x];
            let dropped = x == w / 2 - 1 || x == w / 2 || x == 0;
            assert_eq!(d == 0.0, dropped, "pixel ({x}, {y}) depth {d}");
        }
    }
    // Maps of the wrong size: an error naming the map, the depth untouched.
    let before = depth.clone();
    let err = drop_depth_edges(&mut depth, &normal[3..], &plane, &r, w, w, f).unwrap_err();
    assert!(err.to_string().contains("normal map"), "{err}");
    assert_eq!(depth, before);
}
