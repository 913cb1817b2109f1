//! Synthetic scene tests: round trip through the loader, silhouettes against the analytic
//! shapes, determinism, and radiometric sanity of the path tracer.

use glam::Vec3;
use gtsr_data::Camera;
use gtsr_data::synthetic::{SceneConfig, ShapeKind, generate_scene, scene_cameras};
use gtsr_data::transport::material::Boundary;
use gtsr_data::transport::{Lighting, Material, MaterialPreset, Tracer};
use gtsr_data::{Background, LoadOptions, load_blender};

fn small_config(shape: ShapeKind, spp: u32) -> SceneConfig {
    SceneConfig {
        n_train: 2,
        n_test: 1,
        spp,
        resolution: 128,
        seed: 7,
        ..SceneConfig::new(shape, MaterialPreset::Glassy)
    }
}

/// Generated scenes load back with the same cameras, and their masks match the analytic
/// silhouettes (IoU >= 0.99 at 128x128) for every shape.
#[test]
fn round_trip_and_silhouettes() {
    for shape in ShapeKind::ALL {
        let tmp = tempfile::tempdir().unwrap();
        let cfg = small_config(shape, 32);
        let mut calls = 0;
        let g = generate_scene(tmp.path(), &cfg, |_| calls += 1).unwrap();
        assert_eq!(calls, 3);
        for f in [
            "mesh.ply",
            "meta.json",
            "transforms_train.json",
            "transforms_test.json",
            "train/r_1.png",
            "test/r_0.png",
        ] {
            assert!(tmp.path().join(f).is_file(), "{f}");
        }
        // No temporary files left behind.
        for e in walk(tmp.path()) {
            assert!(
                !e.file_name().unwrap().to_string_lossy().contains(".tmp"),
                "{}",
                e.display()
            );
        }
        let meta: serde_json::Value =
            serde_json::from_slice(&std::fs::read(tmp.path().join("meta.json")).unwrap()).unwrap();
        assert_eq!(meta["shape"], shape.name());
        assert_eq!(meta["seed"], 7);
        assert_eq!(meta["spp"], 32);
        assert_eq!(meta["material"]["ior"], 1.5);
        let mesh = gtsr_data::ply::read_ply(&tmp.path().join("mesh.ply")).unwrap();
        assert_eq!(mesh.triangles.len(), g.triangles);
        assert_eq!(mesh, shape.mesh());
        let r = mesh
            .positions
            .iter()
            .map(|p| p.length())
            .fold(0.0f32, f32::max);
        assert!((r - 1.0).abs() < 0.01, "{shape}: bounding radius {r}");

        let scene = load_blender(
            tmp.path(),
            &LoadOptions {
                background: Background::Keep,
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!((scene.train.len(), scene.test.len()), (2, 1));
        let (train, test) = scene_cameras(&cfg);
        for (v, c) in scene
            .train
            .iter()
            .zip(&train)
            .chain(scene.test.iter().zip(&test))
        {
            assert!((v.camera.centre() - c.centre()).length() < 1e-4);
            assert!((v.camera.fx - c.fx).abs() < 1e-2 && v.camera.width == 128);
            let p = Vec3::new(0.3, -0.2, 0.5);
            assert!((v.camera.project(p).unwrap().0 - c.project(p).unwrap().0).length() < 1e-2);
            let mask = v.mask.as_ref().unwrap();
            let (mut inter, mut uni) = (0usize, 0usize);
            for j in 0..128 {
                for i in 0..128 {
                    let (o, d) = v.camera.pixel_ray(i, j);
                    let truth = shape.ray_hits(o, d);
                    let got = mask[(j * 128 + i) as usize] > 0.5;
                    inter += (truth && got) as usize;
                    uni += (truth || got) as usize;
                }
            }
            let iou = inter as f64 / uni as f64;
            eprintln!("{shape} {}: mask IoU {iou:.4}", v.name);
            assert!(iou >= 0.99, "{shape} {}: mask IoU {iou:.4}", v.name);
            assert!(uni > 1000, "{shape}: object too small ({uni} px)");
        }
    }
}

fn walk(dir: &std::path::Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(walk(&p));
        } else {
            out.push(p);
        }
    }
    out
}

