//! `cargo xtask bench-recon`: the full model, the paper's three ablations, the PGSR-like
//! baseline and the masks alone at the dataset's resolution on each scene; a markdown table and one combined
//! error-against-time plot.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Args;
use gtsr_eval::{
    ReportRow, Timeline, ground_truth, markdown_table, native_masks_mesh, plot_png, scene_name,
    score_against_ground_truth, seed_summary_table,
};

/// Options of `bench-recon`.
#[derive(Args, Debug)]
pub struct BenchReconArgs {
    /// Scene folders (Blender/NeRF with `mesh.ply`).
    #[arg(long, num_args = 1.., required = true)]
    pub data: Vec<PathBuf>,
    /// Where runs, the table and the plot go.
    #[arg(long, default_value = "bench-recon")]
    pub out: PathBuf,
    /// Training steps per run (gtsr-train's default for a dataset).
    #[arg(long, default_value_t = 3000)]
    pub iterations: usize,
    /// Longest image side (gtsr-train's default for a dataset; `docs/results.md` keeps the
    /// tables at 64 and 128 px).
    #[arg(long, default_value_t = 256)]
    pub resolution: u32,
    /// Methods (gtsr-train presets; `--methods` alone: none); the masks alone are always added.
    #[arg(long, num_args = 0.., default_values_t = ["full".to_string(), "no-pbr".into(), "no-fresnel".into(), "no-interior".into(), "pgsr".into()])]
    pub methods: Vec<String>,
    /// Re-extract and re-evaluate runs already finished in `--out` (same `--iterations`)
    /// instead of training them again: for changes to mesh extraction or evaluation.
    #[arg(long)]
    pub reuse: bool,
    /// The threshold T of each run's extra "crossing depth only" row (the mesh settings
    /// `depth_crossing` T and `silhouette_carving` off: the depth of the surface splat at which
    /// the transmittance falls to T, instead of the blend, fused alone).
    #[arg(long, default_value_t = 0.97)]
    pub depth_crossing: f64,
    /// Leave the crossing-depth rows out.
    #[arg(long)]
    pub no_crossing_rows: bool,
    /// The extra "crossing depth snapped to the hull" row of each run (the mesh settings
    /// `depth_crossing` T, `snap_to_hull` S, `truncation_footprints` F, with the masks): the
    /// crossing depth, where it lies less than S footprints behind the masks' hull replaced by
    /// the hull's, fused with the masks at a truncation of F footprints. S:
    #[arg(long, default_value_t = 2.0)]
    pub snap_footprints: f32,
    /// ... and F.
    #[arg(long, default_value_t = 4.0)]
    pub snap_truncation: f32,
    /// Leave the snapped rows out.
    #[arg(long)]
    pub no_snap_rows: bool,
    /// Training seeds (gtsr-train `--seed`): every method is trained once per seed, seed 0 in
    /// `{scene}/{method}`, another seed N in `{scene}/{method}-seed{N}`. With any seed but 0
    /// the rows name their seed, and a second table gives each method's mean and spread over
    /// the seeds and in how many of them the full model's depth and normals were the better.
    #[arg(long, num_args = 1.., default_values_t = [0u64])]
    pub seeds: Vec<u64>,
    /// Only the trained runs' rows: no other fusions of them, no masks-only rows and no
    /// masks alone (for seed studies of the training).
    #[arg(long)]
    pub training_only: bool,
}

impl BenchReconArgs {
    /// Whether rows name their seed and the seed summary is written: any seed but 0 alone.
    fn names_seeds(&self) -> bool {
        self.seeds != [0]
    }
}

fn target_dir() -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR").map_or_else(|| PathBuf::from("target"), PathBuf::from)
}

/// A gtsr-train run's `metrics.json`.
type Metrics = gtsr_eval::RunMetrics;

