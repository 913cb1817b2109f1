//! A short run lowers the loss; every parameter receives gradient.

use burn::tensor::Device;
use gtsr_model::config::{Preset, TrainConfig};
use gtsr_model::gaussians::ParamKind;

use burn::tensor::Tensor;
use gtsr_model::trainer::{Trainer, initial_points};

use crate::common::{device, small_config, tiny_scene, trainer, views};

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
        t.model().counts()
    );
    assert!(
        p1 < 0.8 * p0,
        "C_PBR loss went from {p0:.4} to {p1:.4} only"
    );
    assert!(t.counters().densifications > 0);
    let (ns, ni) = t.model().counts();
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
    t.seek(29); // stage 2, SH degree 3
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
    t.seek(29); // stage 2: both sets, Fresnel, PBR
    let opts = t.render_options(t.steps_done(), false);
    let view = t.views()[0].clone();
    let tracked = t.model().render(&view.camera, &view.rays, opts).unwrap();
    let model = t.model().detached();
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
        t.model()
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

/// A trainer of the full model for a 30-step run on the tiny scene (written into `dir`),
/// with `adjust` applied to the configuration.
fn full_trainer_30(
    dir: &std::path::Path,
    adjust: impl FnOnce(&mut gtsr_model::config::TrainConfig),
) -> (gtsr_model::trainer::Trainer, burn::tensor::Device) {
    let scene = tiny_scene(dir);
    let device = device();
    let mut config = small_config(Preset::Full.components().unwrap(), 30);
    adjust(&mut config);
    (trainer(&scene, config, &device), device)
}

/// Makes every surface Gaussian opaque (logit 3), so that the ones deep inside the ball hide
/// behind the front ones.
fn make_surface_opaque(t: &mut gtsr_model::trainer::Trainer, device: &burn::tensor::Device) {
    let mut host = t.model().surface.to_host();
    for o in host.column_mut(ParamKind::Opacity).unwrap() {
        *o = 3.0;
    }
    t.model_mut().surface = host.to_device(device);
}

#[test]
fn multi_view_trim_removes_exactly_the_gaussians_too_few_views_observe() {
    let dir = tempfile::tempdir().unwrap();
    let (mut t, device) = full_trainer_30(dir.path(), |_| {});
    make_surface_opaque(&mut t, &device);
    let counts = |t: &gtsr_model::trainer::Trainer| t.observation_counts(0.5).unwrap();
    let views = counts(&t);
    let before = views.len();
    let expected = views.iter().filter(|&&v| v < 2).count();
    assert!(
        expected > 0 && expected < before,
        "{expected} of {before} Gaussians are seen by fewer than two views"
    );
    let removed = t.trim_unobserved(2, 0.5).unwrap();
    assert_eq!(removed, expected);
    assert_eq!(t.model().surface.len(), before - expected);
    // Removing splats only raises the transmittance in front of the others: every survivor
    // passes the test again. Training goes on with the pruned set.
    let after = counts(&t);
    assert_eq!(after.len(), before - expected);
    assert!(after.iter().all(|&v| v >= 2), "a survivor lost its views");
    let r = t.step().unwrap();
    assert!(!r.skipped && r.loss.is_finite());
}

#[test]
fn scheduled_trim_runs_inside_the_densification_window_and_is_counted() {
    let dir = tempfile::tempdir().unwrap();
    let (mut t, _device) = full_trainer_30(dir.path(), |c| {
        c.densify.trim_every = 10;
        c.densify.end = 25;
    });
    let mut trimmed_at = Vec::new();
    for step in 1..=30 {
        let before = t.counters().trimmed;
        let r = t.step().unwrap();
        assert!(!r.skipped && r.loss.is_finite(), "step {step}");
        if t.counters().trimmed > before {
            trimmed_at.push(step);
        }
        assert_eq!(r.counts.0, t.model().surface.len());
    }
    // Trims run after steps 10 and 20 only (not 30: densification has ended); the random start
    // puts Gaussians behind others, so both remove some.
    assert_eq!(trimmed_at, [10, 20], "trims after steps {trimmed_at:?}");
}