/// The mesh and the analytic shape agree on point membership.
#[test]
fn meshes_are_closed_and_match_analytic_volume() {
    for shape in ShapeKind::ALL {
        let mesh = shape.mesh();
        // Closed, consistently oriented: every directed edge has its reverse exactly once.
        let mut edges = std::collections::HashMap::new();
        for t in &mesh.triangles {
            for k in 0..3 {
                *edges.entry((t[k], t[(k + 1) % 3])).or_insert(0) += 1;
            }
        }
        for (&(a, b), &n) in &edges {
            assert_eq!(n, 1, "{shape}: edge {a}-{b} used {n} times");
            assert_eq!(
                edges.get(&(b, a)),
                Some(&1),
                "{shape}: edge {a}-{b} has no twin"
            );
        }
        // Volume against a Monte Carlo estimate of the analytic shape.
        let mut rng = gtsr_data::transport::rng::Rng::new(3, 0, 0, 0);
        let n = 200_000;
        let inside = (0..n)
            .filter(|_| {
                let p = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - 1.0;
                shape.contains(p)
            })
            .count();
        let mc = 8.0 * inside as f32 / n as f32;
        let v = mesh.volume();
        assert!(
            (v - mc).abs() < 0.02 * mc + 0.01,
            "{shape}: mesh volume {v} vs analytic {mc}"
        );
    }
}

/// The dented sphere's dent is a concavity no silhouette sees: points in it lie outside the
/// shape, yet every ray through them from outside hits the shape, so the masks' hull fills
/// them. Its radial description agrees with the membership test.
#[test]
fn the_dent_is_outside_the_shape_but_inside_every_silhouette() {
    use gtsr_data::synthetic::shapes::{dent_axis, dented_sphere_radius};
    let shape = ShapeKind::DentedSphere;
    let axis = dent_axis();
    // The dent's floor lies 0.25 below the sphere; its rim plane about 0.094 below.
    assert!((dented_sphere_radius(axis) - 0.75).abs() < 1e-5);
    let mut rng = gtsr_data::transport::rng::Rng::new(5, 0, 0, 0);
    let mut unit = || loop {
        let v = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - 1.0;
        if v.length_squared() > 1e-4 && v.length_squared() <= 1.0 {
            return v.normalize();
        }
    };
    for depth in [0.8f32, 0.85, 0.88] {
        let p = axis * depth;
        assert!(!shape.contains(p), "{depth}: the dent should be empty");
        for _ in 0..2000 {
            let d = unit();
            assert!(
                shape.ray_hits(p - 4.0 * d, d),
                "{depth}: a ray along {d} through the dent misses the shape"
            );
        }
    }
    for _ in 0..2000 {
        let u = unit();
        let r = dented_sphere_radius(u);
        assert!(shape.contains(u * (r - 1e-3)), "{u}: inside the radius");
        assert!(!shape.contains(u * (r + 1e-3)), "{u}: outside the radius");
    }
}