/// A table row of a run's mesh and test-view geometry (the rest left empty): for the
/// crossing-depth fusions the test-view depth is the crossing depth the run fused.
fn geometry_row(m: &Metrics, label: String, scene: &str) -> ReportRow {
    ReportRow {
        method: label,
        scene: scene.into(),
        chamfer: m.mesh.as_ref().map(|x| x.chamfer),
        chamfer_whole_gt: m.mesh_whole_gt.as_ref().map(|x| x.chamfer),
        hull_blind: m
            .mesh
            .as_ref()
            .and_then(|x| x.hull_blind.as_ref())
            .map(|b| b.blind),
        fscore: m.mesh.as_ref().map(|x| x.fscore),
        depth_err: m.test_depth.map(|d| d.depth_median_abs),
        depth_bias: m.test_depth.map(|d| d.depth_mean_signed),
        depth_bias_off_edges: m.test_depth.and_then(|d| d.depth_mean_signed_off_edges),
        normal_err_deg: m.test_depth.map(|d| d.normal_mean_deg),
        ..ReportRow::default()
    }
}
/// The masks alone at the dataset's own resolution ([`native_masks_mesh`]), evaluated (with the
/// hull-blind split against themselves) and written to `out/mesh.ply`.
fn masks_row(scene_dir: &Path, name: &str, out: &Path) -> Result<ReportRow> {
    let t0 = Instant::now();
    let (scene, mesh) = native_masks_mesh(scene_dir)?;
    let seconds = t0.elapsed().as_secs_f64();
    let gt = ground_truth(&scene, scene_dir)?;
    let cameras: Vec<_> = scene.train.iter().map(|v| v.camera).collect();
    let (m, whole) = score_against_ground_truth(&mesh, &gt, &cameras, Some(&mesh))?;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    gtsr_data::ply::write_ply(&out.join("mesh.ply"), &mesh)?;
    Ok(ReportRow {
        method: format!(
            "masks alone ({}x{} masks, sub-voxel)",
            cameras[0].width, cameras[0].height
        ),
        scene: name.into(),
        chamfer: Some(m.chamfer),
        chamfer_whole_gt: Some(whole.chamfer),
        hull_blind: m.hull_blind.map(|b| b.blind),
        fscore: Some(m.fscore),
        seconds: Some(seconds),
        ..ReportRow::default()
    })
}

/// The `metrics.json` of a gtsr-train run.
fn read_metrics(run: &Path) -> Result<Metrics> {
    Ok(Metrics::read(&run.join("metrics.json"))?)
}

/// Whether `run` holds a finished gtsr-train run of `iterations` steps.
fn finished(run: &Path, iterations: usize) -> bool {
    run.join("checkpoint.safetensors").is_file()
        && read_metrics(run).is_ok_and(|m| m.iterations == iterations)
}

/// Runs gtsr-train with `method` on `scene_dir` into `out` (with the benchmark's steps and
/// resolution, plus `extra`) and returns its metrics; `what` names the run in errors.
fn run_gtsr_train(
    exe: &Path,
    scene_dir: &Path,
    out: &Path,
    method: &str,
    args: &BenchReconArgs,
    extra: &[&str],
    what: &str,
) -> Result<Metrics> {
    let status = Command::new(exe)
        .arg("--data")
        .arg(scene_dir)
        .arg("--out")
        .arg(out)
        .args(["--preset", method])
        .args(["--iterations", &args.iterations.to_string()])
        .args(["--resolution", &args.resolution.to_string()])
        .args(extra)
        .status()
        .with_context(|| format!("running {}", exe.display()))?;
    if !status.success() {
        bail!("{what}: gtsr-train failed ({status})");
    }
    read_metrics(out)
}

/// Another fusion of a trained run: the copy's folder suffix, the mesh settings it changes in
/// the run's `config.json` (gtsr-eval's `MeshConfig` fields), the row label.
struct Fusion<'a> {
    suffix: &'a str,
    mesh: serde_json::Value,
    label: String,
}

/// The same trained model fused differently, in a copy of the run (`{run}-{suffix}`, its
/// `config.json` changed by `mesh` and read back with `--config`): `silhouette_carving` off
/// fuses the depth maps alone (how much of the mesh the rendered depth carries on its own),
/// `fuse_depth` off the masks alone on the same grid (what the depth adds to them).
fn derived_row(
    exe: &Path,
    scene_dir: &Path,
    run: &Path,
    name: &str,
    method: &str,
    args: &BenchReconArgs,
    Fusion {
        suffix,
        mesh,
        label,
    }: Fusion,
) -> Result<ReportRow> {
    let run_name = run
        .file_name()
        .map_or_else(|| method.to_string(), |n| n.to_string_lossy().into_owned());
    let out = run.with_file_name(format!("{run_name}-{suffix}"));
    if out.exists() {
        std::fs::remove_dir_all(&out).with_context(|| format!("removing {}", out.display()))?;
    }
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    for f in [
        "checkpoint.safetensors",
        "run_state.json",
        "config.json",
        "error_vs_time.csv",
    ] {
        std::fs::copy(run.join(f), out.join(f))
            .with_context(|| format!("copying {} to {}", run.join(f).display(), out.display()))?;
    }
    let config = out.join("config.json");
    let mut json: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(&config)
            .with_context(|| format!("reading {}", config.display()))?,
    )
    .with_context(|| format!("{}: not JSON", config.display()))?;
    for (k, v) in mesh
        .as_object()
        .context("the mesh settings are an object")?
    {
        json["mesh"][k] = v.clone();
    }
    gtsr_data::image_io::write_atomic(&config, serde_json::to_string_pretty(&json)?.as_bytes())
        .with_context(|| format!("writing {}", config.display()))?;
    let t0 = Instant::now();
    let config_arg = config.to_string_lossy().into_owned();
    let extra = ["--resume", "--config", config_arg.as_str()];
    let m = run_gtsr_train(
        exe,
        scene_dir,
        &out,
        method,
        args,
        &extra,
        &format!("{name} / {method} {suffix}"),
    )?;
    Ok(ReportRow {
        seconds: Some(t0.elapsed().as_secs_f64()),
        ..geometry_row(&m, label, name)
    })
}

