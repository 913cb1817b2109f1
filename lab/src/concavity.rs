//! `diagnose-surface --concavity-gap`: what the training pixels show where the masks are blind,
//! how good the run's normals are where the masks are off, and (`--refine-anchors`) how far
//! those normals could refine the masks' mesh ([`gtsr_mesh::refine`]). For the development scenes
//! only: the ground truth diagnoses, it never trains.

use anyhow::{Context, Result};
use glam::Vec3;
use gtsr_mesh::pixels::median_pixel_footprint;
use gtsr_model::gaussians::host_vec;

use rand::{RngExt, SeedableRng, rngs::StdRng};

use clap::Args;

/// Options of the concavity comparison of `diagnose-surface`.
#[derive(Args, Debug)]
pub struct ConcavityArgs {
    /// Also compare, on every training view, the pixels that look into a concavity the masks
    /// cannot see (the ground truth more than this many footprints behind the masks' own
    /// depth) with the pixels around them: the image, the run's residuals and its depth there
    /// (0: skip).
    #[arg(long, default_value_t = 0.0)]
    pub concavity_gap: f32,
    /// With `--concavity-gap`: refine the masks' mesh with the normals the training views
    /// observe (`gtsr_mesh::refine`), once with the run's and once with the truth's, at each
    /// of these anchors (scene units), and score the results.
    #[arg(long, num_args = 0..)]
    pub refine_anchors: Vec<f32>,
    /// With `--concavity-gap`: take the run's normals from the surface splat at which the
    /// transmittance first falls to this threshold (the front of the surface set,
    /// `Model::render_depth_crossing`) instead of the blended normal.
    #[arg(long)]
    pub front_normals: Option<f64>,
    /// With `--concavity-gap`: take the run's normals from the gradient of its depth map (the
    /// blended depth, or with `--front-normals` the front's) instead of the rendered normal.
    #[arg(long)]
    pub depth_normals: bool,
    /// With `--refine-anchors`: also refine with the truth's normals tilted at random per
    /// pixel, by a Gaussian of each of these standard deviations (degrees, per tangent axis;
    /// seeded): how accurate a run's normals must be to shape the mesh.
    #[arg(long, num_args = 0..)]
    pub refine_noise: Vec<f32>,
    /// With `--refine-anchors`: also refine with the truth's normal maps blurred over a
    /// square window of each of these radii (pixels): what a smooth normal costs.
    #[arg(long, num_args = 0..)]
    pub refine_blur: Vec<usize>,
    /// With `--refine-anchors`: also refine with a depth term, each face pulled towards the
    /// offset the views' depth maps observe (the median over the views, less the median over
    /// the faces: the depth's own bias against the masks), over each of these lengths (scene
    /// units; smaller trusts the depth more); from the truth's depth, the run's blended
    /// depth and, with `--offset-crossing`, its front.
    #[arg(long, num_args = 0..)]
    pub refine_depth: Vec<f32>,
    /// With `--refine-depth`: also take the run's depth where its transmittance first falls
    /// to this threshold (`Model::render_depth_crossing`).
    #[arg(long)]
    pub offset_crossing: Option<f64>,
    /// With `--refine-depth`: the run's offsets are trusted only beyond each of these
    /// thresholds (footprints): inward offsets are shrunk by it, the rest ask the face to stay.
    #[arg(long, num_args = 0.., default_values_t = [0.0])]
    pub offset_thresholds: Vec<f32>,
    /// With `--refine-depth`: also refine with the truth's offsets scaled by each of these
    /// factors (towards the masks' mesh, as a run that bridges concavities would see them),
    /// thresholded as the run's: how much of a concavity a run's depth must see.
    #[arg(long, num_args = 0..)]
    pub offset_truth_scale: Vec<f32>,
    /// With `--refine-depth`: also refine with the truth's offsets plus seeded Gaussian noise
    /// per face of each of these standard deviations (footprints), thresholded as the run's.
    #[arg(long, num_args = 0..)]
    pub offset_truth_noise: Vec<f32>,
}

