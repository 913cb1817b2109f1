//! `cargo xtask bench-recon`: the full model, the paper's three ablations, the PGSR-like
//! baseline and a mask-only visual hull on each scene; a markdown table and one combined
//! error-against-time plot.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Args;
use gtsr_data::{Downscale, LoadOptions, load_scene};
use gtsr_eval::{ReportRow, Timeline, chamfer, markdown_table, plot_png, visual_hull};

/// Options of `bench-recon`.
#[derive(Args, Debug)]
pub struct BenchReconArgs {
    /// Scene folders (Blender/NeRF with `mesh.ply`).
    #[arg(long, num_args = 1.., required = true)]
    pub data: Vec<PathBuf>,
    /// Where runs, the table and the plot go.
    #[arg(long, default_value = "bench-recon")]
    pub out: PathBuf,
    /// Training steps per run.
    #[arg(long, default_value_t = 3000)]
    pub iterations: usize,
    /// Longest image side.
    #[arg(long, default_value_t = 128)]
    pub resolution: u32,
    /// Methods (gtsr-train presets); the visual hull is always added.
    #[arg(long, num_args = 1.., default_values_t = ["full".to_string(), "no-pbr".into(), "no-fresnel".into(), "no-interior".into(), "pgsr".into()])]
    pub methods: Vec<String>,
    /// Visual hull resolution (voxels along the longest side).
    #[arg(long, default_value_t = 192)]
    pub hull_resolution: usize,
}

fn target_dir() -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR").map_or_else(|| PathBuf::from("target"), PathBuf::from)
}

#[derive(serde::Deserialize)]
struct Metrics {
    test_psnr: f64,
    test_ssim: f64,
    surface_gaussians: u64,
    interior_gaussians: u64,
    mesh: Option<MeshM>,
}

#[derive(serde::Deserialize)]
struct MeshM {
    chamfer: f64,
    fscore: f64,
}

fn hull_row(scene_dir: &Path, name: &str, resolution: u32, hull_res: usize) -> Result<ReportRow> {
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
    let gt_path = scene
        .mesh_path
        .clone()
        .with_context(|| format!("{}: no mesh.ply", scene_dir.display()))?;
    let gt = gtsr_data::ply::read_ply(&gt_path)?;
    let (lo, hi) = gt.bounds();
    let pad = 0.15 * (hi - lo).max_element();
    let hull = visual_hull(&views, lo - pad, hi + pad, hull_res)?;
    let radius = 0.5 * (hi - lo).max_element();
    let m = chamfer(&hull, &gt, 50_000, 0.01 * radius, 0)?;
    Ok(ReportRow {
        method: "visual hull (masks only)".into(),
        scene: name.into(),
        chamfer: Some(m.chamfer),
        fscore: Some(m.fscore),
        psnr: None,
        ssim: None,
        wall_seconds: Some(t0.elapsed().as_secs_f64()),
        gaussians: None,
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
        let name = scene_dir
            .file_name()
            .map_or_else(|| "scene".to_string(), |s| s.to_string_lossy().into_owned());
        for method in &args.methods {
            let out = args.out.join(&name).join(method);
            println!("== {name} / {method}");
            let t0 = Instant::now();
            let status = Command::new(&exe)
                .arg("--data")
                .arg(scene_dir)
                .arg("--out")
                .arg(&out)
                .args(["--preset", method])
                .args(["--iterations", &args.iterations.to_string()])
                .args(["--resolution", &args.resolution.to_string()])
                .status()
                .with_context(|| format!("running {}", exe.display()))?;
            let wall = t0.elapsed().as_secs_f64();
            if !status.success() {
                bail!("{name} / {method}: gtsr-train failed ({status})");
            }
            let mpath = out.join("metrics.json");
            let m: Metrics = serde_json::from_str(
                &std::fs::read_to_string(&mpath)
                    .with_context(|| format!("reading {}", mpath.display()))?,
            )
            .with_context(|| format!("parsing {}", mpath.display()))?;
            rows.push(ReportRow {
                method: method.clone(),
                scene: name.clone(),
                chamfer: m.mesh.as_ref().map(|x| x.chamfer),
                fscore: m.mesh.as_ref().map(|x| x.fscore),
                psnr: Some(m.test_psnr),
                ssim: Some(m.test_ssim),
                wall_seconds: Some(wall),
                gaussians: Some(m.surface_gaussians + m.interior_gaussians),
            });
            if let Ok(tl) = Timeline::read_csv(&out.join("error_vs_time.csv")) {
                series.push((format!("{name} {method}"), tl));
            }
        }
        println!("== {name} / visual hull");
        rows.push(hull_row(
            scene_dir,
            &name,
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
