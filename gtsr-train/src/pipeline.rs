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
use gtsr_eval::MeshConfig;
use gtsr_eval::Timeline;
use gtsr_model::checkpoint;
use gtsr_model::config::{Decision, Preset, TrainConfig, auto_components};
use gtsr_model::trainer::{StepTimes, Trainer, initial_points};
use gtsr_model::views::{ViewTensors, scene_evidence, upload_views};
use indicatif::{ProgressBar, ProgressStyle};
use serde::{Deserialize, Serialize};

use crate::outputs::{self, MeshSettings};
use crate::{Args, Backend};

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
    preset: Preset,
    decisions: Vec<Decision>,
    train: TrainConfig,
    /// Absent in the files of runs from before the mesh settings were recorded.
    #[serde(default)]
    mesh: MeshConfig,
}

/// Progress saved with each checkpoint (training time is not in the model checkpoint).
#[derive(Serialize, Deserialize, Default)]
struct RunState {
    train_seconds: f64,
}

/// What `--config` gives: a run's `config.json`, or a bare training configuration (then the
/// mesh settings are the defaults, and neither the dataset, the resolution nor the preset is
/// given).
struct FileConfig {
    data: Option<PathBuf>,
    train: TrainConfig,
    mesh: MeshConfig,
    resolution: Option<u32>,
    preset: Option<Preset>,
    decisions: Vec<Decision>,
}

fn read_config(path: &Path) -> Result<FileConfig> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    match serde_json::from_str::<ResolvedConfig>(&text) {
        Ok(r) => Ok(FileConfig {
            data: Some(r.data),
            train: r.train,
            mesh: r.mesh,
            resolution: Some(r.resolution),
            preset: Some(r.preset),
            decisions: r.decisions,
        }),
        Err(run_err) => match serde_json::from_str::<TrainConfig>(&text) {
            Ok(train) => Ok(FileConfig {
                data: None,
                train,
                mesh: MeshConfig::default(),
                resolution: None,
                preset: None,
                decisions: Vec::new(),
            }),
            Err(_) => Err(anyhow::anyhow!(
                "{}: not a gtsr-train configuration ({run_err})",
                path.display()
            )),
        },
    }
}

/// Overlays on `base` the settings that `args` gave on the command line: each given id is a
/// path in `config.json` (`train.weights.mask`), and the value at that path comes from the
/// parsed command line.
fn overlay_given(base: &mut serde_json::Value, args: &Args) -> Result<()> {
    let cli = serde_json::json!({ "train": args.train, "mesh": args.mesh });
    for id in &args.given {
        if !(id.starts_with("train.") || id.starts_with("mesh.")) {
            continue;
        }
        let pointer = format!("/{}", id.replace('.', "/"));
        let value = cli
            .pointer(&pointer)
            .with_context(|| format!("setting {id} is not in the configuration"))?;
        *base
            .pointer_mut(&pointer)
            .with_context(|| format!("setting {id} is not in the configuration"))? = value.clone();
    }
    Ok(())
}

