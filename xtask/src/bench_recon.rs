//! `cargo xtask bench-recon`: the full model, the paper's three ablations, the PGSR-like
//! baseline and a mask-only visual hull on each scene; a markdown table and one combined
//! error-against-time plot.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Args;
use gtsr_data::ply::TriMesh;
use gtsr_data::{Downscale, LoadOptions, load_scene};
use gtsr_eval::{
    ReportRow, Timeline, markdown_table, plot_png, score_against_ground_truth, visual_hull,
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
    /// Training steps per run (the default is what the README's table used).
    #[arg(long, default_value_t = 1500)]
    pub iterations: usize,
    /// Longest image side (the default is what the README's table used).
    #[arg(long, default_value_t = 64)]
    pub resolution: u32,
    /// Methods (gtsr-train presets; `--methods` alone: none); the visual hull is always added.
    #[arg(long, num_args = 0.., default_values_t = ["full".to_string(), "no-pbr".into(), "no-fresnel".into(), "no-interior".into(), "pgsr".into()])]
    pub methods: Vec<String>,
    /// Re-extract and re-evaluate runs already finished in `--out` (same `--iterations`)
    /// instead of training them again: for changes to mesh extraction or evaluation.
    #[arg(long)]
    pub reuse: bool,
    /// Visual hull resolution (voxels along the longest side of the ground truth's box grown
    /// by 30 %; 640 gives about the voxel gtsr-train's fusion uses on the shared scenes).
    #[arg(long, default_value_t = 640)]
    pub hull_resolution: usize,
    /// The threshold T of each run's extra "crossing depth only" row (gtsr-train
    /// `--depth-crossing T --no-silhouette-carving`: the depth of the surface splat at which
    /// the transmittance falls to T, instead of the blend, fused alone).
    #[arg(long, default_value_t = 0.97)]
    pub depth_crossing: f64,
    /// Leave the crossing-depth rows out.
    #[arg(long)]
    pub no_crossing_rows: bool,
    /// The extra "crossing depth snapped to the hull" row of each run (gtsr-train
    /// `--depth-crossing T --snap-to-hull S --truncation-footprints F`, with the masks): the
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
}

fn target_dir() -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR").map_or_else(|| PathBuf::from("target"), PathBuf::from)
}

#[derive(serde::Deserialize)]
struct Metrics {
    iterations: usize,
    train_seconds: f64,
    test_psnr: f64,
    test_ssim: f64,
    surface_gaussians: u64,
    interior_gaussians: u64,
    mesh: Option<MeshM>,
    mesh_whole_gt: Option<MeshM>,
    #[serde(default)]
    test_depth: Option<gtsr_eval::DepthMetrics>,
    /// Absent in runs from before gtsr-train counted them.
    #[serde(default)]
    tile_splats: Option<u64>,
}

#[derive(serde::Deserialize)]
struct MeshM {
    chamfer: f64,
    fscore: f64,
}

/// A scene folder's name, as the tables and output folders use it.
pub(crate) fn scene_name(scene_dir: &Path) -> String {
    scene_dir
        .file_name()
        .map_or_else(|| "scene".to_string(), |s| s.to_string_lossy().into_owned())
}

/// The scene's ground-truth `mesh.ply`; an error naming the folder when it has none.
pub(crate) fn ground_truth(scene: &gtsr_data::Scene, scene_dir: &Path) -> Result<TriMesh> {
    let gt_path = scene
        .mesh_path
        .clone()
        .with_context(|| format!("{}: no mesh.ply", scene_dir.display()))?;
    Ok(gtsr_data::ply::read_ply(&gt_path)?)
}

