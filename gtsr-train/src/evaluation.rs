//! The evaluations along the run and at its end: test PSNR / SSIM, the mesh and the depth
//! alone against the ground truth, the masks alone beside them, and the test views' depth.

use std::time::Instant;

use crate::mesh::{MeshSettings, extract_meshes, readout, training_cameras};
use anyhow::{Context, Result};
use gtsr_data::Scene;
use gtsr_data::ply::TriMesh;
use gtsr_eval::{
    DepthComparison, DepthMetrics, ImageRef, MeshMetrics, psnr, score_against_ground_truth, ssim,
};
use gtsr_mesh::raycast::MeshRaycaster;
use gtsr_model::gaussians::host_vec;
use gtsr_model::model::{Model, RenderOptions};
use gtsr_model::readout::rendered_image;
use gtsr_model::trainer::Trainer;
use gtsr_model::views::ViewTensors;

/// What an evaluation and the mesh extraction read of a trainer at one step: the model
/// (detached from the training's graph), the training views, the render options of the step
/// and the step itself. It owns what it holds, so an evaluation can run beside the training
/// while the trainer steps on (the tensors are shared, not copied, until the training
/// replaces them).
#[derive(Clone, Debug)]
pub struct Snapshot {
    /// The model at the step, detached.
    pub model: Model,
    /// The training views as trained at the step.
    pub views: Vec<ViewTensors>,
    /// The render options of the step, without the training's offset tracking.
    pub options: RenderOptions,
    /// Steps done.
    pub step: usize,
    /// Whether the last step done was in stage 2 (the model has its geometry and C_PBR).
    pub stage2: bool,
}

impl Snapshot {
    /// The trainer as it stands.
    pub fn of(trainer: &Trainer) -> Snapshot {
        let step = trainer.steps_done();
        Snapshot {
            model: trainer.model().detached(),
            views: trainer.views().to_vec(),
            options: trainer.render_options(step, false),
            step,
            stage2: trainer.is_stage2(step.saturating_sub(1)),
        }
    }
}

/// The masks' mesh of `masks` against the ground truth `gt` that the training cameras see, split
/// by the part it misses (the scene's masks alone, with a ground truth).
pub fn score_masks_alone(
    masks: Option<&gtsr_mesh::MasksAlone>,
    gt: Option<&TriMesh>,
    scene: &Scene,
) -> Result<Option<MeshMetrics>> {
    Ok(match (gt, masks) {
        (Some(gt), Some(masks)) => {
            let cameras = training_cameras(scene);
            Some(score_against_ground_truth(&masks.mesh, gt, &cameras, Some(&masks.mesh))?.0)
        }
        _ => None,
    })
}

/// One evaluation.
pub struct Evaluation {
    /// Mean test PSNR of C_SH.
    pub psnr: f64,
    /// Mean test SSIM of C_SH.
    pub ssim: f64,
    /// Mean masked test PSNR of C_SH.
    pub psnr_masked: Option<f64>,
    /// Mean test PSNR of C_PBR (stage 2 with PBR).
    pub psnr_pbr: Option<f64>,
    /// Mesh metrics against the ground truth that the training cameras see
    /// ([`gtsr_eval::chamfer_seen`]).
    pub mesh: Option<MeshMetrics>,
    /// Mesh metrics against the whole ground truth ([`gtsr_eval::chamfer`]), hidden faces included;
    /// only for the final (not coarse) evaluation.
    pub mesh_whole_gt: Option<MeshMetrics>,
    /// The mesh fused from the rendered depth alone ([`gtsr_mesh::MeshConfig::depth_only`])
    /// against the seen ground truth: the model's own geometry, which follows the training
    /// where `mesh` is bounded by the masks. Only when the extraction uses the masks.
    pub depth_only: Option<MeshMetrics>,
    /// The masks alone against the same ground truth ([`MeshSettings::masks_alone`]), beside
    /// every evaluation.
    pub masks_alone: Option<MeshMetrics>,
    /// Rendered depth and normals of the test views against the ground-truth mesh, inside the
    /// masks ([`test_view_geometry`]).
    pub depth: Option<DepthMetrics>,
    /// The same against the ground truth averaged over each pixel's area
    /// ([`AREA_RAYS`]^2 rays per pixel); only for the final (not coarse) evaluation.
    pub depth_area: Option<DepthMetrics>,
    /// The extracted mesh.
    pub extracted: Option<TriMesh>,
    /// Seconds spent evaluating.
    pub seconds: f64,
}

