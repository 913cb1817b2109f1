use super::*;

/// A flat grid `z = 0` over `[-1, 1]^2` with `n` cells a side, normals up.
fn grid(n: usize) -> TriMesh {
    crate::mesh::height_grid(n, glam::Vec2::splat(-1.0), glam::Vec2::ONE, |_, _| 0.0)
}

/// The normals of the bowl `z = -0.1 (1 - r^2)` inside `r < 1`, flat outside, per face
/// of `mesh` (at its centroid), and settings that let it move freely.
fn bowl_targets(mesh: &TriMesh) -> (FaceNormals, RefineSettings) {
    let normal: Vec<Vec3> = mesh
        .triangles
        .iter()
        .map(|t| {
            let c = t.map(|i| mesh.positions[i as usize]).iter().sum::<Vec3>() / 3.0;
            if c.x * c.x + c.y * c.y < 1.0 {
                // grad z = 0.2 (x, y); normal (-z_x, -z_y, 1).
                Vec3::new(-0.2 * c.x, -0.2 * c.y, 1.0).normalize()
            } else {
                Vec3::Z
            }
        })
        .collect();
    let settings = RefineSettings {
        anchor: 10.0,
        max_depth: 1.0,
        ..RefineSettings::default()
    };
    (
        FaceNormals {
            weight: vec![1.0; normal.len()],
            normal,
        },
        settings,
    )
}

#[test]
fn normals_of_a_dent_carve_the_dent() {
    let mesh = grid(40);
    let (targets, settings) = bowl_targets(&mesh);
    let (_, d) = refine_with_normals(&mesh, &targets, &settings).unwrap();
    let centre = d[20 * 41 + 20];
    eprintln!(
        "{:?}",
        (0..41)
            .step_by(4)
            .map(|i| d[20 * 41 + i])
            .collect::<Vec<_>>()
    );
    assert!(d.iter().all(|v| *v <= 0.0));
    assert!((centre + 0.1).abs() < 0.02, "centre moved {centre}");
    // Flat target: nothing moves.
    let flat = FaceNormals {
        weight: vec![1.0; mesh.triangles.len()],
        normal: vec![Vec3::Z; mesh.triangles.len()],
    };
    let (_, d) = refine_with_normals(&mesh, &flat, &settings).unwrap();
    assert!(d.iter().all(|v| v.abs() < 1e-6));
}

#[test]
fn a_steep_bowl_is_carved_by_the_slopes_of_its_normals() {
    // The bowl `z = -0.5 (1 - r^2)`, whose wall tilts up to 45 degrees at the rim: a
    // normal tilted by `a` asks for the slope `tan a` (`r` here), more than its sine.
    let mesh = grid(60);
    let normal: Vec<Vec3> = (mesh.triangles.iter())
        .map(|t| {
            let c = t.map(|i| mesh.positions[i as usize]).iter().sum::<Vec3>() / 3.0;
            if c.x * c.x + c.y * c.y < 1.0 {
                Vec3::new(-c.x, -c.y, 1.0).normalize()
            } else {
                Vec3::Z
            }
        })
        .collect();
    let targets = FaceNormals {
        weight: vec![1.0; normal.len()],
        normal,
    };
    let centre = |settings: &RefineSettings| {
        let (_, d) = refine_with_normals(&mesh, &targets, settings).unwrap();
        d[30 * 61 + 30]
    };
    // Trusted up to 60 degrees: the whole depth (the sines would give sqrt(2) - 1).
    let steep = RefineSettings {
        anchor: 10.0,
        max_depth: 1.0,
        max_tilt: 0.866,
        ..RefineSettings::default()
    };
    let d = centre(&steep);
    assert!((d + 0.5).abs() < 0.02, "centre moved {d}");
    // At the default 30 degrees the slope stops at tan 30 from r = 0.577 on: the depth
    // is 0.577^2 / 2 + 0.577 (1 - 0.577) = 0.411 (the capped sines would give 0.366).
    let capped = RefineSettings {
        max_tilt: MAX_TILT_SINE,
        ..steep
    };
    let d = centre(&capped);
    assert!((d + 0.411).abs() < 0.02, "centre moved {d}");
    // Per-face limits override the setting: 60 degrees on the bowl's faces carve it
    // whole under the 30-degree setting, and 30 degrees on them cap it under a
    // 60-degree setting.
    let per_face = |limit: f32, settings: &RefineSettings| {
        let limits = vec![limit; mesh.triangles.len()];
        let (_, d) = refine_anchored(&mesh, &targets, None, settings, None, Some(&limits)).unwrap();
        d[30 * 61 + 30]
    };
    let d = per_face(0.866, &capped);
    assert!((d + 0.5).abs() < 0.02, "centre moved {d}");
    let d = per_face(MAX_TILT_SINE, &steep);
    assert!((d + 0.411).abs() < 0.02, "centre moved {d}");
    // A limit outside (0, 1) or one per vertex is refused.
    for bad in [
        vec![1.0; mesh.triangles.len()],
        vec![0.5; mesh.positions.len()],
    ] {
        assert!(refine_anchored(&mesh, &targets, None, &steep, None, Some(&bad)).is_err());
    }
}

