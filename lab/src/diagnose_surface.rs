//! `cargo lab diagnose-surface`: where a trained run's surface Gaussians lie against the
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
use gtsr_mesh::pixels::median_pixel_footprint;
use gtsr_mesh::raycast::SignedDistance;
use gtsr_model::checkpoint;
use gtsr_model::config::LossWeights;
use gtsr_model::gaussians::{ParamKind, host_vec};
use gtsr_model::views::upload_views;

use gtsr_eval::{ground_truth, scene_name};

use crate::concavity::{ConcavityArgs, percentile};

/// Options of `diagnose-surface`.
#[derive(Args, Debug)]
pub struct DiagnoseSurfaceArgs {
    /// The gtsr-train output folder (its `checkpoint.safetensors`, and its `config.json` for the
    /// resolution and the loss weights: in a copy of the folder, edit the weights to see how
    /// other terms would push the same model).
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
    /// Splits the Gaussians by where their nearest ground truth lies: farther than this from
    /// the masks' mesh (at the masks' own resolution, scene units; the hull-blind part, where
    /// a lid over a concavity the masks cannot see lies far outside the truth) or not.
    #[arg(long)]
    pub hull_blind: Option<f32>,
    /// With `--hull-blind`: also differentiate this many probes, surface Gaussians placed flat
    /// on the hull-blind ground truth (seeded, area-uniform; one footprint wide, opacity 0.5,
    /// the colour of the nearest trained Gaussian): whether the terms would keep a surface
    /// on the true inside, or push it out to the lid. The probes join the model for the
    /// diagnosis only.
    #[arg(long, default_value_t = 0)]
    pub probes: usize,
    /// The concavity comparison.
    #[command(flatten)]
    pub concavity: ConcavityArgs,
}

/// The rows of one trained model that a table reports on.
struct Group {
    label: &'static str,
    members: Vec<usize>,
}

/// Appends `count` probes to the trainer's surface set: flat Gaussians on the hull-blind part of
/// `gt` (farther than `gap` from `hull`), one `footprint` wide, opacity 0.5, each with the
/// colour and material of the trained surface Gaussian nearest to it. Returns their indices.
fn add_probes(
    trainer: &mut gtsr_model::trainer::Trainer,
    gt: &gtsr_data::ply::TriMesh,
    hull: &SignedDistance<'_>,
    gap: f32,
    footprint: f32,
    count: usize,
) -> Result<Vec<usize>> {
    let samples = gtsr_mesh::mesh::sample_surface(gt, 50 * count, 7, "ground-truth mesh")?;
    let spots: Vec<(Vec3, Vec3)> = (samples.points.iter().zip(&samples.normals))
        .filter(|(p, _)| hull.query(**p).0.abs() > gap)
        .take(count)
        .map(|(p, n)| (*p, *n))
        .collect();
    if spots.is_empty() {
        bail!("no ground truth lies farther than {gap} from the masks' mesh: no probe to place");
    }
    let device = trainer.model().device();
    let mut host = trainer.model().surface.to_host();
    let (means, _) = host.column(ParamKind::Means).context("means")?;
    let means: Vec<Vec3> = means.chunks_exact(3).map(Vec3::from_slice).collect();
    let floor = trainer.model().surface_opacity_floor;
    let first = host.n;
    for (p, normal) in &spots {
        let nearest = (0..means.len())
            .min_by(|a, b| {
                means[*a]
                    .distance_squared(*p)
                    .total_cmp(&means[*b].distance_squared(*p))
            })
            .context("an empty surface set")?;
        let mut row = host.row(nearest);
        let q = glam::Quat::from_rotation_arc(Vec3::Z, normal.normalize());
        for (k, (kind, _, _)) in host.columns.iter().enumerate() {
            match kind {
                ParamKind::Means => row[k] = p.to_array().to_vec(),
                ParamKind::Rotations => row[k] = vec![q.w, q.x, q.y, q.z],
                ParamKind::LogScales => {
                    row[k] = vec![footprint.ln(), footprint.ln(), (0.05 * footprint).ln()]
                }
                ParamKind::Opacity => {
                    // The logit whose floored opacity is 0.5.
                    let o = ((0.5 - floor) / (1.0 - floor)).clamp(1e-3, 1.0 - 1e-3);
                    row[k] = vec![gtsr_model::gaussians::logit(o) as f32];
                }
                _ => {}
            }
        }
        host.push_row(&row);
    }
    let last = host.n;
    trainer.model_mut().surface = host.to_device(&device);
    Ok((first..last).collect())
}

