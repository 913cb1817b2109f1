//! The run: settings, data, resume, the training loop with its evaluations and checkpoints,
//! and the outputs.

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use gtsr_data::{Downscale, LoadOptions, load_scene};
use gtsr_eval::Timeline;
use gtsr_model::checkpoint;
use gtsr_model::trainer::{StepReport, StepTimes, Trainer, initial_points};
use gtsr_model::views::upload_views;
use indicatif::{ProgressBar, ProgressStyle};

use crate::args::{Args, Backend, ExposureMode};
use crate::evaluation::{Evaluation, Snapshot, evaluate, score_masks_alone};
use crate::mesh::{MeshSettings, hull_bounds};
use crate::outputs::{finish, write_json, write_splats};
use crate::prepare::{
    Exposure, attach_hull_depth, camera_extent, compute_device, ensure_default_scene, fusion_views,
    load_exposed, native_masks, points_on_mesh,
};
use crate::profile::write_profile;
use crate::settings::{
    FileConfig, ResolvedConfig, RunState, differing_fields, read_config, resolve_config,
};
use crate::settle::Settle;

/// How the run ended.
pub enum Outcome {
    /// All iterations ran and the outputs were written.
    Finished,
    /// Ctrl-C: a checkpoint and partial outputs were written.
    Interrupted,
}

/// What a run reports as it goes, to the observer of [`run_with`].
#[derive(Clone, Copy)]
pub enum RunEvent<'a> {
    /// A training step ran.
    Step {
        /// Steps done, this one included.
        step: usize,
        /// The steps of the schedule.
        of: usize,
        /// The step's loss, Gaussian counts and times.
        report: &'a StepReport,
        /// Training seconds so far (the evaluations not counted).
        train_seconds: f64,
    },
    /// An evaluation along the run finished (also written to `error_vs_time.csv`). It runs
    /// beside the training on a snapshot of the step it names, so it is reported after later
    /// steps (at the latest before the next evaluation starts and before the end).
    Evaluation {
        /// The step it evaluated.
        step: usize,
        /// What it measured.
        evaluation: &'a Evaluation,
        /// Training seconds so far.
        train_seconds: f64,
    },
    /// A checkpoint was written.
    Checkpoint {
        /// The step it holds.
        step: usize,
        /// Where.
        path: &'a Path,
    },
}

/// Runs everything `args` asks for.
pub fn run(args: &Args) -> Result<Outcome> {
    run_with(args, |_| {})
}