#[test]
fn demotion_moves_the_hidden_surface_gaussians_into_the_interior_set() {
    let dir = tempfile::tempdir().unwrap();
    // No densification, so that only the demotion changes the sets.
    let (mut t, device) = full_trainer_30(dir.path(), |c| c.densify.start = 1000);
    let stage2 = t.config().stage2_start;
    // Without an interior set (stage 1) nothing moves.
    assert_eq!(t.demote_hidden(2, 0.9).unwrap(), (0, 0));
    for _ in 0..=stage2 {
        t.step().unwrap();
    }
    make_surface_opaque(&mut t, &device);
    let views = t.observation_counts(0.9).unwrap();
    let hidden: Vec<usize> = (0..views.len()).filter(|&i| views[i] < 2).collect();
    assert!(!hidden.is_empty() && hidden.len() < views.len());
    let surface = t.model().surface.to_host();
    let interior_before = t.model().interior.as_ref().unwrap().len();
    let (moved, pruned) = t.demote_hidden(2, 0.9).unwrap();
    assert_eq!(
        (moved, pruned),
        (hidden.len(), 0),
        "the cap leaves room for all"
    );
    assert_eq!(t.counters().demoted, moved);
    assert_eq!(t.model().surface.len(), surface.n - moved);
    // The moved rows are the hidden ones, in order, with every parameter the interior set has.
    let interior = t.model().interior.as_ref().unwrap().to_host();
    assert_eq!(interior.n, interior_before + moved);
    for (kind, w, values) in &interior.columns {
        let (src, sw) = surface.column(*kind).unwrap();
        assert_eq!(sw, *w);
        for (j, &i) in hidden.iter().enumerate() {
            let k = interior_before + j;
            assert_eq!(
                &values[k * w..(k + 1) * w],
                &src[i * w..(i + 1) * w],
                "{kind:?}"
            );
        }
    }
    // Every surface Gaussian left is observed by two views: removing splats only raises the
    // transmittance in front of the others. Training goes on with both sets.
    assert!(t.observation_counts(0.9).unwrap().iter().all(|&v| v >= 2));
    let r = t.step().unwrap();
    assert!(!r.skipped && r.loss.is_finite());
}

#[test]
fn scheduled_demotion_runs_through_stage_2_and_keeps_the_interior_cap() {
    let dir = tempfile::tempdir().unwrap();
    let (mut t, _device) = full_trainer_30(dir.path(), |c| {
        c.densify.start = 1000;
        c.densify.demote_every = 5;
        c.densify.demote_transmittance = 0.99;
        c.densify.max_interior = 170;
    });
    let stage2 = t.config().stage2_start;
    let mut demoted_at = Vec::new();
    for step in 1..=30 {
        let before = t.counters().demoted + t.counters().trimmed;
        let r = t.step().unwrap();
        assert!(!r.skipped && r.loss.is_finite(), "step {step}");
        if t.counters().demoted + t.counters().trimmed > before {
            demoted_at.push(step);
        }
        if let Some(int) = t.model().interior.as_ref() {
            assert!(
                int.len() <= 170,
                "the interior set passed its cap: {}",
                int.len()
            );
        }
        assert_eq!(r.counts.0, t.model().surface.len());
    }
    // Only right after the first stage-2 step and every 5 steps after it; the random start
    // hides Gaussians behind others at the first one, and more than the cap leaves room for.
    assert_eq!(demoted_at.first(), Some(&(stage2 + 1)), "{demoted_at:?}");
    assert!(
        demoted_at.iter().all(|s| (s - stage2 - 1) % 5 == 0),
        "{demoted_at:?}"
    );
    assert_eq!(t.model().interior.as_ref().unwrap().len(), 170);
    assert!(t.counters().trimmed > 0);
}

#[test]
fn loss_weights_can_be_replaced_but_not_with_refused_ones() {
    let dir = tempfile::tempdir().unwrap();
    let (mut t, _device) = full_trainer_30(dir.path(), |_| {});
    let mut w = t.config().weights.clone();
    w.photometric_band = 2;
    t.set_loss_weights(w.clone()).unwrap();
    assert_eq!(t.config().weights, w);
    let mut bad = w.clone();
    bad.mask_band = gtsr_model::config::MASK_EDGE_CAP as u32;
    let e = t.set_loss_weights(bad).unwrap_err().to_string();
    assert!(e.contains("weights.mask_band"), "{e}");
    assert_eq!(
        t.config().weights,
        w,
        "a refused change leaves the weights as they were"
    );
    let r = t.step().unwrap();
    assert!(!r.skipped && r.loss.is_finite());
}