/// The run's settings: the scene's defaults (or `--config`), the schedule laid out again when
/// `--iterations` changes the length, then the flags given on the command line.
fn resolve_config(
    args: &Args,
    scene: &Scene,
    file: Option<FileConfig>,
    iterations: usize,
) -> Result<(TrainConfig, MeshConfig, Vec<Decision>)> {
    let mut decisions = Vec::new();
    let (mut train, mesh) = match file {
        Some(f) => {
            let mut t = f.train;
            if args.iterations.is_some() && t.iterations != iterations {
                t.set_schedule(iterations);
            }
            decisions = f.decisions;
            (t, f.mesh)
        }
        None => {
            let components = match args.preset.components() {
                Some(c) => c,
                None => {
                    let (c, d) = auto_components(&scene_evidence(scene, 30.0)?);
                    decisions = d;
                    c
                }
            };
            let view = &scene.train[0];
            let pixels = view.width() as usize * view.height() as usize;
            let masked = scene.train.iter().all(|v| v.mask.is_some());
            (
                TrainConfig::for_views(components, iterations, pixels, masked),
                MeshConfig::default(),
            )
        }
    };
    let mut json = serde_json::json!({ "train": train, "mesh": mesh });
    overlay_given(&mut json, args)?;
    let (given_train, mesh): (TrainConfig, MeshConfig) = (
        serde_json::from_value(json["train"].take()).context("the training settings")?,
        serde_json::from_value(json["mesh"].take()).context("the mesh settings")?,
    );
    // A component switched on the command line is a decision too.
    for id in &args.given {
        if let Some(name) = id.strip_prefix("train.components.")
            && name != "sh_degree"
        {
            let on = serde_json::to_value(given_train.components)?[name] == true;
            decisions.retain(|d| d.component != name);
            decisions.push(Decision {
                component: name.into(),
                enabled: on,
                reason: format!("--{} {on} on the command line", name.replace('_', "-")),
            });
        }
    }
    train = given_train;
    if !train.components.pbr && train.components.smoothness {
        // Smoothness regularises the PBR maps only.
        train.components.smoothness = false;
    }
    train
        .validate()
        .map_err(|e| anyhow::anyhow!("invalid configuration: {e}"))?;
    mesh.validate()
        .map_err(|e| anyhow::anyhow!("invalid mesh settings: {e}"))?;
    Ok((train, mesh, decisions))
}