/// The `q` quantile of `sorted` (nearest rank); NaN when it is empty.
pub fn percentile(sorted: &[f32], q: f64) -> f32 {
    if sorted.is_empty() {
        return f32::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

/// Pixel classes of [`report`].
const CLASSES: [&str; 3] = [
    "into a concavity (truth beyond the gap)",
    "around them (8-neighbours, truth within half a footprint of the masks)",
    "elsewhere on the object (truth within half a footprint of the masks)",
];

/// The transmittances of [`report`]'s light column: the share of pixels where the surface set
/// lets at least this much of the ray through to the gap's depth.
const LIGHT_LEFT: [f64; 3] = [0.5, 0.1, 0.01];

/// Per class: pixels, and sums of the image's mean channel, the C_SH and C_PBR absolute
/// residuals and the signed C_SH one (render minus image; mean over channels), the run's depth
/// and the truth's behind the masks' depth (footprints), the pixels where the run's depth
/// lies beyond the gap, and per [`LIGHT_LEFT`] threshold the pixels whose surface set still
/// lets that much light through at the gap.
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
    light_left: [usize; LIGHT_LEFT.len()],
    light_pixels: usize,
}

/// Of the pixels into a concavity, how many the extraction's depth still holds beyond the gap,
/// stage by stage of its preparation (gtsr-train's fusion readout, then
/// [`gtsr_mesh::prepare_depth`], then the median offset taken out as the carving does).
#[derive(Default)]
struct ExtractionReading {
    /// Pixels into a concavity.
    pixels: usize,
    /// Of them, beyond the gap in the blended depth, in the fusion readout (at the outlines the
    /// plane-blurred depth where it lies farther), after the mask, coverage and facing filter,
    /// and after the depth-edge drop.
    beyond: [usize; 4],
    /// Pixels into a concavity dropped by the facing filter, by the coverage or mask.
    dropped_facing: usize,
    dropped_covered: usize,
    /// Per pixel into a concavity that survives the edge drop: its prepared depth, the
    /// masks' depth, the masks' depth step to its 4-neighbours, the focal length.
    kept: Vec<(f32, f32, f32, f32)>,
    /// Every prepared sample's offset behind the masks' depth (footprints, `(d - h) fx / d`).
    offsets: Vec<f32>,
}

/// The concavity report of `diagnose-surface --concavity-gap`: on every training view,
/// the masks' mesh (native masks, [`gtsr_eval::native_masks_mesh`]) and the ground truth are ray cast
/// through each pixel; a pixel looks into a concavity the masks cannot see when the truth lies
/// more than `gap` footprints (`z / fx`) behind the masks' depth there. Those pixels are
/// compared with their 8-neighbours on the flush surface and with the rest of the object: if
/// the run fits them as well as their neighbours while its depth stays at the masks', the
/// images do not contradict a lid over the concavity. The report also bins the normal error of
/// the masks' mesh and of the run by how far the truth lies behind the masks' depth, and with
/// `anchors` adds [`refine_rows`].
pub(crate) fn report(
    trainer: &gtsr_model::trainer::Trainer,
    scene: &gtsr_data::Scene,
    gt: &gtsr_data::ply::TriMesh,
    data: &std::path::Path,
    args: &ConcavityArgs,
) -> Result<String> {
    let (gap, anchors) = (args.concavity_gap, &args.refine_anchors);
    let front_normals = args.front_normals;
    let (_, hull_mesh) = gtsr_eval::native_masks_mesh(data)?;
    let hull_caster = gtsr_mesh::raycast::MeshRaycaster::new(&hull_mesh, "masks' mesh")?;
    let gt_caster = gtsr_mesh::raycast::MeshRaycaster::new(gt, "ground-truth mesh")?;
    let model = trainer.model().detached();
    let last = trainer.steps_done().saturating_sub(1);
    let opts = trainer.render_options(last, false);
    let mut sums = [ClassSums::default(); 3];
    let mut kept_maps: Vec<ViewMaps> = Vec::new();
    let mut reading = ExtractionReading::default();
    // The extraction's readout at the default mesh settings (gtsr-train's).
    let extraction = gtsr_model::readout::Readout::new(
        trainer.model(),
        &gtsr_train::mesh::readout_settings(&gtsr_mesh::MeshConfig::default()),
    );
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
        let crossing_depth = match args.offset_crossing {
            Some(t) if !args.refine_depth.is_empty() => Some(host_vec(
                model.render_depth_crossing(&v.camera, &v.rays, t)?.depth,
            )),
            _ => None,
        };
        let front = match front_normals {
            Some(t) => Some(model.render_depth_crossing(&v.camera, &v.rays, t)?),
            None => None,
        };
        let run_normal = match (front, args.depth_normals) {
            (Some(f), false) => host_vec(f.normal),
            (Some(f), true) => depth_normals(&data.camera, &host_vec(f.depth)),
            (None, false) => host_vec(g.normal),
            (None, true) => depth_normals(&data.camera, &depth),
        };
        let fx = data.camera.fx;
        let on = |p: usize| mask[p] > 0.5 && truth[p] > 0.0 && hull[p] > 0.0;
        let gap_fp = |p: usize| (truth[p] - hull[p]) * fx / hull[p];
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
        // The depth at which the surface set's transmittance falls to each threshold, on the
        // views with a pixel into a concavity (a miss: the light never falls that far).
        let crossings = if (0..w * h).any(|p| class_of(p) == Some(0)) {
            LIGHT_LEFT
                .iter()
                .map(|t| {
                    let g = model.render_depth_crossing(&v.camera, &v.rays, *t)?;
                    Ok((host_vec(g.depth), host_vec(g.coverage)))
                })
                .collect::<Result<Vec<_>>>()?
        } else {
            Vec::new()
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
            s.light_pixels += usize::from(!crossings.is_empty());
            for (k, (d, found)) in crossings.iter().enumerate() {
                let beyond = (d[p] - hull[p]) * fx / hull[p] > gap;
                s.light_left[k] += usize::from(found[p] < 0.5 || !d[p].is_finite() || beyond);
            }
        }
        // The extraction's reading of the same depth (gtsr-train's fusion readout, then
        // prepare_depth).
        let read = extraction.host_geometry(&v.camera, &v.rays)?;
        let read_depth = read.depth.clone();
        let geometry = gtsr_mesh::DepthGeometry {
            normal: &read.normal,
            plane: &read.plane,
            rays: &read.rays,
            coverage: Some(&read.coverage),
        };
        let mut filtered = read_depth.clone();
        gtsr_mesh::prepare_depth(&data.camera, &mut filtered, &geometry, mask, false)?;
        let mut prepared = read_depth.clone();
        gtsr_mesh::prepare_depth(&data.camera, &mut prepared, &geometry, mask, true)?;
        let steps = gtsr_mesh::carve::depth_steps(&gtsr_mesh::carve::DepthMap {
            camera: &data.camera,
            depth: hull,
            hull_depth: None,
        });
        let beyond = |d: f32, p: usize| d > 0.0 && (d - hull[p]) * fx / hull[p] > gap;
        for p in 0..w * h {
            if prepared[p] > 0.0 && hull[p] > 0.0 {
                reading
                    .offsets
                    .push((prepared[p] - hull[p]) * fx / prepared[p]);
            }
            if class_of(p) != Some(0) {
                continue;
            }
            reading.pixels += 1;
            for (k, d) in [depth[p], read_depth[p], filtered[p], prepared[p]]
                .into_iter()
                .enumerate()
            {
                reading.beyond[k] += usize::from(beyond(d, p));
            }
            if beyond(read_depth[p], p) && filtered[p] <= 0.0 {
                let nrm = Vec3::from_slice(&read.normal[3 * p..3 * p + 3]);
                let ray = Vec3::from_slice(&read.rays[3 * p..3 * p + 3]);
                if gtsr_mesh::tsdf::faces_ray(nrm, ray) {
                    reading.dropped_covered += 1;
                } else {
                    reading.dropped_facing += 1;
                }
            }
            if prepared[p] > 0.0 {
                reading.kept.push((prepared[p], hull[p], steps[p], fx));
            }
        }
        if !anchors.is_empty() {
            let flat = |n: Vec<Vec3>| -> Vec<f32> { n.iter().flat_map(|n| n.to_array()).collect() };
            kept_maps.push(ViewMaps {
                run_normal,
                truth_normal: flat(truth_maps.normal),
                hull_depth: hull_maps.depth,
                hull_normal: flat(hull_maps.normal),
                run_depth: if args.refine_depth.is_empty() {
                    Vec::new()
                } else {
                    depth
                },
                crossing_depth,
                truth_depth: truth_maps.depth,
            });
        }
    }
    let mut md = format!(
        "\n## Pixels that look into a concavity the masks cannot see\n\nEvery training view \
         ({} views); the truth more than {gap} footprints behind the masks' depth. Means per \
         pixel: the image (mean channel), the run's absolute residuals and its signed C_SH one \
         (render minus image), the run's depth and the truth behind the masks' depth, in \
         footprints, the share of pixels where the run's depth lies beyond the gap, and (on the \
         views with a pixel into a concavity) the share where the surface set lets at least \
         {} of the light through to the gap's depth.\n\n\
         | pixels | count | image | C_SH residual | C_PBR residual | C_SH signed | run's depth \
         behind the masks | truth behind the masks | run beyond the gap | light past the gap \
         |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---|\n",
        scene.train.len(),
        LIGHT_LEFT.map(|t| t.to_string()).join(" / ")
    );
    for (name, s) in CLASSES.iter().zip(&sums) {
        let n = s.pixels.max(1) as f64;
        let light = s
            .light_left
            .map(|k| format!("{:.1} %", 100.0 * k as f64 / s.light_pixels.max(1) as f64))
            .join(" / ");
        md.push_str(&format!(
            "| {name} | {} | {:.4} | {:.4} | {:.4} | {:+.4} | {:+.2} | {:+.2} | {:.1} % | {} |\n",
            s.pixels,
            s.image / n,
            s.res_sh / n,
            s.res_pbr / n,
            s.signed_sh / n,
            s.model_gap / n,
            s.truth_gap / n,
            100.0 * s.model_beyond as f64 / n,
            light
        ));
    }
    md.push_str(&extraction_rows(&mut reading, gap));
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
        let label = bin_label(&NORMAL_BINS, b);
        let (hm, ha) = median_mean(hull);
        let (rm, ra) = median_mean(run);
        md.push_str(&format!(
            "| {label} | {} | {hm:.1} / {ha:.1} | {rm:.1} / {ra:.1} |\n",
            hull.len()
        ));
    }
    if !anchors.is_empty() {
        md.push_str(&refine_rows(scene, gt, &hull_mesh, &kept_maps, args)?);
    }
    Ok(md)
}

