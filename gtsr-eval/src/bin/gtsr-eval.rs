//! `gtsr-eval`: mesh and image metrics from the command line.
//!
//! ```text
//! gtsr-eval mesh --pred pred.ply --gt gt.ply [--seen-from SCENE] [--samples 100000] [--threshold 0.01] [--seed 0] [--json out.json]
//! gtsr-eval images --pred renders/ --gt gt/ [--mask] [--json out.json]
//! gtsr-eval plot --out timeline.png run_a.csv run_b.csv
//! ```

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use gtsr_eval::{ImageRef, SEEN_MIN_EYES, chamfer, chamfer_seen, psnr, ssim};

#[derive(Parser)]
#[command(name = "gtsr-eval", about = "Mesh and image metrics for GTSR-rs")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Chamfer distance, F-score and normal consistency between two PLY meshes.
    Mesh {
        /// Predicted mesh (PLY).
        #[arg(long)]
        pred: PathBuf,
        /// Ground-truth mesh (PLY).
        #[arg(long)]
        gt: PathBuf,
        /// Scene folder (Blender or COLMAP) whose training camera centres are the eyes:
        /// ground-truth surface that fewer than `--min-eyes` of them see is left out
        /// (`chamfer_seen`).
        #[arg(long)]
        seen_from: Option<PathBuf>,
        /// With `--seen-from`: how many of the cameras must see a ground-truth sample.
        #[arg(long, default_value_t = SEEN_MIN_EYES)]
        min_eyes: usize,
        /// Area-uniform samples per mesh.
        #[arg(long, default_value_t = 100_000)]
        samples: usize,
        /// F-score distance threshold (mesh units).
        #[arg(long, default_value_t = 0.01)]
        threshold: f32,
        /// Sampling seed.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Also write the metrics as JSON here.
        #[arg(long)]
        json: Option<PathBuf>,
    },
    /// PSNR and SSIM between a predicted and a ground-truth image, or two folders of PNGs
    /// matched by file name.
    Images {
        /// Predicted image or folder.
        #[arg(long)]
        pred: PathBuf,
        /// Ground-truth image or folder.
        #[arg(long)]
        gt: PathBuf,
        /// Restrict both metrics to pixels where the ground truth's alpha is > 0.5.
        #[arg(long)]
        mask: bool,
        /// Also write per-image and mean metrics as JSON here.
        #[arg(long)]
        json: Option<PathBuf>,
    },
    /// Plots timeline CSV files (written by `Timeline::write_csv`) into one PNG, one series
    /// per file, named by the file stem.
    Plot {
        /// Output PNG.
        #[arg(long)]
        out: PathBuf,
        /// Timeline CSV files.
        #[arg(required = true)]
        csv: Vec<PathBuf>,
    },
}

fn plot_command(out: &Path, csv: &[PathBuf]) -> Result<()> {
    let timelines = csv
        .iter()
        .map(|p| gtsr_eval::Timeline::read_csv(p).map_err(anyhow::Error::from))
        .collect::<Result<Vec<_>>>()?;
    let names: Vec<String> = csv
        .iter()
        .map(|p| {
            p.file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default()
        })
        .collect();
    let series: Vec<(&str, &gtsr_eval::Timeline)> =
        names.iter().map(|n| n.as_str()).zip(&timelines).collect();
    gtsr_eval::plot_png(out, &series)?;
    println!("wrote {}", out.display());
    Ok(())
}

fn write_json(path: &Path, value: &serde_json::Value) -> Result<()> {
    let text = serde_json::to_string_pretty(value)?;
    std::fs::write(path, text + "\n").with_context(|| format!("writing {}", path.display()))
}

fn mesh_command(
    pred: &Path,
    gt: &Path,
    seen_from: Option<(&Path, usize)>,
    samples: usize,
    threshold: f32,
    seed: u64,
    json: Option<&Path>,
) -> Result<()> {
    let p = gtsr_data::ply::read_ply(pred)
        .with_context(|| format!("reading predicted mesh {}", pred.display()))?;
    let g = gtsr_data::ply::read_ply(gt)
        .with_context(|| format!("reading ground-truth mesh {}", gt.display()))?;
    let m = match seen_from {
        Some((dir, min_eyes)) => {
            let scene = gtsr_data::load_scene(dir, &gtsr_data::LoadOptions::default())
                .with_context(|| format!("loading the cameras of {}", dir.display()))?;
            let eyes: Vec<_> = scene.train.iter().map(|v| v.camera.centre()).collect();
            chamfer_seen(&p, &g, &eyes, min_eyes, samples, threshold, seed)
        }
        None => chamfer(&p, &g, samples, threshold, seed),
    }
    .with_context(|| format!("comparing {} with {}", pred.display(), gt.display()))?;
    println!(
        "pred:               {} ({} vertices, {} triangles)",
        pred.display(),
        p.positions.len(),
        p.triangles.len()
    );
    println!(
        "gt:                 {} ({} vertices, {} triangles)",
        gt.display(),
        g.positions.len(),
        g.triangles.len()
    );
    println!("samples per mesh:   {}", m.samples);
    if seen_from.is_some() {
        println!("ground truth seen:  {:.4} of its samples", m.gt_seen);
    }
    println!(
        "chamfer:            {:.6} (x1e3: {:.3})",
        m.chamfer,
        m.chamfer * 1e3
    );
    println!("accuracy:           {:.6}", m.accuracy);
    println!("completeness:       {:.6}", m.completeness);
    println!("precision @ {:<7}: {:.4}", m.threshold, m.precision);
    println!("recall    @ {:<7}: {:.4}", m.threshold, m.recall);
    println!("F-score   @ {:<7}: {:.4}", m.threshold, m.fscore);
    println!("normal consistency: {:.4}", m.normal_consistency);
    if let Some(j) = json {
        write_json(j, &serde_json::to_value(m)?)?;
    }
    Ok(())
}

