//! Evaluation, mesh extraction and everything written to `--out`.

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result};
use glam::Vec3;
use gtsr_data::Scene;
use gtsr_data::ply::{TriMesh, write_ply};
use gtsr_eval::{
    DepthComparison, DepthMetrics, ImageRef, MeshMetrics, MeshRaycaster, OUTLINE_GAP_FOOTPRINTS,
    PlaneReadout, Timeline, psnr, score_against_ground_truth, ssim,
};
use gtsr_model::checkpoint::write_atomic;
use gtsr_model::export::write_splat_ply;
use gtsr_model::gaussians::host_vec;
use gtsr_model::geometry::pixel_rays;
use gtsr_model::model::{GeometryMaps, Model};
use gtsr_model::trainer::Trainer;
use gtsr_model::views::ViewTensors;
use gtsr_model::views::kernel_camera;
use serde::Serialize;

/// Mesh extraction: the settings and what the scene gives them.
pub struct MeshSettings {
    /// The settings (`config.json`'s `mesh`).
    pub config: gtsr_eval::MeshConfig,
    /// The masks at the dataset's resolution (every training view has one).
    pub masks: Option<gtsr_eval::MasksAlone>,
    /// The training views at the fusion resolution (cameras and masks), rendered again for the
    /// mesh; empty: the training views as trained.
    pub fusion_views: Vec<gtsr_data::View>,
    /// The mesh box from the masks ([`hull_bounds`], computed once per run); `None`: from the
    /// surface Gaussians at each extraction.
    pub bounds: Option<(Vec3, Vec3)>,
    /// The masks alone scored against the ground truth the training cameras see
    /// ([`score_masks_alone`], once per run): the baseline beside every mesh.
    pub masks_alone: Option<MeshMetrics>,
    /// The shading refinement's rounds in the evaluations along the run (0: none;
    /// [`gtsr_eval::MeshConfig::with_shading_rounds`]).
    pub in_run_shading_rounds: usize,
}

/// The masks' mesh of `masks` against the ground truth `gt` that the training cameras see, split
/// by the part it misses (the scene's masks alone, with a ground truth).
pub fn score_masks_alone(
    masks: Option<&gtsr_eval::MasksAlone>,
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
    /// The mesh fused from the rendered depth alone ([`gtsr_eval::MeshConfig::depth_only`])
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
    /// The evaluation as a point of the error-against-time log, at the trainer's step.
    pub fn timeline_point(
        &self,
        trainer: &Trainer,
        train_seconds: f64,
        label: &str,
    ) -> gtsr_eval::TimelinePoint {
        let (ns, ni) = trainer.model().counts();
        // The split only where the ground truth has a hull-blind part.
        let split = |m: &Option<MeshMetrics>| m.as_ref()?.hull_blind.filter(|b| b.fraction > 0.0);
        let (mesh, masks) = (split(&self.mesh), split(&self.masks_alone));
        gtsr_eval::TimelinePoint {
            iteration: trainer.steps_done() as u64,
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
            gaussians: (ns + ni) as u64,
            label: label.into(),
        }
    }
}

/// Without masks: the axis-aligned box around the surface Gaussians that matter (opacity at
/// least 0.05; all of them when fewer than 100 do), grown by 10 %. Percentile boxes cut thin parts such as ears
/// off, so the extremes are kept.
fn mesh_bounds(model: &Model) -> (Vec3, Vec3) {
    use gtsr_model::gaussians::ParamKind;
    let mut host = model.surface.to_host();
    host.unfloor_opacity(model.surface_opacity_floor);
    let (m, _) = host.column(ParamKind::Means).expect("means");
    let (o, _) = host.column(ParamKind::Opacity).expect("opacity");
    let min_logit = gtsr_model::gaussians::logit(0.05) as f32;
    let pick = |strong: bool| -> Vec<Vec3> {
        m.chunks_exact(3)
            .zip(o)
            .filter(|(p, l)| p.iter().all(|x| x.is_finite()) && (!strong || **l >= min_logit))
            .map(|(p, _)| Vec3::new(p[0], p[1], p[2]))
            .collect()
    };
    let mut pts = pick(true);
    if pts.len() < 100 {
        pts = pick(false);
    }
    let (lo, hi) = pts.iter().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(a, b), p| (a.min(*p), b.max(*p)),
    );
    if !lo.is_finite() || !hi.is_finite() {
        return (Vec3::splat(-1.0), Vec3::splat(1.0));
    }
    let pad = 0.1 * (hi - lo).max_element().max(1e-3);
    (lo - pad, hi + pad)
}

