//! Leaving components out: parameters not allocated, raster passes not run.

use gtsr_model::config::Preset;
use gtsr_model::gaussians::ParamKind;

use crate::common::{device, small_config, tiny_scene, trainer};

#[test]
fn switches_change_allocations_and_pass_counts() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let device = device();
    // (preset, passes of a stage-1 step, passes of a stage-2 step including the neighbour)
    let expect = [
        (Preset::Full, 1, 4),
        (Preset::NoPbr, 1, 3),
        (Preset::NoFresnel, 1, 4),
        (Preset::NoInterior, 1, 2),
        (Preset::Pgsr, 1, 2),
    ];
    for (preset, s1, s2) in expect {
        let comps = preset.components().unwrap();
        let mut t = trainer(&scene, small_config(comps, 6), &device);
        let r1 = t.step().unwrap();
        assert_eq!(r1.stage, 1);
        assert_eq!(r1.passes, s1, "{preset:?} stage 1");
        t.seek(t.config().stage2_start);
        let r2 = t.step().unwrap();
        assert_eq!(r2.stage, 2);
        assert_eq!(r2.passes, s2, "{preset:?} stage 2");
        assert_eq!(
            t.model().interior.is_some(),
            comps.interior,
            "{preset:?} interior set"
        );
        assert_eq!(t.model().log_light.is_some(), comps.pbr, "{preset:?} light");
        assert_eq!(
            t.model().surface.get(ParamKind::BaseColour).is_some(),
            comps.pbr,
            "{preset:?} material"
        );
        assert!(!r2.skipped && r2.loss.is_finite());
    }
    // Without the multi-view term the neighbour pass goes too; SH degree 0 allocates no
    // higher coefficients.
    let mut comps = Preset::Full.components().unwrap();
    comps.multi_view = false;
    comps.sh_degree = 0;
    let mut t = trainer(&scene, small_config(comps, 6), &device);
    t.seek(t.config().stage2_start);
    assert_eq!(t.step().unwrap().passes, 3);
    assert!(t.model().surface.get(ParamKind::ShRest).is_none());
    assert!(
        t.model()
            .interior
            .as_ref()
            .unwrap()
            .get(ParamKind::ShRest)
            .is_none()
    );
}

/// Tile-splat pairs: each pass reports what it blended, a step sums its passes, the counters
/// sum the steps.
#[test]
fn tile_splat_pairs_add_up_over_passes_and_steps() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let device = device();
    let mut t = trainer(
        &scene,
        small_config(Preset::Full.components().unwrap(), 6),
        &device,
    );

    // Stage 1 blends the surface set once, in the same pass as its geometry: the step's pairs
    // are the depth-only render's of the same view.
    let vi = t.view_for_step(t.steps_done());
    let v = t.views()[vi].clone();
    let alone = t
        .model()
        .render_depth(&v.camera, &v.rays)
        .unwrap()
        .tile_splats;
    assert!(alone > 0, "the tiny scene's surface set is on screen");
    let r1 = t.step().unwrap();
    assert_eq!((r1.stage, r1.passes, r1.tile_splats), (1, 1, alone));

    // Stage 2: C_SH (both sets), geometry (surface), scattering (interior), the neighbour
    // (surface). The geometry pass is the depth-only render again, and the whole is more than
    // the geometry and neighbour passes.
    t.seek(t.config().stage2_start);
    let f = t.forward(t.steps_done()).unwrap();
    let v = t.views()[f.view].clone();
    let geometry = f.renders.geometry.as_ref().unwrap().tile_splats;
    assert_eq!(
        geometry,
        t.model()
            .render_depth(&v.camera, &v.rays)
            .unwrap()
            .tile_splats
    );
    assert_eq!(f.passes, 4);
    assert!(
        f.renders.tile_splats > geometry,
        "C_SH and scattering passes counted"
    );
    assert!(
        f.tile_splats > f.renders.tile_splats,
        "the neighbour pass counted"
    );
    drop(f);

    let before = t.counters().tile_splats;
    assert_eq!(before, alone, "the counters hold the stage-1 step");
    let r2 = t.step().unwrap();
    assert_eq!(t.counters().tile_splats, before + r2.tile_splats);
}