/// The slotted cube's slot is empty, and no silhouette sees it: every ray through it from
/// outside the bounding sphere hits the shape. Its mesh puts the floor and the walls where
/// the analytic slot has them.
#[test]
fn the_slot_is_outside_the_shape_but_inside_every_silhouette() {
    use gtsr_data::synthetic::shapes::{
        CUBE_HALF, SLOT_DEPTH, SLOT_WIDTH, cube_rotation, slot_box,
    };
    let shape = ShapeKind::SlottedCube;
    let turn = cube_rotation();
    let (lo, hi) = slot_box();
    assert!(((hi.y - lo.y) - SLOT_WIDTH).abs() < 1e-6 && (hi.z - lo.z - SLOT_DEPTH).abs() < 1e-6);
    let mut rng = gtsr_data::transport::rng::Rng::new(9, 0, 0, 0);
    let mut uniform = || Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
    for _ in 0..400 {
        let p = turn * (lo + (hi - lo) * (uniform() * 0.98 + 0.01));
        assert!(!shape.contains(p), "{p}: the slot should be empty");
        assert!(
            ShapeKind::Cube.contains(p),
            "{p}: the slot lies inside the cube"
        );
        for _ in 0..20 {
            let d = (uniform() * 2.0 - 1.0).normalize();
            assert!(
                shape.ray_hits(p - 4.0 * d, d),
                "a ray along {d} through {p} misses"
            );
        }
    }
    // Just under the face beside the slot and just under its floor: solid.
    let mid = (lo + hi) * 0.5;
    for q in [
        Vec3::new(mid.x, lo.y - 0.01, CUBE_HALF - 0.01),
        Vec3::new(mid.x, mid.y, lo.z - 0.01),
    ] {
        assert!(shape.contains(turn * q), "{q}");
    }
    // The mesh: every vertex lies on the cube's surface or on the slot's floor or walls.
    let mesh = shape.mesh();
    let on_floor = mesh
        .positions
        .iter()
        .map(|&p| turn.inverse() * p)
        .filter(|q| (q.z - lo.z).abs() < 1e-5)
        .count();
    assert_eq!(on_floor, 41 * 6, "the floor's grid points");
    for &p in &mesh.positions {
        let q = turn.inverse() * p;
        let on_cube = (q.abs().max_element() - CUBE_HALF).abs() < 1e-5;
        let in_outline =
            q.x >= lo.x - 1e-5 && q.x <= hi.x + 1e-5 && q.y >= lo.y - 1e-5 && q.y <= hi.y + 1e-5;
        assert!(on_cube || (in_outline && (q.z - lo.z).abs() < 1e-5), "{q}");
    }
}

/// The capped wells' gaps and the hollows under their caps are empty, and no silhouette sees
/// them: every ray through them from outside the bounding sphere hits the shape. The mesh
/// puts the block, the well and the cap where the analytic shape has them.
#[test]
fn the_hollow_under_the_cap_is_outside_the_shape_but_inside_every_silhouette() {
    for shape in [
        ShapeKind::CappedWell,
        ShapeKind::NarrowCappedWell,
        ShapeKind::ShallowCappedWell,
    ] {
        capped_well_checks(shape);
    }
}