/// Pairs of (name, predicted path, ground-truth path).
fn image_pairs(pred: &Path, gt: &Path) -> Result<Vec<(String, PathBuf, PathBuf)>> {
    match (pred.is_dir(), gt.is_dir()) {
        (false, false) => Ok(vec![(
            gt.display().to_string(),
            pred.to_path_buf(),
            gt.to_path_buf(),
        )]),
        (true, true) => {
            let mut names: Vec<String> = std::fs::read_dir(gt)
                .with_context(|| format!("listing {}", gt.display()))?
                .filter_map(|e| e.ok())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| {
                    let l = n.to_ascii_lowercase();
                    l.ends_with(".png")
                        || l.ends_with(".jpg")
                        || l.ends_with(".jpeg")
                        || l.ends_with(".exr")
                })
                .collect();
            names.sort();
            if names.is_empty() {
                bail!("{}: no PNG/JPEG/EXR images", gt.display());
            }
            let mut pairs = Vec::new();
            for n in names {
                let p = pred.join(&n);
                if !p.is_file() {
                    bail!(
                        "{}: missing (ground truth {} has it)",
                        p.display(),
                        gt.join(&n).display()
                    );
                }
                pairs.push((n.clone(), p, gt.join(&n)));
            }
            Ok(pairs)
        }
        _ => bail!(
            "--pred {} and --gt {} must both be files or both be folders",
            pred.display(),
            gt.display()
        ),
    }
}

fn images_command(pred: &Path, gt: &Path, use_mask: bool, json: Option<&Path>) -> Result<()> {
    let pairs = image_pairs(pred, gt)?;
    let mut rows = Vec::new();
    let (mut sum_p, mut sum_s) = (0.0, 0.0);
    for (name, pp, gp) in &pairs {
        let pi = gtsr_data::image_io::read_image(pp)
            .with_context(|| format!("reading {}", pp.display()))?;
        let gi = gtsr_data::image_io::read_image(gp)
            .with_context(|| format!("reading {}", gp.display()))?;
        let mask = if use_mask {
            Some(gi.alpha.as_deref().with_context(|| {
                format!(
                    "{}: --mask needs an alpha channel, the image has none",
                    gp.display()
                )
            })?)
        } else {
            None
        };
        let ctx = || format!("comparing {} with {}", pp.display(), gp.display());
        let p = psnr(ImageRef::rgb(&pi), ImageRef::rgb(&gi), mask).with_context(ctx)?;
        let s = ssim(ImageRef::rgb(&pi), ImageRef::rgb(&gi), mask).with_context(ctx)?;
        println!("{name}: PSNR {p:.3} dB, SSIM {s:.5}");
        sum_p += p;
        sum_s += s;
        rows.push(serde_json::json!({"name": name, "psnr": if p.is_finite() { Some(p) } else { None }, "ssim": s}));
    }
    let n = pairs.len() as f64;
    println!(
        "mean over {} image(s): PSNR {:.3} dB, SSIM {:.5}",
        pairs.len(),
        sum_p / n,
        sum_s / n
    );
    if let Some(j) = json {
        let mean_p = sum_p / n;
        write_json(
            j,
            &serde_json::json!({
                "images": rows,
                "mean_psnr": if mean_p.is_finite() { Some(mean_p) } else { None },
                "mean_ssim": sum_s / n,
                "masked": use_mask,
            }),
        )?;
    }
    Ok(())
}

fn main() -> Result<()> {
    match Cli::parse().command {
        Command::Mesh {
            pred,
            gt,
            seen_from,
            min_eyes,
            samples,
            threshold,
            seed,
            json,
        } => mesh_command(
            &pred,
            &gt,
            seen_from.as_deref().map(|d| (d, min_eyes)),
            samples,
            threshold,
            seed,
            json.as_deref(),
        ),
        Command::Images {
            pred,
            gt,
            mask,
            json,
        } => images_command(&pred, &gt, mask, json.as_deref()),
        Command::Plot { out, csv } => plot_command(&out, &csv),
    }
}