/// With a mask on every view: the box around the masks' visual hull
/// ([`gtsr_eval::hull::hull_box`]); `None` without masks. The object is inside every mask, so
/// the box cannot cut it off, whatever the opacity of its surface Gaussians (the Gaussian box
/// keeps only those of opacity 0.05 and more).
pub fn hull_bounds(views: &[gtsr_data::View]) -> Result<Option<(Vec3, Vec3)>> {
    let masked: Vec<(gtsr_data::Camera, &[f32])> = views
        .iter()
        .filter_map(|v| v.mask.as_deref().map(|m| (v.camera, m)))
        .collect();
    if masked.is_empty() || masked.len() != views.len() {
        return Ok(None);
    }
    Ok(gtsr_eval::hull::hull_box(&masked)?)
}

/// The training cameras (whose centres decide which ground truth is seen).
fn training_cameras(scene: &Scene) -> Vec<gtsr_data::Camera> {
    scene.train.iter().map(|v| v.camera).collect()
}

/// The model(s) whose depth is fused and measured ([`readout`]).
struct Readout {
    /// The training's render, or with the mesh setting `readout_blur_px2` a copy with that
    /// screen-space blur, or with `readout_blur_in_plane` everywhere a copy with the blur in
    /// each splat's plane.
    model: Model,
    /// With `readout_blur_in_plane` at the outlines: the copy with the blur in the plane.
    outlines: Option<Model>,
}

/// The readout of `model` under the mesh settings.
fn readout(model: &Model, settings: &MeshSettings) -> Readout {
    let c = &settings.config;
    let screen = || {
        c.readout_blur_px2
            .map(|b| model.detached_with_blur(b))
            .unwrap_or_else(|| model.detached())
    };
    let plane = || model.detached_with_plane_blur(c.readout_blur_px2.unwrap_or(model.blur_px2));
    match c.readout_blur_in_plane {
        PlaneReadout::Off => Readout {
            model: screen(),
            outlines: None,
        },
        PlaneReadout::Everywhere => Readout {
            model: plane(),
            outlines: None,
        },
        PlaneReadout::Outlines => Readout {
            model: screen(),
            outlines: Some(plane()),
        },
    }
}

/// The surface geometry whose depth is fused and measured: the blended maps, or with the mesh
/// setting `depth_crossing` those of the crossing splat; with `readout_blur_in_plane` at the
/// outlines, the plane's maps where the screen's nearer surface only spills over
/// ([`GeometryMaps::with_farther`]).
fn fusion_geometry(
    readout: &Readout,
    camera: &gtsr_render_kernels::Camera,
    rays: &burn::tensor::Tensor<3>,
    settings: &MeshSettings,
) -> Result<GeometryMaps> {
    let read = |model: &Model| -> Result<GeometryMaps> {
        Ok(match settings.config.depth_crossing {
            Some(t) => model.render_depth_crossing(camera, rays, t)?,
            None => model.render_depth(camera, rays)?,
        })
    };
    let maps = read(&readout.model)?;
    Ok(match &readout.outlines {
        Some(plane) => maps.with_farther(read(plane)?, camera.fx, OUTLINE_GAP_FOOTPRINTS),
        None => maps,
    })
}

/// The mesh: every fusion view's depth rendered and prepared ([`fusion_depth`]), then
/// gtsr-eval's recipe ([`gtsr_eval::extract_mesh`]: with masks and carving the native masks
/// carved by the depth, otherwise a TSDF). The notes of the recipe are printed unless `coarse`.
pub fn extract_mesh(
    trainer: &Trainer,
    scene: &Scene,
    settings: &MeshSettings,
    coarse: bool,
) -> Result<TriMesh> {
    Ok(extract_meshes(trainer, scene, settings, coarse, false)?.0)
}

/// Whether the extraction under `config` uses the masks (so that the depth alone gives
/// another mesh), on views that all have one.
fn uses_masks(config: &gtsr_eval::MeshConfig, masked: bool) -> bool {
    masked && (config.fusion == gtsr_eval::Fusion::Carve || config.silhouette_carving)
}

