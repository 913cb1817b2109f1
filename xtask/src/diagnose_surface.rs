//! `cargo xtask diagnose-surface`: where a trained run's surface Gaussians lie against the
//! ground truth, how opaque they are there, and which loss term pushes their opacity and their
//! position along the outward normal which way. For the development scenes only: the ground
//! truth diagnoses, it never trains.
//!
//! Each surface centre is binned by its signed distance to the ground truth (positive outside,
//! along the closest triangle's outward normal), in training-pixel footprints. Per bin: the
//! number of centres, their opacity percentiles, and per loss term the mean descent direction
//! (minus the gradient, summed over the diagnosed views) on the opacity logit (positive: the
//! term makes the Gaussian more opaque) and on the centre's displacement along the outward
//! normal (positive: the term pushes it outward). Every term is differentiated on its own
//! forward pass, at the run's last step's settings.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use burn::tensor::Device;
use clap::Args;
use glam::Vec3;
use gtsr_data::{Downscale, LoadOptions, load_scene};
use gtsr_eval::SignedDistance;
use gtsr_eval::tsdf::median_pixel_footprint;
use gtsr_model::checkpoint;
use gtsr_model::gaussians::{ParamKind, host_vec, logistic};
use gtsr_model::views::upload_views;

use crate::bench_recon::{ground_truth, scene_name};

/// Options of `diagnose-surface`.
#[derive(Args, Debug)]
pub struct DiagnoseSurfaceArgs {
    /// The gtsr-train output folder (its `checkpoint.safetensors` and `config.json`).
    #[arg(long)]
    pub run: PathBuf,
    /// The scene it was trained on (Blender/NeRF with `mesh.ply`).
    #[arg(long)]
    pub data: PathBuf,
    /// Training views differentiated (the run's last steps' views, going back).
    #[arg(long, default_value_t = 8)]
    pub views: usize,
    /// Where the markdown report goes (default: `diagnosis.md` in the run folder).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Also compare, on every training view, the pixels that look into a concavity the masks
    /// cannot see (the ground truth more than this many footprints behind the masks' own
    /// depth) with the pixels around them: the image, the run's residuals and its depth there
    /// (0: skip).
    #[arg(long, default_value_t = 0.0)]
    pub concavity_gap: f32,
    /// With `--concavity-gap`: refine the masks' mesh with the normals the training views
    /// observe (`refine.rs`), once with the run's and once with the truth's, at each
    /// of these anchors (scene units), and score the results.
    #[arg(long, num_args = 0..)]
    pub refine_anchors: Vec<f32>,
    /// With `--concavity-gap`: take the run's normals from the surface splat at which the
    /// transmittance first falls to this threshold (the front of the surface set,
    /// `Model::render_depth_crossing`) instead of the blended normal.
    #[arg(long)]
    pub front_normals: Option<f64>,
}

/// Bin edges in training-pixel footprints (signed distance to the ground truth).
const EDGES: [f32; 9] = [-4.0, -2.0, -1.0, -0.5, -0.25, 0.25, 0.5, 1.0, 2.0];

fn bin_of(sd_fp: f32) -> usize {
    EDGES.iter().take_while(|e| sd_fp >= **e).count()
}

fn bin_label(b: usize) -> String {
    match b {
        0 => format!("< {}", EDGES[0]),
        b if b == EDGES.len() => format!(">= {}", EDGES[EDGES.len() - 1]),
        b => format!("[{}, {})", EDGES[b - 1], EDGES[b]),
    }
}

