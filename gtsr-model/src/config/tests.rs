use super::*;

/// `c` as a `config.json` written before the fields `paths` (`"group.field"` or `"field"`)
/// existed, read back.
fn read_without(c: &TrainConfig, paths: &[&str]) -> TrainConfig {
    let mut json = serde_json::to_value(c).unwrap();
    for path in paths {
        let (group, field) = match path.split_once('.') {
            Some((g, f)) => (&mut json[g], f),
            None => (&mut json, *path),
        };
        group.as_object_mut().unwrap().remove(field);
    }
    serde_json::from_value(json).unwrap()
}

#[test]
fn opacity_resets_stop_before_the_end_of_densification() {
    let c = TrainConfig::for_iterations(Components::FULL, 1500);
    let d = &c.densify;
    assert_eq!((d.opacity_reset_every, d.end), (150, 750));
    let resets: Vec<usize> = (1..=c.iterations).filter(|s| d.resets_after(*s)).collect();
    assert_eq!(resets, vec![150, 300, 450, 600]);
    // Every reset is followed by a densification (and its pruning).
    for r in resets {
        assert!((r + 1..=d.end).any(|s| s >= d.start && s.is_multiple_of(d.every)));
    }
    let never = DensifyConfig {
        opacity_reset_every: 0,
        ..d.clone()
    };
    assert!(!(1..=c.iterations).any(|s| never.resets_after(s)));
    // Resets only in stage 1 (before step 350 of 1500).
    let stage1 = DensifyConfig {
        reset_until: c.stage2_start,
        ..d.clone()
    };
    let early: Vec<usize> = (1..=c.iterations)
        .filter(|s| stage1.resets_after(*s))
        .collect();
    assert_eq!((c.stage2_start, early), (350, vec![150, 300]));
    // A config written before `reset_until` existed resets as it did.
    let old = read_without(&c, &["densify.reset_until"]);
    assert!((1..=c.iterations).all(|s| old.densify.resets_after(s) == d.resets_after(s)));
}

#[test]
fn trims_run_on_their_schedule_while_densification_runs() {
    let mut d = TrainConfig::for_iterations(Components::FULL, 1500).densify;
    assert!(!(1..=1500).any(|s| d.trims_after(s)), "off by default");
    // PGSR's every 1000 of 30000 steps, while densification runs (to step 750 here).
    d.trim_every = 50;
    let trims: Vec<usize> = (1..=1500).filter(|s| d.trims_after(*s)).collect();
    assert_eq!(trims.first(), Some(&50));
    assert_eq!(trims.last(), Some(&700));
    assert_eq!(trims.len(), 14);
    // Configurations written before the trim existed read with it off.
    let back = read_without(
        &TrainConfig::for_iterations(Components::FULL, 10),
        &[
            "densify.trim_every",
            "densify.trim_min_views",
            "densify.trim_transmittance",
        ],
    );
    assert_eq!(
        (back.densify.trim_every, back.densify.trim_min_views),
        (0, 2)
    );
    assert_eq!(back.densify.trim_transmittance, 0.9);
}

#[test]
fn demotions_run_from_the_start_of_stage_2_to_the_end() {
    let c = TrainConfig::for_iterations(Components::FULL, 1500);
    let mut d = c.densify.clone();
    assert!(
        !(1..=1500).any(|s| d.demotes_after(s, c.stage2_start)),
        "off by default"
    );
    d.demote_every = 50;
    let at: Vec<usize> = (1..=1500)
        .filter(|s| d.demotes_after(*s, c.stage2_start))
        .collect();
    // Right after the first stage-2 step (step 350 makes 351 done), then every 50 steps,
    // past the end of densification.
    assert_eq!(at.first(), Some(&351));
    assert_eq!(at.last(), Some(&1451));
    assert_eq!(at.len(), 23);
    // Configurations written before the demotion existed read with it off.
    let back = read_without(
        &c,
        &[
            "densify.demote_every",
            "densify.demote_min_views",
            "densify.demote_transmittance",
        ],
    );
    assert_eq!(back.densify, c.densify);
    // Out-of-range settings and a demotion without an interior set are refused.
    let mut bad = c.clone();
    bad.densify.demote_transmittance = 1.0;
    assert!(bad.validate().is_err());
    let mut bad = TrainConfig::for_iterations(Preset::NoInterior.components().unwrap(), 1500);
    bad.densify.demote_every = 50;
    assert!(bad.validate().is_err());
}

#[test]
fn silhouette_bands_are_off_by_default_and_kept_below_the_measured_distance() {
    let c = TrainConfig::for_iterations(Components::FULL, 100);
    assert_eq!((c.weights.mask_band, c.weights.photometric_band), (0, 0));
    let old = read_without(&c, &["weights.photometric_band"]);
    assert_eq!(old.weights.photometric_band, 0);
    let cap = MASK_EDGE_CAP as u32;
    for (mask_band, photometric_band) in [(cap - 1, 0), (0, cap - 1)] {
        let mut ok = c.clone();
        ok.weights.mask_band = mask_band;
        ok.weights.photometric_band = photometric_band;
        assert!(ok.validate().is_ok());
    }
    for (mask_band, photometric_band, name) in [
        (cap, 0, "weights.mask_band"),
        (0, cap, "weights.photometric_band"),
    ] {
        let mut bad = c.clone();
        bad.weights.mask_band = mask_band;
        bad.weights.photometric_band = photometric_band;
        let e = bad.validate().unwrap_err();
        assert!(e.contains(name), "{e}");
    }
    // The band's hinge: off by default, absent from older files, and only with a band.
    assert!(!c.weights.mask_band_hinge);
    assert!(
        !read_without(&c, &["weights.mask_band_hinge"])
            .weights
            .mask_band_hinge
    );
    let mut hinge = c.clone();
    hinge.weights.mask_band_hinge = true;
    let e = hinge.validate().unwrap_err();
    assert!(e.contains("weights.mask_band_hinge"), "{e}");
    hinge.weights.mask_band = 1;
    assert!(hinge.validate().is_ok());
}