/// [`extract_mesh`], and with `depth_only` where the extraction uses the masks, the mesh
/// fused from the same depth maps alone ([`gtsr_eval::MeshConfig::depth_only`]).
fn extract_meshes(
    trainer: &Trainer,
    scene: &Scene,
    settings: &MeshSettings,
    coarse: bool,
    depth_only: bool,
) -> Result<(TriMesh, Option<TriMesh>)> {
    let readout = readout(trainer.model(), settings);
    let host_views: Vec<&gtsr_data::View> = if settings.fusion_views.is_empty() {
        scene.train.iter().collect()
    } else {
        settings.fusion_views.iter().collect()
    };
    let masked = host_views.iter().all(|v| v.mask.is_some());
    let in_run;
    let config = if coarse {
        in_run = settings
            .config
            .with_shading_rounds(settings.in_run_shading_rounds);
        &in_run
    } else {
        &settings.config
    };
    let maps = host_views
        .iter()
        .enumerate()
        .map(|(k, data)| {
            if settings.config.fuse_depth {
                fusion_depth(trainer, &readout, k, data, settings)
            } else {
                let mask = data
                    .mask
                    .clone()
                    .context("fusing the masks alone needs masks")?;
                Ok((Vec::new(), mask, Vec::new()))
            }
        })
        .collect::<Result<Vec<_>>>()?;
    let views: Vec<gtsr_eval::FusionView> = host_views
        .iter()
        .zip(&maps)
        .map(|(v, (depth, mask, normal))| gtsr_eval::FusionView {
            camera: &v.camera,
            depth,
            mask,
            normal,
        })
        .collect();
    let cameras = training_cameras(scene);
    let blended = masks_with_rendered_radiance(trainer, scene, settings, config, coarse)?;
    let inputs = gtsr_eval::FusionInputs {
        views: &views,
        masked,
        masks: blended.as_ref().or(settings.masks.as_ref()),
        footprint_cameras: &cameras,
        bounds: settings
            .bounds
            .unwrap_or_else(|| mesh_bounds(trainer.model())),
        coarse,
    };
    let (mesh, notes) = gtsr_eval::extract_mesh(config, &inputs)?;
    if !coarse {
        for n in notes {
            println!("{n}");
        }
    }
    let alone = if depth_only && config.fuse_depth && uses_masks(config, masked) {
        let t0 = Instant::now();
        let m = gtsr_eval::extract_mesh(&config.depth_only(), &inputs)?.0;
        if !coarse {
            println!(
                "the depth alone fused (TSDF, no masks): {} triangles ({:.1} s)",
                m.triangles.len(),
                t0.elapsed().as_secs_f64()
            );
        }
        Some(m)
    } else {
        None
    };
    Ok((mesh, alone))
}

/// With [`gtsr_eval::MeshConfig::shading_radiance_rendered`] above 0 in `config`, the masks
/// whose images feed the shading refinement blended with the model's C_SH render of each
/// training view, linear as the images are read; `None` where the refinement does not run (no
/// images, no carving, no anchor) or the trained views' size is not the masks' (the render
/// would be resampled). What it did is printed unless `coarse`.
fn masks_with_rendered_radiance(
    trainer: &Trainer,
    scene: &Scene,
    settings: &MeshSettings,
    config: &gtsr_eval::MeshConfig,
    coarse: bool,
) -> Result<Option<gtsr_eval::MasksAlone>> {
    let share = config.shading_radiance_rendered;
    let Some(masks) = settings.masks.as_ref().filter(|m| m.radiance.is_some()) else {
        return Ok(None);
    };
    let carving = config.fusion == gtsr_eval::Fusion::Carve;
    if share <= 0.0 || !carving || config.shading_anchor <= 0.0 {
        return Ok(None);
    }
    let views = trainer.views();
    let same_size = views.len() == masks.views.len()
        && (views.iter().zip(&masks.views))
            .all(|(v, (c, _))| v.size() == (c.width as usize, c.height as usize));
    if !same_size {
        if !coarse {
            println!(
                "mesh.shading_radiance_rendered: the trained views' size is not the masks', so \
                 the shading reads the images alone"
            );
        }
        return Ok(None);
    }
    let t0 = Instant::now();
    let model = trainer.model().detached();
    // C_SH alone: neither the geometry maps nor C_PBR, which it does not depend on.
    let opts = gtsr_model::RenderOptions {
        geometry: false,
        ..trainer.render_options(trainer.steps_done(), false)
    };
    let rendered = (views.iter().zip(&scene.train))
        .map(|(v, data)| {
            let r = model.render(&v.camera, &v.rays, opts)?;
            let img = rendered_image(r.c_sh);
            let srgb = data.encoding == gtsr_data::Encoding::Srgb;
            Ok(gtsr_eval::shading::linear_radiance(&img, srgb, None))
        })
        .collect::<Result<Vec<_>>>()?;
    let blended = masks
        .clone()
        .with_rendered_radiance(&rendered, share)
        .context("blending the rendered radiance into the images'")?;
    if !coarse {
        println!(
            "the shading reads {:.0} % of the model's render and {:.0} % of the images ({} \
             views rendered in {:.1} s)",
            100.0 * share,
            100.0 * (1.0 - share),
            rendered.len(),
            t0.elapsed().as_secs_f64()
        );
    }
    Ok(Some(blended))
}