/// The paragraph of [`ExtractionReading`]: of the pixels into a concavity, the share whose
/// depth lies beyond the gap at each stage of the extraction's preparation, then after the
/// median offset is taken out (the carving's debias), and through the carving's concavity gate
/// (`gap` footprints stretched by the masks' depth step).
fn extraction_rows(r: &mut ExtractionReading, gap: f32) -> String {
    let n = r.pixels.max(1) as f64;
    let pct = |k: usize| format!("{:.1} %", 100.0 * k as f64 / n);
    r.offsets.sort_unstable_by(f32::total_cmp);
    let median = r.offsets.get(r.offsets.len() / 2).copied().unwrap_or(0.0);
    let shift = median.max(0.0);
    let (mut debiased, mut gated) = (0usize, 0usize);
    for &(d, hd, step, fx) in &r.kept {
        let d = d * (1.0 - shift / fx);
        debiased += usize::from((d - hd) * fx / hd > gap);
        let footprint = d / fx;
        gated += usize::from(
            step.is_finite() && d - hd > gap * (footprint * footprint + step * step).sqrt(),
        );
    }
    format!(
        "\nWhat the extraction reads of those {} pixels (the depth beyond the gap): the blended \
         depth {}; the fusion readout (the plane-blurred depth at the outlines) {}; after the \
         mask, coverage and facing filter {} (dropped as not facing the ray {}, as uncovered or \
         unmasked {}); after the depth-edge drop {}; moved {median:+.2} footprints (the median \
         offset of every prepared sample, taken out when positive) {}; through the concavity \
         gate (the gap stretched by the masks' depth step) {}.\n",
        r.pixels,
        pct(r.beyond[0]),
        pct(r.beyond[1]),
        pct(r.beyond[2]),
        pct(r.dropped_facing),
        pct(r.dropped_covered),
        pct(r.beyond[3]),
        pct(debiased),
        pct(gated),
    )
}