/// The visual hull of the training masks, evaluated and written to `out/mesh.ply`.
fn hull_row(
    scene_dir: &Path,
    name: &str,
    out: &Path,
    resolution: u32,
    hull_res: usize,
) -> Result<ReportRow> {
    let t0 = Instant::now();
    let opts = LoadOptions {
        downscale: Downscale::MaxSide(resolution),
        ..LoadOptions::default()
    };
    let scene = load_scene(scene_dir, &opts)?;
    let views: Vec<_> = scene
        .train
        .iter()
        .filter_map(|v| v.mask.as_ref().map(|m| (v.camera, m.as_slice())))
        .collect();
    if views.is_empty() {
        bail!("{}: the visual hull needs masks", scene_dir.display());
    }
    let gt = ground_truth(&scene, scene_dir)?;
    let (lo, hi) = gt.bounds();
    let pad = 0.15 * (hi - lo).max_element();
    let hull = visual_hull(&views, lo - pad, hi + pad, hull_res)?;
    let eyes: Vec<_> = scene.train.iter().map(|v| v.camera.centre()).collect();
    let (m, whole) = score_against_ground_truth(&hull, &gt, &eyes)?;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    gtsr_data::ply::write_ply(&out.join("mesh.ply"), &hull)?;
    Ok(ReportRow {
        method: "visual hull (masks only)".into(),
        scene: name.into(),
        chamfer: Some(m.chamfer),
        chamfer_whole_gt: Some(whole.chamfer),
        fscore: Some(m.fscore),
        seconds: Some(t0.elapsed().as_secs_f64()),
        ..ReportRow::default()
    })
}

/// The `metrics.json` of a gtsr-train run.
fn read_metrics(run: &Path) -> Result<Metrics> {
    let path = run.join("metrics.json");
    serde_json::from_str(
        &std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?,
    )
    .with_context(|| format!("parsing {}", path.display()))
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

/// Another fusion of a trained run: the copy's folder suffix, gtsr-train's flags, the row label.
struct Fusion<'a> {
    suffix: &'a str,
    flags: Vec<String>,
    label: String,
}

/// The same trained model fused differently, in a copy of the run (`{method}-{suffix}`, with
/// gtsr-train's `flag`): `--no-silhouette-carving` fuses the depth maps alone (how much of the
/// mesh the rendered depth carries on its own), `--silhouettes-only` the masks alone on the
/// same grid (what the depth adds to them).
fn derived_row(
    exe: &Path,
    scene_dir: &Path,
    run: &Path,
    name: &str,
    method: &str,
    args: &BenchReconArgs,
    Fusion {
        suffix,
        flags,
        label,
    }: Fusion,
) -> Result<ReportRow> {
    let out = run.with_file_name(format!("{method}-{suffix}"));
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
    let t0 = Instant::now();
    let mut extra = vec!["--resume"];
    extra.extend(flags.iter().map(String::as_str));
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
        method: label,
        scene: name.into(),
        chamfer: m.mesh.as_ref().map(|x| x.chamfer),
        chamfer_whole_gt: m.mesh_whole_gt.as_ref().map(|x| x.chamfer),
        fscore: m.mesh.as_ref().map(|x| x.fscore),
        // The test-view depth of the fusion (the crossing depth with `--depth-crossing`).
        depth_err: m.test_depth.map(|d| d.depth_median_abs),
        depth_bias: m.test_depth.map(|d| d.depth_mean_signed),
        normal_err_deg: m.test_depth.map(|d| d.normal_mean_deg),
        seconds: Some(t0.elapsed().as_secs_f64()),
        ..ReportRow::default()
    })
}