/// Bin edges in training-pixel footprints (signed distance to the ground truth).
const EDGES: [f32; 12] = [
    -4.0, -2.0, -1.0, -0.5, -0.25, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0,
];

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

#[derive(serde::Deserialize)]
struct RunConfig {
    resolution: u32,
    train: Option<RunTrain>,
}

#[derive(serde::Deserialize)]
struct RunTrain {
    weights: LossWeights,
}

/// Errors unless every value is finite and positive (`positive`) or at least 0, naming `what`.
fn all_finite(values: &[f32], positive: bool, what: &str) -> Result<()> {
    let ok = |v: f32| v.is_finite() && if positive { v > 0.0 } else { v >= 0.0 };
    if !values.iter().all(|v| ok(*v)) {
        bail!(
            "{what} must be finite and {}",
            if positive { "positive" } else { ">= 0" }
        );
    }
    Ok(())
}

/// Runs the diagnosis and prints (and writes) the report.
#[allow(deprecated)] // burn-ndarray: deprecated upstream, kept as the CPU backend.
pub fn run(args: &DiagnoseSurfaceArgs) -> Result<()> {
    if args.views == 0 {
        bail!("--views must be at least 1");
    }
    if !(args.concavity.concavity_gap.is_finite() && args.concavity.concavity_gap >= 0.0) {
        bail!("--concavity-gap must be a finite number >= 0");
    }
    all_finite(&args.concavity.refine_anchors, true, "--refine-anchors")?;
    all_finite(&args.concavity.refine_noise, false, "--refine-noise")?;
    all_finite(&args.concavity.refine_depth, true, "--refine-depth lengths")?;
    all_finite(
        &args.concavity.offset_thresholds,
        false,
        "--offset-thresholds",
    )?;
    if args
        .concavity
        .offset_crossing
        .is_some_and(|t| !(t > 0.0 && t < 1.0))
    {
        bail!("--offset-crossing must lie strictly between 0 and 1");
    }
    let truth_degraded: Vec<f32> = (args.concavity.offset_truth_scale.iter())
        .chain(&args.concavity.offset_truth_noise)
        .copied()
        .collect();
    all_finite(
        &truth_degraded,
        false,
        "--offset-truth-scale and --offset-truth-noise",
    )?;
    if (!args.concavity.refine_depth.is_empty() || args.concavity.offset_crossing.is_some())
        && args.concavity.refine_anchors.is_empty()
    {
        bail!("--refine-depth and --offset-crossing need --refine-anchors");
    }
    if args
        .concavity
        .front_normals
        .is_some_and(|t| !(t > 0.0 && t < 1.0))
    {
        bail!("--front-normals must lie strictly between 0 and 1");
    }
    if args.concavity.concavity_gap == 0.0
        && (!args.concavity.refine_anchors.is_empty()
            || args.concavity.front_normals.is_some()
            || args.concavity.depth_normals)
    {
        bail!("--refine-anchors, --front-normals and --depth-normals need --concavity-gap");
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
    if let Some(t) = cfg.train {
        trainer
            .set_loss_weights(t.weights)
            .with_context(|| format!("the loss weights of {}", cfg_path.display()))?;
    }
    let last = trainer.steps_done().saturating_sub(1);
    if !trainer.is_stage2(last) {
        bail!("{}: the run has not reached stage 2", args.run.display());
    }
    let footprint = median_pixel_footprint(scene.train.iter().map(|v| &v.camera), Vec3::ZERO);

    if args.probes > 0 && args.hull_blind.is_none() {
        bail!("--probes needs --hull-blind");
    }
    let masks = match args.hull_blind {
        Some(_) => Some(gtsr_eval::native_masks_mesh(&args.data)?.1),
        None => None,
    };
    let hull = (masks.as_ref())
        .map(|m| SignedDistance::new(m, "masks' mesh"))
        .transpose()?;
    let probes = match (&hull, args.hull_blind) {
        (Some(h), Some(gap)) if args.probes > 0 => {
            add_probes(&mut trainer, &gt, h, gap, footprint, args.probes)?
        }
        _ => Vec::new(),
    };
    let probe_count = probes.len();
    let surface = trainer.model().surface.to_host();
    let (means, _) = surface.column(ParamKind::Means).context("means")?;
    let means: Vec<Vec3> = means.chunks_exact(3).map(Vec3::from_slice).collect();
    let opacity = host_vec(trainer.model().opacities(&trainer.model().surface));
    let n = means.len();
    // The view-dependent colour each Gaussian carries: the root of the summed squares of its
    // higher SH coefficients (0 at degree 0).
    let view_dependence: Vec<f32> = match surface.column(ParamKind::ShRest) {
        Some((rest, w)) => rest
            .chunks_exact(w)
            .map(|r| r.iter().map(|c| c * c).sum::<f32>().sqrt())
            .collect(),
        None => vec![0.0; n],
    };
    let located: Vec<(f32, Vec3)> = means.iter().map(|p| sdf.query(*p)).collect();
    let bins: Vec<usize> = located.iter().map(|(d, _)| bin_of(d / footprint)).collect();
    let groups = match (&hull, args.hull_blind) {
        (Some(hull), Some(gap)) => {
            // Each trained Gaussian by its nearest truth (the point `d` along the normal).
            let (blind, seen): (Vec<usize>, Vec<usize>) = (0..n - probe_count).partition(|&i| {
                let (d, normal) = located[i];
                hull.query(means[i] - d * normal).0.abs() > gap
            });
            let mut g = vec![
                Group {
                    label: "nearest truth the masks place",
                    members: seen,
                },
                Group {
                    label: "nearest truth hull-blind",
                    members: blind,
                },
            ];
            if probe_count > 0 {
                g.push(Group {
                    label: "probes on the hull-blind truth",
                    members: probes,
                });
            }
            g
        }
        _ => vec![Group {
            label: "all surface Gaussians",
            members: (0..n).collect(),
        }],
    };

    // Per term: per Gaussian, summed descent on the logit and along the normal.
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
                    sums.push(vec![(0.0, 0.0); n]);
                    term_names.len() - 1
                }
            };
            for i in 0..n {
                let g = Vec3::from_slice(&g_means[3 * i..3 * i + 3]);
                sums[ti][i].0 -= g_logit[i] as f64;
                sums[ti][i].1 -= g.dot(located[i].1) as f64;
            }
        }
        println!("view {} of {} differentiated", k + 1, args.views);
    }

    let mut md = format!(
        "# Surface diagnosis of {} ({}, step {})\n\n{} surface Gaussians{}; training-pixel \
         footprint {:.4}; {} views differentiated. Signed distance to the ground truth in \
         footprints (+: outside). Descent = minus the gradient summed over the views, mean per \
         Gaussian of the bin: on the opacity logit (+: more opaque) and along the outward normal \
         of the nearest truth (+: outward, away from it), x1e6. View-dependent SH: the mean \
         root of the summed squares of the higher SH coefficients (what lets a lid show a \
         different colour to each view).\n",
        args.run.display(),
        scene_name(&args.data),
        trainer.steps_done(),
        n - probe_count,
        if probe_count > 0 {
            format!(" and {probe_count} probes")
        } else {
            String::new()
        },
        footprint,
        args.views
    );
    for group in &groups {
        md.push_str(&group_table(
            group,
            &bins,
            &opacity,
            &view_dependence,
            &term_names,
            &sums,
        ));
    }
    md.push_str(&interior_outside(&trainer, &sdf, footprint)?);
    md.push_str(&light_shares(&trainer)?);
    if args.concavity.concavity_gap > 0.0 {
        md.push_str(&crate::concavity::report(
            &trainer,
            &scene,
            &gt,
            &args.data,
            &args.concavity,
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

/// One group's table: per signed-distance bin, the count, the opacity percentiles and each
/// term's mean descent, then the group's opacity mass per bin.
fn group_table(
    group: &Group,
    bins: &[usize],
    opacity: &[f32],
    view_dependence: &[f32],
    term_names: &[&'static str],
    sums: &[Vec<(f64, f64)>],
) -> String {
    let nb = EDGES.len() + 1;
    let mut counts = vec![0usize; nb];
    let mut op_bins: Vec<Vec<f32>> = vec![Vec::new(); nb];
    let mut vd_bins = vec![0.0f64; nb];
    let mut term_bins = vec![vec![(0.0f64, 0.0f64); nb]; term_names.len()];
    for &i in &group.members {
        counts[bins[i]] += 1;
        op_bins[bins[i]].push(opacity[i]);
        vd_bins[bins[i]] += f64::from(view_dependence[i]);
        for (t, s) in sums.iter().enumerate() {
            term_bins[t][bins[i]].0 += s[i].0;
            term_bins[t][bins[i]].1 += s[i].1;
        }
    }
    for o in op_bins.iter_mut() {
        o.sort_by(f32::total_cmp);
    }
    let total = group.members.len();
    let mut md = format!("\n## {} ({total})\n\n", group.label);
    if total == 0 {
        return md;
    }
    md.push_str(
        "| signed distance (fp) | Gaussians | share | opacity p10 / p50 / p90 | view-dependent SH |",
    );
    for t in term_names {
        md.push_str(&format!(" {t} logit / normal |"));
    }
    md.push('\n');
    md.push_str("|---|---:|---:|---|---:|");
    for _ in term_names {
        md.push_str("---|");
    }
    md.push('\n');
    for b in 0..nb {
        if counts[b] == 0 {
            continue;
        }
        let o = &op_bins[b];
        md.push_str(&format!(
            "| {} | {} | {:.1} % | {:.3} / {:.3} / {:.3} | {:.3} |",
            bin_label(b),
            counts[b],
            100.0 * counts[b] as f64 / total as f64,
            percentile(o, 0.1),
            percentile(o, 0.5),
            percentile(o, 0.9),
            vd_bins[b] / counts[b] as f64
        ));
        for t in &term_bins {
            let c = counts[b] as f64;
            md.push_str(&format!(
                " {:+.2} / {:+.2} |",
                1e6 * t[b].0 / c,
                1e6 * t[b].1 / c
            ));
        }
        md.push('\n');
    }
    // Opacity-weighted: where the opacity is.
    let total_op: f64 = group.members.iter().map(|i| f64::from(opacity[*i])).sum();
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
    md
}

/// Where the interior set lies against the ground truth: the share of its Gaussians, and of
/// their opacity, more than a footprint outside the truth (in a concavity the surface set
/// lids over, where the scattering set can paint what the views see). Empty without one.
fn interior_outside(
    trainer: &gtsr_model::trainer::Trainer,
    sdf: &SignedDistance<'_>,
    footprint: f32,
) -> Result<String> {
    let Some(set) = &trainer.model().interior else {
        return Ok(String::new());
    };
    let host = set.to_host();
    let (means, _) = host.column(ParamKind::Means).context("interior means")?;
    let opacity = host_vec(trainer.model().opacities(set));
    let (mut count, mut mass, mut total) = (0usize, 0.0f64, 0.0f64);
    for (p, o) in means.chunks_exact(3).zip(&opacity) {
        total += f64::from(*o);
        if sdf.query(Vec3::from_slice(p)).0 > footprint {
            count += 1;
            mass += f64::from(*o);
        }
    }
    Ok(format!(
        "\nInterior set: {count} of {} Gaussians ({:.1} %) lie more than a footprint outside the \
         ground truth, with {:.1} % of its opacity.\n",
        opacity.len(),
        100.0 * count as f64 / opacity.len().max(1) as f64,
        100.0 * mass / total.max(1e-12)
    ))
}

/// A channel at least this high (of 1) counts as at the top of its range.
const SATURATED: f32 = 0.999;

/// Training views whose C_PBR [`light_shares`] decomposes (evenly spaced over the views).
const SHARE_VIEWS: usize = 16;

/// Where C_PBR's light comes from on the object: on up to [`SHARE_VIEWS`] training views, over
/// the pixels inside the mask (covered pixels without one), the mean linear radiance of the
/// image and of C_PBR's three terms (the specular lobe, the diffuse term, the scattering map
/// as weighted by `1 - A F`), mean over the colour channels. A markdown paragraph, empty
/// without PBR.
fn light_shares(trainer: &gtsr_model::trainer::Trainer) -> Result<String> {
    let model = trainer.model().detached();
    let opts = trainer.render_options(trainer.steps_done().saturating_sub(1), false);
    let Some(light) = model.light() else {
        return Ok(String::new());
    };
    let views = trainer.views();
    let stride = views.len().div_ceil(SHARE_VIEWS).max(1);
    let (mut image, mut spec, mut diffuse, mut scatter, mut pixels) = (0.0, 0.0, 0.0, 0.0, 0usize);
    // Per channel, the image and C_PBR as the loss compares them.
    let mut channels = [(0.0f64, 0.0f64); 3];
    // Pixels with a channel at the top of the range: the image's, C_PBR's.
    let mut saturated = (0usize, 0usize);
    for v in views.iter().step_by(stride) {
        let r = model.render(&v.camera, &v.rays, opts)?;
        let (Some(g), Some(s), Some(compared)) = (r.geometry, r.scatter, r.c_pbr) else {
            return Ok(String::new());
        };
        let compared = host_vec(compared);
        let gb = gtsr_model::pbr::GBuffer {
            normal: g.normal,
            depth: g.depth,
            coverage: g.coverage.clone(),
            base: g.base.context("base colour map")?,
            roughness: g.roughness.context("roughness map")?,
            scatter: Some(s),
            rays: v.rays.clone(),
        };
        let all = gtsr_model::pbr::shade(&gb, light.clone(), opts.shading);
        let surface = gtsr_model::pbr::shade(
            &gtsr_model::pbr::GBuffer {
                scatter: None,
                ..gb
            },
            light.clone(),
            opts.shading,
        )
        .colour;
        let (all_c, surf_c) = (host_vec(all.colour), host_vec(surface));
        let (lobe, cov) = (host_vec(all.specular), host_vec(g.coverage));
        let rgb = host_vec(v.rgb.clone());
        let inside = match &v.mask {
            Some(m) => host_vec(m.clone()),
            None => cov.clone(),
        };
        let lin = |x: f32| {
            if opts.pbr_srgb {
                gtsr_data::image_io::srgb_to_linear(x)
            } else {
                x
            }
        };
        for p in (0..cov.len()).filter(|p| inside[*p] >= 0.5) {
            let mean = |x: &[f32]| f64::from(x[3 * p] + x[3 * p + 1] + x[3 * p + 2]) / 3.0;
            let lobe_p = f64::from(cov[p] * lobe[p]);
            image += (0..3).map(|c| f64::from(lin(rgb[3 * p + c]))).sum::<f64>() / 3.0;
            spec += lobe_p;
            diffuse += mean(&surf_c) - lobe_p;
            scatter += mean(&all_c) - mean(&surf_c);
            for c in 0..3 {
                channels[c].0 += f64::from(rgb[3 * p + c]);
                channels[c].1 += f64::from(compared[3 * p + c]);
            }
            let top = |x: &[f32]| (0..3).any(|c| x[3 * p + c] >= SATURATED);
            saturated.0 += usize::from(top(&rgb));
            saturated.1 += usize::from(top(&compared));
            pixels += 1;
        }
    }
    if pixels == 0 {
        return Ok(String::new());
    }
    let n = pixels as f64;
    let model_total = spec + diffuse + scatter;
    let share = |x: f64| 100.0 * x / model_total.max(1e-12);
    let per_channel: Vec<String> = (channels.iter())
        .map(|(i, c)| format!("{:.3} / {:.3}", i / n, c / n))
        .collect();
    Ok(format!(
        "\nWhere C_PBR's light comes from, over the object's pixels of {} training views \
         (mean linear radiance): the images {:.4}, C_PBR {:.4} (before its sRGB clamp): the \
         specular lobe {:.4} ({:.1} %), the diffuse term {:.4} ({:.1} %), the scattering map \
         {:.4} ({:.1} %). The surface normals enter the scattering map only through Fresnel's \
         weight{}. As the loss compares them (R, G, B: image / C_PBR): {}; a channel at \
         the top of the range on {:.1} % / {:.1} % of these pixels.\n",
        views.len().div_ceil(stride),
        image / n,
        model_total / n,
        spec / n,
        share(spec),
        diffuse / n,
        share(diffuse),
        scatter / n,
        share(scatter),
        if opts.shading.scatter_lambert {
            " and the light's cosine (scatter_lambert)"
        } else {
            ""
        },
        per_channel.join(", "),
        100.0 * saturated.0 as f64 / n,
        100.0 * saturated.1 as f64 / n
    ))
}

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
        assert_eq!(bin_of(50.0), EDGES.len());
        assert_eq!(bin_of(5.0), 10);
        assert_eq!(bin_label(0), "< -4");
        assert_eq!(bin_label(5), "[-0.25, 0.25)");
        assert_eq!(bin_label(EDGES.len()), ">= 16");
        let sorted = [0.1, 0.2, 0.3, 0.4, 0.5];
        assert_eq!(percentile(&sorted, 0.5), 0.3);
        assert!(percentile(&[], 0.5).is_nan());
    }
}