/// Per training view, what the refinement rows read (normals 3 per pixel, camera space;
/// z-depths).
struct ViewMaps {
    run_normal: Vec<f32>,
    truth_normal: Vec<f32>,
    hull_depth: Vec<f32>,
    hull_normal: Vec<f32>,
    /// Empty without `--refine-depth`.
    run_depth: Vec<f32>,
    crossing_depth: Option<Vec<f32>>,
    truth_depth: Vec<f32>,
}

/// The refinement rows of `--refine-anchors`: the masks' mesh refined
/// (`gtsr_mesh::refine`) by the normals of the run, of the truth, of the masks' mesh itself (what the
/// refinement gives without any new information), and of the run only where it departs from
/// the masks' own by more than 8 degrees; inward only and with a quarter footprint outward.
fn refine_rows(
    scene: &gtsr_data::Scene,
    gt: &gtsr_data::ply::TriMesh,
    hull: &gtsr_data::ply::TriMesh,
    maps: &[ViewMaps],
    args: &ConcavityArgs,
) -> Result<String> {
    let (anchors, noise, blur) = (&args.refine_anchors, &args.refine_noise, &args.refine_blur);
    use gtsr_mesh::refine::{
        FaceNormals, NormalView, RefineSettings, observed_normals, refine, refine_with_normals,
    };
    let cameras: Vec<gtsr_data::Camera> = scene.train.iter().map(|v| v.camera).collect();
    let footprint = median_pixel_footprint(cameras.iter(), Vec3::ZERO);
    let score = |mesh: &gtsr_data::ply::TriMesh| score_cells(mesh, gt, &cameras, hull);
    // The faces' observed normals from one normal map per view.
    let observe = |normals: Vec<&[f32]>| -> Result<FaceNormals> {
        let views: Vec<NormalView<'_>> = cameras
            .iter()
            .zip(maps)
            .zip(normals)
            .map(|((c, m), n)| NormalView {
                camera: c,
                normal: n,
                mesh_depth: &m.hull_depth,
            })
            .collect();
        Ok(observed_normals(hull, &views, 1, REFINE_MIN_COS)?)
    };
    let observed =
        |pick: fn(&ViewMaps) -> &[f32]| observe(maps.iter().map(pick).collect::<Vec<_>>());
    // One refinement, scored, as a table row (also printed).
    let row = |label: &str, targets: &FaceNormals, anchor: f32, outward: f32| -> Result<String> {
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
        Ok(row)
    };
    let run = observed(|m| &m.run_normal)?;
    let truth = observed(|m| &m.truth_normal)?;
    let own = observed(|m| &m.hull_normal)?;
    // Per face, after the views are averaged: how far the run's and the masks' own normals
    // lie from the truth's.
    let face_error = |x: &FaceNormals| -> (f32, f64) { median_mean(&mut face_angles(x, &truth)) };
    let ((rm, ra), (om, oa)) = (face_error(&run), face_error(&own));
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
        "\nThe masks' mesh refined by the observed normals (`gtsr_mesh::refine`; chamfer, \
         accuracy, completeness, hull-blind, x1e3; moves in scene units):\n\n",
    );
    let errors = format!(
        "Per face, the views averaged, against the truth's (degrees, median / mean): the run's \
         normals {rm:.1} / {ra:.1}, the masks' own {om:.1} / {oa:.1}.\n\n"
    );
    println!("{}", errors.trim_end());
    md.push_str(&errors);
    md.push_str(
        "| normals | anchor | outward (footprints) | chamfer | accuracy | completeness | \
         hull-blind | mean / largest inward move |\n|---|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    md.push_str(&format!(
        "| none (masks alone) | | | {} | |\n",
        score(hull)?
    ));
    for outward in [0.0f32, 0.25] {
        for (label, targets) in sources {
            for &anchor in anchors {
                md.push_str(&row(label, targets, anchor, outward)?);
            }
        }
    }
    // The truth's normals altered per view: refined with each set at every anchor, a quarter
    // footprint outward allowed.
    let altered_rows = |label: String, normals: &[Vec<f32>], md: &mut String| -> Result<()> {
        let targets = observe(normals.iter().map(Vec::as_slice).collect())?;
        for &anchor in anchors {
            md.push_str(&row(&label, &targets, anchor, 0.25)?);
        }
        Ok(())
    };
    // Tilted at random: each pixel's normal plus a tangent Gaussian.
    for &sigma in noise {
        let mut rng = StdRng::seed_from_u64(0x6e6f697365);
        let mut tilts = Vec::new();
        let noisy: Vec<Vec<f32>> = maps
            .iter()
            .map(|m| {
                m.truth_normal
                    .chunks_exact(3)
                    .flat_map(|c| {
                        let n = Vec3::from_slice(c);
                        if n == Vec3::ZERO {
                            return [0.0; 3];
                        }
                        let g = Vec3::new(gauss(&mut rng), gauss(&mut rng), gauss(&mut rng))
                            * sigma.to_radians();
                        let tilted = (n + (g - g.dot(n) * n)).normalize();
                        tilts.push(tilted.dot(n).clamp(-1.0, 1.0).acos().to_degrees());
                        tilted.to_array()
                    })
                    .collect()
            })
            .collect();
        tilts.sort_by(f32::total_cmp);
        let label = format!(
            "truth tilted by {sigma} deg per axis (median tilt {:.1} deg)",
            percentile(&tilts, 0.5)
        );
        altered_rows(label, &noisy, &mut md)?;
    }
    // Blurred: each pixel's normal the mean of the covered pixels within a square window.
    for &radius in blur {
        let r = radius as i64;
        let blurred: Vec<Vec<f32>> = cameras
            .iter()
            .zip(maps)
            .map(|(c, m)| {
                let (w, h) = (c.width as i64, c.height as i64);
                let at = |x: i64, y: i64| {
                    Vec3::from_slice(&m.truth_normal[3 * (y * w + x) as usize..][..3])
                };
                (0..h)
                    .flat_map(|y| (0..w).map(move |x| (x, y)))
                    .flat_map(|(x, y)| {
                        if at(x, y) == Vec3::ZERO {
                            return [0.0; 3];
                        }
                        let mut sum = Vec3::ZERO;
                        for yy in (y - r).max(0)..=(y + r).min(h - 1) {
                            for xx in (x - r).max(0)..=(x + r).min(w - 1) {
                                sum += at(xx, yy);
                            }
                        }
                        sum.normalize_or_zero().to_array()
                    })
                    .collect()
            })
            .collect();
        let label = format!("truth blurred over {0}x{0} pixels", 2 * radius + 1);
        altered_rows(label, &blurred, &mut md)?;
    }
    if !args.refine_depth.is_empty() {
        md.push_str(&depth_rows(
            &cameras,
            maps,
            hull,
            footprint,
            &own,
            args,
            &|label: &str,
              normals: &FaceNormals,
              depth: &gtsr_mesh::refine::DepthTargets,
              anchor: f32| {
                let settings = RefineSettings {
                    anchor,
                    max_outward: 0.25 * footprint,
                    ..RefineSettings::default()
                };
                let (mesh, d) = refine(hull, normals, Some(depth), &settings)?;
                let mean = d.iter().map(|v| *v as f64).sum::<f64>() / d.len().max(1) as f64;
                let row = format!("| {label} | {anchor} | {} | {mean:.4} |\n", score(&mesh)?);
                println!("{}", row.trim_end());
                Ok(row)
            },
        )?);
    }
    Ok(md)
}

