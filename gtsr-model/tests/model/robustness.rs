//! Non-finite steps are skipped, checkpoints resume exactly and are written the same each
//! time, exports are readable, bad input is refused with a clear error, and `auto` explains
//! itself.

use burn::tensor::Device;
use gtsr_data::Normalisation;
use gtsr_model::checkpoint;
use gtsr_model::config::{Init, Preset, SceneEvidence, auto_components};
use gtsr_model::export::write_splat_ply;
use gtsr_model::model::scalar_param;
use gtsr_model::trainer::initial_points;
use gtsr_model::views::{ViewTensors, scene_evidence};

use crate::common::{device, small_config, tiny_scene, trainer, views};

#[test]
fn non_finite_steps_are_skipped_and_counted() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let device = device();
    let mut t = trainer(
        &scene,
        small_config(Preset::Full.components().unwrap(), 30),
        &device,
    );
    t.seek(t.config().stage2_start);
    t.step().unwrap();
    t.model_mut().log_light = Some(scalar_param(f64::NAN, &device));
    let before = t.model().surface.to_host();
    let r = t.step().unwrap();
    assert!(r.skipped && !r.loss.is_finite());
    assert_eq!(t.counters().skipped_steps, 1);
    assert_eq!(
        t.model().surface.to_host(),
        before,
        "a skipped step must not touch the parameters"
    );
}

#[test]
fn resume_from_checkpoint_equals_uninterrupted_training() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let device = device();
    let cfg = small_config(Preset::Full.components().unwrap(), 36);
    let mut a = trainer(&scene, cfg.clone(), &device);
    for _ in 0..26 {
        a.step().unwrap();
    }
    let mut b = trainer(&scene, cfg, &device);
    for _ in 0..17 {
        b.step().unwrap();
    }
    let path = dir.path().join("run.ckpt");
    checkpoint::save(&b, &path).unwrap();
    // The same trainer writes the same bytes each time (no map order in the header).
    let first = std::fs::read(&path).unwrap();
    for k in 0..3 {
        let again = dir.path().join(format!("again{k}.ckpt"));
        checkpoint::save(&b, &again).unwrap();
        assert!(
            std::fs::read(&again).unwrap() == first,
            "save {k} wrote other bytes"
        );
    }
    drop(b);
    let mut c = checkpoint::load(&path, views(&scene, &device), &device).unwrap();
    assert_eq!(c.steps_done(), 17);
    for _ in 17..26 {
        c.step().unwrap();
    }
    assert_eq!(a.model().surface.to_host(), c.model().surface.to_host());
    assert_eq!(
        a.model().interior.as_ref().unwrap().to_host(),
        c.model().interior.as_ref().unwrap().to_host()
    );
    let la: f32 = a.model().log_light.clone().unwrap().into_scalar();
    let lc: f32 = c.model().log_light.clone().unwrap().into_scalar();
    assert_eq!(la, lc);
    // A damaged checkpoint is refused with the file named.
    std::fs::write(&path, b"not a checkpoint").unwrap();
    let err = checkpoint::load(&path, views(&scene, &device), &device)
        .unwrap_err()
        .to_string();
    assert!(err.contains("run.ckpt"), "{err}");
}