impl Evaluation {
    /// The evaluation as a point of the error-against-time log, at the snapshot's step.
    pub fn timeline_point(
        &self,
        at: &Snapshot,
        train_seconds: f64,
        label: &str,
    ) -> gtsr_eval::TimelinePoint {
        let (ns, ni) = at.model.counts();
        // The split only where the ground truth has a hull-blind part.
        let split = |m: &Option<MeshMetrics>| m.as_ref()?.hull_blind.filter(|b| b.fraction > 0.0);
        let (mesh, masks) = (split(&self.mesh), split(&self.masks_alone));
        gtsr_eval::TimelinePoint {
            iteration: at.step as u64,
            train_seconds,
            psnr: self.psnr,
            ssim: self.ssim,
            chamfer: self.mesh.as_ref().map(|m| m.chamfer),
            depth_only_chamfer: self.depth_only.as_ref().map(|m| m.chamfer),
            masks_alone_chamfer: self.masks_alone.as_ref().map(|m| m.chamfer),
            depth_error: self.depth.as_ref().map(|d| d.depth_median_abs),
            blind_completeness: mesh.map(|b| b.blind),
            rest_completeness: mesh.map(|b| b.rest),
            masks_alone_blind_completeness: masks.map(|b| b.blind),
            masks_alone_rest_completeness: masks.map(|b| b.rest),
            mesh_change: None,
            gaussians: (ns + ni) as u64,
            label: label.into(),
        }
    }
}