/// One scored refinement with a depth term, as a table row.
type DepthRow<'a> = dyn Fn(
        &str,
        &gtsr_mesh::refine::FaceNormals,
        &gtsr_mesh::refine::DepthTargets,
        f32,
    ) -> Result<String>
    + 'a;

/// The rows of `--refine-depth`: per face, the offsets the depth maps observe against the
/// masks' mesh (the truth's, the run's blended and its front), how well the run's track the
/// truth's, and the masks' mesh refined with each as a depth term (normals: the masks' own).
fn depth_rows(
    cameras: &[gtsr_data::Camera],
    maps: &[ViewMaps],
    hull: &gtsr_data::ply::TriMesh,
    footprint: f32,
    own: &gtsr_mesh::refine::FaceNormals,
    args: &ConcavityArgs,
    row: &DepthRow<'_>,
) -> Result<String> {
    let (lengths, thresholds, anchors) = (
        &args.refine_depth,
        &args.offset_thresholds,
        &args.refine_anchors,
    );
    let (truth_scales, truth_noise) = (&args.offset_truth_scale, &args.offset_truth_noise);
    use gtsr_mesh::refine::{DepthTargets, DepthView, FaceOffsets, observed_offsets};
    let offsets = |pick: &dyn Fn(&ViewMaps) -> Option<&[f32]>| -> Result<Option<FaceOffsets>> {
        let mut views = Vec::new();
        for (c, m) in cameras.iter().zip(maps) {
            let Some(depth) = pick(m) else {
                return Ok(None);
            };
            views.push(DepthView {
                camera: c,
                depth,
                mesh_depth: &m.hull_depth,
            });
        }
        Ok(Some(observed_offsets(hull, &views, REFINE_MIN_COS)?))
    };
    let truth = offsets(&|m| Some(&m.truth_depth))?.context("truth offsets")?;
    let blended = offsets(&|m| Some(&m.run_depth))?.context("run offsets")?;
    let crossing = offsets(&|m| m.crossing_depth.as_deref())?;
    // A face counts with at least this many views; its offset less the median over such faces.
    const MIN_VIEWS: u32 = 3;
    let debias = |o: &FaceOffsets| -> (DepthTargets, f32) {
        let mut kept: Vec<f32> = (0..o.offset.len())
            .filter(|f| o.views[*f] >= MIN_VIEWS)
            .map(|f| o.offset[f])
            .collect();
        let bias = if kept.is_empty() {
            0.0
        } else {
            median_mean(&mut kept).0
        };
        let t = DepthTargets {
            offset: o.offset.iter().map(|v| v - bias).collect(),
            weight: o
                .views
                .iter()
                .map(|n| if *n >= MIN_VIEWS { 1.0 } else { 0.0 })
                .collect(),
            length: 1.0,
        };
        (t, bias)
    };
    let with_length = |t: &DepthTargets, length: f32| DepthTargets {
        length,
        ..t.clone()
    };
    let mut md = format!(
        "\nPer face of the masks' mesh (seen in at least {MIN_VIEWS} views), the offset the depth \
         maps observe along the face normal (footprints of {footprint:.4}, negative: inside), \
         each less its median over the faces (the bias), by the truth's offset; median / mean, \
         and the median distance from the truth's:\n\n"
    );
    // Where both the blend and the front say the face lies inside: the less inward of the two.
    let both = crossing.as_ref().map(|c| FaceOffsets {
        offset: (debias(c).0.offset.iter())
            .zip(&debias(&blended).0.offset)
            .map(|(a, b)| a.max(*b))
            .collect(),
        views: (c.views.iter().zip(&blended.views))
            .map(|(a, b)| *a.min(b))
            .collect(),
    });
    let mut sources: Vec<(&str, &FaceOffsets)> = vec![("run, blended", &blended)];
    if let (Some(c), Some(b)) = (&crossing, &both) {
        sources.push(("run, front", c));
        sources.push(("run, the less inward of both", b));
    }
    md.push_str("| truth's offset (fp) | faces |");
    for (name, _) in &sources {
        md.push_str(&format!(" {name} | distance | below -0.5 / -1 fp |"));
    }
    md.push_str("\n|---|---:|");
    for _ in &sources {
        md.push_str("---:|---:|---:|");
    }
    md.push('\n');
    const EDGES: [f32; 5] = [-3.0, -1.0, -0.5, -0.25, 0.25];
    let (truth_t, truth_bias) = debias(&truth);
    let debiased: Vec<(DepthTargets, f32)> = sources.iter().map(|(_, o)| debias(o)).collect();
    for b in 0..=EDGES.len() {
        let in_bin = |f: usize| {
            let t = truth_t.offset[f] / footprint;
            truth_t.weight[f] > 0.0 && EDGES.iter().take_while(|e| t >= **e).count() == b
        };
        let faces: Vec<usize> = (0..truth_t.offset.len()).filter(|f| in_bin(*f)).collect();
        if faces.is_empty() {
            continue;
        }
        let label = bin_label(&EDGES, b);
        md.push_str(&format!("| {label} | {} |", faces.len()));
        for (t, _) in &debiased {
            let mut v: Vec<f32> = faces
                .iter()
                .filter(|f| t.weight[**f] > 0.0)
                .map(|f| t.offset[*f] / footprint)
                .collect();
            let mut dist: Vec<f32> = faces
                .iter()
                .filter(|f| t.weight[**f] > 0.0)
                .map(|f| ((t.offset[*f] - truth_t.offset[*f]) / footprint).abs())
                .collect();
            let share = |x: f32| {
                100.0 * v.iter().filter(|o| **o < x).count() as f64 / v.len().max(1) as f64
            };
            let (s5, s1) = (share(-0.5), share(-1.0));
            let (m, a) = median_mean(&mut v);
            let (dm, _) = median_mean(&mut dist);
            md.push_str(&format!(
                " {m:+.2} / {a:+.2} | {dm:.2} | {s5:.1} / {s1:.1} % |"
            ));
        }
        md.push('\n');
    }
    md.push_str(&format!(
        "\nBiases (median offset over the faces, footprints): truth {:+.3}",
        truth_bias / footprint
    ));
    for ((name, _), (_, bias)) in sources.iter().zip(&debiased) {
        md.push_str(&format!(", {name} {:+.3}", bias / footprint));
    }
    md.push_str(
        ".\n\nThe masks' mesh refined with a depth term (normals as labelled; a quarter \
         footprint outward; chamfer, accuracy, completeness, hull-blind x1e3; mean move):\n\n\
         | depth / normals / length | anchor | chamfer | accuracy | completeness | hull-blind \
         | mean move |\n|---|---:|---:|---:|---:|---:|---:|\n",
    );
    for &length in lengths {
        let mut runs: Vec<(String, DepthTargets, &gtsr_mesh::refine::FaceNormals)> = vec![(
            format!("truth / masks' own / {length}"),
            with_length(&truth_t, length),
            own,
        )];
        for ((name, _), (source, _)) in sources.iter().zip(&debiased) {
            for &tau in thresholds {
                // Inward only, and shrunk by the threshold: offsets within it say "stay".
                let mut t = with_length(source, length);
                for v in t.offset.iter_mut() {
                    *v = (*v + tau * footprint).min(0.0);
                }
                runs.push((
                    format!("{name}, threshold {tau} fp / masks' own / {length}"),
                    t,
                    own,
                ));
            }
        }
        // The truth's offsets degraded as a run's might be: scaled towards the masks and
        // with seeded Gaussian noise per face (footprints), then thresholded as the run's.
        let scales: &[f32] = if truth_scales.is_empty() && !truth_noise.is_empty() {
            &[1.0]
        } else {
            truth_scales
        };
        let noises: &[f32] = if truth_noise.is_empty() && !truth_scales.is_empty() {
            &[0.0]
        } else {
            truth_noise
        };
        for &scale in scales {
            for &sigma in noises {
                let mut rng = StdRng::seed_from_u64(0x6f6666736574);
                let base = with_length(&truth_t, length);
                let degraded: Vec<f32> = base
                    .offset
                    .iter()
                    .map(|v| scale * v + sigma * footprint * gauss(&mut rng))
                    .collect();
                for &tau in thresholds {
                    let t = DepthTargets {
                        offset: degraded
                            .iter()
                            .map(|v| (*v + tau * footprint).min(0.0))
                            .collect(),
                        ..base.clone()
                    };
                    runs.push((
                        format!(
                            "truth x {scale} + noise {sigma} fp, threshold {tau} fp / masks' own / {length}"
                        ),
                        t,
                        own,
                    ));
                }
            }
        }
        for (label, t, normals) in &runs {
            for &anchor in anchors {
                md.push_str(&row(label, normals, t, anchor)?);
            }
        }
    }
    Ok(md)
}

