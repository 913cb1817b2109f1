//! The mesh of a trained model: the settings and what the scene gives them, the model's
//! depth, normals and radiance read out per fusion view, and `gtsr-mesh`'s recipe on them.

use std::time::Instant;

use crate::evaluation::Snapshot;
use anyhow::{Context, Result};
use glam::Vec3;
use gtsr_data::Scene;
use gtsr_data::ply::TriMesh;
use gtsr_eval::MeshMetrics;
use gtsr_mesh::{OUTLINE_GAP_FOOTPRINTS, PlaneReadout};
use gtsr_model::geometry::pixel_rays;
use gtsr_model::model::Model;
use gtsr_model::readout::{HostGeometry, PlaneBlur, Readout, ReadoutSettings, rendered_image};
use gtsr_model::views::kernel_camera;

/// Mesh extraction: the settings and what the scene gives them.
pub struct MeshSettings {
    /// The settings (`config.json`'s `mesh`).
    pub config: gtsr_mesh::MeshConfig,
    /// The masks at the dataset's resolution (every training view has one).
    pub masks: Option<gtsr_mesh::MasksAlone>,
    /// The training views at the fusion resolution (cameras and masks), rendered again for the
    /// mesh; empty: the training views as trained.
    pub fusion_views: Vec<gtsr_data::View>,
    /// The mesh box from the masks ([`hull_bounds`], computed once per run); `None`: from the
    /// surface Gaussians at each extraction.
    pub bounds: Option<(Vec3, Vec3)>,
    /// The masks alone scored against the ground truth the training cameras see
    /// ([`crate::evaluation::score_masks_alone`], once per run): the baseline beside every mesh.
    pub masks_alone: Option<MeshMetrics>,
    /// The shading refinement's rounds in the evaluations along the run (0: none;
    /// [`gtsr_mesh::MeshConfig::with_shading_rounds`]).
    pub in_run_shading_rounds: usize,
}

/// Without masks: the axis-aligned box around the surface Gaussians that matter (opacity at
/// least 0.05; all of them when fewer than 100 do), grown by 10 %. Percentile boxes cut thin parts such as ears
/// off, so the extremes are kept.
pub(crate) fn mesh_bounds(model: &Model) -> (Vec3, Vec3) {
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
/// ([`gtsr_mesh::hull::hull_box`]); `None` without masks. The object is inside every mask, so
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
    Ok(gtsr_mesh::hull::hull_box(&masked)?)
}

/// The training cameras (whose centres decide which ground truth is seen).
pub(crate) fn training_cameras(scene: &Scene) -> Vec<gtsr_data::Camera> {
    scene.train.iter().map(|v| v.camera).collect()
}

/// The readout settings of the mesh settings.
pub fn readout_settings(config: &gtsr_mesh::MeshConfig) -> ReadoutSettings {
    ReadoutSettings {
        blur_px2: config.readout_blur_px2,
        plane_blur: match config.readout_blur_in_plane {
            PlaneReadout::Off => PlaneBlur::Off,
            PlaneReadout::Everywhere => PlaneBlur::Everywhere,
            PlaneReadout::Outlines => PlaneBlur::Outlines,
        },
        depth_crossing: config.depth_crossing,
        outline_gap_footprints: OUTLINE_GAP_FOOTPRINTS,
    }
}

/// The readout of `model` under the mesh settings.
pub(crate) fn readout(model: &Model, settings: &MeshSettings) -> Readout {
    Readout::new(model, &readout_settings(&settings.config))
}

/// The mesh: every fusion view's depth rendered and prepared ([`fusion_depth`]), then
/// gtsr-mesh's recipe ([`gtsr_mesh::extract_mesh`]: with masks and carving the native masks
/// carved by the depth, otherwise a TSDF). The notes of the recipe are printed unless `coarse`.
pub fn extract_mesh(
    at: &Snapshot,
    scene: &Scene,
    settings: &MeshSettings,
    coarse: bool,
) -> Result<TriMesh> {
    Ok(extract_meshes(at, scene, settings, coarse, false)?.0)
}

/// Whether the extraction under `config` uses the masks (so that the depth alone gives
/// another mesh), on views that all have one.
pub(crate) fn uses_masks(config: &gtsr_mesh::MeshConfig, masked: bool) -> bool {
    masked && (config.fusion == gtsr_mesh::Fusion::Carve || config.silhouette_carving)
}

