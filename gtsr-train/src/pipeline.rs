//! The run: scene, configuration, training loop with progress, evaluations along the way
//! (off the training clock), checkpoints, Ctrl-C, final outputs.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use burn::tensor::Device;
use gtsr_data::synthetic::{MaterialPreset, SceneConfig, ShapeKind, generate_scene};
use gtsr_data::{Downscale, LoadOptions, Scene, load_scene};
use gtsr_eval::{Timeline, TimelinePoint};
use gtsr_model::checkpoint;
use gtsr_model::config::{Decision, Init, Preset, TrainConfig, auto_components};
use gtsr_model::trainer::{StepTimes, Trainer, initial_points};
use gtsr_model::views::{ViewTensors, scene_evidence, upload_views};
use indicatif::{ProgressBar, ProgressStyle};
use serde::{Deserialize, Serialize};

use crate::outputs::{self, MeshSettings};
use crate::{Args, Backend};

/// The default cap on the surface set (three per pixel of a view up to this).
const MAX_SURFACE: usize = 65_536;
/// The default cap on the interior set (one per pixel of a view up to this).
const MAX_INTERIOR: usize = 32_768;

/// How the run ended.
pub enum Outcome {
    /// All iterations ran and the outputs were written.
    Finished,
    /// Ctrl-C: a checkpoint and partial outputs were written.
    Interrupted,
}

/// The built-in scene: a wax teddy bear, 64x64, 60 training and 8 test views.
fn default_scene_config() -> SceneConfig {
    let mut c = SceneConfig::new(ShapeKind::Bear, MaterialPreset::Wax);
    c.resolution = 64;
    c.n_train = 60;
    c.n_test = 8;
    c.spp = 32;
    c.seed = 0;
    c
}

fn ensure_default_scene(dir: &Path) -> Result<PathBuf> {
    let ready = [
        "transforms_train.json",
        "transforms_test.json",
        "mesh.ply",
        "meta.json",
    ]
    .iter()
    .all(|f| dir.join(f).is_file());
    if ready {
        println!("built-in scene: reusing {}", dir.display());
        return Ok(dir.to_path_buf());
    }
    let cfg = default_scene_config();
    let tmp = dir.with_extension("partial");
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).with_context(|| format!("removing {}", tmp.display()))?;
    }
    let total = (cfg.n_train + cfg.n_test) as u64;
    println!(
        "built-in scene: path-tracing a wax bear ({}x{}, {} views, {} spp) into {}",
        cfg.resolution,
        cfg.resolution,
        total,
        cfg.spp,
        dir.display()
    );
    let bar = ProgressBar::new(total).with_style(
        ProgressStyle::with_template("  {bar:40} {pos}/{len} views  {elapsed_precise}")
            .expect("template"),
    );
    generate_scene(&tmp, &cfg, |_| bar.inc(1))
        .with_context(|| format!("generating {}", tmp.display()))?;
    bar.finish_and_clear();
    if let Some(parent) = dir.parent() {
        std::fs::create_dir_all(parent)
            .with_context(|| format!("creating {}", parent.display()))?;
    }
    if dir.exists() {
        std::fs::remove_dir_all(dir)
            .with_context(|| format!("removing stale {}", dir.display()))?;
    }
    std::fs::rename(&tmp, dir).with_context(|| format!("moving the scene to {}", dir.display()))?;
    Ok(dir.to_path_buf())
}

/// What `config.json` holds: every setting, plus what was decided and why.
#[derive(Serialize, Deserialize)]
struct ResolvedConfig {
    data: PathBuf,
    resolution: u32,
    preset: String,
    decisions: Vec<Decision>,
    train: TrainConfig,
}

/// Progress saved with each checkpoint (training time is not in the model checkpoint).
#[derive(Serialize, Deserialize, Default)]
struct RunState {
    train_seconds: f64,
}

/// The resolution recorded in a run's `config.json` (none for a bare training configuration,
/// or a file that does not parse: [`resolve_config`] reports that).
fn config_resolution(path: &Path) -> Option<u32> {
    let text = std::fs::read_to_string(path).ok()?;
    serde_json::from_str::<ResolvedConfig>(&text)
        .ok()
        .map(|r| r.resolution)
}