/// Renders the test views (PSNR/SSIM of C_SH, and of C_PBR when present) and, with a
/// ground-truth mesh, extracts a mesh and measures it and the test views' surface depth.
/// `coarse` (the in-run evaluations): the TSDF fusion on a coarser grid, and the chamfer
/// against the seen ground truth only.
pub fn evaluate(
    at: &Snapshot,
    tests: &[ViewTensors],
    scene: &Scene,
    gt: Option<&TriMesh>,
    settings: &MeshSettings,
    coarse: bool,
) -> Result<Evaluation> {
    let t0 = Instant::now();
    let (model, opts) = (&at.model, at.options);
    let (mut p, mut s, mut pm, mut pp, mut n, mut nm, mut np) =
        (0.0, 0.0, 0.0, 0.0, 0usize, 0usize, 0usize);
    for (v, data) in tests.iter().zip(&scene.test) {
        let (w, h) = v.size();
        let r = model.render(&v.camera, &v.rays, opts)?;
        let img = rendered_image(r.c_sh);
        let pred = ImageRef::new(w, h, 3, &img);
        let gt_img = ImageRef::new(w, h, 3, &data.rgb);
        p += psnr(pred, gt_img, None)?.min(99.0);
        s += ssim(pred, gt_img, None)?;
        n += 1;
        if let Some(m) = &data.mask
            && m.iter().any(|x| *x > 0.5)
        {
            pm += psnr(pred, gt_img, Some(m))?.min(99.0);
            nm += 1;
        }
        if let Some(pbr) = r.c_pbr {
            let img: Vec<f32> = host_vec(pbr).iter().map(|x| x.clamp(0.0, 1.0)).collect();
            pp += psnr(ImageRef::new(w, h, 3, &img), gt_img, None)?.min(99.0);
            np += 1;
        }
    }
    let (mesh, mesh_whole_gt, depth_only, extracted) = match gt {
        Some(gt) if at.stage2 => {
            let (m, alone) = extract_meshes(at, scene, settings, coarse, true)?;
            let hull = settings.masks.as_ref().map(|m| &m.mesh);
            let cameras = training_cameras(scene);
            let depth_only = match alone {
                Some(a) if !a.triangles.is_empty() => {
                    Some(score_against_ground_truth(&a, gt, &cameras, hull)?.0)
                }
                _ => None,
            };
            if m.triangles.is_empty() {
                (None, None, depth_only, Some(m))
            } else {
                let (seen, whole) = score_against_ground_truth(&m, gt, &cameras, hull)?;
                // The whole-ground-truth number is reported only at the end (`finish`).
                (Some(seen), (!coarse).then_some(whole), depth_only, Some(m))
            }
        }
        _ => (None, None, None, None),
    };
    let (depth, depth_area) = match gt {
        Some(gt) => test_view_geometry(model, tests, scene, gt, settings, !coarse)?,
        _ => (None, None),
    };
    let avg = |x: f64, k: usize| if k > 0 { Some(x / k as f64) } else { None };
    Ok(Evaluation {
        psnr: p / n.max(1) as f64,
        ssim: s / n.max(1) as f64,
        psnr_masked: avg(pm, nm),
        psnr_pbr: avg(pp, np),
        mesh,
        mesh_whole_gt,
        depth_only,
        masks_alone: settings.masks_alone,
        depth,
        depth_area,
        extracted,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// Rays per pixel side of the area-averaged ground truth ([`MeshRaycaster::render_area`]).
pub const AREA_RAYS: u32 = 4;

/// The surface Gaussians' unbiased depth and blended normal on the test views against the
/// ground-truth mesh's (ray cast through each pixel centre), over the pixels inside the
/// ground-truth mask (all pixels without one) that the surface covers (coverage >= 0.5);
/// with `area`, also against the ground truth averaged over each pixel's area.
/// The depth is the raw render, before the grazing and edge filters of the fusion.
pub(crate) fn test_view_geometry(
    model: &Model,
    tests: &[ViewTensors],
    scene: &Scene,
    gt: &TriMesh,
    settings: &MeshSettings,
    area: bool,
) -> Result<(Option<DepthMetrics>, Option<DepthMetrics>)> {
    let caster = MeshRaycaster::new(gt, "ground-truth mesh")?;
    let bound = match &settings.masks {
        Some(m) if !m.mesh.triangles.is_empty() => {
            Some(MeshRaycaster::new(&m.mesh, "masks' mesh")?)
        }
        _ => None,
    };
    let mut cmp = DepthComparison::new();
    let mut cmp_area = area.then(DepthComparison::new);
    let readout = readout(model, settings);
    for (v, data) in tests.iter().zip(&scene.test) {
        let truth = caster.render(&data.camera);
        let g = readout.geometry(&v.camera, &v.rays)?;
        let depth = host_vec(g.depth);
        let normal = host_vec(g.normal);
        let cov = host_vec(g.coverage);
        let select: Vec<bool> = match &data.mask {
            Some(m) => m
                .iter()
                .zip(&cov)
                .map(|(m, c)| *m > 0.5 && *c >= 0.5)
                .collect(),
            None => cov.iter().map(|c| *c >= 0.5).collect(),
        };
        let bound_depth = bound.as_ref().map(|b| b.render(&data.camera));
        cmp.add_with_bound(&truth, &depth, &normal, &select, bound_depth.as_ref())
            .with_context(|| format!("comparing the depth of test view {}", data.name))?;
        if let Some(c) = cmp_area.as_mut() {
            let truth = caster.render_area(&data.camera, AREA_RAYS)?;
            c.add_with_bound(&truth, &depth, &normal, &select, bound_depth.as_ref())
                .with_context(|| format!("comparing the depth of test view {}", data.name))?;
        }
    }
    Ok((cmp.finish(), cmp_area.and_then(|c| c.finish())))
}