#[test]
fn the_hull_depth_term_is_on_with_masks_off_without_and_in_old_configs() {
    let masked = TrainConfig::for_views(Components::FULL, 3000, 256 * 256, true);
    assert_eq!(masked.weights.hull_depth, DEFAULT_HULL_DEPTH_WEIGHT);
    const { assert!(DEFAULT_HULL_DEPTH_WEIGHT > 0.0) };
    let unmasked = TrainConfig::for_views(Components::FULL, 3000, 256 * 256, false);
    assert_eq!(unmasked.weights.hull_depth, 0.0);
    // The bound's occluding edges count unless a config leaves them out.
    assert_eq!(masked.weights.hull_depth_edges, 0.0);
    // The pixels behind the bound's occluding edges count only as the bound reads them.
    assert_eq!(masked.weights.hull_depth_occluders, 0.0);
    // A run from before the term (or before either edge setting) repeats without it, and
    // every setting must be finite and non-negative.
    type Field = fn(&mut LossWeights) -> &mut f64;
    let fields: [(&str, Field); 3] = [
        ("weights.hull_depth", |w| &mut w.hull_depth),
        ("weights.hull_depth_edges", |w| &mut w.hull_depth_edges),
        ("weights.hull_depth_occluders", |w| {
            &mut w.hull_depth_occluders
        }),
    ];
    for (name, field) in fields {
        let mut old = read_without(&masked, &[name]);
        assert_eq!(*field(&mut old.weights), 0.0, "{name}");
        let mut bad = masked.clone();
        *field(&mut bad.weights) = -1.0;
        let e = bad.validate().unwrap_err();
        assert!(e.contains(name), "{e}");
    }
}

#[test]
fn the_surface_opacity_floor_is_off_by_default_and_below_one() {
    let c = TrainConfig::for_iterations(Components::FULL, 100);
    assert_eq!(c.surface_opacity_floor, 0.0);
    let old = read_without(&c, &["surface_opacity_floor"]);
    assert_eq!(old.surface_opacity_floor, 0.0);
    for ok in [0.0, 0.5, 0.99] {
        let mut cfg = c.clone();
        cfg.surface_opacity_floor = ok;
        assert!(cfg.validate().is_ok(), "{ok}");
    }
    for bad in [1.0, -0.1, f64::NAN] {
        let mut cfg = c.clone();
        cfg.surface_opacity_floor = bad;
        let e = cfg.validate().unwrap_err();
        assert!(e.contains("surface_opacity_floor"), "{e}");
    }
}

/// A switch that is off by default, reads as off from a configuration written before it
/// existed, and survives a round trip when on. `field` reads and writes it; `name` is its
/// key in `config.json`.
fn off_by_default_and_in_old_configs(name: &str, field: fn(&mut TrainConfig) -> &mut bool) {
    let mut c = TrainConfig::for_iterations(Components::FULL, 100);
    assert!(!*field(&mut c), "{name} on by default");
    *field(&mut c) = true;
    assert!(
        !*field(&mut read_without(&c, &[name])),
        "{name} on in an old config"
    );
    let json = serde_json::to_string(&c).unwrap();
    let mut back = serde_json::from_str::<TrainConfig>(&json).unwrap();
    assert!(*field(&mut back), "{name} lost on the round trip");
}

#[test]
fn the_lit_scattering_map_is_off_by_default_and_in_old_configs() {
    off_by_default_and_in_old_configs("scatter_lambert", |c| &mut c.scatter_lambert);
}

#[test]
fn the_scattering_map_decoding_is_off_by_default_and_in_old_configs() {
    off_by_default_and_in_old_configs("pbr_scatter_srgb", |c| &mut c.pbr_scatter_srgb);
}

#[test]
fn the_scattering_smoothness_is_off_by_default_in_old_configs_and_checked() {
    let c = TrainConfig::for_iterations(Components::FULL, 100);
    assert_eq!(c.weights.smooth_scatter, 0.0);
    let mut on = c.clone();
    on.weights.smooth_scatter = 0.5;
    assert_eq!(
        read_without(&on, &["weights.smooth_scatter"])
            .weights
            .smooth_scatter,
        0.0
    );
    let json = serde_json::to_string(&on).unwrap();
    let back: TrainConfig = serde_json::from_str(&json).unwrap();
    assert_eq!(back.weights.smooth_scatter, 0.5);
    on.weights.smooth_scatter = -1.0;
    let err = on.validate().unwrap_err();
    assert!(err.contains("weights.smooth_scatter"), "{err}");
}

#[test]
fn blur_defaults_to_the_pixel_box_and_old_configs_keep_3dgs_blur() {
    let c = TrainConfig::for_iterations(Components::FULL, 100);
    assert_eq!(c.blur_px2, gtsr_render_kernels::PIXEL_BOX_BLUR_PX2);
    let old = read_without(&c, &["blur_px2"]);
    assert_eq!(old.blur_px2, gtsr_render_kernels::BLUR_PX2);
    for bad in [-0.5, f64::NAN] {
        let e = TrainConfig {
            blur_px2: bad,
            ..c.clone()
        }
        .validate()
        .unwrap_err();
        assert!(e.contains("blur_px2"), "{e}");
    }
    // The blur's compensation is off by default and in configs written before it.
    assert!(!c.compensate_blur);
    let on = TrainConfig {
        compensate_blur: true,
        ..c.clone()
    };
    assert!(!read_without(&on, &["compensate_blur"]).compensate_blur);
}