/// The training views at `--mesh-resolution`, loaded again when that is larger than what was
/// trained on; empty when it is not (the trained views are fused as they are). The default is
/// the training size: depth rendered above the size the model was trained at is no better.
fn fusion_views(
    mesh_resolution: Option<u32>,
    data_dir: &Path,
    opts: &LoadOptions,
    scene: &Scene,
) -> Result<Vec<gtsr_data::View>> {
    let trained = scene.train[0].width().max(scene.train[0].height());
    let wanted = mesh_resolution.unwrap_or(trained);
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

/// Each view's [`ViewTensors::hull_depth`]: `caster`'s mesh (the masks' bound) ray cast from
/// the view's camera at the view's own size (`hosts`: the same views, for their poses),
/// without the pixels on its occluding edges at `edges` footprints (0: all kept;
/// [`gtsr_eval::MeshDepth::occluding_edges`]), and with `occluders` > 0 each view's
/// [`ViewTensors::hull_occluders`] at that many footprints
/// ([`gtsr_eval::MeshDepth::occluders`]).
fn attach_hull_depth(
    views: &mut [ViewTensors],
    hosts: &[gtsr_data::View],
    caster: &gtsr_eval::MeshRaycaster,
    edges: f32,
    occluders: f32,
) {
    for (v, host) in views.iter_mut().zip(hosts) {
        let k = &v.camera;
        let camera = gtsr_data::Camera {
            world_to_camera: host.camera.world_to_camera,
            fx: k.fx as f32,
            fy: k.fy as f32,
            cx: k.cx as f32,
            cy: k.cy as f32,
            width: k.width,
            height: k.height,
        };
        let md = caster.render(&camera);
        let shape = [k.height as usize, k.width as usize];
        let device = v.rays.device();
        let map = |values: Vec<f32>| {
            burn::tensor::Tensor::from_data(burn::tensor::TensorData::new(values, shape), &device)
        };
        v.hull_occluders = (occluders > 0.0).then(|| map(md.occluders(occluders)));
        let cut = if edges > 0.0 {
            md.occluding_edges(edges)
        } else {
            Vec::new()
        };
        let mut depth = md.depth;
        for (d, _) in depth.iter_mut().zip(cut).filter(|(_, e)| *e) {
            *d = 0.0;
        }
        v.hull_depth = Some(map(depth));
    }
}

/// With a mask on every training view: the masks at the dataset's own resolution (loaded again
/// when training downscales), their mesh and, with `shading`, the views' linear radiance at
/// that size (for the shading refinement), and with `edge_hull` the hull of their edges that
/// bounds the extraction, read with `profile` or, without one, the measured profile
/// ([`gtsr_eval::MasksAlone::with_edge_profile`]); `None` otherwise.
fn native_masks(
    data_dir: &Path,
    opts: &LoadOptions,
    scene: &Scene,
    shading: bool,
    edge_hull: bool,
    profile: Option<gtsr_eval::EdgeProfile>,
) -> Result<Option<gtsr_eval::MasksAlone>> {
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
    let radiance: Option<Vec<Vec<f32>>> = shading.then(|| {
        views
            .iter()
            .map(|v| gtsr_eval::shading::view_radiance(v, None))
            .collect()
    });
    let views = views
        .iter()
        .map(|v| {
            v.mask
                .clone()
                .map(|m| (v.camera, m))
                .with_context(|| format!("view {} has no mask", v.name))
        })
        .collect::<Result<Vec<_>>>()?;
    let masks = match (gtsr_eval::MasksAlone::new(views)?, radiance) {
        (Some(m), Some(r)) => Some(
            m.with_radiance(r)
                .with_context(|| format!("the images of {}", data_dir.display()))?,
        ),
        (m, _) => m,
    };
    let Some(mut masks) = masks else {
        return Ok(None);
    };
    println!(
        "masks alone at {}x{}: {} triangles, voxel {:.4} ({:.1} s)",
        masks.views[0].0.width,
        masks.views[0].0.height,
        masks.mesh.triangles.len(),
        masks.voxel,
        t0.elapsed().as_secs_f64()
    );
    if edge_hull {
        let t0 = Instant::now();
        masks = masks
            .with_edge_profile(profile)
            .with_context(|| format!("the masks' edges of {}", data_dir.display()))?;
        if let Some(e) = &masks.edge_hull {
            println!(
                "hull of the masks' edges (edge width {:.4} px, read as {}): {} triangles \
                 ({:.1} s)",
                e.width,
                e.profile,
                e.mesh.triangles.len(),
                t0.elapsed().as_secs_f64()
            );
        }
    }
    Ok(Some(masks))
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
    // The settings: --config, else with --resume those the run in --out recorded.
    let own_config = args.out.join("config.json");
    let config_path = args
        .config
        .clone()
        .or_else(|| (args.resume && own_config.is_file()).then_some(own_config));
    let file = config_path.as_deref().map(read_config).transpose()?;
    // The dataset: --data, else the one that configuration names, else the built-in scene.
    let data_arg = match (&args.data, &file, &config_path) {
        (Some(d), _, _) => Some((d.clone(), "--data".to_string())),
        (None, Some(FileConfig { data: Some(d), .. }), Some(p)) => {
            Some((d.clone(), p.display().to_string()))
        }
        _ => None,
    };
    if let Some((d, from)) = &data_arg {
        if !d.is_dir() {
            bail!(
                "dataset {} (from {from}): {}",
                d.display(),
                if d.exists() {
                    "not a folder (give the dataset's folder)"
                } else {
                    "no such folder"
                }
            );
        }
        if from != "--data" {
            println!("dataset {} (from {from})", d.display());
        }
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let builtin = data_arg.is_none();
    let data_dir = match data_arg {
        Some((d, _)) => d,
        None => ensure_default_scene(&args.scene_cache)?,
    };
    let blender = data_dir.join("transforms_train.json").is_file();
    // A run's own config.json also gives the resolution it trained at.
    let resolution = args
        .resolution
        .or(file.as_ref().and_then(|f| f.resolution))
        .unwrap_or(if builtin { 64 } else { 256 });
    let opts = LoadOptions {
        downscale: Downscale::MaxSide(resolution),
        // Blender/NeRF object scenes are already object-centred; COLMAP scenes are normalised
        // (the outputs are mapped back to the dataset's frame).
        apply_normalisation: !blender,
        ..LoadOptions::default()
    };
    let scene = load_scene(&data_dir, &opts)
        .with_context(|| format!("loading the dataset {}", data_dir.display()))?;
    if scene.train.is_empty() {
        bail!("{}: no training views", data_dir.display());
    }
    let iterations =
        args.iterations
            .map(|n| n as usize)
            .unwrap_or(if builtin { 1500 } else { 3000 });
    // With --config the file's preset is the one the settings came from.
    let preset = file.as_ref().and_then(|f| f.preset).unwrap_or(args.preset);
    if file.is_some() && args.given.iter().any(|id| id == "preset") && preset != args.preset {
        println!(
            "note: --preset {} is ignored with --config, whose components come from {}; switch \
             components with --interior false and the like",
            args.preset.name(),
            preset.name()
        );
    }
    let (config, mesh_config, decisions) = resolve_config(args, &scene, file, iterations)?;
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
        preset,
        decisions,
        train: config.clone(),
        mesh: mesh_config.clone(),
    };

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
        // The last finish's final evaluation is written again when this run finishes.
        let mut tl = Timeline::read_csv(&timeline_path).unwrap_or_default();
        tl.drop_final();
        if let Some(n) = args.iterations.map(|n| n as usize)
            && n != t.config().iterations
        {
            bail!(
                "--iterations {n} with --resume: the run in {} was started for {} steps and \
                 its schedule (stage 2, learning-rate decay, densification) depends on that; \
                 resume without --iterations, or start a new run",
                args.out.display(),
                t.config().iterations
            );
        }
        // The checkpoint trains on with its own settings; settings that say otherwise (a flag,
        // `--config`, an edited config.json) would be silently ignored, and config.json would
        // misrecord the run.
        let differ = differing_fields(
            &serde_json::to_value(t.config())?,
            &serde_json::to_value(&config)?,
        );
        if !differ.is_empty() {
            bail!(
                "--resume: the checkpoint in {} trains on with its own settings, and these \
                 given here differ from them: {}; resume without them (mesh settings may \
                 change), or start a new run",
                args.out.display(),
                differ.join(", ")
            );
        }
        println!(
            "resuming at step {} of {}",
            t.steps_done(),
            t.config().iterations
        );
        (t, state.train_seconds, tl)
    } else {
        let points = match &args.init_mesh {
            Some(path) => points_on_mesh(path, config.init_surface, config.seed, &scene)?,
            None => initial_points(&config, &views, &scene.train)?,
        };
        (
            Trainer::new(config, views, extent, &points, &device)?,
            0.0,
            Timeline::new(),
        )
    };
    outputs::write_json(&args.out.join("config.json"), &resolved)?;
    let iterations = trainer.config().iterations;
    // Where this invocation stops: the end of the schedule, or `--stop-at`.
    let stop_at = match args.stop_at.map(|n| n as usize) {
        Some(n) if n > iterations => bail!(
            "--stop-at {n}: the run's schedule has {iterations} steps; give a step up to that"
        ),
        Some(n) if n < trainer.steps_done() => bail!(
            "--stop-at {n}: the checkpoint in {} is already at step {}",
            args.out.display(),
            trainer.steps_done()
        ),
        Some(n) => n,
        None => iterations,
    };
    // Coarse to fine: the steps before `coarse_until` train on the views at half the size.
    let mut full_views = None;
    if trainer.steps_done() < trainer.config().coarse_until {
        let (w, h) = trainer.views()[0].size();
        let side = (w.max(h) / 2).max(8) as u32;
        let coarse = load_scene(
            &data_dir,
            &LoadOptions {
                downscale: Downscale::MaxSide(side),
                ..opts.clone()
            },
        )
        .with_context(|| format!("loading {} at {side} px", data_dir.display()))?;
        let coarse_views = upload_views(&coarse.train, &device)
            .with_context(|| format!("dataset {} at {side} px", data_dir.display()))?;
        full_views = Some(trainer.views().to_vec());
        trainer
            .set_views(coarse_views)
            .context("the coarse training views")?;
        let (cw, ch) = trainer.views()[0].size();
        println!(
            "coarse to fine: {cw}x{ch} until step {}, then {w}x{h}",
            trainer.config().coarse_until
        );
    }
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
    let masked = scene.train.iter().all(|v| v.mask.is_some());
    if !mesh_config.fuse_depth && !masked {
        bail!(
            "mesh.fuse_depth off (the masks alone) needs a mask on every training view; {} has \
             none on some",
            data_dir.display()
        );
    }
    if mesh_config.fusion == gtsr_eval::Fusion::Carve
        && masked
        && let Some(name) = mesh_config.tsdf_settings_set().first()
    {
        bail!("mesh.{name} applies to --fusion tsdf (the default is carve)");
    }
    // The shading refinement and the carving's shading check read the images as lit by one
    // light at the camera, the PBR component's assumption.
    let shading = (mesh_config.shading_anchor > 0.0 || mesh_config.carve_min_lid_departure > 0.0)
        && trainer.config().components.pbr;
    if mesh_config.shading_anchor > 0.0 && !shading {
        println!("shading refinement: off (the light is not known to be at the camera)");
    }
    let edge_hull = mesh_config.edge_hull && mesh_config.fusion == gtsr_eval::Fusion::Carve;
    let masks = native_masks(
        &data_dir,
        &opts,
        &scene,
        shading,
        edge_hull,
        mesh_config.edge_profile(),
    )?;
    match (trainer.config().weights.hull_depth > 0.0, masks.as_ref()) {
        (false, _) => {}
        (true, None) => println!("hull depth: off (it needs a mask on every training view)"),
        (true, Some(bound)) => {
            let t0 = Instant::now();
            let caster = gtsr_eval::MeshRaycaster::new(bound.bound_mesh(), "the masks' bound")?;
            let mut views = trainer.views().to_vec();
            let weights = &trainer.config().weights;
            let edges = weights.hull_depth_edges as f32;
            let occluders = weights.hull_depth_occluders as f32;
            attach_hull_depth(&mut views, &scene.train, &caster, edges, occluders);
            trainer.set_views(views)?;
            if let Some(full) = full_views.as_mut() {
                attach_hull_depth(full, &scene.train, &caster, edges, occluders);
            }
            println!(
                "hull depth: the masks' bound ray cast from the {} training views ({:.1} s)",
                scene.train.len(),
                t0.elapsed().as_secs_f64()
            );
        }
    }
    let mesh_settings = MeshSettings {
        fusion_views: fusion_views(mesh_config.mesh_resolution, &data_dir, &opts, &scene)?,
        config: mesh_config,
        masks_alone: outputs::score_masks_alone(masks.as_ref(), gt_mesh.as_ref(), &scene)?,
        masks,
        bounds: outputs::hull_bounds(&scene.train)?,
        in_run_shading_rounds: args.eval_shading_rounds,
    };

    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        ctrlc::set_handler(move || stop.store(true, Ordering::SeqCst))
            .context("installing the Ctrl-C handler")?;
    }
    // Evenly spaced, but never right after an opacity reset: the default schedule resets every
    // tenth of the run, so ten evenly spaced evaluations would all land on freshly reset
    // models and the curve would show the resets, not the progress. Such a point moves one
    // step earlier.
    let densify = trainer.config().densify.clone();
    if stop_at < iterations && densify.resets_after(stop_at) {
        println!(
            "note: step {stop_at} is right after an opacity reset; its outputs show the faded \
             model (step {} is the one before)",
            stop_at.saturating_sub(1).max(1)
        );
    }
    let eval_steps: Vec<usize> = (1..=args.eval_points)
        .map(|k| (iterations * k).div_ceil(args.eval_points))
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
        trainer.views().len(),
        trainer.views()[0].size().0,
        trainer.views()[0].size().1,
        tests.len(),
        args.out.display()
    );
    let bar = ProgressBar::new(iterations as u64).with_style(
        ProgressStyle::with_template(
            "{bar:40} {pos}/{len} [{elapsed_precise} < {eta_precise}] {msg}",
        )
        .expect("template"),
    );
    bar.set_position(trainer.steps_done() as u64);
    let log_every = (iterations / 20).max(1);
    // Per stage: summed step times and the number of steps.
    let mut profile = [
        (StepTimes::default(), 0usize),
        (StepTimes::default(), 0usize),
    ];
    while trainer.steps_done() < stop_at {
        if stop.load(Ordering::SeqCst) {
            bar.abandon_with_message("interrupted");
            println!("Ctrl-C: writing a checkpoint and partial outputs");
            if args.profile {
                write_profile(&profile, &trainer, &args.out)?;
            }
            save_checkpoint(&trainer, &ckpt_path, &state_path, train_seconds)?;
            timeline.write_csv(&timeline_path)?;
            outputs::write_splats(&trainer, &scene, &args.out)?;
            println!("checkpoint {}; continue with --resume", ckpt_path.display());
            return Ok(Outcome::Interrupted);
        }
        if trainer.steps_done() >= trainer.config().coarse_until
            && let Some(views) = full_views.take()
        {
            trainer
                .set_views(views)
                .context("the full-size training views")?;
        }
        let t0 = Instant::now();
        let r = trainer.step()?;
        train_seconds += t0.elapsed().as_secs_f64();
        let slot = &mut profile[usize::from(r.stage == 2)];
        slot.0 += &r.times;
        slot.1 += 1;
        bar.set_position(trainer.steps_done() as u64);
        bar.set_message(format!(
            "stage {} loss {:.4} gaussians {}+{}",
            r.stage, r.loss, r.counts.0, r.counts.1
        ));
        if trainer.steps_done() % log_every == 0 && bar.is_hidden() {
            println!(
                "step {:6}/{iterations}  stage {}  loss {:.6}  gaussians {}+{}  \
                 tile-splats/pass {}  {:.1} s",
                trainer.steps_done(),
                r.stage,
                r.loss,
                r.counts.0,
                r.counts.1,
                r.tile_splats / r.passes.max(1) as u64,
                train_seconds
            );
        }
        if eval_steps.contains(&trainer.steps_done()) {
            let e = outputs::evaluate(
                &trainer,
                &tests,
                &scene,
                gt_mesh.as_ref(),
                &mesh_settings,
                true,
            )?;
            timeline.push(e.timeline_point(&trainer, train_seconds, "test"));
            timeline.write_csv(&timeline_path)?;
            say(
                &bar,
                format!(
                    "eval @ {:6}: test PSNR {:.2} dB, SSIM {:.4}{}  (train time {:.0} s, eval {:.1} s)",
                    trainer.steps_done(),
                    e.psnr,
                    e.ssim,
                    e.mesh.as_ref().map_or(String::new(), |m| format!(
                        ", chamfer {:.5} (x1e3: {:.2})",
                        m.chamfer,
                        m.chamfer * 1e3
                    )) + &e.depth_only.as_ref().map_or(String::new(), |m| format!(
                        ", depth alone x1e3 {:.2}",
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
        if args.checkpoint_every > 0 && trainer.steps_done() % args.checkpoint_every == 0 {
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
    if stop_at < iterations {
        println!("stopped at step {stop_at} of {iterations} (--stop-at); continue with --resume");
    }
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
    let (w, h) = trainer.views()[0].size();
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

/// The paths (`weights.mask`) at which two JSON values differ, as `path: a -> b`; at most
/// eight.
fn differing_fields(a: &serde_json::Value, b: &serde_json::Value) -> Vec<String> {
    fn walk(a: &serde_json::Value, b: &serde_json::Value, path: &str, out: &mut Vec<String>) {
        use serde_json::Value;
        match (a, b) {
            (Value::Object(x), Value::Object(y)) => {
                let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
                keys.sort();
                keys.dedup();
                for k in keys {
                    let p = if path.is_empty() {
                        k.clone()
                    } else {
                        format!("{path}.{k}")
                    };
                    walk(
                        x.get(k).unwrap_or(&Value::Null),
                        y.get(k).unwrap_or(&Value::Null),
                        &p,
                        out,
                    );
                }
            }
            _ if a != b && out.len() < 8 => out.push(format!("{path}: {a} -> {b}")),
            _ => {}
        }
    }
    let mut out = Vec::new();
    walk(a, b, "", &mut out);
    out
}

/// `n` points sampled uniformly by area on the mesh at `path` (the dataset's own frame),
/// moved into the trained frame, for `--init-mesh`.
fn points_on_mesh(path: &Path, n: usize, seed: u64, scene: &Scene) -> Result<Vec<[f32; 3]>> {
    let mesh = gtsr_data::ply::read_ply(path)
        .with_context(|| format!("--init-mesh: reading {}", path.display()))?;
    let what = format!("--init-mesh {}", path.display());
    let samples = gtsr_eval::sample_surface(&mesh, n, seed, &what)?;
    println!(
        "initialisation: {n} surface points on {} ({} triangles)",
        path.display(),
        mesh.triangles.len()
    );
    Ok((samples.points.iter())
        .map(|&p| {
            let p = if scene.normalisation_applied {
                scene.normalisation.to_normalised(p)
            } else {
                p
            };
            p.to_array()
        })
        .collect())
}