fn capped_well_checks(shape: ShapeKind) {
    use gtsr_data::synthetic::shapes::{WELL_BLOCK, WELL_RADIUS, well_rotation};
    let dip = shape.cap_dip().unwrap();
    let gap = shape.well_gap().unwrap();
    let turn = well_rotation();
    let top = WELL_BLOCK.2;
    let mut rng = gtsr_data::transport::rng::Rng::new(13, 0, 0, 0);
    let mut uniform = || Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
    let mut points = Vec::new();
    // In the gap: between the cap's sphere and the well's, below the block's top.
    for k in 0..200 {
        let a = std::f32::consts::TAU * k as f32 / 200.0;
        let r = WELL_RADIUS - gap * (0.1 + 0.8 * (k % 7) as f32 / 6.0);
        let polar = std::f32::consts::FRAC_PI_2 + 0.3 * (k % 5) as f32 / 4.0 + 0.05;
        points.push(Vec3::new(
            r * polar.sin() * a.cos(),
            r * polar.sin() * a.sin(),
            top + r * polar.cos(),
        ));
    }
    // In the hollow: under the cap's bottom, inside the well.
    for _ in 0..200 {
        let u = uniform();
        let a = std::f32::consts::TAU * u.x;
        let z = top - dip - 0.01 - u.y * (WELL_RADIUS - dip - 0.03);
        let rim = (WELL_RADIUS * WELL_RADIUS - (z - top) * (z - top)).sqrt();
        let r = rim * 0.95 * u.z.sqrt();
        points.push(Vec3::new(r * a.cos(), r * a.sin(), z));
    }
    for q in points {
        let p = turn * q;
        assert!(!shape.contains(p), "{q}: the well should be empty there");
        for _ in 0..20 {
            let d = (uniform() * 2.0 - 1.0).normalize();
            assert!(
                shape.ray_hits(p - 4.0 * d, d),
                "a ray along {d} through {q} misses"
            );
        }
    }
    // Solid: the cap just inside its sphere and above its bottom, the block just under the
    // well and beside its rim.
    let cap = WELL_RADIUS - gap;
    for q in [
        Vec3::new(0.0, 0.0, top + cap - 0.01),
        Vec3::new(0.0, 0.0, top - dip + 0.01),
        Vec3::new(0.0, 0.0, top - WELL_RADIUS - 0.01),
        Vec3::new(WELL_RADIUS + 0.01, 0.0, top - 0.01),
    ] {
        assert!(shape.contains(turn * q), "{q}");
    }
    // The mesh: every vertex lies on the block's faces, on the well's sphere or on the cap's
    // sphere or bottom, and both spheres carry vertices all the way round.
    let (radius, bottom, _) = WELL_BLOCK;
    let floor = top - dip;
    let near = |a: f32, b: f32| (a - b).abs() < 1e-4;
    let (mut on_cap, mut on_well) = (0, 0);
    for &p in &shape.mesh().positions {
        let q = turn.inverse() * p;
        let (r, from_centre) = (q.truncate().length(), (q - Vec3::Z * top).length());
        let block = (near(r, radius) && q.z >= bottom - 1e-4 && q.z <= top + 1e-4)
            || ((near(q.z, top) || near(q.z, bottom)) && r <= radius + 1e-4);
        let well = near(from_centre, WELL_RADIUS) && q.z <= top + 1e-4;
        let cap_side = near(from_centre, cap) && q.z >= floor - 1e-4;
        let cap_bottom = near(q.z, floor) && r <= cap + 1e-4;
        on_well += well as usize;
        on_cap += cap_side as usize;
        assert!(block || well || cap_side || cap_bottom, "{q}");
    }
    assert!(
        on_cap > 1000 && on_well > 1000,
        "{on_cap} cap and {on_well} well vertices"
    );
}