#[test]
fn an_irregular_fine_mesh_converges_within_the_iterations() {
    // The bowl of the test above on a finer grid whose vertices are jittered in the
    // plane (triangles of very different sizes, as marching cubes makes them), at the
    // default iteration count.
    let n = 150;
    let mut mesh = grid(n);
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f32 / (1u64 << 53) as f32 - 0.5
    };
    let cell = 2.0 / n as f32;
    for p in mesh.positions.iter_mut() {
        if p.x.abs() < 1.0 && p.y.abs() < 1.0 {
            p.x += 0.9 * cell * next();
            p.y += 0.9 * cell * next();
        }
    }
    let (targets, settings) = bowl_targets(&mesh);
    let (_, d) = refine_with_normals(&mesh, &targets, &settings).unwrap();
    let centre = d[(n / 2) * (n + 1) + n / 2];
    assert!((centre + 0.1).abs() < 0.01, "centre moved {centre}");
}

/// The assembled system's product is the sum of its faces' blocks applied one face at a
/// time, with the diagonal, on the free rows and zero on the others, and the dot product
/// it returns is `x` against that; its diagonal is that of the blocks; the rows span
/// several of the parallel tasks' chunks.
#[test]
fn the_assembled_system_applies_as_its_faces_do() {
    let mesh = grid(100);
    let nv = mesh.positions.len();
    assert!(nv > 2 * ROWS_PER_TASK);
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    let diag: Vec<f64> = (0..nv).map(|_| 1.0 + next()).collect();
    let blocks: Vec<[[f64; 3]; 3]> = (0..mesh.triangles.len())
        .map(|_| {
            let (a, b, c, d, e, f) = (next(), next(), next(), next(), next(), next());
            [[a, b, c], [b, d, e], [c, e, f]]
        })
        .collect();
    let system = VertexSystem::assemble(&mesh.triangles, diag.clone(), |f| blocks[f]);
    let x: Vec<f64> = (0..nv).map(|_| next()).collect();
    let free: Vec<bool> = (0..nv).map(|i| i % 7 != 3).collect();
    let mut want: Vec<f64> = diag.iter().zip(&x).map(|(d, x)| d * x).collect();
    let mut want_diag = diag.clone();
    for (t, b) in mesh.triangles.iter().zip(&blocks) {
        for a in 0..3 {
            for c in 0..3 {
                want[t[a] as usize] += b[a][c] * x[t[c] as usize];
            }
            want_diag[t[a] as usize] += b[a][a];
        }
    }
    let mut got = vec![f64::NAN; nv];
    let x_dot = system.apply(&x, &mut got, &free);
    let want_dot: f64 = (0..nv).filter(|i| free[*i]).map(|i| x[i] * want[i]).sum();
    assert!((x_dot - want_dot).abs() <= 1e-9 * want_dot.abs().max(1.0));
    for i in 0..nv {
        let w = if free[i] { want[i] } else { 0.0 };
        assert!(
            (got[i] - w).abs() <= 1e-12 * (1.0 + w.abs()),
            "row {i}: {} against {w}",
            got[i]
        );
    }
    for (g, w) in system.diagonal().iter().zip(&want_diag) {
        assert!((g - w).abs() <= 1e-12 * (1.0 + w.abs()));
    }
    let serial: f64 = x.iter().zip(&diag).map(|(a, b)| a * b).sum();
    assert!((dot(&x, &diag) - serial).abs() <= 1e-9 * serial.abs().max(1.0));
}