/// A C_SH render as an image: its values on the host, clamped to `[0, 1]` as the images are.
fn rendered_image(c_sh: burn::tensor::Tensor<3>) -> Vec<f32> {
    host_vec(c_sh).iter().map(|x| x.clamp(0.0, 1.0)).collect()
}

/// One fusion view's depth map as fused (zero where not fused; [`gtsr_eval::prepare_depth`]),
/// its mask (without masks, the coverage at least 0.5) and its rendered camera-space normals
/// (premultiplied by the coverage). `k` indexes the trainer's views when
/// [`MeshSettings::fusion_views`] is empty.
fn fusion_depth(
    trainer: &Trainer,
    readout: &Readout,
    k: usize,
    data: &gtsr_data::View,
    settings: &MeshSettings,
) -> Result<(Vec<f32>, Vec<f32>, Vec<f32>)> {
    let trained = &trainer.views()[k];
    let same_size = trained.size() == (data.camera.width as usize, data.camera.height as usize);
    let (g, rays) = if settings.fusion_views.is_empty() && same_size {
        let v = trained;
        (
            fusion_geometry(readout, &v.camera, &v.rays, settings)?,
            v.rays.clone(),
        )
    } else {
        let device = trainer.views()[0].rays.device();
        let camera = kernel_camera(&data.camera, &data.name)?;
        let rays = pixel_rays(&camera, &device);
        (fusion_geometry(readout, &camera, &rays, settings)?, rays)
    };
    let normal = host_vec(g.normal);
    let rays = host_vec(rays);
    let mut depth = host_vec(g.depth);
    let cov = host_vec(g.coverage);
    let plane = host_vec(g.plane);
    let mask: Vec<f32> = match &data.mask {
        Some(m) => m.clone(),
        None => cov
            .iter()
            .map(|c| if *c >= 0.5 { 1.0 } else { 0.0 })
            .collect(),
    };
    let geometry = gtsr_eval::DepthGeometry {
        normal: &normal,
        plane: &plane,
        rays: &rays,
        coverage: Some(&cov),
    };
    gtsr_eval::prepare_depth(&data.camera, &mut depth, &geometry, &mask, true)
        .with_context(|| format!("preparing the depth of {}", data.name))?;
    Ok((depth, mask, normal))
}