/// [`run`], telling `observe` of each step, evaluation and checkpoint as they happen.
pub fn run_with(args: &Args, mut observe: impl FnMut(RunEvent<'_>)) -> Result<Outcome> {
    let started = Instant::now();
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
    let mut scene = load_scene(&data_dir, &opts)
        .with_context(|| format!("loading the dataset {}", data_dir.display()))?;
    if scene.train.is_empty() {
        bail!("{}: no training views", data_dir.display());
    }
    let exposure_mode = args
        .exposure
        .or(file.as_ref().and_then(|f| f.exposure))
        .unwrap_or_default();
    let exposure = match exposure_mode {
        ExposureMode::Auto => Exposure::read(&scene),
        ExposureMode::Off => Exposure::default(),
    };
    exposure.apply(&mut scene);
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
        exposure: exposure_mode,
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
    write_json(&args.out.join("config.json"), &resolved)?;
    if exposure.applies() {
        let (train, test) = exposure.stops();
        write_json(
            &args.out.join("exposure.json"),
            &serde_json::json!({ "train_stops": train, "test_stops": test }),
        )?;
    }
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
        let coarse = load_exposed(
            &data_dir,
            &LoadOptions {
                downscale: Downscale::MaxSide(side),
                ..opts.clone()
            },
            &exposure,
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
    if mesh_config.fusion == gtsr_mesh::Fusion::Carve
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
    let edge_hull = mesh_config.edge_hull && mesh_config.fusion == gtsr_mesh::Fusion::Carve;
    let masks = native_masks(
        &data_dir,
        &opts,
        &scene,
        shading,
        edge_hull,
        mesh_config.edge_profile(),
        &exposure,
    )?;
    match (trainer.config().weights.hull_depth > 0.0, masks.as_ref()) {
        (false, _) => {}
        (true, None) => println!("hull depth: off (it needs a mask on every training view)"),
        (true, Some(bound)) => {
            let t0 = Instant::now();
            let caster =
                gtsr_mesh::raycast::MeshRaycaster::new(bound.bound_mesh(), "the masks' bound")?;
            let mut views = trainer.views().to_vec();
            let weights = &trainer.config().weights;
            let edges = weights.hull_depth_edges as f32;
            let occluders = weights.hull_depth_occluders as f32;
            attach_hull_depth(&mut views, &caster, edges, occluders);
            trainer.set_views(views)?;
            if let Some(full) = full_views.as_mut() {
                attach_hull_depth(full, &caster, edges, occluders);
            }
            println!(
                "hull depth: the masks' bound ray cast from the {} training views ({:.1} s)",
                scene.train.len(),
                t0.elapsed().as_secs_f64()
            );
        }
    }
    let mesh_settings = MeshSettings {
        fusion_views: fusion_views(
            mesh_config.mesh_resolution,
            &data_dir,
            &opts,
            &scene,
            &exposure,
        )?,
        config: mesh_config,
        masks_alone: score_masks_alone(masks.as_ref(), gt_mesh.as_ref(), &scene)?,
        masks,
        bounds: hull_bounds(&scene.train)?,
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
    let centre = mesh_settings
        .bounds
        .map_or(glam::Vec3::ZERO, |(lo, hi)| (lo + hi) * 0.5);
    let mut settle = Settle::new(f64::from(gtsr_mesh::pixels::median_pixel_footprint(
        scene.train.iter().map(|v| &v.camera),
        centre,
    )));
    let (loop_started, train_seconds_before) = (Instant::now(), train_seconds);
    // Per stage: summed step times and the number of steps.
    let mut profile = [
        (StepTimes::default(), 0usize),
        (StepTimes::default(), 0usize),
    ];
    // The evaluations along the run go to a thread of their own, with a rayon pool as large as
    // the training's, beside the training and below it: its threads are in the idle scheduling
    // class ([`yield_to_the_training`]), so they run on the cores the training leaves idle (its
    // one-thread phases, Burn's element-wise work) and never slow its parallel kernels, which
    // wait for their slowest thread; while the training waits for an evaluation, the
    // evaluation has every core. An evaluation reads a snapshot of the model, so it measures
    // what it would in the foreground, and the training does not wait for it (only for the one
    // before, if that is still running). With `--eval-beside-training false`, and under
    // `--profile` (off the step timers), they run in turn with the training.
    let in_turn = !args.eval_beside_training || args.profile;
    let eval_pool = if in_turn || eval_steps.is_empty() || rayon::current_num_threads() < 2 {
        None
    } else {
        Some(
            rayon::ThreadPoolBuilder::new()
                .num_threads(rayon::current_num_threads())
                .thread_name(|_| "gtsr-eval".into())
                .start_handler(|_| yield_to_the_training())
                .build()
                .context("starting the evaluation thread")?,
        )
    };
    let mut recorder = Recorder {
        waited: 0.0,
        evaluated: 0.0,
        timeline: &mut timeline,
        timeline_path: &timeline_path,
        settle: &mut settle,
        bar: &bar,
    };
    let (tests_ref, scene_ref, gt_ref, settings_ref) =
        (tests.as_slice(), &scene, gt_mesh.as_ref(), &mesh_settings);
    let interrupted = std::thread::scope(|s| -> Result<bool> {
        let mut pending: Option<std::thread::ScopedJoinHandle<'_, Background>> = None;
        while trainer.steps_done() < stop_at {
            if stop.load(Ordering::SeqCst) {
                collect(&mut pending, &mut recorder, &mut observe)?;
                return Ok(true);
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
            observe(RunEvent::Step {
                step: trainer.steps_done(),
                of: iterations,
                report: &r,
                train_seconds,
            });
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
                let at = Snapshot::of(&trainer);
                // One evaluation at a time: the one before finishes first.
                collect(&mut pending, &mut recorder, &mut observe)?;
                match &eval_pool {
                    Some(pool) => {
                        pending = Some(s.spawn(move || {
                            yield_to_the_training();
                            let evaluation = pool.install(|| {
                                evaluate(&at, tests_ref, scene_ref, gt_ref, settings_ref, true)
                            });
                            Background {
                                evaluation,
                                at,
                                train_seconds,
                            }
                        }));
                    }
                    None => {
                        let e = evaluate(&at, tests_ref, scene_ref, gt_ref, settings_ref, true)?;
                        recorder.waited += e.seconds;
                        recorder.record(&e, &at, train_seconds, &mut observe)?;
                    }
                }
            }
            if args.checkpoint_every > 0 && trainer.steps_done() % args.checkpoint_every == 0 {
                save_checkpoint(&trainer, &ckpt_path, &state_path, train_seconds)?;
                observe(RunEvent::Checkpoint {
                    step: trainer.steps_done(),
                    path: &ckpt_path,
                });
            }
        }
        collect(&mut pending, &mut recorder, &mut observe)?;
        Ok(false)
    })?;
    let (waited, evaluated) = (recorder.waited, recorder.evaluated);
    if interrupted {
        bar.abandon_with_message("interrupted");
        println!("Ctrl-C: writing a checkpoint and partial outputs");
        if args.profile {
            write_profile(&profile, &trainer, &args.out)?;
        }
        save_checkpoint(&trainer, &ckpt_path, &state_path, train_seconds)?;
        timeline.write_csv(&timeline_path)?;
        write_splats(&trainer, &scene, &args.out)?;
        println!("checkpoint {}; continue with --resume", ckpt_path.display());
        return Ok(Outcome::Interrupted);
    }
    bar.finish_and_clear();
    if let Some(since) = settle.settled_since() {
        println!(
            "the in-run meshes settled after step {since} (each moved less than {} footprints, \
             {} % of it within half of one)",
            crate::settle::SETTLED_FOOTPRINTS,
            100.0 * crate::settle::SETTLED_SHARE
        );
    }
    if args.profile {
        write_profile(&profile, &trainer, &args.out)?;
    }
    save_checkpoint(&trainer, &ckpt_path, &state_path, train_seconds)?;
    observe(RunEvent::Checkpoint {
        step: trainer.steps_done(),
        path: &ckpt_path,
    });
    timeline.write_csv(&timeline_path)?;
    let loop_seconds = loop_started.elapsed().as_secs_f64();
    let final_started = Instant::now();
    finish(
        &trainer,
        &tests,
        &scene,
        gt_mesh.as_ref(),
        &mesh_settings,
        &timeline,
        train_seconds,
        &args.out,
    )?;
    let wall = started.elapsed().as_secs_f64();
    let final_seconds = final_started.elapsed().as_secs_f64();
    println!(
        "time: {wall:.0} s wall: {:.0} s preparing, {:.0} s training, {waited:.0} s waiting for \
         the evaluations along the run ({evaluated:.0} s of evaluating, the rest beside the \
         training), {:.0} s checkpoints and the rest of the loop, {final_seconds:.0} s the final \
         evaluation and outputs",
        wall - loop_seconds - final_seconds,
        train_seconds - train_seconds_before,
        (loop_seconds - (train_seconds - train_seconds_before) - waited).max(0.0),
    );
    if stop_at < iterations {
        println!("stopped at step {stop_at} of {iterations} (--stop-at); continue with --resume");
    }
    Ok(Outcome::Finished)
}

/// What an evaluation in the background hands back: its result, the snapshot it read and
/// the training seconds at its step.
struct Background {
    evaluation: Result<Evaluation>,
    at: Snapshot,
    train_seconds: f64,
}

/// Puts the calling thread in Linux's idle scheduling class (`SCHED_IDLE`): it runs only on a
/// core that no other thread wants. Elsewhere, or where the call is refused, the thread keeps
/// its class and shares the cores as usual.
fn yield_to_the_training() {
    #[cfg(target_os = "linux")]
    {
        let param = libc::sched_param { sched_priority: 0 };
        // SAFETY: pid 0 names the calling thread; the call only changes its scheduling class
        // and reads `param`, which outlives it.
        unsafe {
            libc::sched_setscheduler(0, libc::SCHED_IDLE, &param);
        }
    }
}

/// Waits for the evaluation in the background, if one is running, and records it.
fn collect(
    pending: &mut Option<std::thread::ScopedJoinHandle<'_, Background>>,
    recorder: &mut Recorder<'_>,
    observe: &mut dyn FnMut(RunEvent<'_>),
) -> Result<()> {
    if let Some(handle) = pending.take() {
        let t0 = Instant::now();
        let done = handle
            .join()
            .map_err(|_| anyhow::anyhow!("the evaluation thread panicked"))?;
        recorder.waited += t0.elapsed().as_secs_f64();
        let e = done.evaluation?;
        recorder.record(&e, &done.at, done.train_seconds, observe)?;
    }
    Ok(())
}

/// Where the evaluations along the run are recorded: the error-against-time log (written at
/// each), the settling of the mesh and the progress bar's lines.
struct Recorder<'a> {
    /// Seconds the training waited for the evaluations (all of a foreground one's).
    waited: f64,
    /// Seconds of evaluation, wherever they ran.
    evaluated: f64,
    timeline: &'a mut Timeline,
    timeline_path: &'a Path,
    settle: &'a mut Settle,
    bar: &'a ProgressBar,
}

impl Recorder<'_> {
    /// Records the evaluation `e` of the snapshot `at`, and tells `observe`.
    fn record(
        &mut self,
        e: &Evaluation,
        at: &Snapshot,
        train_seconds: f64,
        observe: &mut dyn FnMut(RunEvent<'_>),
    ) -> Result<()> {
        self.evaluated += e.seconds;
        let mut point = e.timeline_point(at, train_seconds, "test");
        if let Some(mesh) = &e.extracted {
            let change = self.settle.compare(at.step, mesh)?;
            point.mesh_change = change.map(|c| c.distance);
            if let Some(note) = change.map(|c| self.settle.note(&c)) {
                say(self.bar, note);
            }
        }
        self.timeline.push(point);
        self.timeline.write_csv(self.timeline_path)?;
        observe(RunEvent::Evaluation {
            step: at.step,
            evaluation: e,
            train_seconds,
        });
        say(
            self.bar,
            format!(
                "eval @ {:6}: test PSNR {:.2} dB, SSIM {:.4}{}  (train time {:.0} s, eval {:.1} s)",
                at.step,
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
        Ok(())
    }
}

/// Prints above the progress bar, or plainly when the bar is hidden (not a terminal).
pub(crate) fn say(bar: &ProgressBar, line: String) {
    if bar.is_hidden() {
        println!("{line}");
    } else {
        bar.println(line);
    }
}

pub(crate) fn save_checkpoint(
    trainer: &Trainer,
    ckpt: &Path,
    state: &Path,
    train_seconds: f64,
) -> Result<()> {
    checkpoint::save(trainer, ckpt)?;
    write_json(state, &RunState { train_seconds })
}