/// Runs the benchmark.
pub fn run(args: &BenchReconArgs) -> Result<()> {
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
    let mut series: Vec<(String, Timeline)> = Vec::new();
    for scene_dir in &args.data {
        let name = scene_name(scene_dir);
        for method in &args.methods {
            let out = args.out.join(&name).join(method);
            // A finished run of the same length is re-extracted and re-evaluated instead of
            // trained again (gtsr-train --resume on a finished run).
            let reuse = args.reuse && finished(&out, args.iterations);
            println!(
                "== {name} / {method}{}",
                if reuse {
                    " (reusing the trained run)"
                } else {
                    ""
                }
            );
            let extra: &[&str] = if reuse { &["--resume"] } else { &[] };
            let m = run_gtsr_train(
                &exe,
                scene_dir,
                &out,
                method,
                args,
                extra,
                &format!("{name} / {method}"),
            )?;
            rows.push(ReportRow {
                method: method.clone(),
                scene: name.clone(),
                chamfer: m.mesh.as_ref().map(|x| x.chamfer),
                chamfer_whole_gt: m.mesh_whole_gt.as_ref().map(|x| x.chamfer),
                fscore: m.mesh.as_ref().map(|x| x.fscore),
                depth_err: m.test_depth.map(|d| d.depth_median_abs),
                depth_bias: m.test_depth.map(|d| d.depth_mean_signed),
                normal_err_deg: m.test_depth.map(|d| d.normal_mean_deg),
                psnr: Some(m.test_psnr),
                ssim: Some(m.test_ssim),
                seconds: Some(m.train_seconds),
                gaussians: Some(m.surface_gaussians + m.interior_gaussians),
                tile_splats_per_step: m
                    .tile_splats
                    .filter(|_| m.iterations > 0)
                    .map(|t| t as f64 / m.iterations as f64),
            });
            if let Ok(tl) = Timeline::read_csv(&out.join("error_vs_time.csv")) {
                series.push((format!("{name} {method}"), tl));
            }
            if m.mesh.is_some() {
                let mut fusions = vec![Fusion {
                    suffix: "depth-only",
                    flags: vec!["--no-silhouette-carving".into()],
                    label: format!("{method}, depth only (no silhouettes in the fusion)"),
                }];
                if !args.no_crossing_rows {
                    let t = args.depth_crossing;
                    fusions.push(Fusion {
                        suffix: "crossing-depth-only",
                        flags: vec![
                            "--no-silhouette-carving".into(),
                            "--depth-crossing".into(),
                            t.to_string(),
                        ],
                        label: format!("{method}, crossing depth only (T = {t}, no silhouettes)"),
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
                        flags: vec![
                            "--depth-crossing".into(),
                            t.to_string(),
                            "--snap-to-hull".into(),
                            sf.to_string(),
                            "--truncation-footprints".into(),
                            tf.to_string(),
                        ],
                        label: format!(
                            "{method}, crossing depth snapped to the hull (T = {t}; snap {sf}, \
                             truncation {tf} footprints; with the masks)"
                        ),
                    });
                }
                for fusion in fusions {
                    rows.push(derived_row(
                        &exe, scene_dir, &out, &name, method, args, fusion,
                    )?);
                }
            }
        }
        if args.methods.iter().any(|m| m == "full") {
            println!("== {name} / the full model's fusion without its depth");
            let run = args.out.join(&name).join("full");
            for fusion in [
                Fusion {
                    suffix: "silhouettes-only",
                    flags: vec!["--silhouettes-only".into()],
                    label: "masks only, fused as gtsr-train does (the full run's grid, no depth)"
                        .into(),
                },
                Fusion {
                    suffix: "silhouettes-only-inside-distance",
                    flags: vec!["--silhouettes-only".into(), "--hull-inside-distance".into()],
                    label: "masks only, the hull's own distance inside (--hull-inside-distance)"
                        .into(),
                },
            ] {
                rows.push(derived_row(
                    &exe, scene_dir, &run, &name, "full", args, fusion,
                )?);
            }
        }
        println!("== {name} / visual hull");
        rows.push(hull_row(
            scene_dir,
            &name,
            &args.out.join(&name).join("visual-hull"),
            args.resolution,
            args.hull_resolution,
        )?);
    }
    let table = markdown_table(&rows);
    let md = args.out.join("bench-recon.md");
    std::fs::write(&md, &table).with_context(|| format!("writing {}", md.display()))?;
    let refs: Vec<(&str, &Timeline)> = series.iter().map(|(n, t)| (n.as_str(), t)).collect();
    let png = args.out.join("error_vs_time.png");
    if !refs.is_empty() {
        plot_png(&png, &refs)?;
    }
    println!("{table}");
    println!("table {}; plot {}", md.display(), png.display());
    Ok(())
}
