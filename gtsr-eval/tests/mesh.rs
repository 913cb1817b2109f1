use glam::Vec3;
use gtsr_data::ply::TriMesh;
use gtsr_eval::{EvalError, chamfer, chamfer_seen};
use gtsr_mesh::MeshError;
use gtsr_mesh::mesh::{component_sizes, icosphere, is_closed, sample_surface, surface_area};
use gtsr_mesh::mesh::{largest_component, weld};

#[test]
fn icosphere_is_closed_outward_and_close_to_the_sphere() {
    let r = 0.7;
    let m = icosphere(Vec3::new(0.1, -0.2, 0.3), r, 4);
    assert_eq!(m.triangles.len(), 20 * 4usize.pow(4));
    assert!(is_closed(&m));
    assert_eq!(component_sizes(&m), vec![m.triangles.len()]);
    let v = m.volume() as f64;
    let exact = 4.0 / 3.0 * std::f64::consts::PI * (r as f64).powi(3);
    assert!(
        v > 0.0 && (v - exact).abs() / exact < 0.01,
        "volume {v} vs {exact}"
    );
}

#[test]
fn sampling_is_seeded_area_uniform_and_on_the_surface() {
    // Two triangles of area 1 and 3: about a quarter of the samples on the first.
    let m = TriMesh {
        positions: vec![
            Vec3::ZERO,
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(0.0, 0.0, 5.0),
            Vec3::new(3.0, 0.0, 5.0),
            Vec3::new(0.0, 2.0, 5.0),
        ],
        triangles: vec![[0, 1, 2], [3, 4, 5]],
    };
    assert!((surface_area(&m) - 4.0).abs() < 1e-9);
    let a = sample_surface(&m, 40_000, 7, "test").unwrap();
    let b = sample_surface(&m, 40_000, 7, "test").unwrap();
    let c = sample_surface(&m, 40_000, 8, "test").unwrap();
    assert_eq!(a.points, b.points);
    assert_ne!(a.points, c.points);
    let first = a.triangles.iter().filter(|&&t| t == 0).count() as f64 / 40_000.0;
    assert!(
        (first - 0.25).abs() < 0.01,
        "fraction on the small triangle {first}"
    );
    for (p, &t) in a.points.iter().zip(&a.triangles) {
        if t == 0 {
            assert!(p.z == 0.0 && p.x >= 0.0 && p.y >= 0.0 && p.x / 2.0 + p.y <= 1.0 + 1e-6);
        } else {
            assert!((p.z - 5.0).abs() < 1e-6 && p.x / 3.0 + p.y / 2.0 <= 1.0 + 1e-6);
        }
    }
    // Uniform within a triangle: mean of the samples is the centroid.
    let mean = a
        .points
        .iter()
        .zip(&a.triangles)
        .filter(|(_, t)| **t == 1)
        .fold(Vec3::ZERO, |s, (p, _)| s + *p)
        / a.triangles.iter().filter(|&&t| t == 1).count() as f32;
    assert!(
        (mean - Vec3::new(1.0, 2.0 / 3.0, 5.0)).length() < 0.02,
        "mean {mean}"
    );
}

#[test]
fn mesh_against_itself_has_zero_chamfer() {
    let m = icosphere(Vec3::ZERO, 1.0, 3);
    let r = chamfer(&m, &m, 20_000, 1e-3, 1).unwrap();
    assert!(r.chamfer < 1e-6, "{r:?}");
    assert_eq!(r.fscore, 1.0);
    assert!((r.normal_consistency - 1.0).abs() < 1e-6);
}

#[test]
fn concentric_spheres_have_chamfer_close_to_the_radius_gap() {
    let (r1, r2) = (1.0f32, 1.1f32);
    let a = icosphere(Vec3::ZERO, r1, 5);
    let b = icosphere(Vec3::ZERO, r2, 5);
    let m = chamfer(&a, &b, 50_000, 0.05, 3).unwrap();
    // Faces sag inside the sphere by at most r (1 - cos(edge / 2r)) ~ 1.5e-4 r here; the
    // spheres have the same tessellation, so the gap is scaled by up to that much.
    assert!((m.chamfer - 0.1).abs() < 1e-3, "{m:?}");
    assert!((m.accuracy - 0.1).abs() < 1e-3 && (m.completeness - 0.1).abs() < 1e-3);
    assert_eq!(m.fscore, 0.0);
    let m = chamfer(&a, &b, 50_000, 0.2, 3).unwrap();
    assert_eq!(m.fscore, 1.0);
    assert!(m.normal_consistency > 0.99);
}