/// Renders the test views (PSNR/SSIM of C_SH, and of C_PBR when present) and, with a
/// ground-truth mesh, extracts a mesh and measures it and the test views' surface depth.
/// `coarse` (the in-run evaluations): the TSDF fusion on a coarser grid, and the chamfer
/// against the seen ground truth only.
pub fn evaluate(
    trainer: &Trainer,
    tests: &[ViewTensors],
    scene: &Scene,
    gt: Option<&TriMesh>,
    settings: &MeshSettings,
    coarse: bool,
) -> Result<Evaluation> {
    let t0 = Instant::now();
    let model = trainer.model().detached();
    let opts = trainer.render_options(trainer.steps_done(), false);
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
        Some(gt) if trainer.is_stage2(trainer.steps_done().saturating_sub(1)) => {
            let (m, alone) = extract_meshes(trainer, scene, settings, coarse, true)?;
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
        Some(gt) => test_view_geometry(&model, tests, scene, gt, settings, !coarse)?,
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
fn test_view_geometry(
    model: &Model,
    tests: &[ViewTensors],
    scene: &Scene,
    gt: &TriMesh,
    settings: &MeshSettings,
    area: bool,
) -> Result<(Option<DepthMetrics>, Option<DepthMetrics>)> {
    let caster = MeshRaycaster::new(gt, "ground-truth mesh")?;
    let mut cmp = DepthComparison::new();
    let mut cmp_area = area.then(DepthComparison::new);
    let readout = readout(model, settings);
    for (v, data) in tests.iter().zip(&scene.test) {
        let truth = caster.render(&data.camera);
        let g = fusion_geometry(&readout, &v.camera, &v.rays, settings)?;
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
        cmp.add(&truth, &depth, &normal, &select)
            .with_context(|| format!("comparing the depth of test view {}", data.name))?;
        if let Some(c) = cmp_area.as_mut() {
            let truth = caster.render_area(&data.camera, AREA_RAYS)?;
            c.add(&truth, &depth, &normal, &select)
                .with_context(|| format!("comparing the depth of test view {}", data.name))?;
        }
    }
    Ok((cmp.finish(), cmp_area.and_then(|c| c.finish())))
}

/// Writes `value` as pretty JSON, atomically.
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<()> {
    let text = serde_json::to_string_pretty(value).context("serialising JSON")?;
    write_atomic(path, text.as_bytes()).with_context(|| format!("writing {}", path.display()))
}

/// Writes `text` to `path`, atomically.
pub fn write_text(path: &Path, text: &str) -> Result<()> {
    write_atomic(path, text.as_bytes()).with_context(|| format!("writing {}", path.display()))
}

/// The map from the trained (normalised) frame back to the dataset's own coordinates.
pub fn dataset_frame(scene: &Scene) -> gtsr_data::Normalisation {
    if scene.normalisation_applied {
        scene.normalisation
    } else {
        gtsr_data::Normalisation::IDENTITY
    }
}

/// `gaussians.ply`, in the dataset's frame.
pub fn write_splats(trainer: &Trainer, scene: &Scene, out: &Path) -> Result<usize> {
    let path = out.join("gaussians.ply");
    write_splat_ply(trainer.model(), &path, &dataset_frame(scene))
        .with_context(|| format!("writing {}", path.display()))
}

fn to_u8(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8
}

/// PNG strips per test view: ground truth | C_SH | C_PBR | normal | depth.
fn write_strips(
    trainer: &Trainer,
    tests: &[ViewTensors],
    scene: &Scene,
    dir: &Path,
) -> Result<usize> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let model = trainer.model().detached();
    let mut opts = trainer.render_options(trainer.steps_done(), false);
    opts.geometry = true;
    for (k, (v, data)) in tests.iter().zip(&scene.test).enumerate() {
        let (w, h) = v.size();
        let r = model.render(&v.camera, &v.rays, opts)?;
        let geo = match r.geometry.clone() {
            Some(g) => g,
            None => model.render_depth(&v.camera, &v.rays)?,
        };
        let sh = host_vec(r.c_sh);
        let pbr = r.c_pbr.map(host_vec);
        let normal = host_vec(geo.normal);
        let depth = host_vec(geo.depth);
        let cov = host_vec(geo.coverage);
        let covered: Vec<f32> = depth
            .iter()
            .zip(&cov)
            .filter(|(d, c)| **c > 0.5 && d.is_finite())
            .map(|(d, _)| *d)
            .collect();
        let (dmin, dmax) = covered
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), d| {
                (a.min(*d), b.max(*d))
            });
        let mut img = image::RgbImage::new((5 * w) as u32, h as u32);
        for y in 0..h {
            for x in 0..w {
                let p = y * w + x;
                let rgb = |v: &[f32]| [to_u8(v[3 * p]), to_u8(v[3 * p + 1]), to_u8(v[3 * p + 2])];
                let panels = [
                    rgb(&data.rgb),
                    rgb(&sh),
                    pbr.as_ref().map_or([0, 0, 0], |b| rgb(b)),
                    {
                        let c = cov[p].max(1e-3);
                        let n: [f32; 3] = std::array::from_fn(|i| normal[3 * p + i] / c);
                        if cov[p] > 0.5 {
                            n.map(|v| to_u8(0.5 - 0.5 * v))
                        } else {
                            [0, 0, 0]
                        }
                    },
                    if cov[p] > 0.5 && dmax > dmin {
                        let g = to_u8(1.0 - (depth[p] - dmin) / (dmax - dmin) * 0.8);
                        [g, g, g]
                    } else {
                        [0, 0, 0]
                    },
                ];
                for (i, c) in panels.iter().enumerate() {
                    img.put_pixel((i * w + x) as u32, y as u32, image::Rgb(*c));
                }
            }
        }
        let path = dir.join(format!("test_{k:03}.png"));
        let tmp = dir.join(format!(".test_{k:03}.png.tmp"));
        img.save_with_format(&tmp, image::ImageFormat::Png)
            .with_context(|| format!("writing {}", tmp.display()))?;
        std::fs::rename(&tmp, &path).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(tests.len())
}