#[test]
fn splat_ply_has_the_3dgs_layout() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let device = device();
    let mut t = trainer(
        &scene,
        small_config(Preset::Full.components().unwrap(), 30),
        &device,
    );
    t.seek(t.config().stage2_start);
    t.step().unwrap();
    let path = dir.path().join("gaussians.ply");
    let n = write_splat_ply(t.model(), &path, &Normalisation::IDENTITY).unwrap();
    let (ns, ni) = t.model().counts();
    assert_eq!(n, ns + ni);
    let bytes = std::fs::read(&path).unwrap();
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    let header = std::str::from_utf8(&bytes[..end]).unwrap();
    let props: Vec<&str> = header
        .lines()
        .filter(|l| l.starts_with("property float "))
        .collect();
    // x y z, nx ny nz, 3 DC, 45 rest, opacity, 3 scales, 4 rotations, set flag.
    assert_eq!(props.len(), 3 + 3 + 3 + 45 + 1 + 3 + 4 + 1);
    for p in [
        "x",
        "f_dc_0",
        "f_rest_44",
        "opacity",
        "scale_2",
        "rot_3",
        "gtsr_set",
    ] {
        assert!(
            props.contains(&format!("property float {p}").as_str()),
            "missing {p}"
        );
    }
    assert!(header.contains(&format!("element vertex {n}")));
    assert_eq!(bytes.len() - end, n * props.len() * 4);
    // The last splat is interior (flag 1), the first surface (flag 0).
    let flag = |i: usize| {
        let o = end + (i * props.len() + props.len() - 1) * 4;
        f32::from_le_bytes(bytes[o..o + 4].try_into().unwrap())
    };
    assert_eq!(flag(0), 0.0);
    assert_eq!(flag(n - 1), 1.0);

    // In a dataset's own frame: positions mapped back, log-scales shifted by ln(radius), the
    // rest unchanged.
    let frame = Normalisation {
        centre: glam::Vec3::new(3.0, -2.0, 0.5),
        radius: 4.0,
    };
    let world = dir.path().join("gaussians_world.ply");
    assert_eq!(write_splat_ply(t.model(), &world, &frame).unwrap(), n);
    let wbytes = std::fs::read(&world).unwrap();
    assert_eq!(wbytes.len(), bytes.len());
    let at = |b: &[u8], i: usize, name: &str| {
        let col = props
            .iter()
            .position(|p| *p == format!("property float {name}"))
            .unwrap();
        let o = end + (i * props.len() + col) * 4;
        f32::from_le_bytes(b[o..o + 4].try_into().unwrap())
    };
    for i in [0, n / 2, n - 1] {
        for (a, name) in ["x", "y", "z"].iter().enumerate() {
            let want = at(&bytes, i, name) * frame.radius + frame.centre[a];
            assert!((at(&wbytes, i, name) - want).abs() < 1e-5, "{name} of {i}");
        }
        let s = at(&wbytes, i, "scale_1") - at(&bytes, i, "scale_1");
        assert!((s - frame.radius.ln()).abs() < 1e-5);
        for name in ["rot_0", "rot_3", "opacity", "f_dc_1"] {
            assert_eq!(at(&wbytes, i, name), at(&bytes, i, name), "{name}");
        }
    }
    // A normalisation that cannot be inverted is refused with the file named.
    let bad = Normalisation {
        radius: 0.0,
        ..frame
    };
    let e = write_splat_ply(t.model(), &world, &bad)
        .unwrap_err()
        .to_string();
    assert!(e.contains("gaussians_world.ply"), "{e}");
}

#[test]
fn views_are_replaced_only_by_the_same_cameras() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let device = device();
    let mut t = trainer(
        &scene,
        small_config(Preset::Full.components().unwrap(), 10),
        &device,
    );
    let same = t.views().to_vec();
    t.set_views(same.clone()).unwrap();
    let e = t.set_views(same[1..].to_vec()).unwrap_err().to_string();
    assert!(e.contains("replace"), "{e}");
    let mut swapped = same.clone();
    swapped.swap(0, 1);
    let e = t.set_views(swapped).unwrap_err().to_string();
    assert!(e.contains("camera centre"), "{e}");
    t.step().unwrap();
}

#[test]
fn bad_views_and_configs_are_refused_with_reasons() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let device = Device::ndarray();
    let mut v = scene.train[0].clone();
    v.rgb[5] = f32::NAN;
    let e = ViewTensors::new(&v, 0, &device).unwrap_err().to_string();
    assert!(e.contains(&v.name) && e.contains("non-finite"), "{e}");
    let mut v = scene.train[0].clone();
    v.rgb.pop();
    let e = ViewTensors::new(&v, 0, &device).unwrap_err().to_string();
    assert!(e.contains("colour values"), "{e}");
    let mut v = scene.train[0].clone();
    v.camera.fx = 0.0;
    let e = ViewTensors::new(&v, 0, &device).unwrap_err().to_string();
    assert!(e.contains("camera"), "{e}");
    let mut cfg = small_config(Preset::Full.components().unwrap(), 10);
    cfg.f0 = 2.0;
    cfg.init_radius = f64::NAN;
    let e = cfg.validate().unwrap_err();
    assert!(e.contains("f0") && e.contains("init_radius"), "{e}");
    let mut cfg = small_config(Preset::Full.components().unwrap(), 10);
    cfg.weights.multi_view = f64::NAN;
    cfg.weights.spread = -1.0;
    cfg.weights.lambda_l1 = 1.5;
    cfg.multi_view_every = 0;
    let e = cfg.validate().unwrap_err();
    assert!(
        e.contains("weights.multi_view")
            && e.contains("weights.spread")
            && e.contains("weights.lambda_l1 must be in [0, 1]")
            && e.contains("multi_view_every must be at least 1"),
        "{e}"
    );
    let mut cfg = small_config(Preset::Full.components().unwrap(), 10);
    cfg.weights.multi_view_ncc = 0.15;
    cfg.components.multi_view = false;
    let e = cfg.validate().unwrap_err();
    assert!(
        e.contains("weights.multi_view_ncc needs the multi-view"),
        "{e}"
    );
    let mut comps = Preset::NoPbr.components().unwrap();
    comps.smoothness = true;
    assert!(comps.validate().is_err());
}