/// Concatenation of two meshes (no welding).
fn union(a: &TriMesh, b: &TriMesh) -> TriMesh {
    let off = a.positions.len() as u32;
    TriMesh {
        positions: a.positions.iter().chain(&b.positions).copied().collect(),
        triangles: a
            .triangles
            .iter()
            .copied()
            .chain(b.triangles.iter().map(|t| t.map(|i| i + off)))
            .collect(),
    }
}

#[test]
fn hidden_ground_truth_faces_count_in_chamfer_but_not_in_chamfer_seen() {
    // Ground truth: a unit sphere with a sphere of radius 0.5 left inside it, as a union of
    // closed parts without a boolean leaves faces inside. The prediction is the outer sphere.
    let outer = icosphere(Vec3::ZERO, 1.0, 4);
    let inner = icosphere(Vec3::new(0.1, 0.0, 0.0), 0.5, 3);
    let gt = union(&outer, &inner);
    // Eyes 3 away on the six axes: each sees the cap within acos(1/3) of its axis, and
    // together they see every point of the outer sphere.
    let eyes: Vec<Vec3> = [Vec3::X, Vec3::Y, Vec3::Z]
        .into_iter()
        .flat_map(|a| [3.0 * a, -3.0 * a])
        .collect();
    let all = chamfer(&outer, &gt, 20_000, 0.01, 9).unwrap();
    let seen = chamfer_seen(&outer, &gt, &eyes, 1, 20_000, 0.01, 9).unwrap();
    // The inner sphere holds 0.25 / 1.25 of the area and sits 0.4-0.6 from the outer one.
    assert!(all.completeness > 0.07 && all.recall < 0.85, "{all:?}");
    assert_eq!(all.gt_seen, 1.0);
    let outer_share = surface_area(&outer) / surface_area(&gt);
    assert!(
        (seen.gt_seen - outer_share).abs() < 0.01,
        "{seen:?} {outer_share}"
    );
    assert!(seen.completeness < 1e-3 && seen.recall > 0.99, "{seen:?}");
    assert_eq!(seen.accuracy, all.accuracy);
    // Every sample of a lone convex mesh is seen from eyes spread around it.
    let m = chamfer_seen(&outer, &outer, &eyes, 1, 5_000, 0.01, 2).unwrap();
    assert_eq!(m.gt_seen, 1.0);
    // One eye three radii away sees a third of a sphere's area.
    let m = chamfer_seen(&outer, &outer, &eyes[..1], 1, 5_000, 0.01, 2).unwrap();
    assert!((m.gt_seen - 1.0 / 3.0).abs() < 0.02, "{m:?}");
    assert!(chamfer_seen(&outer, &gt, &[], 1, 100, 0.01, 0).is_err());
    assert!(chamfer_seen(&outer, &gt, &[Vec3::NAN], 1, 100, 0.01, 0).is_err());
    // An eye inside sees the inner sphere (from within) but none of the outer one.
    let inside = [Vec3::new(0.1, 0.0, 0.0)];
    let m = chamfer_seen(&outer, &gt, &inside, 1, 5_000, 0.01, 2).unwrap();
    assert!((m.gt_seen - (1.0 - outer_share)).abs() < 0.02, "{m:?}");
}