/// The table (and with seeds other than 0 the seed summary) written to `bench-recon.md`,
/// atomically: after every row, so an interrupted benchmark keeps what it finished.
fn write_report(
    args: &BenchReconArgs,
    rows: &[ReportRow],
    trained: &[(u64, ReportRow)],
) -> Result<String> {
    let mut text = markdown_table(rows);
    if args.names_seeds() {
        text.push_str(
            "\nOver the seeds (mean ± sample standard deviation; the last two columns: in how \
             many of the seeds both ran the full model had the smaller error):\n\n",
        );
        text.push_str(&seed_summary_table(trained, "full"));
    }
    let md = args.out.join("bench-recon.md");
    gtsr_data::image_io::write_atomic(&md, text.as_bytes())
        .with_context(|| format!("writing {}", md.display()))?;
    Ok(text)
}

/// Runs the benchmark.
pub fn run(args: &BenchReconArgs) -> Result<()> {
    if args.seeds.is_empty() {
        bail!("--seeds needs at least one seed");
    }
    if let Some(d) = args
        .seeds
        .iter()
        .enumerate()
        .find_map(|(i, s)| args.seeds[..i].contains(s).then_some(s))
    {
        bail!("--seeds: seed {d} is given twice (each seed trains into one folder)");
    }
    let status = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()))
        .args(["build", "--release", "-p", "gtsr-train"])
        .status()
        .context("running cargo build")?;
    if !status.success() {
        bail!("building gtsr-train failed");
    }
    let exe = target_dir().join("release").join("gtsr-train");
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let mut rows = Vec::new();
    // The trained runs' rows with their seeds and bare method names, for the seed summary.
    let mut trained: Vec<(u64, ReportRow)> = Vec::new();
    let mut series: Vec<(String, Timeline)> = Vec::new();
    for scene_dir in &args.data {
        let name = scene_name(scene_dir);
        let mut full_run: Option<PathBuf> = None;
        for &seed in &args.seeds {
            for method in &args.methods {
                let run_dir = if seed == 0 {
                    method.clone()
                } else {
                    format!("{method}-seed{seed}")
                };
                let label = if args.names_seeds() {
                    format!("{method} (seed {seed})")
                } else {
                    method.clone()
                };
                let out = args.out.join(&name).join(&run_dir);
                // A finished run of the same length is re-extracted and re-evaluated instead
                // of trained again (gtsr-train --resume on a finished run).
                let reuse = args.reuse && finished(&out, args.iterations);
                println!(
                    "== {name} / {label}{}",
                    if reuse {
                        " (reusing the trained run)"
                    } else {
                        ""
                    }
                );
                let seed_arg = seed.to_string();
                let extra: Vec<&str> = if reuse {
                    vec!["--resume"]
                } else {
                    vec!["--seed", &seed_arg]
                };
                let m = run_gtsr_train(
                    &exe,
                    scene_dir,
                    &out,
                    method,
                    args,
                    &extra,
                    &format!("{name} / {label}"),
                )?;
                let row = ReportRow {
                    psnr: Some(m.test_psnr),
                    ssim: Some(m.test_ssim),
                    seconds: Some(m.train_seconds),
                    gaussians: Some((m.surface_gaussians + m.interior_gaussians) as u64),
                    tile_splats_per_step: (m.tile_splats > 0 && m.iterations > 0)
                        .then(|| m.tile_splats as f64 / m.iterations as f64),
                    ..geometry_row(&m, label.clone(), &name)
                };
                trained.push((
                    seed,
                    ReportRow {
                        method: method.clone(),
                        ..row.clone()
                    },
                ));
                rows.push(row);
                // The run fuses its depth alone too (`metrics.json`'s `mesh_depth_only`); like
                // the other fusions of a run, not with `--training-only`.
                if let Some(alone) = m.mesh_depth_only.filter(|_| !args.training_only) {
                    let depth_only = Metrics {
                        mesh: Some(alone),
                        mesh_whole_gt: None,
                        ..m.clone()
                    };
                    rows.push(geometry_row(
                        &depth_only,
                        format!("{label}, depth only (no silhouettes in the fusion)"),
                        &name,
                    ));
                }
                write_report(args, &rows, &trained)?;
                if let Ok(tl) = Timeline::read_csv(&out.join("error_vs_time.csv")) {
                    series.push((format!("{name} {label}"), tl));
                }
                if method == "full" && full_run.is_none() {
                    full_run = Some(out.clone());
                }
                if args.training_only || m.mesh.is_none() {
                    continue;
                }
                let mut fusions = vec![Fusion {
                    suffix: "tsdf",
                    mesh: serde_json::json!({ "fusion": "tsdf" }),
                    label: format!("{label}, TSDF fusion with the masks' hull"),
                }];
                if !args.no_crossing_rows {
                    let t = args.depth_crossing;
                    fusions.push(Fusion {
                        suffix: "crossing-depth-only",
                        mesh: serde_json::json!({
                            "fusion": "tsdf",
                            "silhouette_carving": false,
                            "depth_crossing": t,
                        }),
                        label: format!("{label}, crossing depth only (T = {t}, no silhouettes)"),
                    });
                }
                if !args.no_snap_rows {
                    let (t, sf, tf) = (
                        args.depth_crossing,
                        args.snap_footprints,
                        args.snap_truncation,
                    );
                    fusions.push(Fusion {
                        suffix: "crossing-snapped",
                        mesh: serde_json::json!({
                            "fusion": "tsdf",
                            "depth_crossing": t,
                            "snap_to_hull": sf,
                            "truncation_footprints": tf,
                        }),
                        label: format!(
                            "{label}, crossing depth snapped to the hull (T = {t}; snap {sf}, \
                             truncation {tf} footprints; with the masks)"
                        ),
                    });
                }
                for fusion in fusions {
                    rows.push(derived_row(
                        &exe, scene_dir, &out, &name, method, args, fusion,
                    )?);
                    write_report(args, &rows, &trained)?;
                }
            }
        }
        if args.training_only {
            continue;
        }
        // The masks alone depend on the full run's grid only, not on its seed: the first one.
        if let Some(run) = &full_run {
            println!(
                "== {name} / the full model's extraction without the shading refinement or without its depth"
            );
            for fusion in [
                Fusion {
                    suffix: "no-shading",
                    mesh: serde_json::json!({ "shading_anchor": 0.0 }),
                    label: "the default extraction without the shading refinement \
                            (--shading-anchor 0)"
                        .into(),
                },
                Fusion {
                    suffix: "silhouettes-only",
                    mesh: serde_json::json!({ "fusion": "tsdf", "fuse_depth": false }),
                    label: "masks only, fused as gtsr-train does (the full run's grid, no depth)"
                        .into(),
                },
                Fusion {
                    suffix: "silhouettes-only-inside-distance",
                    mesh: serde_json::json!({
                        "fusion": "tsdf",
                        "fuse_depth": false,
                        "hull_inside_distance": true,
                    }),
                    label: "masks only, the hull's own distance inside (hull_inside_distance)"
                        .into(),
                },
            ] {
                rows.push(derived_row(
                    &exe, scene_dir, run, &name, "full", args, fusion,
                )?);
                write_report(args, &rows, &trained)?;
            }
        }
        println!("== {name} / masks alone");
        rows.push(masks_row(
            scene_dir,
            &name,
            &args.out.join(&name).join("masks-alone"),
        )?);
        write_report(args, &rows, &trained)?;
    }
    let table = write_report(args, &rows, &trained)?;
    let refs: Vec<(&str, &Timeline)> = series.iter().map(|(n, t)| (n.as_str(), t)).collect();
    let png = args.out.join("error_vs_time.png");
    if !refs.is_empty() {
        plot_png(&png, &refs)?;
    }
    println!("{table}");
    println!(
        "table {}; plot {}",
        args.out.join("bench-recon.md").display(),
        png.display()
    );
    Ok(())
}