fn percentile(sorted: &[f32], q: f64) -> f32 {
    if sorted.is_empty() {
        return f32::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

#[derive(serde::Deserialize)]
struct RunConfig {
    resolution: u32,
}

/// Runs the diagnosis and prints (and writes) the report.
#[allow(deprecated)] // burn-ndarray: deprecated upstream, kept as the CPU backend.
pub fn run(args: &DiagnoseSurfaceArgs) -> Result<()> {
    if args.views == 0 {
        bail!("--views must be at least 1");
    }
    let cfg_path = args.run.join("config.json");
    let cfg: RunConfig = serde_json::from_str(
        &std::fs::read_to_string(&cfg_path)
            .with_context(|| format!("reading {}", cfg_path.display()))?,
    )
    .with_context(|| format!("parsing {}", cfg_path.display()))?;
    let scene = load_scene(
        &args.data,
        &LoadOptions {
            downscale: Downscale::MaxSide(cfg.resolution),
            ..LoadOptions::default()
        },
    )
    .with_context(|| format!("loading {}", args.data.display()))?;
    let gt = ground_truth(&scene, &args.data)?;
    let sdf = SignedDistance::new(&gt, "ground-truth mesh")?;
    let device = Device::ndarray().autodiff();
    let views = upload_views(&scene.train, &device)?;
    let ckpt = args.run.join("checkpoint.safetensors");
    let mut trainer = checkpoint::load(&ckpt, views, &device)
        .with_context(|| format!("loading {}", ckpt.display()))?;
    let last = trainer.steps_done().saturating_sub(1);
    if !trainer.is_stage2(last) {
        bail!("{}: the run has not reached stage 2", args.run.display());
    }
    let footprint = median_pixel_footprint(scene.train.iter().map(|v| &v.camera), Vec3::ZERO);

    let surface = trainer.model().surface.to_host();
    let (means, _) = surface.column(ParamKind::Means).context("means")?;
    let means: Vec<Vec3> = means.chunks_exact(3).map(Vec3::from_slice).collect();
    let opacity = host_vec(logistic(
        trainer.model().surface.req(ParamKind::Opacity).clone(),
    ));
    let n = means.len();
    let located: Vec<(f32, Vec3)> = means.iter().map(|p| sdf.query(*p)).collect();
    let bins: Vec<usize> = located.iter().map(|(d, _)| bin_of(d / footprint)).collect();
    let nb = EDGES.len() + 1;

    // Per term: per bin, summed descent on the logit and along the normal.
    let mut term_names: Vec<&'static str> = Vec::new();
    let mut sums: Vec<Vec<(f64, f64)>> = Vec::new();
    for k in 0..args.views {
        let step = last.saturating_sub(k);
        let count = trainer.forward(step)?.terms.len();
        for t in 0..count {
            let f = trainer.forward(step)?;
            let (name, term) = f.terms[t].clone();
            drop(f);
            let grads = term.backward();
            let s = &trainer.model().surface;
            let g_logit = s
                .req(ParamKind::Opacity)
                .grad(&grads)
                .map(host_vec)
                .unwrap_or_else(|| vec![0.0; n]);
            let g_means = s
                .req(ParamKind::Means)
                .grad(&grads)
                .map(host_vec)
                .unwrap_or_else(|| vec![0.0; 3 * n]);
            let ti = match term_names.iter().position(|x| *x == name) {
                Some(i) => i,
                None => {
                    term_names.push(name);
                    sums.push(vec![(0.0, 0.0); nb]);
                    term_names.len() - 1
                }
            };
            for i in 0..n {
                let g = Vec3::from_slice(&g_means[3 * i..3 * i + 3]);
                let normal = located[i].1;
                let b = bins[i];
                sums[ti][b].0 -= g_logit[i] as f64;
                sums[ti][b].1 -= g.dot(normal) as f64;
            }
        }
        println!("view {} of {} differentiated", k + 1, args.views);
    }

    let mut counts = vec![0usize; nb];
    let mut op_bins: Vec<Vec<f32>> = vec![Vec::new(); nb];
    for i in 0..n {
        counts[bins[i]] += 1;
        op_bins[bins[i]].push(opacity[i]);
    }
    for o in op_bins.iter_mut() {
        o.sort_by(f32::total_cmp);
    }
    let mut md = format!(
        "# Surface diagnosis of {} ({}, step {})\n\n{} surface Gaussians; training-pixel \
         footprint {:.4}; {} views differentiated. Signed distance to the ground truth in \
         footprints (+: outside). Descent = minus the gradient summed over the views, mean per \
         Gaussian of the bin: on the opacity logit (+: more opaque) and along the outward normal \
         (+: outward), x1e6.\n\n",
        args.run.display(),
        scene_name(&args.data),
        trainer.steps_done(),
        n,
        footprint,
        args.views
    );
    md.push_str("| signed distance (fp) | Gaussians | share | opacity p10 / p50 / p90 |");
    for t in &term_names {
        md.push_str(&format!(" {t} logit / normal |"));
    }
    md.push('\n');
    md.push_str("|---|---:|---:|---|");
    for _ in &term_names {
        md.push_str("---|");
    }
    md.push('\n');
    for b in 0..nb {
        if counts[b] == 0 {
            continue;
        }
        let o = &op_bins[b];
        md.push_str(&format!(
            "| {} | {} | {:.1} % | {:.3} / {:.3} / {:.3} |",
            bin_label(b),
            counts[b],
            100.0 * counts[b] as f64 / n as f64,
            percentile(o, 0.1),
            percentile(o, 0.5),
            percentile(o, 0.9)
        ));
        for s in &sums {
            let c = counts[b] as f64;
            md.push_str(&format!(
                " {:+.2} / {:+.2} |",
                1e6 * s[b].0 / c,
                1e6 * s[b].1 / c
            ));
        }
        md.push('\n');
    }
    // Opacity-weighted: where the opacity is.
    let total_op: f64 = opacity.iter().map(|o| *o as f64).sum();
    md.push_str("\nOpacity mass per bin (sum of opacities, share): ");
    let parts: Vec<String> = (0..nb)
        .filter(|b| counts[*b] > 0)
        .map(|b| {
            let m: f64 = op_bins[b].iter().map(|o| *o as f64).sum();
            format!("{} {:.1} %", bin_label(b), 100.0 * m / total_op.max(1e-12))
        })
        .collect();
    md.push_str(&parts.join(", "));
    md.push('\n');
    if args.concavity_gap > 0.0 {
        md.push_str(&concavities(
            &trainer,
            &scene,
            &gt,
            &args.data,
            args.concavity_gap,
            &args.refine_anchors,
            args.front_normals,
        )?);
    }
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| args.run.join("diagnosis.md"));
    gtsr_data::image_io::write_atomic(&out, md.as_bytes())
        .with_context(|| format!("writing {}", out.display()))?;
    println!("{md}");
    println!("written to {}", out.display());
    Ok(())
}

/// Pixel classes of [`concavities`].
const CLASSES: [&str; 3] = [
    "into a concavity (truth beyond the gap)",
    "around them (8-neighbours, truth within half a footprint of the masks)",
    "elsewhere on the object (truth within half a footprint of the masks)",
];

/// Per class: pixels, and sums of the image's mean channel, the C_SH and C_PBR absolute
/// residuals and the signed C_SH one (render minus image; mean over channels), the run's depth
/// and the truth's behind the masks' depth (footprints), and the pixels where the run's depth
/// lies beyond the gap.
#[derive(Clone, Copy, Default)]
struct ClassSums {
    pixels: usize,
    image: f64,
    res_sh: f64,
    res_pbr: f64,
    signed_sh: f64,
    model_gap: f64,
    model_beyond: usize,
    truth_gap: f64,
}

/// The concavity report of [`DiagnoseSurfaceArgs::concavity_gap`]: on every training view,
/// the masks' mesh (native masks, [`gtsr_eval::MasksAlone`]) and the ground truth are ray cast
/// through each pixel; a pixel looks into a concavity the masks cannot see when the truth lies
/// more than `gap` footprints (`z / fx`) behind the masks' depth there. Those pixels are
/// compared with their 8-neighbours on the flush surface and with the rest of the object: if
/// the run fits them as well as their neighbours while its depth stays at the masks', the
/// images do not contradict a lid over the concavity. The report also bins the normal error of
/// the masks' mesh and of the run by how far the truth lies behind the masks' depth, and with
/// `anchors` adds [`refine_rows`].
fn concavities(
    trainer: &gtsr_model::Trainer,
    scene: &gtsr_data::Scene,
    gt: &gtsr_data::ply::TriMesh,
    data: &std::path::Path,
    gap: f32,
    anchors: &[f32],
    front_normals: Option<f64>,
) -> Result<String> {
    let native = load_scene(
        data,
        &LoadOptions {
            downscale: Downscale::None,
            ..LoadOptions::default()
        },
    )
    .with_context(|| format!("loading {} at its own size", data.display()))?;
    let masks: Vec<(gtsr_data::Camera, Vec<f32>)> = native
        .train
        .iter()
        .filter_map(|v| v.mask.clone().map(|m| (v.camera, m)))
        .collect();
    if masks.len() != native.train.len() {
        bail!(
            "{}: the concavity report needs a mask on every training view",
            data.display()
        );
    }
    let alone = gtsr_eval::MasksAlone::new(masks)?.context("the masks are empty")?;
    let hull_caster = gtsr_eval::MeshRaycaster::new(&alone.mesh, "masks' mesh")?;
    let gt_caster = gtsr_eval::MeshRaycaster::new(gt, "ground-truth mesh")?;
    let model = trainer.model().detached();
    let last = trainer.steps_done().saturating_sub(1);
    let opts = trainer.render_options(last, false);
    let mut sums = [ClassSums::default(); 3];
    let mut kept_maps: Vec<NormalMaps> = Vec::new();
    let mut normal_bins: Vec<(Vec<f32>, Vec<f32>)> =
        vec![Default::default(); NORMAL_BINS.len() + 1];
    for (v, data) in trainer.views().iter().zip(&scene.train) {
        let mask = data
            .mask
            .as_deref()
            .context("a training view without a mask")?;
        let (w, h) = (data.camera.width as usize, data.camera.height as usize);
        let truth_maps = gt_caster.render(&data.camera);
        let hull_maps = hull_caster.render(&data.camera);
        let (truth, hull) = (&truth_maps.depth, &hull_maps.depth);
        let r = model.render(&v.camera, &v.rays, opts)?;
        let c_sh = host_vec(r.c_sh);
        let c_pbr = r.c_pbr.map(host_vec);
        let g = model.render_depth(&v.camera, &v.rays)?;
        let depth = host_vec(g.depth);
        let run_normal = match front_normals {
            Some(t) => host_vec(model.render_depth_crossing(&v.camera, &v.rays, t)?.normal),
            None => host_vec(g.normal),
        };
        let fx = data.camera.fx;
        let on = |p: usize| mask[p] > 0.5 && truth[p] > 0.0 && hull[p] > 0.0;
        let gap_fp = |p: usize| (truth[p] - hull[p]) * fx / hull[p];
        if !anchors.is_empty() {
            let flat =
                |n: &[Vec3]| -> Vec<f32> { n.iter().flat_map(|n| [n.x, n.y, n.z]).collect() };
            kept_maps.push((
                run_normal.clone(),
                flat(&truth_maps.normal),
                hull.clone(),
                flat(&hull_maps.normal),
            ));
        }
        for p in (0..w * h).filter(|p| on(*p)) {
            let b = NORMAL_BINS.iter().take_while(|e| gap_fp(p) >= **e).count();
            let t = truth_maps.normal[p];
            let angle = |n: Vec3| -> Option<f32> {
                let l = n.length();
                (l.is_finite() && l > 0.0)
                    .then(|| (n / l).dot(t).clamp(-1.0, 1.0).acos().to_degrees())
            };
            let rn = Vec3::from_slice(&run_normal[3 * p..3 * p + 3]);
            if let (Some(a_hull), Some(a_run)) = (angle(hull_maps.normal[p]), angle(rn)) {
                normal_bins[b].0.push(a_hull);
                normal_bins[b].1.push(a_run);
            }
        }
        let class_of = |p: usize| -> Option<usize> {
            if !on(p) {
                return None;
            }
            let g = gap_fp(p);
            if g > gap {
                return Some(0);
            }
            if g.abs() > 0.5 {
                return None;
            }
            let (i, j) = ((p % w) as i64, (p / w) as i64);
            let near = (-1..=1i64).any(|dj| {
                (-1..=1i64).any(|di| {
                    let (x, y) = (i + di, j + dj);
                    x >= 0
                        && y >= 0
                        && (x as usize) < w
                        && (y as usize) < h
                        && on(y as usize * w + x as usize)
                        && gap_fp(y as usize * w + x as usize) > gap
                })
            });
            Some(if near { 1 } else { 2 })
        };
        for p in 0..w * h {
            let Some(c) = class_of(p) else { continue };
            let s = &mut sums[c];
            let px = &data.rgb[3 * p..3 * p + 3];
            let res = |img: &[f32]| -> f64 {
                (0..3)
                    .map(|k| (img[3 * p + k].clamp(0.0, 1.0) - px[k]).abs() as f64)
                    .sum::<f64>()
                    / 3.0
            };
            s.pixels += 1;
            s.image += px.iter().map(|x| *x as f64).sum::<f64>() / 3.0;
            s.res_sh += res(&c_sh);
            s.res_pbr += c_pbr.as_deref().map_or(f64::NAN, res);
            s.signed_sh += (0..3)
                .map(|k| (c_sh[3 * p + k].clamp(0.0, 1.0) - px[k]) as f64)
                .sum::<f64>()
                / 3.0;
            let model_gap = (depth[p] - hull[p]) * fx / hull[p];
            s.model_gap += model_gap as f64;
            s.model_beyond += usize::from(model_gap > gap);
            s.truth_gap += gap_fp(p) as f64;
        }
    }
    let mut md = format!(
        "\n## Pixels that look into a concavity the masks cannot see\n\nEvery training view \
         ({} views); the truth more than {gap} footprints behind the masks' depth. Means per \
         pixel: the image (mean channel), the run's absolute residuals and its signed C_SH one \
         (render minus image), the run's depth and the truth behind the masks' depth, in \
         footprints, and the share of pixels where the run's depth lies beyond the gap.\n\n\
         | pixels | count | image | C_SH residual | C_PBR residual | C_SH signed | run's depth \
         behind the masks | truth behind the masks | run beyond the gap |\n\
         |---|---:|---:|---:|---:|---:|---:|---:|---:|\n",
        scene.train.len()
    );
    for (name, s) in CLASSES.iter().zip(&sums) {
        let n = s.pixels.max(1) as f64;
        md.push_str(&format!(
            "| {name} | {} | {:.4} | {:.4} | {:.4} | {:+.4} | {:+.2} | {:+.2} | {:.1} % |\n",
            s.pixels,
            s.image / n,
            s.res_sh / n,
            s.res_pbr / n,
            s.signed_sh / n,
            s.model_gap / n,
            s.truth_gap / n,
            100.0 * s.model_beyond as f64 / n
        ));
    }
    md.push_str(&format!(
        "\nNormal error (degrees, median / mean) of the masks' mesh and of the run's {} \
         against the truth's, on the same pixels, by where the truth lies behind the masks' \
         depth (footprints):\n\n| truth behind the masks | pixels | masks' mesh | run |\n\
         |---|---:|---:|---:|\n",
        front_normals.map_or("blended normal".to_string(), |t| format!(
            "normal at its front (transmittance {t})"
        ))
    ));
    for (b, (hull, run)) in normal_bins.iter_mut().enumerate() {
        if hull.is_empty() {
            continue;
        }
        let label = match b {
            0 => format!("< {}", NORMAL_BINS[0]),
            b if b == NORMAL_BINS.len() => format!(">= {}", NORMAL_BINS[b - 1]),
            b => format!("[{}, {})", NORMAL_BINS[b - 1], NORMAL_BINS[b]),
        };
        let stats = |v: &mut Vec<f32>| -> (f32, f64) {
            v.sort_by(f32::total_cmp);
            let mean = v.iter().map(|x| *x as f64).sum::<f64>() / v.len() as f64;
            (percentile(v, 0.5), mean)
        };
        let (hm, ha) = stats(hull);
        let (rm, ra) = stats(run);
        md.push_str(&format!(
            "| {label} | {} | {hm:.1} / {ha:.1} | {rm:.1} / {ra:.1} |\n",
            hull.len()
        ));
    }
    if !anchors.is_empty() {
        md.push_str(&refine_rows(scene, gt, &alone.mesh, &kept_maps, anchors)?);
    }
    Ok(md)
}

/// Per training view: the run's normal map, the truth's, the masks' mesh depth and its normals.
type NormalMaps = (Vec<f32>, Vec<f32>, Vec<f32>, Vec<f32>);

/// The refinement rows of [`DiagnoseSurfaceArgs::refine_anchors`]: the masks' mesh refined
/// (`refine.rs`) by the normals of the run, of the truth, of the masks' mesh itself (what the
/// refinement gives without any new information), and of the run only where it departs from
/// the masks' own by more than 8 degrees; inward only and with a quarter footprint outward.
fn refine_rows(
    scene: &gtsr_data::Scene,
    gt: &gtsr_data::ply::TriMesh,
    hull: &gtsr_data::ply::TriMesh,
    maps: &[NormalMaps],
    anchors: &[f32],
) -> Result<String> {
    use crate::refine::{
        FaceNormals, NormalView, RefineSettings, observed_normals, refine_with_normals,
    };
    let cameras: Vec<gtsr_data::Camera> = scene.train.iter().map(|v| v.camera).collect();
    let footprint = median_pixel_footprint(cameras.iter(), Vec3::ZERO);
    let score = |mesh: &gtsr_data::ply::TriMesh| -> Result<String> {
        let (seen, _) = gtsr_eval::score_against_ground_truth(mesh, gt, &cameras, Some(hull))?;
        Ok(format!(
            "{:.3} | {:.3} | {:.3} | {:.2}",
            1e3 * seen.chamfer,
            1e3 * seen.accuracy,
            1e3 * seen.completeness,
            1e3 * seen.hull_blind.map_or(f64::NAN, |b| b.blind)
        ))
    };
    let observed = |normal: fn(&NormalMaps) -> &[f32]| -> Result<FaceNormals> {
        let views: Vec<NormalView<'_>> = cameras
            .iter()
            .zip(maps)
            .map(|(c, m)| NormalView {
                camera: c,
                normal: normal(m),
                mesh_depth: &m.2,
            })
            .collect();
        observed_normals(hull, &views, 1, REFINE_MIN_COS)
    };
    let run = observed(|m| &m.0)?;
    let truth = observed(|m| &m.1)?;
    let own = observed(|m| &m.3)?;
    let mut departing = own.clone();
    let cos = 8f32.to_radians().cos();
    for f in 0..departing.normal.len() {
        if run.weight[f] > 0.0 && own.weight[f] > 0.0 && run.normal[f].dot(own.normal[f]) < cos {
            departing.normal[f] = run.normal[f];
            departing.weight[f] = run.weight[f];
        }
    }
    let sources = [
        ("run", &run),
        ("truth", &truth),
        ("masks' own", &own),
        ("run beyond 8 deg of the masks' own", &departing),
    ];
    let mut md = String::from(
        "\nThe masks' mesh refined by the observed normals (`xtask/src/refine.rs`; chamfer, \
         accuracy, completeness, hull-blind, x1e3; moves in scene units):\n\n| normals | \
         anchor | outward (footprints) | chamfer | accuracy | completeness | hull-blind | mean \
         / largest inward move |\n|---|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    md.push_str(&format!(
        "| none (masks alone) | | | {} | |\n",
        score(hull)?
    ));
    for outward in [0.0f32, 0.25] {
        for (label, targets) in sources {
            for &anchor in anchors {
                let settings = RefineSettings {
                    anchor,
                    max_outward: outward * footprint,
                    ..RefineSettings::default()
                };
                let (mesh, d) = refine_with_normals(hull, targets, &settings)?;
                let mean = d.iter().map(|v| *v as f64).sum::<f64>() / d.len().max(1) as f64;
                let most = d.iter().fold(0.0f32, |a, v| a.min(*v));
                let row = format!(
                    "| {label} | {anchor} | {outward} | {} | {mean:.4} / {most:.4} |\n",
                    score(&mesh)?
                );
                println!("{}", row.trim_end());
                md.push_str(&row);
            }
        }
    }
    Ok(md)
}

/// Least cosine between a face and the view direction for a view's normal to count in the
/// refinement; above it each view counts with that cosine as its weight.
const REFINE_MIN_COS: f32 = 0.2;

/// Bin edges (footprints) of the truth's depth behind the masks' depth, for the normal table.
const NORMAL_BINS: [f32; 5] = [-0.25, 0.25, 0.5, 1.0, 3.0];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bins_cover_the_line_in_order() {
        assert_eq!(bin_of(-10.0), 0);
        assert_eq!(bin_of(-4.0), 1);
        assert_eq!(bin_of(-0.3), 4);
        assert_eq!(bin_of(0.0), 5);
        assert_eq!(bin_of(0.25), 6);
        assert_eq!(bin_of(5.0), EDGES.len());
        assert_eq!(bin_label(0), "< -4");
        assert_eq!(bin_label(5), "[-0.25, 0.25)");
        assert_eq!(bin_label(EDGES.len()), ">= 2");
        let sorted = [0.1, 0.2, 0.3, 0.4, 0.5];
        assert_eq!(percentile(&sorted, 0.5), 0.3);
        assert!(percentile(&[], 0.5).is_nan());
    }
}