/// `weights.hull_depth_from` keeps the hull-depth term off until that share of the run, in
/// stage 2 too, and on after it.
#[test]
fn the_hull_depth_term_starts_at_its_share_of_the_run() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let device = device();
    let mut cfg = small_config(Preset::Full.components().unwrap(), 30);
    cfg.weights.hull_depth = 0.03;
    cfg.weights.hull_depth_from = 0.5;
    let mut vs = views(&scene, &device);
    for v in &mut vs {
        let (w, h) = v.size();
        v.hull_depth = Some(Tensor::ones([h, w], &device) * 4.0);
    }
    let pts = initial_points(&cfg, &vs, &scene.train).expect("points");
    let mut t = Trainer::new(cfg, vs, 1.0, &pts, &device).expect("trainer");
    let has_term = |t: &mut Trainer, step: usize| {
        (t.forward(step).unwrap().terms.iter()).any(|(name, _)| *name == "hull_depth")
    };
    assert!(t.is_stage2(12));
    assert!(!has_term(&mut t, 12), "off before half the run");
    assert!(has_term(&mut t, 15), "on from half the run");
    assert!(has_term(&mut t, 25));
}

/// A trainer of the full model over `scene`'s views, 30 steps, with `edit` applied to its
/// configuration.
fn full_trainer(
    scene: &gtsr_data::Scene,
    device: &Device,
    edit: impl FnOnce(&mut TrainConfig),
) -> Trainer {
    let mut cfg = small_config(Preset::Full.components().unwrap(), 30);
    edit(&mut cfg);
    let vs = views(scene, device);
    let pts = initial_points(&cfg, &vs, &scene.train).expect("points");
    Trainer::new(cfg, vs, 1.0, &pts, device).expect("trainer")
}

#[test]
fn the_multi_view_term_runs_one_step_in_n_weighted_by_n() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let device = device();
    let build = |every: usize| full_trainer(&scene, &device, |cfg| cfg.multi_view_every = every);
    let term = |t: &mut Trainer, step: usize| {
        let f = t.forward(step).unwrap();
        let mv = f.terms.iter().find(|(name, _)| *name == "multi_view");
        mv.map(|(_, v)| v.clone().into_scalar::<f64>())
    };
    let (mut every, mut thirds) = (build(1), build(3));
    assert!(every.is_stage2(12));
    for step in 12..16 {
        let full = term(&mut every, step).expect("the term runs on every step at 1");
        assert!(full > 0.0, "step {step}: no reprojection error to weigh");
        match term(&mut thirds, step) {
            Some(v) if step % 3 == 0 => assert!(
                (v - 3.0 * full).abs() <= 1e-5 * full.abs().max(1e-6),
                "step {step}: {v} against 3 x {full}"
            ),
            Some(v) => panic!("step {step}: the term ran ({v}) off its steps"),
            None => assert!(step % 3 != 0, "step {step}: the term did not run"),
        }
    }
}

#[test]
fn the_multi_view_ncc_term_runs_beside_the_multi_view_term_only_when_weighted() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let device = device();
    let build = |weight: f64| {
        full_trainer(&scene, &device, |cfg| {
            cfg.multi_view_every = 1;
            cfg.weights.multi_view_ncc = weight;
        })
    };
    let names = |t: &mut Trainer, step: usize| -> Vec<(&'static str, f64)> {
        let f = t.forward(step).unwrap();
        f.terms
            .iter()
            .map(|(name, v)| (*name, v.clone().into_scalar::<f64>()))
            .collect()
    };
    let (mut off, mut on) = (build(0.0), build(0.15));
    assert!(on.is_stage2(12));
    assert!(
        !names(&mut off, 12)
            .iter()
            .any(|(n, _)| *n == "multi_view_ncc")
    );
    let terms = names(&mut on, 12);
    let ncc = terms.iter().find(|(n, _)| *n == "multi_view_ncc");
    let (_, v) = ncc.expect("the term runs when weighted");
    assert!(v.is_finite() && *v >= 0.0, "{v}");
    assert!(terms.iter().any(|(n, _)| *n == "multi_view"));
    // A whole step with it: finite gradients, parameters updated.
    on.seek(12);
    let report = on.step().expect("a step with the term");
    assert!(
        report
            .terms
            .iter()
            .any(|(n, v)| *n == "multi_view_ncc" && v.is_finite())
    );
}