/// The label of bin `b` of `edges` (bin 0 below the first edge, the last above the last).
fn bin_label(edges: &[f32], b: usize) -> String {
    match b {
        0 => format!("< {}", edges[0]),
        b if b == edges.len() => format!(">= {}", edges[b - 1]),
        b => format!("[{}, {})", edges[b - 1], edges[b]),
    }
}

/// A standard normal sample (Box-Muller), drawing two uniforms from `rng`.
fn gauss(rng: &mut StdRng) -> f32 {
    let u1: f32 = rng.random_range(f32::EPSILON..1.0);
    let u2: f32 = rng.random_range(0.0..1.0);
    (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos()
}

/// The median and the mean of `v` (sorted in place); NaN for an empty `v`.
pub(crate) fn median_mean(v: &mut [f32]) -> (f32, f64) {
    v.sort_by(f32::total_cmp);
    let mean = v.iter().map(|x| *x as f64).sum::<f64>() / v.len() as f64;
    (percentile(v, 0.5), mean)
}

/// Camera-space normals of a z-depth map (`0`: nothing) from central differences of the
/// back-projected pixel centres, facing the camera; zero where a neighbour is missing.
fn depth_normals(camera: &gtsr_data::Camera, depth: &[f32]) -> Vec<f32> {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let point = |x: usize, y: usize| -> Option<Vec3> {
        let z = depth[y * w + x];
        (z.is_finite() && z > 0.0).then(|| {
            Vec3::new(
                (x as f32 + 0.5 - camera.cx) / camera.fx * z,
                (y as f32 + 0.5 - camera.cy) / camera.fy * z,
                z,
            )
        })
    };
    let mut out = vec![0.0; 3 * w * h];
    for y in 1..h.saturating_sub(1) {
        for x in 1..w.saturating_sub(1) {
            let (Some(c), Some(l), Some(r), Some(u), Some(d)) = (
                point(x, y),
                point(x - 1, y),
                point(x + 1, y),
                point(x, y - 1),
                point(x, y + 1),
            ) else {
                continue;
            };
            let mut n = (r - l).cross(d - u).normalize_or_zero();
            if n.dot(c) > 0.0 {
                n = -n;
            }
            out[3 * (y * w + x)..][..3].copy_from_slice(&n.to_array());
        }
    }
    out
}

/// Least cosine between a face and the view direction for a view's normal to count in the
/// refinement; above it each view counts with that cosine as its weight.
const REFINE_MIN_COS: f32 = 0.2;

/// Bin edges (footprints) of the truth's depth behind the masks' depth, for the normal table.
const NORMAL_BINS: [f32; 5] = [-0.25, 0.25, 0.5, 1.0, 3.0];

/// A refined mesh scored against the ground truth (what one training camera sees), as the
/// table cells `chamfer | accuracy | completeness | hull-blind`, x1e3.
pub(crate) fn score_cells(
    mesh: &gtsr_data::ply::TriMesh,
    gt: &gtsr_data::ply::TriMesh,
    cameras: &[gtsr_data::Camera],
    hull: &gtsr_data::ply::TriMesh,
) -> Result<String> {
    let (seen, _) = gtsr_eval::score_against_ground_truth(mesh, gt, cameras, Some(hull))?;
    Ok(format!(
        "{:.3} | {:.3} | {:.3} | {:.2}",
        1e3 * seen.chamfer,
        1e3 * seen.accuracy,
        1e3 * seen.completeness,
        1e3 * seen.hull_blind.map_or(f64::NAN, |b| b.blind)
    ))
}

/// Per face where both sets have a normal (weight > 0), the angle between them in degrees.
pub(crate) fn face_angles(
    x: &gtsr_mesh::refine::FaceNormals,
    truth: &gtsr_mesh::refine::FaceNormals,
) -> Vec<f32> {
    (0..x.normal.len())
        .filter(|f| x.weight[*f] > 0.0 && truth.weight[*f] > 0.0)
        .map(|f| {
            x.normal[f]
                .dot(truth.normal[f])
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees()
        })
        .collect()
}
