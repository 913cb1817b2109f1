//! A short run lowers the loss; every parameter receives gradient.

use gtsr_model::config::Preset;

use crate::common::{device, small_config, tiny_scene, trainer};

#[test]
fn short_training_run_lowers_the_photometric_loss() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let device = device();
    let comps = Preset::Full.components().unwrap();
    let mut t = trainer(&scene, small_config(comps, 150), &device);
    let mut c_sh = Vec::new();
    let mut reports = Vec::new();
    for _ in 0..150 {
        let r = t.step().unwrap();
        assert!(!r.skipped, "step {} skipped", r.step);
        c_sh.push(r.terms.iter().find(|(n, _)| *n == "c_sh").unwrap().1);
        reports.push(r);
    }
    let first: f64 = c_sh[..8].iter().sum::<f64>() / 8.0;
    let last: f64 = c_sh[c_sh.len() - 8..].iter().sum::<f64>() / 8.0;
    assert!(
        last < 0.6 * first,
        "C_SH loss went from {first:.4} to {last:.4} only"
    );
    let pbr: Vec<f64> = reports
        .iter()
        .filter_map(|r| r.terms.iter().find(|(n, _)| *n == "c_pbr").map(|t| t.1))
        .collect();
    let p0 = pbr[..8].iter().sum::<f64>() / 8.0;
    let p1 = pbr[pbr.len() - 8..].iter().sum::<f64>() / 8.0;
    eprintln!(
        "C_SH {first:.4} -> {last:.4}, C_PBR {p0:.4} -> {p1:.4}, sets {:?}",
        t.model.counts()
    );
    assert!(
        p1 < 0.8 * p0,
        "C_PBR loss went from {p0:.4} to {p1:.4} only"
    );
    assert!(t.counters.densifications > 0);
    let (ns, ni) = t.model.counts();
    assert!(ns > 0 && ni > 0);
}

#[test]
fn every_parameter_tensor_receives_gradient() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let device = device();
    let comps = Preset::Full.components().unwrap();
    let mut cfg = small_config(comps, 30);
    cfg.sh_increase_every = 1;
    let mut t = trainer(&scene, cfg, &device);
    t.step = 29; // stage 2, SH degree 3
    let norms = t.gradient_norms().unwrap();
    assert_eq!(norms.len(), 8 + 6 + 1, "{norms:?}");
    for (set, param, g) in &norms {
        assert!(
            g.is_finite() && *g > 0.0,
            "{set}.{param} received gradient {g}"
        );
    }
}

#[test]
fn detached_model_renders_the_same_and_records_no_graph() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let device = device();
    let comps = Preset::Full.components().unwrap();
    let mut t = trainer(&scene, small_config(comps, 30), &device);
    t.step = 29; // stage 2: both sets, Fresnel, PBR
    let opts = t.render_options(t.step, false);
    let view = t.views[0].clone();
    let tracked = t.model.render(&view.camera, &view.rays, opts).unwrap();
    let model = t.model.detached();
    let free = model.render(&view.camera, &view.rays, opts).unwrap();
    assert!(
        tracked.c_sh.is_tracked(),
        "the training model's renders are in the graph"
    );
    assert!(
        !free.c_sh.is_tracked(),
        "a detached model's render records a graph"
    );
    let depth = model.render_depth(&view.camera, &view.rays).unwrap();
    assert!(!depth.depth.is_tracked());
    let sets = [Some(&model.surface), model.interior.as_ref()];
    for set in sets.into_iter().flatten() {
        for (kind, p) in &set.params {
            assert!(!p.is_require_grad(), "{} still requires grad", kind.name());
        }
    }
    assert!(
        model
            .log_light
            .as_ref()
            .is_some_and(|l| !l.is_require_grad())
    );
    // The training parameters are untouched.
    assert!(
        t.model
            .surface
            .params
            .iter()
            .all(|(_, p)| p.is_require_grad())
    );
    let a = tracked
        .c_sh
        .into_data()
        .convert::<f32>()
        .into_vec::<f32>()
        .unwrap();
    let b = free
        .c_sh
        .into_data()
        .convert::<f32>()
        .into_vec::<f32>()
        .unwrap();
    assert_eq!(a, b, "the detached render differs");
}