/// A signed mean over a subset of the pixels x1e3 for the log (`-` when the subset is empty,
/// e.g. [`DepthMetrics::depth_mean_signed_off_edges`] when every pixel lies on an edge).
fn signed_x1e3(v: Option<f64>) -> String {
    v.map_or("-".into(), |v| format!("{:+.2}", v * 1e3))
}

/// Final outputs: mesh, splats, renders, metrics, error-against-time plot.
#[allow(clippy::too_many_arguments)]
pub fn finish(
    trainer: &Trainer,
    tests: &[ViewTensors],
    scene: &Scene,
    gt: Option<&TriMesh>,
    settings: &MeshSettings,
    timeline: &Timeline,
    train_seconds: f64,
    out: &Path,
) -> Result<()> {
    println!("final evaluation and mesh extraction...");
    let e = evaluate(trainer, tests, scene, gt, settings, false)?;
    let mesh = match e.extracted.clone() {
        Some(m) => m,
        None => extract_mesh(trainer, scene, settings, false)?,
    };
    let mesh_path = out.join("mesh.ply");
    // Metrics are taken in the trained frame (above); the file is in the dataset's.
    let frame = dataset_frame(scene);
    let world = TriMesh {
        positions: mesh.positions.iter().map(|p| frame.to_world(*p)).collect(),
        ..mesh.clone()
    };
    write_ply(&mesh_path, &world).with_context(|| format!("writing {}", mesh_path.display()))?;
    let n_splats = write_splats(trainer, scene, out)?;
    let n_strips = write_strips(trainer, tests, scene, &out.join("renders"))?;
    let (ns, ni) = trainer.model().counts();
    let masks_alone = settings.masks_alone;
    let metrics = gtsr_eval::RunMetrics {
        iterations: trainer.steps_done(),
        train_seconds,
        surface_gaussians: ns,
        interior_gaussians: ni,
        skipped_steps: trainer.counters().skipped_steps,
        raster_passes: trainer.counters().passes,
        tile_splats: trainer.counters().tile_splats,
        tile_splats_per_pass: trainer.counters().tile_splats as f64
            / trainer.counters().passes.max(1) as f64,
        trimmed_surface: trainer.counters().trimmed,
        demoted_surface: trainer.counters().demoted,
        test_psnr: e.psnr,
        test_ssim: e.ssim,
        test_psnr_masked: e.psnr_masked,
        test_psnr_pbr: e.psnr_pbr,
        mesh: e.mesh,
        mesh_whole_gt: e.mesh_whole_gt,
        masks_alone,
        mesh_depth_only: e.depth_only,
        test_depth: e.depth,
        test_depth_area: e.depth_area,
        mesh_vertices: mesh.positions.len(),
        mesh_triangles: mesh.triangles.len(),
    };
    let path = out.join("metrics.json");
    metrics
        .write(&path)
        .with_context(|| format!("writing {}", path.display()))?;
    // The curve's last point is the mesh as written (the evaluations during training take
    // the quicker extraction).
    let mut timeline = timeline.clone();
    timeline.set_final(e.timeline_point(trainer, train_seconds, gtsr_eval::FINAL_LABEL));
    let csv = out.join("error_vs_time.csv");
    timeline
        .write_csv(&csv)
        .with_context(|| format!("writing {}", csv.display()))?;
    let plot = out.join("error_vs_time.png");
    gtsr_eval::plot_png(&plot, &[("gtsr", &timeline)])
        .with_context(|| format!("writing {}", plot.display()))?;
    println!("outputs in {}:", out.display());
    println!(
        "  mesh.ply            {} vertices, {} triangles",
        mesh.positions.len(),
        mesh.triangles.len()
    );
    println!("  gaussians.ply       {n_splats} splats ({ns} surface, {ni} interior)");
    println!(
        "  renders/            {n_strips} strips: ground truth | C_SH | C_PBR | normal | depth"
    );
    println!(
        "  metrics.json, config.json, error_vs_time.csv, error_vs_time.png, checkpoint.safetensors"
    );
    println!(
        "final: {} steps in {:.0} s training; test PSNR {:.2} dB, SSIM {:.4}{}{}",
        trainer.steps_done(),
        train_seconds,
        e.psnr,
        e.ssim,
        e.psnr_pbr
            .map_or(String::new(), |p| format!(", C_PBR PSNR {p:.2} dB")),
        e.mesh.as_ref().map_or(String::new(), |m| format!(
            "; chamfer {:.5} (x1e3 {:.2}; {:.1} % of the ground truth seen{}), F-score {:.3} at \
             {:.4}, normal consistency {:.3}",
            m.chamfer,
            m.chamfer * 1e3,
            100.0 * m.gt_seen,
            e.mesh_whole_gt.as_ref().map_or(String::new(), |w| format!(
                "; x1e3 {:.2} against all of it",
                w.chamfer * 1e3
            )),
            m.fscore,
            m.threshold,
            m.normal_consistency
        ))
    );
    let blind = |m: &MeshMetrics| {
        m.hull_blind.map_or(String::new(), |b| {
            format!(
                "; on the {:.1} % the masks miss by > {:.3}: {:.2} x1e3 (elsewhere {:.2})",
                100.0 * b.fraction,
                b.threshold,
                b.blind * 1e3,
                b.rest * 1e3
            )
        })
    };
    if let Some(m) = &e.mesh {
        println!("mesh: chamfer x1e3 {:.2}{}", m.chamfer * 1e3, blind(m));
    }
    if let Some(m) = &masks_alone {
        println!(
            "masks alone ({} px masks): chamfer x1e3 {:.2}{}",
            settings.masks.as_ref().map_or(0, |n| n.views[0].0.width),
            m.chamfer * 1e3,
            blind(m)
        );
    }
    if let Some(m) = &e.depth_only {
        println!(
            "the rendered depth alone (TSDF, no masks): chamfer x1e3 {:.2}{}",
            m.chamfer * 1e3,
            blind(m)
        );
    }
    if let Some(d) = &e.depth {
        println!(
            "test-view geometry against the ground truth ({} px, {:.1} % covered): depth error \
             x1e3 median {:.2}, mean {:.2}, mean signed {:+.2} (+: behind the surface); normal \
             error median {:.1} deg, mean {:.1} deg",
            d.pixels,
            100.0 * d.coverage,
            d.depth_median_abs * 1e3,
            d.depth_mean_abs * 1e3,
            d.depth_mean_signed * 1e3,
            d.normal_median_deg,
            d.normal_mean_deg
        );
        let q = d.depth_signed_quantiles.map(|v| format!("{:+.2}", v * 1e3));
        println!(
            "  signed depth error x1e3 at 5/25/50/75/95 %: {}; mean signed within 5-95 %: {:+.2}; \
             {:.1} % of the pixels on the truth's occluding edges, mean signed off them {}; \
             {:.1} % just behind one, mean signed there {}",
            q.join(" / "),
            d.depth_mean_signed_inner * 1e3,
            100.0 * d.edge_share,
            signed_x1e3(d.depth_mean_signed_off_edges),
            100.0 * d.far_side_share,
            signed_x1e3(d.depth_mean_signed_far_side)
        );
    }
    if let Some(d) = &e.depth_area {
        println!(
            "  against the truth averaged over each pixel ({AREA_RAYS}x{AREA_RAYS} rays): depth \
             error x1e3 median {:.2}, mean {:.2}, mean signed {:+.2}; off the occluding edges {}",
            d.depth_median_abs * 1e3,
            d.depth_mean_abs * 1e3,
            d.depth_mean_signed * 1e3,
            signed_x1e3(d.depth_mean_signed_off_edges)
        );
    }
    Ok(())
}