/// The hidden part of each shape with one is exactly what no silhouette sees: the slot's floor
/// and walls (their area to float precision), the dent's cap, the well and the cap's part in
/// it (to their meshes' facets); the shapes without one have none.
#[test]
fn the_hidden_part_is_the_slot_the_dent_and_the_well() {
    use gtsr_data::synthetic::shapes::{
        CUBE_HALF, DENT_CENTRE, DENT_RADIUS, SLOT_DEPTH, SLOT_WIDTH, WELL_RADIUS, slot_box,
    };
    let area = |m: &gtsr_data::ply::TriMesh| -> f64 {
        (m.triangles.iter())
            .map(|t| {
                let [a, b, c] = t.map(|i| m.positions[i as usize]);
                0.5 * f64::from((b - a).cross(c - a).length())
            })
            .sum()
    };
    for shape in ShapeKind::ALL {
        let part = shape.hidden_part();
        let expected = match shape {
            ShapeKind::SlottedCube => {
                let (lo, hi) = slot_box();
                let length = hi.x - lo.x;
                assert!(length > 0.5 && length < 2.0 * CUBE_HALF);
                f64::from(length * SLOT_WIDTH + 2.0 * (length + SLOT_WIDTH) * SLOT_DEPTH)
            }
            ShapeKind::DentedSphere => {
                // The cut ball's cap inside the unit sphere: height R - (C - a), where the
                // two spheres meet at a = (C^2 + 1 - R^2) / 2C along the axis.
                let (c, r) = (f64::from(DENT_CENTRE), f64::from(DENT_RADIUS));
                let a = (c * c + 1.0 - r * r) / (2.0 * c);
                std::f64::consts::TAU * r * (r - (c - a))
            }
            ShapeKind::CappedWell | ShapeKind::NarrowCappedWell | ShapeKind::ShallowCappedWell => {
                // The hemispherical well, the cap's spherical zone below the block's top and
                // its flat bottom.
                let (w, cap, dip) = (
                    f64::from(WELL_RADIUS),
                    f64::from(WELL_RADIUS - shape.well_gap().unwrap()),
                    f64::from(shape.cap_dip().unwrap()),
                );
                let tau = std::f64::consts::TAU;
                tau * w * w + tau * cap * dip + 0.5 * tau * (cap * cap - dip * dip)
            }
            _ => {
                assert!(part.is_none(), "{shape} has no hidden part");
                continue;
            }
        };
        let part = part.unwrap_or_else(|| panic!("{shape} has a hidden part"));
        let got = area(&part);
        let tolerance = if shape == ShapeKind::SlottedCube {
            1e-4
        } else {
            0.03
        };
        assert!(
            (got - expected).abs() <= tolerance * expected
                && (shape != ShapeKind::SlottedCube || got <= expected * (1.0 + 1e-4)),
            "{shape}: hidden area {got}, expected {expected}"
        );
        // Every face but those across the dent's rim lies outside the masks' reach: its
        // centroid, pushed a little along the face's normal, is outside the shape but inside
        // its convex cover (the cube, the unit sphere).
        let cover = match shape {
            ShapeKind::SlottedCube => ShapeKind::Cube,
            _ => ShapeKind::Sphere,
        };
        for t in &part.triangles {
            let [a, b, c] = t.map(|i| part.positions[i as usize]);
            if [a, b, c].iter().any(|p| p.length() > 1.0 - 1e-4) {
                continue; // across the dent's rim: its chord dips into the solid
            }
            let n = (b - a).cross(c - a).normalize();
            let p = (a + b + c) / 3.0 + n * 2e-3;
            assert!(
                !shape.contains(p) && cover.contains(p),
                "{shape}: face at {p}"
            );
        }
    }
}

/// The same seed gives the same bytes whatever the thread count; another seed differs.
#[test]
fn deterministic_for_a_seed() {
    let cfg = SceneConfig {
        resolution: 48,
        n_train: 2,
        n_test: 1,
        spp: 8,
        seed: 11,
        ..SceneConfig::new(ShapeKind::Torus, MaterialPreset::Wax)
    };
    let run = |threads: usize, seed: u64| {
        let tmp = tempfile::tempdir().unwrap();
        let cfg = SceneConfig {
            seed,
            ..cfg.clone()
        };
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| generate_scene(tmp.path(), &cfg, |_| {}))
            .unwrap();
        [
            "train/r_0.png",
            "train/r_1.png",
            "test/r_0.png",
            "transforms_train.json",
        ]
        .map(|f| std::fs::read(tmp.path().join(f)).unwrap())
    };
    let a = run(1, 11);
    let b = run(3, 11);
    assert!(a == b, "thread count changed the output");
    let c = run(2, 12);
    assert!(a[0] != c[0], "another seed should change the noise");
    assert!(a[3] == c[3], "cameras do not depend on the seed");
}

fn mean_over_object(r: &gtsr_data::transport::Rendered) -> (f64, usize) {
    let idx: Vec<usize> = (0..r.alpha.len()).filter(|&i| r.alpha[i] >= 1.0).collect();
    let s: f64 = idx
        .iter()
        .map(|&i| (r.rgb[3 * i] + r.rgb[3 * i + 1] + r.rgb[3 * i + 2]) as f64 / 3.0)
        .sum();
    (s / idx.len() as f64, idx.len())
}