/// [`extract_mesh`], and with `depth_only` where the extraction uses the masks, the mesh
/// fused from the same depth maps alone ([`gtsr_mesh::MeshConfig::depth_only`]).
pub(crate) fn extract_meshes(
    at: &Snapshot,
    scene: &Scene,
    settings: &MeshSettings,
    coarse: bool,
    depth_only: bool,
) -> Result<(TriMesh, Option<TriMesh>)> {
    let readout = readout(&at.model, settings);
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
                fusion_depth(at, &readout, k, data, settings)
            } else {
                let mask = data
                    .mask
                    .clone()
                    .context("fusing the masks alone needs masks")?;
                Ok((Vec::new(), mask, Vec::new()))
            }
        })
        .collect::<Result<Vec<_>>>()?;
    let views: Vec<gtsr_mesh::FusionView> = host_views
        .iter()
        .zip(&maps)
        .map(|(v, (depth, mask, normal))| gtsr_mesh::FusionView {
            camera: &v.camera,
            depth,
            mask,
            normal,
        })
        .collect();
    let cameras = training_cameras(scene);
    let blended = masks_with_rendered_radiance(at, scene, settings, config, coarse)?;
    let inputs = gtsr_mesh::FusionInputs {
        views: &views,
        masked,
        masks: blended.as_ref().or(settings.masks.as_ref()),
        footprint_cameras: &cameras,
        bounds: settings.bounds.unwrap_or_else(|| mesh_bounds(&at.model)),
        coarse,
    };
    let (mesh, notes) = gtsr_mesh::extract_mesh(config, &inputs)?;
    if !coarse {
        for n in notes {
            println!("{n}");
        }
    }
    let alone = if depth_only && config.fuse_depth && uses_masks(config, masked) {
        let t0 = Instant::now();
        let m = gtsr_mesh::extract_mesh(&config.depth_only(), &inputs)?.0;
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

/// With [`gtsr_mesh::MeshConfig::shading_radiance_rendered`] above 0 in `config`, the masks
/// whose images feed the shading refinement blended with the model's C_SH render of each
/// training view at the masks' own size (rendered from the masks' cameras where the trained
/// views are another size), linear as the images are read; `None` where the refinement does
/// not run (no images, no carving, no anchor) or the views are not the masks' views. What it
/// did is printed unless `coarse`.
pub(crate) fn masks_with_rendered_radiance(
    at: &Snapshot,
    scene: &Scene,
    settings: &MeshSettings,
    config: &gtsr_mesh::MeshConfig,
    coarse: bool,
) -> Result<Option<gtsr_mesh::MasksAlone>> {
    let share = config.shading_radiance_rendered;
    let Some(masks) = settings.masks.as_ref().filter(|m| m.radiance.is_some()) else {
        return Ok(None);
    };
    let carving = config.fusion == gtsr_mesh::Fusion::Carve;
    if share <= 0.0 || !carving || config.shading_anchor <= 0.0 {
        return Ok(None);
    }
    let views = &at.views;
    let same_views = views.len() == masks.views.len()
        && (scene.train.iter().zip(&masks.views))
            .all(|(data, (c, _))| data.camera.world_to_camera == c.world_to_camera);
    if !same_views {
        if !coarse {
            println!(
                "mesh.shading_radiance_rendered: the trained views are not the masks' views, so \
                 the shading reads the images alone"
            );
        }
        return Ok(None);
    }
    let t0 = Instant::now();
    let model = &at.model;
    // C_SH alone: neither the geometry maps nor C_PBR, which it does not depend on.
    let opts = gtsr_model::model::RenderOptions {
        geometry: false,
        ..at.options
    };
    let mut resized = 0;
    let rendered = (views.iter().zip(&scene.train).zip(&masks.views))
        .map(|((v, data), (native, _))| {
            let r = if v.size() == (native.width as usize, native.height as usize) {
                model.render(&v.camera, &v.rays, opts)?
            } else {
                resized += 1;
                let camera = kernel_camera(native, &data.name)?;
                let rays = pixel_rays(&camera, &v.rays.device());
                model.render(&camera, &rays, opts)?
            };
            let img = rendered_image(r.c_sh);
            let srgb = data.encoding == gtsr_data::Encoding::Srgb;
            Ok(gtsr_mesh::shading::linear_radiance(&img, srgb, None))
        })
        .collect::<Result<Vec<_>>>()?;
    let blended = masks
        .clone()
        .with_rendered_radiance(&rendered, share)
        .context("blending the rendered radiance into the images'")?;
    if !coarse {
        let at = if resized > 0 {
            let (c, _) = &masks.views[0];
            format!(" at the masks' {}x{}", c.width, c.height)
        } else {
            String::new()
        };
        println!(
            "the shading reads {:.0} % of the model's render and {:.0} % of the images ({} \
             views rendered{at} in {:.1} s)",
            100.0 * share,
            100.0 * (1.0 - share),
            rendered.len(),
            t0.elapsed().as_secs_f64()
        );
    }
    Ok(Some(blended))
}

/// One fusion view's depth map as fused (zero where not fused; [`gtsr_mesh::prepare_depth`]),
/// its mask (without masks, the coverage at least 0.5) and its rendered camera-space normals
/// (premultiplied by the coverage). `k` indexes the snapshot's views when
/// [`MeshSettings::fusion_views`] is empty.
pub(crate) fn fusion_depth(
    at: &Snapshot,
    readout: &Readout,
    k: usize,
    data: &gtsr_data::View,
    settings: &MeshSettings,
) -> Result<(Vec<f32>, Vec<f32>, Vec<f32>)> {
    let trained = &at.views[k];
    let same_size = trained.size() == (data.camera.width as usize, data.camera.height as usize);
    let g = if settings.fusion_views.is_empty() && same_size {
        readout.host_geometry(&trained.camera, &trained.rays)?
    } else {
        let device = at.views[0].rays.device();
        let camera = kernel_camera(&data.camera, &data.name)?;
        readout.host_geometry(&camera, &pixel_rays(&camera, &device))?
    };
    let HostGeometry {
        mut depth,
        normal,
        plane,
        coverage: cov,
        rays,
    } = g;
    let mask: Vec<f32> = match &data.mask {
        Some(m) => m.clone(),
        None => cov
            .iter()
            .map(|c| if *c >= 0.5 { 1.0 } else { 0.0 })
            .collect(),
    };
    let geometry = gtsr_mesh::DepthGeometry {
        normal: &normal,
        plane: &plane,
        rays: &rays,
        coverage: Some(&cov),
    };
    gtsr_mesh::prepare_depth(&data.camera, &mut depth, &geometry, &mask, true)
        .with_context(|| format!("preparing the depth of {}", data.name))?;
    Ok((depth, mask, normal))
}