#[test]
fn a_depth_term_pulls_the_faces_to_their_offsets() {
    // Flat normals (the mesh's own) and a dent of -0.05 wished inside r < 0.5.
    let mesh = grid(40);
    let nf = mesh.triangles.len();
    let centre = |f: usize| -> Vec3 {
        mesh.triangles[f]
            .map(|i| mesh.positions[i as usize])
            .iter()
            .sum::<Vec3>()
            / 3.0
    };
    let offset: Vec<f32> = (0..nf)
        .map(|f| {
            let c = centre(f);
            if c.x * c.x + c.y * c.y < 0.25 {
                -0.05
            } else {
                0.0
            }
        })
        .collect();
    let flat = FaceNormals {
        weight: vec![1.0; nf],
        normal: vec![Vec3::Z; nf],
    };
    let settings = RefineSettings {
        anchor: 10.0,
        max_depth: 1.0,
        ..RefineSettings::default()
    };
    let targets = DepthTargets {
        offset: offset.clone(),
        weight: vec![1.0; nf],
        length: 0.01,
    };
    let (_, d) = refine(&mesh, &flat, Some(&targets), &settings).unwrap();
    assert!(d.iter().all(|v| *v <= 0.0));
    let (mid, edge) = (d[20 * 41 + 20], d[20 * 41 + 2]);
    assert!((mid + 0.05).abs() < 0.005, "centre moved {mid}");
    assert!(edge.abs() < 0.005, "edge moved {edge}");
    // With no weight on the offsets nothing moves.
    let none = DepthTargets {
        weight: vec![0.0; nf],
        ..targets
    };
    let (_, d) = refine(&mesh, &flat, Some(&none), &settings).unwrap();
    assert!(d.iter().all(|v| v.abs() < 1e-6));
    // Offsets and weights must match the faces.
    let short = DepthTargets {
        offset: vec![0.0; 3],
        weight: vec![1.0; 3],
        length: 0.01,
    };
    assert!(refine(&mesh, &flat, Some(&short), &settings).is_err());
}

/// The offsets' common bias is removed, the threshold asks the faces within it to stay,
/// and the faces too few views observe carry no weight.
#[test]
fn debiased_depth_targets_remove_the_bias_and_keep_the_inward_wishes() {
    let offsets = FaceOffsets {
        offset: vec![0.01, 0.011, 0.009, 0.01, -0.03, 0.5],
        views: vec![5, 5, 5, 5, 5, 1],
    };
    let (t, bias) = debiased_depth_targets(&offsets, 3, 0.002, 0.05);
    assert!((bias - 0.01).abs() < 1e-6, "{bias}");
    assert_eq!(t.length, 0.05);
    assert_eq!(t.weight, vec![1.0, 1.0, 1.0, 1.0, 1.0, 0.0]);
    assert_eq!(&t.offset[..4], &[0.0; 4]);
    assert!((t.offset[4] + 0.038).abs() < 1e-6, "{}", t.offset[4]);
}