#[test]
fn chamfer_seen_can_ask_for_several_eyes_per_sample() {
    let sphere = icosphere(Vec3::ZERO, 1.0, 4);
    // Eyes 3 away on the six axes: the eye on +a (or -a) sees the unit direction u when
    // u . a > 1/3 (or < -1/3), so u is seen by as many eyes as it has components past 1/3.
    let eyes: Vec<Vec3> = [Vec3::X, Vec3::Y, Vec3::Z]
        .into_iter()
        .flat_map(|a| [3.0 * a, -3.0 * a])
        .collect();
    // The expected shares, by quadrature over a Fibonacci sphere.
    let n = 200_000;
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    let mut counts = [0usize; 4];
    for i in 0..n {
        let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
        let r = (1.0 - z * z).sqrt();
        let u = Vec3::new(
            r * (golden * i as f32).cos(),
            r * (golden * i as f32).sin(),
            z,
        );
        let k = u.to_array().iter().filter(|c| c.abs() > 1.0 / 3.0).count();
        counts[k] += 1;
    }
    assert_eq!(counts[0], 0);
    let share_at_least = |m: usize| counts[m..].iter().sum::<usize>() as f64 / n as f64;
    for min_eyes in 1..=3 {
        let m = chamfer_seen(&sphere, &sphere, &eyes, min_eyes, 20_000, 0.01, 4).unwrap();
        let want = share_at_least(min_eyes);
        assert!((m.gt_seen - want).abs() < 0.02, "{min_eyes}: {m:?} {want}");
    }
    assert!(share_at_least(2) < 0.9 && share_at_least(3) > 0.05);
    // No point sees four of them; zero eyes or more eyes than there are is an error.
    assert!(chamfer_seen(&sphere, &sphere, &eyes, 4, 1_000, 0.01, 4).is_err());
    assert!(chamfer_seen(&sphere, &sphere, &eyes, 0, 1_000, 0.01, 4).is_err());
    assert!(chamfer_seen(&sphere, &sphere, &eyes, 7, 1_000, 0.01, 4).is_err());
}

#[test]
fn chamfer_is_asymmetric_for_a_partial_prediction() {
    // Prediction = the upper half of the ground-truth sphere: accuracy ~0, completeness > 0.
    let gt = icosphere(Vec3::ZERO, 1.0, 4);
    let pred = TriMesh {
        positions: gt.positions.clone(),
        triangles: gt
            .triangles
            .iter()
            .copied()
            .filter(|t| t.iter().all(|&i| gt.positions[i as usize].z > 0.0))
            .collect(),
    };
    let m = chamfer(&pred, &gt, 20_000, 0.01, 5).unwrap();
    assert!(m.accuracy < 1e-6, "{m:?}");
    assert!(m.completeness > 0.2, "{m:?}");
    assert!(
        m.precision == 1.0 && m.recall < 0.6 && m.recall > 0.4,
        "{m:?}"
    );
}

#[test]
fn largest_component_drops_a_small_blob_and_welds_soup() {
    let big = icosphere(Vec3::ZERO, 1.0, 3);
    let small = icosphere(Vec3::new(3.0, 0.0, 0.0), 0.2, 1);
    // Triangle soup: every triangle has its own three vertices.
    let mut soup = TriMesh::default();
    for m in [&small, &big] {
        for t in &m.triangles {
            let base = soup.positions.len() as u32;
            soup.positions.extend(t.map(|i| m.positions[i as usize]));
            soup.triangles.push([base, base + 1, base + 2]);
        }
    }
    assert_eq!(
        component_sizes(&soup),
        vec![big.triangles.len(), small.triangles.len()]
    );
    let kept = largest_component(&soup);
    assert_eq!(kept.triangles.len(), big.triangles.len());
    assert_eq!(kept.positions.len(), big.positions.len());
    assert!(kept.positions.iter().all(|p| p.x < 2.0));
    assert!(is_closed(&kept));
    assert!((kept.volume() - big.volume()).abs() < 1e-5);
    assert!(largest_component(&TriMesh::default()).triangles.is_empty());
}

#[test]
fn weld_merges_within_tolerance_and_drops_degenerate_triangles() {
    let m = TriMesh {
        positions: vec![
            Vec3::ZERO,
            Vec3::X,
            Vec3::Y,
            Vec3::new(1.0, 1e-7, 0.0),
            Vec3::new(0.0, 1.0, 1e-7),
            Vec3::ONE,
        ],
        triangles: vec![[0, 1, 2], [3, 5, 4], [1, 3, 2]],
    };
    let w = weld(&m, 1e-4);
    assert_eq!(w.positions.len(), 4);
    assert_eq!(w.triangles, vec![[0, 1, 2], [1, 3, 2]]);
    // Exact welding keeps the nearly coincident vertices apart.
    assert_eq!(weld(&m, 0.0).positions.len(), 6);
}