#[test]
fn auto_leaves_out_what_the_scene_does_not_need_and_says_why() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let ev = scene_evidence(&scene, 30.0).unwrap();
    assert_eq!(ev.colocated_light, Some(true));
    assert_eq!(ev.opaque, Some(false));
    let (c, decisions) = auto_components(&ev);
    assert!(c.pbr && c.interior, "{decisions:?}");
    let opaque = SceneEvidence {
        colocated_light: None,
        opaque: Some(true),
        light: Some(gtsr_data::light::LightEvidence {
            points: 900,
            views_per_point: 20,
            facing_correlation: 0.05,
            share_following: 0.1,
            facing_exponent: 0.02,
        }),
        train_views: 10,
        views_with_neighbours: 10,
    };
    let (c, decisions) = auto_components(&opaque);
    assert!(!c.pbr && !c.interior && !c.fresnel && !c.smoothness && c.multi_view);
    let pbr = decisions.iter().find(|d| d.component == "pbr").unwrap();
    assert!(
        !pbr.enabled && pbr.reason.contains("does not follow the camera"),
        "{pbr:?}"
    );
    assert!(
        decisions
            .iter()
            .any(|d| d.component == "interior" && d.reason.contains("opaque"))
    );
    let flash = SceneEvidence {
        opaque: None,
        light: Some(gtsr_data::light::LightEvidence {
            facing_correlation: 0.8,
            share_following: 0.9,
            ..opaque.light.clone().unwrap()
        }),
        ..opaque.clone()
    };
    let (c, decisions) = auto_components(&flash);
    assert!(c.pbr && c.smoothness && c.interior, "{decisions:?}");
    let none = SceneEvidence {
        light: None,
        ..flash
    };
    let (c, _) = auto_components(&none);
    assert!(!c.pbr && !c.smoothness);
}

/// The initial points of `init` on the tiny sphere scene, and how many were asked for.
fn tiny_initial_points(init: Init) -> (Vec<[f32; 3]>, usize) {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let device = device();
    let vs = views(&scene, &device);
    let mut cfg = small_config(Preset::Full.components().unwrap(), 10);
    cfg.init = init;
    (
        initial_points(&cfg, &vs, &scene.train).unwrap(),
        cfg.init_surface,
    )
}

#[test]
fn mask_carved_points_project_inside_the_masks() {
    let (pts, asked) = tiny_initial_points(Init::MaskCarved);
    assert_eq!(pts.len(), asked);
    // The sphere has radius 1: carved points lie close to it, random ones fill the ball.
    let outside = pts
        .iter()
        .filter(|p| p.iter().map(|v| v * v).sum::<f32>().sqrt() > 1.15)
        .count();
    assert!(
        outside < pts.len() / 20,
        "{outside} of {} points outside the object",
        pts.len()
    );
}

#[test]
fn hull_surface_points_lie_on_the_boundary_of_the_masks_hull() {
    let (pts, asked) = tiny_initial_points(Init::HullSurface);
    assert_eq!(pts.len(), asked);
    // The object is a unit sphere; its hull from a few views is a little larger, and mask-carved
    // points fill it. Points on the hull's boundary have radius about 1, none near the centre.
    let radii: Vec<f32> = pts
        .iter()
        .map(|p| p.iter().map(|v| v * v).sum::<f32>().sqrt())
        .collect();
    let inner = radii.iter().filter(|r| **r < 0.9).count();
    let outer = radii.iter().filter(|r| **r > 1.25).count();
    assert!(
        inner == 0,
        "{inner} of {} points inside radius 0.9",
        pts.len()
    );
    assert!(outer < pts.len() / 20, "{outer} points beyond 1.25");
    let (carved, _) = tiny_initial_points(Init::MaskCarved);
    let deep = carved
        .iter()
        .filter(|p| p.iter().map(|v| v * v).sum::<f32>().sqrt() < 0.9)
        .count();
    assert!(
        deep > carved.len() / 2,
        "mask-carved points fill the hull ({deep})"
    );
}
