use glam::Vec3;
use gtsr_eval::chamfer;
use gtsr_mesh::marching::{Grid, case_triangle_count, marching_cubes, table_fallbacks};
use gtsr_mesh::mesh::{SplitMix64, component_sizes, icosphere, is_closed};

fn sphere_grid(r: f32, voxel: f32) -> Grid {
    let n = (2.6 * r / voxel).ceil() as usize + 1;
    let origin = Vec3::splat(-1.3 * r);
    Grid::from_fn(origin, voxel, [n, n, n], |p| p.length() - r)
}

#[test]
fn sphere_sdf_gives_a_closed_outward_sphere() {
    let r = 0.8;
    let g = sphere_grid(r, 0.02);
    let m = marching_cubes(&g, 0.0);
    assert!(is_closed(&m), "not closed");
    assert_eq!(component_sizes(&m).len(), 1);
    let v = m.volume() as f64;
    let exact = 4.0 / 3.0 * std::f64::consts::PI * (r as f64).powi(3);
    assert!(v > 0.0, "inward orientation: volume {v}");
    assert!((v - exact).abs() / exact < 0.005, "volume {v} vs {exact}");
    // Vertices lie on the sphere up to the linear-interpolation error.
    for p in &m.positions {
        assert!(
            (p.length() - r).abs() < 0.02 * 0.05,
            "vertex at radius {}",
            p.length()
        );
    }
    // Each face normal points away from the centre.
    for t in &m.triangles {
        let [a, b, c] = t.map(|i| m.positions[i as usize]);
        let n = (b - a).cross(c - a);
        assert!(n.dot(a + b + c) >= 0.0);
    }
    let reference = icosphere(Vec3::ZERO, r, 6);
    let cd = chamfer(&m, &reference, 20_000, 0.01, 0).unwrap();
    assert!(cd.chamfer < 2e-4, "{cd:?}");
}

#[test]
fn negated_field_flips_orientation_and_iso_level_moves_the_surface() {
    let r = 0.5;
    let mut g = sphere_grid(r, 0.025);
    let outward = marching_cubes(&g, 0.0);
    let bigger = marching_cubes(&g, 0.1);
    assert!(bigger.volume() > outward.volume() * 1.5);
    for v in &mut g.values {
        *v = -*v;
    }
    let inward = marching_cubes(&g, 0.0);
    assert!((inward.volume() + outward.volume()).abs() < 1e-4 * outward.volume());
}

#[test]
fn random_fields_give_watertight_consistently_oriented_meshes() {
    // Every corner pattern and every ambiguous face configuration occur; with the grid
    // border positive the surface must be closed (each edge used once in each direction).
    let mut rng = SplitMix64::new(42);
    for trial in 0..20 {
        let n = 12;
        let mut g = Grid::new(Vec3::ZERO, 1.0, [n, n, n]);
        for k in 0..n {
            for j in 0..n {
                for i in 0..n {
                    let id = g.index(i, j, k);
                    let border =
                        i == 0 || j == 0 || k == 0 || i == n - 1 || j == n - 1 || k == n - 1;
                    g.values[id] = if border {
                        1.0
                    } else {
                        rng.next_f64() as f32 - 0.5
                    };
                    g.observed[id] = true;
                }
            }
        }
        let m = marching_cubes(&g, 0.0);
        assert!(!m.triangles.is_empty());
        assert!(is_closed(&m), "trial {trial}: not watertight");
        assert!(m.volume() > 0.0, "trial {trial}: volume {}", m.volume());
    }
}

#[test]
fn table_matches_the_classic_triangle_counts_for_simple_cases() {
    assert_eq!(
        table_fallbacks(),
        0,
        "a table loop needed a face-chord diagonal"
    );
    assert_eq!(case_triangle_count(0), 0);
    assert_eq!(case_triangle_count(255), 0);
    for c in 0..8 {
        assert_eq!(case_triangle_count(1 << c), 1, "single corner {c}");
        assert_eq!(case_triangle_count(!(1u8 << c)), 1, "all but corner {c}");
    }
    // One face inside: a quad.
    assert_eq!(case_triangle_count(0b0000_1111), 2);
    // Two opposite corners of the cube: two separate triangles.
    assert_eq!(case_triangle_count(0b0100_0001), 2);
    // An edge (corners 0 and 1): a quad.
    assert_eq!(case_triangle_count(0b0000_0011), 2);
    // Three corners of one face: a pentagon.
    assert_eq!(case_triangle_count(0b0000_0111), 3);
}

#[test]
fn unobserved_corners_produce_no_triangles() {
    let r = 0.5;
    let mut g = sphere_grid(r, 0.025);
    let full = marching_cubes(&g, 0.0);
    // Unobserve the upper half: only the lower half-sphere remains, as an open cap.
    let [nx, ny, nz] = g.dims;
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                if g.point(i, j, k).z > 0.0 {
                    let id = g.index(i, j, k);
                    g.observed[id] = false;
                }
            }
        }
    }
    let half = marching_cubes(&g, 0.0);
    assert!(!is_closed(&half));
    assert!(half.positions.iter().all(|p| p.z <= 0.0));
    let ratio = half.triangles.len() as f64 / full.triangles.len() as f64;
    assert!((ratio - 0.5).abs() < 0.05, "ratio {ratio}");
    // Degenerate grids give an empty mesh rather than a panic.
    assert!(
        marching_cubes(&Grid::new(Vec3::ZERO, 1.0, [1, 5, 5]), 0.0)
            .triangles
            .is_empty()
    );
}