#[test]
fn empty_and_invalid_meshes_are_errors() {
    let good = icosphere(Vec3::ZERO, 1.0, 1);
    let empty = TriMesh::default();
    assert!(matches!(
        chamfer(&empty, &good, 100, 0.1, 0),
        Err(EvalError::Input(MeshError::EmptyMesh { .. }))
    ));
    assert!(matches!(
        chamfer(&good, &empty, 100, 0.1, 0),
        Err(EvalError::Input(MeshError::EmptyMesh { .. }))
    ));
    let flat = TriMesh {
        positions: vec![Vec3::ZERO, Vec3::X, Vec3::X * 2.0],
        triangles: vec![[0, 1, 2]],
    };
    assert!(matches!(
        chamfer(&flat, &good, 100, 0.1, 0),
        Err(EvalError::Input(MeshError::EmptyMesh { .. }))
    ));
    let out_of_range = TriMesh {
        positions: vec![Vec3::ZERO],
        triangles: vec![[0, 1, 2]],
    };
    assert!(matches!(
        chamfer(&out_of_range, &good, 100, 0.1, 0),
        Err(EvalError::Input(MeshError::InvalidMesh { .. }))
    ));
    let mut nan = good.clone();
    nan.positions[0].x = f32::NAN;
    assert!(matches!(
        chamfer(&nan, &good, 100, 0.1, 0),
        Err(EvalError::Input(MeshError::InvalidMesh { .. }))
    ));
    assert!(matches!(
        chamfer(&good, &good, 0, 0.1, 0),
        Err(EvalError::Input(MeshError::InvalidArgument(_)))
    ));
    assert!(matches!(
        chamfer(&good, &good, 10, f32::NAN, 0),
        Err(EvalError::Input(MeshError::InvalidArgument(_)))
    ));
    let e = chamfer(&empty, &good, 100, 0.1, 0).unwrap_err().to_string();
    assert!(e.contains("predicted"), "{e}");
}

#[test]
fn the_hull_blind_split_measures_what_the_masks_miss() {
    let gt = icosphere(Vec3::ZERO, 1.0, 4);
    let cameras: Vec<gtsr_data::Camera> = [Vec3::X, Vec3::Y, Vec3::Z, -Vec3::X, -Vec3::Y, -Vec3::Z]
        .iter()
        .map(|d| {
            let up = if d.y.abs() > 0.5 { Vec3::X } else { Vec3::Y };
            gtsr_data::Camera::look_at(*d * 4.0, Vec3::ZERO, up, 0.8, 32, 32)
        })
        .collect();
    // A hull 0.05 outside everywhere: all of the ground truth is hull-blind at 0.01.
    let loose = icosphere(Vec3::ZERO, 1.05, 4);
    let (m, whole) =
        gtsr_eval::score_against_ground_truth(&gt, &gt, &cameras, Some(&loose)).unwrap();
    let b = m.hull_blind.expect("a split");
    assert!(b.fraction > 0.99, "{b:?}");
    assert!(b.blind < 2e-3, "the prediction is the ground truth: {b:?}");
    assert!((b.hull_on_blind - 0.05).abs() < 5e-3, "{b:?}");
    assert!(whole.hull_blind.is_some());
    // The loose hull as the prediction scores its own distance there.
    let (m, _) =
        gtsr_eval::score_against_ground_truth(&loose, &gt, &cameras, Some(&loose)).unwrap();
    let b = m.hull_blind.unwrap();
    assert!((b.blind - b.hull_on_blind).abs() < 1e-6, "{b:?}");
    // A hull on the ground truth leaves nothing blind.
    let (m, _) = gtsr_eval::score_against_ground_truth(&loose, &gt, &cameras, Some(&gt)).unwrap();
    let b = m.hull_blind.unwrap();
    assert_eq!(b.fraction, 0.0);
    assert_eq!(b.blind, 0.0);
    assert!((b.rest - m.completeness).abs() < 1e-9, "{b:?} {m:?}");
    // Without a hull there is no split.
    let (m, _) = gtsr_eval::score_against_ground_truth(&gt, &gt, &cameras, None).unwrap();
    assert!(m.hull_blind.is_none());
}

#[test]
fn signed_distance_is_positive_outside_an_outward_mesh() {
    let sphere = icosphere(Vec3::ZERO, 1.0, 4);
    let sd = gtsr_mesh::raycast::SignedDistance::new(&sphere, "sphere").unwrap();
    let (out, n) = sd.query(Vec3::new(0.0, 0.0, 1.5));
    assert!((out - 0.5).abs() < 5e-3, "{out}");
    assert!(n.z > 0.99, "{n}");
    let (inside, _) = sd.query(Vec3::new(0.0, 0.7, 0.0));
    assert!((inside + 0.3).abs() < 5e-3, "{inside}");
    assert!(gtsr_mesh::raycast::SignedDistance::new(&TriMesh::default(), "empty").is_err());
}