/// White furnace: a white, non-absorbing medium behind a lossless (smooth) boundary, lit
/// by a uniform environment of radiance 1, looks exactly 1 everywhere (energy is conserved,
/// including the 1/eta^2 radiance scaling of the refractive model). With a slightly rough
/// GGX boundary the single-scattering microfacet model may only lose a little energy.
#[test]
fn white_medium_conserves_energy() {
    let cam = Camera::look_at(Vec3::new(0.5, -4.0, 1.0), Vec3::ZERO, Vec3::Z, 0.7, 40, 40);
    let env = Lighting {
        point_intensity: 0.0,
        environment: 1.0,
    };
    let white = Material::from_mfp_albedo([1.0; 3], [1.0; 3], 0.0, 1.5, 0.0);
    let tracers = [ShapeKind::Sphere, ShapeKind::Torus].map(|s| Tracer::new(&s.mesh(), white));
    for boundary in [Boundary::DiffuseTransmission, Boundary::Refractive] {
        for (shape, mfp) in [(ShapeKind::Sphere, 0.2f32), (ShapeKind::Torus, 0.05)] {
            let base = &tracers[(shape == ShapeKind::Torus) as usize];
            let m = Material {
                boundary,
                ..Material::from_mfp_albedo([mfp; 3], [1.0; 3], 0.3, 1.5, 0.0)
            };
            let r = base.with_material(m).render(&cam, env, 128, 5, 0);
            let (mean, n) = mean_over_object(&r);
            eprintln!("furnace {boundary:?} {shape} smooth: {mean:.4}");
            assert!(n > 100);
            assert!(
                (mean - 1.0).abs() < 0.01,
                "{boundary:?} {shape} smooth: furnace mean {mean}"
            );
            let rough = Material {
                roughness: 0.05,
                ..m
            };
            let r = base.with_material(rough).render(&cam, env, 128, 5, 0);
            let (mean, _) = mean_over_object(&r);
            eprintln!("furnace {boundary:?} {shape} alpha 0.05: {mean:.4}");
            assert!(
                mean < 1.01 && mean > 0.93,
                "{boundary:?} {shape} rough: furnace mean {mean}"
            );
        }
    }
}

/// With the point light, raising absorption darkens the object monotonically.
#[test]
fn absorption_darkens_monotonically() {
    let base = Tracer::new(&ShapeKind::Bear.mesh(), MaterialPreset::Wax.material());
    let cam = Camera::look_at(Vec3::new(0.0, -4.0, 0.5), Vec3::ZERO, Vec3::Z, 0.7, 40, 40);
    let light = Lighting {
        point_intensity: 20.0,
        environment: 0.0,
    };
    for boundary in [Boundary::DiffuseTransmission, Boundary::Refractive] {
        let mut last = f64::INFINITY;
        for sigma_a in [0.0f32, 0.3, 1.0, 3.0, 10.0] {
            let m = Material {
                sigma_s: [5.0; 3],
                sigma_a: [sigma_a; 3],
                g: 0.2,
                ior: 1.5,
                roughness: 0.2,
                boundary,
            };
            let r = base.with_material(m).render(&cam, light, 64, 9, 0);
            let mean = r.rgb.iter().map(|&v| v as f64).sum::<f64>() / r.rgb.len() as f64;
            assert!(
                mean < last * 0.97,
                "{boundary:?} sigma_a {sigma_a}: mean {mean} not below {last}"
            );
            eprintln!("absorption {boundary:?} sigma_a {sigma_a}: mean {mean:.5}");
            assert!(mean > 0.0);
            last = mean;
        }
    }
}

#[test]
fn bad_configuration_is_an_error() {
    let tmp = tempfile::tempdir().unwrap();
    let mut cfg = small_config(ShapeKind::Sphere, 1);
    cfg.material.g = 1.5;
    let e = generate_scene(tmp.path(), &cfg, |_| {}).unwrap_err();
    assert!(e.to_string().contains("g must be"), "{e}");
    let mut cfg = small_config(ShapeKind::Sphere, 1);
    cfg.n_train = 0;
    assert!(generate_scene(tmp.path(), &cfg, |_| {}).is_err());
    assert!("dodecahedron".parse::<ShapeKind>().is_err());
    assert_eq!(
        "torus_knot".parse::<ShapeKind>().unwrap(),
        ShapeKind::TorusKnot
    );
    assert_eq!(
        "wax".parse::<MaterialPreset>().unwrap(),
        MaterialPreset::Wax
    );
}