fn resolve_config(
    args: &Args,
    scene: &Scene,
    iterations: usize,
) -> Result<(TrainConfig, Vec<Decision>)> {
    let mut decisions = Vec::new();
    let mut cfg = if let Some(path) = &args.config {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        // Accept both a bare TrainConfig and a config.json written by a previous run.
        match serde_json::from_str::<ResolvedConfig>(&text) {
            Ok(r) => r.train,
            Err(_) => serde_json::from_str::<TrainConfig>(&text)
                .with_context(|| format!("{}: not a gtsr-train configuration", path.display()))?,
        }
    } else {
        let preset = Preset::from_name(&args.preset).with_context(|| {
            format!(
                "unknown preset '{}' (choose from {})",
                args.preset,
                Preset::ALL
                    .iter()
                    .map(|p| p.name())
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        })?;
        let components = match preset.components() {
            Some(c) => c,
            None => {
                let (c, d) = auto_components(&scene_evidence(scene, 30.0)?);
                decisions = d;
                c
            }
        };
        let mut c = TrainConfig::for_iterations(components, iterations);
        // CPU-sized defaults: a few thousand steps on small images.
        // Caps scale with the image size: about 3 surface and 1 interior Gaussian per pixel
        // of one view (64x64: 12k + 4k; 128x128: 49k + 16k), and at most 64k + 32k: a stage-2
        // step's cost grows with the Gaussians, and at 256 px the larger sets (196k + 65k)
        // took twice the time per step for a lower test PSNR at equal training time.
        let pixels = scene.train[0].width() as usize * scene.train[0].height() as usize;
        c.init_surface = (pixels).clamp(2_000, 20_000);
        c.init_interior = (pixels / 2).clamp(1_000, 10_000);
        c.densify.max_surface = (3 * pixels).clamp(10_000, MAX_SURFACE);
        c.densify.max_interior = pixels.clamp(4_000, MAX_INTERIOR);
        // With masks on every training view: start the surface set inside them and weigh the
        // mask term as much as the images. With the paper's random start and 0.1 the surface
        // set on wax_knot (64 px, 1500 steps) stayed a smooth blob over the knot's holes, which
        // the Fresnel weighting hides from C_SH (chamfer 0.042 against 0.021 with both changes,
        // both fused with truncation 0.12; test PSNR 27.4 against 28.5 dB).
        if scene.train.iter().all(|v| v.mask.is_some()) {
            c.init = Init::MaskCarved;
            c.weights.mask = 1.0;
        }
        c
    };
    if args.iterations.is_some() && cfg.iterations != iterations {
        let comps = cfg.components;
        let keep = cfg.clone();
        cfg = TrainConfig::for_iterations(comps, iterations);
        cfg.weights = keep.weights;
        cfg.lr = keep.lr;
        cfg.init = keep.init;
        cfg.init_surface = keep.init_surface;
        cfg.init_interior = keep.init_interior;
        cfg.densify.max_surface = keep.densify.max_surface;
        cfg.densify.max_interior = keep.densify.max_interior;
        cfg.seed = keep.seed;
        cfg.blur_px2 = keep.blur_px2;
    }
    let c = &mut cfg.components;
    for (flag, name, field) in [
        (args.no_interior, "interior", &mut c.interior),
        (args.no_fresnel, "fresnel", &mut c.fresnel),
        (args.no_pbr, "pbr", &mut c.pbr),
        (args.no_multi_view, "multi_view", &mut c.multi_view),
        (args.no_single_view, "single_view", &mut c.single_view),
    ] {
        if flag {
            *field = false;
            decisions.push(Decision {
                component: name.into(),
                enabled: false,
                reason: format!("--no-{}", name.replace('_', "-")),
            });
        }
    }
    if !c.pbr {
        c.smoothness = false;
    }
    if let Some(d) = args.sh_degree {
        c.sh_degree = d;
    }
    if let Some(s) = args.seed {
        cfg.seed = s;
    }
    if let Some(w) = args.opacity_entropy {
        cfg.weights.opacity_entropy = w;
    }
    if args.mask_deficit_only {
        cfg.weights.mask_deficit_only = true;
    }
    if let Some(init) = &args.init {
        cfg.init = match init.as_str() {
            "random" => Init::Random,
            "mask-carved" => Init::MaskCarved,
            "hull-surface" => Init::HullSurface,
            other => bail!("unknown --init '{other}' (random, mask-carved or hull-surface)"),
        };
    }
    cfg.validate()
        .map_err(|e| anyhow::anyhow!("invalid configuration: {e}"))?;
    Ok((cfg, decisions))
}

/// The training views at `--mesh-resolution`, loaded again when that is larger than what was
/// trained on; empty when it is not (the trained views are fused as they are). The default is
/// the training size: a model trained at 64 px and fused at 128 px measured worse on wax_knot
/// (chamfer x1e3 5.9 against 5.4).
fn fusion_views(
    args: &Args,
    data_dir: &Path,
    opts: &LoadOptions,
    scene: &Scene,
) -> Result<Vec<gtsr_data::View>> {
    let trained = scene.train[0].width().max(scene.train[0].height());
    let wanted = args.mesh_resolution.unwrap_or(trained);
    if wanted <= trained {
        return Ok(Vec::new());
    }
    let fusion = load_scene(
        data_dir,
        &LoadOptions {
            downscale: Downscale::MaxSide(wanted),
            ..opts.clone()
        },
    )
    .with_context(|| format!("loading {} for mesh fusion", data_dir.display()))?;
    if fusion.train.len() != scene.train.len()
        || fusion.train[0].width().max(fusion.train[0].height()) <= trained
    {
        return Ok(Vec::new());
    }
    println!(
        "mesh fusion at {}x{} (trained at {}x{})",
        fusion.train[0].width(),
        fusion.train[0].height(),
        scene.train[0].width(),
        scene.train[0].height()
    );
    Ok(fusion.train)
}

/// With a mask on every training view: the masks at the dataset's own resolution (loaded again
/// when training downscales) and their mesh; `None` otherwise.
fn native_masks(
    data_dir: &Path,
    opts: &LoadOptions,
    scene: &Scene,
) -> Result<Option<outputs::NativeMasks>> {
    if scene.train.iter().any(|v| v.mask.is_none()) {
        return Ok(None);
    }
    let t0 = Instant::now();
    let native;
    let views = if matches!(opts.downscale, Downscale::None) {
        &scene.train
    } else {
        native = load_scene(
            data_dir,
            &LoadOptions {
                downscale: Downscale::None,
                ..opts.clone()
            },
        )
        .with_context(|| format!("loading the masks of {} at full size", data_dir.display()))?;
        if native.train.len() != scene.train.len() || native.train.iter().any(|v| v.mask.is_none())
        {
            bail!(
                "{}: the full-size training views differ",
                data_dir.display()
            );
        }
        &native.train
    };
    let masks = outputs::NativeMasks::new(views)?;
    if let Some(m) = &masks {
        println!(
            "masks alone at {}x{}: {} triangles, voxel {:.4} ({:.1} s)",
            views[0].width(),
            views[0].height(),
            m.mesh.triangles.len(),
            m.voxel,
            t0.elapsed().as_secs_f64()
        );
    }
    Ok(masks)
}

/// 3DGS's scene extent: 1.1 times the largest distance of a camera centre from their mean.
fn camera_extent(views: &[ViewTensors]) -> f64 {
    let n = views.len() as f64;
    let centres: Vec<[f64; 3]> = views.iter().map(|v| v.camera.centre()).collect();
    let mean: [f64; 3] = std::array::from_fn(|k| centres.iter().map(|c| c[k]).sum::<f64>() / n);
    let r = centres
        .iter()
        .map(|c| (0..3).map(|k| (c[k] - mean[k]).powi(2)).sum::<f64>().sqrt())
        .fold(0.0, f64::max);
    (1.1 * r).max(1e-3)
}

/// The Burn device of a backend choice (wgpu: the default adapter, a GPU where there is one).
fn compute_device(backend: Backend) -> Device {
    match backend {
        #[cfg(feature = "wgpu")]
        Backend::Wgpu => Device::wgpu(burn::tensor::DeviceKind::DefaultDevice),
        _ => Device::ndarray(),
    }
}

/// Runs everything `args` asks for.
pub fn run(args: &Args) -> Result<Outcome> {
    if args.backend == Backend::Wgpu && !cfg!(feature = "wgpu") {
        bail!(
            "--backend wgpu: this gtsr-train was built without its `wgpu` feature; rebuild with the default features or use --backend ndarray"
        );
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let data_dir = match &args.data {
        Some(d) => d.clone(),
        None => ensure_default_scene(&args.scene_cache)?,
    };
    let blender = data_dir.join("transforms_train.json").is_file();
    // A run's own config.json also gives the resolution it trained at.
    let resolution = args
        .resolution
        .or_else(|| args.config.as_deref().and_then(config_resolution))
        .unwrap_or(if args.data.is_none() { 64 } else { 128 });
    let opts = LoadOptions {
        downscale: Downscale::MaxSide(resolution),
        // Blender/NeRF object scenes are already object-centred; COLMAP scenes are normalised.
        apply_normalisation: !blender,
        ..LoadOptions::default()
    };
    let scene = load_scene(&data_dir, &opts)
        .with_context(|| format!("loading the dataset {}", data_dir.display()))?;
    if scene.train.is_empty() {
        bail!("{}: no training views", data_dir.display());
    }
    let iterations = args
        .iterations
        .unwrap_or(if args.data.is_none() { 1500 } else { 3000 });
    let (config, decisions) = resolve_config(args, &scene, iterations)?;
    for d in &decisions {
        println!(
            "component {}: {} ({})",
            d.component,
            if d.enabled { "on" } else { "off" },
            d.reason
        );
    }
    let resolved = ResolvedConfig {
        data: data_dir.clone(),
        resolution,
        preset: args.preset.clone(),
        decisions,
        train: config.clone(),
    };
    outputs::write_json(&args.out.join("config.json"), &resolved)?;

    let device = compute_device(args.backend).autodiff();
    println!("compute device: {device:?}");
    let views = upload_views(&scene.train, &device)
        .with_context(|| format!("dataset {}", data_dir.display()))?;
    let tests = upload_views(&scene.test, &device)
        .with_context(|| format!("dataset {}", data_dir.display()))?;
    let extent = camera_extent(&views);
    let ckpt_path = args.out.join("checkpoint.safetensors");
    let state_path = args.out.join("run_state.json");
    let timeline_path = args.out.join("error_vs_time.csv");
    let (mut trainer, mut train_seconds, mut timeline) = if args.resume {
        let t = checkpoint::load(&ckpt_path, views, &device)
            .with_context(|| "resuming (--resume)".to_string())?;
        let state: RunState = std::fs::read_to_string(&state_path)
            .ok()
            .and_then(|s| serde_json::from_str(&s).ok())
            .unwrap_or_default();
        let tl = Timeline::read_csv(&timeline_path).unwrap_or_default();
        if let Some(n) = args.iterations
            && n != t.config.iterations
        {
            bail!(
                "--iterations {n} with --resume: the run in {} was started for {} steps and \
                 its schedule (stage 2, learning-rate decay, densification) depends on that; \
                 resume without --iterations, or start a new run",
                args.out.display(),
                t.config.iterations
            );
        }
        println!("resuming at step {} of {}", t.step, t.config.iterations);
        (t, state.train_seconds, tl)
    } else {
        let points = initial_points(&config, &views, &scene.train)?;
        (
            Trainer::new(config, views, extent, &points, &device)?,
            0.0,
            Timeline::new(),
        )
    };
    let iterations = trainer.config.iterations;
    let gt_mesh = match &scene.mesh_path {
        Some(p) => {
            let mut m = gtsr_data::ply::read_ply(p)
                .with_context(|| format!("reading the ground-truth mesh {}", p.display()))?;
            if scene.normalisation_applied {
                for v in m.positions.iter_mut() {
                    *v = scene.normalisation.to_normalised(*v);
                }
            }
            Some(m)
        }
        None => None,
    };
    if let Some(t) = args.depth_crossing
        && !(t > 0.0 && t < 1.0)
    {
        bail!("--depth-crossing must be in (0, 1), got {t}");
    }
    if let Some(k) = args.depth_consistency
        && !(k >= 1 && k <= args.consistency_neighbours)
    {
        bail!(
            "--depth-consistency must be in 1..=--consistency-neighbours ({}), got {k}",
            args.consistency_neighbours
        );
    }
    if !(args.consistency_footprints.is_finite() && args.consistency_footprints > 0.0) {
        bail!(
            "--consistency-footprints must be positive, got {}",
            args.consistency_footprints
        );
    }
    if let Some(f) = args.truncation_footprints
        && !(f.is_finite() && f > 0.0)
    {
        bail!("--truncation-footprints must be positive, got {f}");
    }
    if let Some(f) = args.snap_to_hull
        && !(f.is_finite() && f >= 0.0)
    {
        bail!("--snap-to-hull must be a finite number of footprints >= 0, got {f}");
    }
    if args.silhouettes_only && scene.train.iter().any(|v| v.mask.is_none()) {
        bail!(
            "--silhouettes-only needs a mask on every training view; {} has none on some",
            data_dir.display()
        );
    }
    if args.fusion == crate::Fusion::Carve && scene.train.iter().all(|v| v.mask.is_some()) {
        let tsdf_only = [
            (args.no_silhouette_carving, "--no-silhouette-carving"),
            (args.hull_inside_distance, "--hull-inside-distance"),
            (args.snap_to_hull.is_some(), "--snap-to-hull"),
            (args.depth_consistency.is_some(), "--depth-consistency"),
            (args.truncation.is_some(), "--truncation"),
            (
                args.truncation_footprints.is_some(),
                "--truncation-footprints",
            ),
            (args.voxel.is_some(), "--voxel"),
        ];
        if let Some((_, flag)) = tsdf_only.iter().find(|(on, _)| *on) {
            bail!("{flag} applies to --fusion tsdf (the default is carve)");
        }
    }
    let carve = gtsr_eval::CarveSettings {
        min_views: args.carve_views,
        margin_footprints: args.carve_margin,
        min_free_ratio: args.carve_free_ratio,
    };
    carve
        .validate()
        .map_err(|e| anyhow::anyhow!("--carve-views / --carve-margin / --carve-free-ratio: {e}"))?;
    if let Some(v) = args.carve_voxel
        && !(v.is_finite() && v > 0.0)
    {
        bail!("--carve-voxel must be positive, got {v}");
    }
    let masks = native_masks(&data_dir, &opts, &scene)?;
    let mesh_settings = MeshSettings {
        fusion: args.fusion,
        carve,
        carve_voxel: args.carve_voxel,
        masks,
        voxel: args.voxel,
        truncation: args.truncation,
        truncation_footprints: args.truncation_footprints,
        fusion_views: fusion_views(args, &data_dir, &opts, &scene)?,
        silhouette_carving: !args.no_silhouette_carving,
        fuse_depth: !args.silhouettes_only,
        depth_crossing: args.depth_crossing,
        snap_to_hull: args.snap_to_hull,
        hull_inside_distance: args.hull_inside_distance,
        consistency: args
            .depth_consistency
            .map(|min_agree| gtsr_eval::ConsistencySettings {
                neighbours: args.consistency_neighbours,
                min_agree,
                footprints: args.consistency_footprints,
            }),
        bounds: outputs::hull_bounds(&scene.train)?,
    };

    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        ctrlc::set_handler(move || stop.store(true, Ordering::SeqCst))
            .context("installing the Ctrl-C handler")?;
    }
    // Evenly spaced, but never right after an opacity reset: the default schedule resets every
    // tenth of the run, so ten evenly spaced evaluations all landed on freshly reset models
    // (test PSNR 12 dB at step 600 of 1500 on wax_knot) and the curve showed the resets, not
    // the progress. Such a point moves one step earlier.
    let densify = trainer.config.densify.clone();
    let eval_steps: Vec<usize> = (1..=args.eval_points.max(1))
        .map(|k| (iterations * k).div_ceil(args.eval_points.max(1)))
        .map(|s| {
            if densify.resets_after(s) && s > 1 {
                s - 1
            } else {
                s
            }
        })
        .collect();
    println!(
        "training {} steps on {} views ({}x{}), {} test views; outputs in {}",
        iterations,
        trainer.views.len(),
        trainer.views[0].size().0,
        trainer.views[0].size().1,
        tests.len(),
        args.out.display()
    );
    let bar = ProgressBar::new(iterations as u64).with_style(
        ProgressStyle::with_template(
            "{bar:40} {pos}/{len} [{elapsed_precise} < {eta_precise}] {msg}",
        )
        .expect("template"),
    );
    bar.set_position(trainer.step as u64);
    let log_every = (iterations / 20).max(1);
    // Per stage: summed step times and the number of steps.
    let mut profile = [
        (StepTimes::default(), 0usize),
        (StepTimes::default(), 0usize),
    ];
    while trainer.step < iterations {
        if stop.load(Ordering::SeqCst) {
            bar.abandon_with_message("interrupted");
            println!("Ctrl-C: writing a checkpoint and partial outputs");
            if args.profile {
                write_profile(&profile, &trainer, &args.out)?;
            }
            save_checkpoint(&trainer, &ckpt_path, &state_path, train_seconds)?;
            timeline.write_csv(&timeline_path)?;
            outputs::write_splats(&trainer, &args.out)?;
            println!("checkpoint {}; continue with --resume", ckpt_path.display());
            return Ok(Outcome::Interrupted);
        }
        let t0 = Instant::now();
        let r = trainer.step()?;
        train_seconds += t0.elapsed().as_secs_f64();
        let slot = &mut profile[usize::from(r.stage == 2)];
        slot.0 += &r.times;
        slot.1 += 1;
        bar.set_position(trainer.step as u64);
        bar.set_message(format!(
            "stage {} loss {:.4} gaussians {}+{}",
            r.stage, r.loss, r.counts.0, r.counts.1
        ));
        if trainer.step % log_every == 0 && bar.is_hidden() {
            println!(
                "step {:6}/{iterations}  stage {}  loss {:.4}  gaussians {}+{}  \
                 tile-splats/pass {}  {:.1} s",
                trainer.step,
                r.stage,
                r.loss,
                r.counts.0,
                r.counts.1,
                r.tile_splats / r.passes.max(1) as u64,
                train_seconds
            );
        }
        if eval_steps.contains(&trainer.step) {
            let e = outputs::evaluate(
                &trainer,
                &tests,
                &scene,
                gt_mesh.as_ref(),
                &mesh_settings,
                true,
            )?;
            let (ns, ni) = trainer.model.counts();
            timeline.push(TimelinePoint {
                iteration: trainer.step as u64,
                train_seconds,
                psnr: e.psnr,
                ssim: e.ssim,
                chamfer: e.mesh.as_ref().map(|m| m.chamfer),
                depth_error: e.depth.as_ref().map(|d| d.depth_median_abs),
                gaussians: (ns + ni) as u64,
                label: "test".into(),
            });
            timeline.write_csv(&timeline_path)?;
            say(
                &bar,
                format!(
                    "eval @ {:6}: test PSNR {:.2} dB, SSIM {:.4}{}  (train time {:.0} s, eval {:.1} s)",
                    trainer.step,
                    e.psnr,
                    e.ssim,
                    e.mesh.as_ref().map_or(String::new(), |m| format!(
                        ", chamfer {:.5} (x1e3: {:.2})",
                        m.chamfer,
                        m.chamfer * 1e3
                    )) + &e.depth.as_ref().map_or(String::new(), |d| format!(
                        ", depth error x1e3 median {:.2} bias {:+.2}",
                        d.depth_median_abs * 1e3,
                        d.depth_mean_signed * 1e3
                    )),
                    train_seconds,
                    e.seconds
                ),
            );
        }
        if args.checkpoint_every > 0 && trainer.step % args.checkpoint_every == 0 {
            save_checkpoint(&trainer, &ckpt_path, &state_path, train_seconds)?;
        }
    }
    bar.finish_and_clear();
    if args.profile {
        write_profile(&profile, &trainer, &args.out)?;
    }
    save_checkpoint(&trainer, &ckpt_path, &state_path, train_seconds)?;
    timeline.write_csv(&timeline_path)?;
    outputs::finish(
        &trainer,
        &tests,
        &scene,
        gt_mesh.as_ref(),
        &mesh_settings,
        &timeline,
        train_seconds,
        &args.out,
    )?;
    Ok(Outcome::Finished)
}

/// Prints the profile table of the steps run so far and writes it to `profile.md`.
fn write_profile(profile: &[(StepTimes, usize); 2], trainer: &Trainer, out: &Path) -> Result<()> {
    let table = profile_table(profile, trainer);
    println!("{table}");
    outputs::write_text(&out.join("profile.md"), &table)
}

/// Mean milliseconds per step of each phase, per stage, as a markdown table.
fn profile_table(profile: &[(StepTimes, usize); 2], trainer: &Trainer) -> String {
    let (w, h) = trainer.views[0].size();
    let mut out = format!(
        "Step time by phase, mean ms per step ({w}x{h}, {} rayon threads, blend {:?}).\n\n\
         | phase | stage 1 | stage 2 |\n|---|---:|---:|\n",
        rayon::current_num_threads(),
        gtsr_render_kernels::cpu::BlendPath::default_path()
    );
    let ms = |d: std::time::Duration, n: usize| {
        if n == 0 {
            "-".to_string()
        } else {
            format!("{:.1}", d.as_secs_f64() * 1e3 / n as f64)
        }
    };
    type Get = fn(&StepTimes) -> std::time::Duration;
    let rows: [(&str, Get); 13] = [
        ("kernels: projection", |t| t.kernels.project),
        ("kernels: depth sort and tile binning", |t| {
            t.kernels.sort_bin
        }),
        ("kernels: blend forward", |t| t.kernels.blend_forward),
        ("kernels: blend backward", |t| t.kernels.blend_backward),
        ("kernels: gradient gather and projection backward", |t| {
            t.kernels.gather
        }),
        ("kernels: copies to and from Burn tensors", |t| {
            t.kernels.host_copies
        }),
        ("Burn ops, forward (SH, Fresnel, C_PBR, losses)", |t| {
            let k = &t.kernels;
            t.forward
                .saturating_sub(k.project + k.sort_bin + k.blend_forward + k.host_copies)
        }),
        ("Burn ops, backward (autodiff outside the kernels)", |t| {
            let k = &t.kernels;
            t.backward.saturating_sub(k.blend_backward + k.gather)
        }),
        ("gradient read-out, finiteness, densify statistics", |t| {
            t.gradients
        }),
        ("Adam", |t| t.adam),
        ("densification and pruning", |t| t.densify),
        ("step total", |t| t.total()),
        ("of which in the kernels", |t| t.kernels.total()),
    ];
    for (name, get) in rows {
        out += &format!(
            "| {name} | {} | {} |\n",
            ms(get(&profile[0].0), profile[0].1),
            ms(get(&profile[1].0), profile[1].1)
        );
    }
    out += &format!("| steps | {} | {} |\n", profile[0].1, profile[1].1);
    // The forward pass by part (renders include the kernels' forward phases).
    let mut names: Vec<&str> = Vec::new();
    for (t, _) in profile {
        for (n, _) in &t.forward_parts {
            if !names.contains(n) {
                names.push(n);
            }
        }
    }
    out += "\nForward pass by part, mean ms per step (the renders include the kernels' forward \
            phases; `multi_view` includes the neighbour view's render).\n\n\
            | part | stage 1 | stage 2 |\n|---|---:|---:|\n";
    for name in names {
        let part = |k: usize| {
            let d = profile[k]
                .0
                .forward_parts
                .iter()
                .find(|(n, _)| *n == name)
                .map_or(std::time::Duration::ZERO, |p| p.1);
            ms(d, profile[k].1)
        };
        out += &format!("| {name} | {} | {} |\n", part(0), part(1));
    }
    out
}

/// Prints above the progress bar, or plainly when the bar is hidden (not a terminal).
fn say(bar: &ProgressBar, line: String) {
    if bar.is_hidden() {
        println!("{line}");
    } else {
        bar.println(line);
    }
}

fn save_checkpoint(trainer: &Trainer, ckpt: &Path, state: &Path, train_seconds: f64) -> Result<()> {
    checkpoint::save(trainer, ckpt)?;
    outputs::write_json(state, &RunState { train_seconds })
}
