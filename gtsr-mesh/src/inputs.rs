//! What [`crate::extract_mesh`] reads besides the settings: the views' depth maps and masks
//! ([`FusionView`], [`FusionInputs`]), and the preparation of a rendered depth map
//! ([`prepare_depth`]).

use glam::Vec3;
use gtsr_data::Camera;

use crate::carve::DepthMap;
use crate::error::{MeshError, Result};
use crate::masks::*;
use crate::tsdf::{drop_depth_edges, faces_ray};

/// One view as the fusion reads it: z-depth (0 where nothing is measured) and the mask (the
/// coverage at least 0.5 where the scene has no masks), both `width * height`.
#[derive(Clone, Copy, Debug)]
pub struct FusionView<'a> {
    /// The view's camera (at the depth map's size).
    pub camera: &'a Camera,
    /// z-depth, 0 where there is no measurement; ignored when the settings fuse no depth.
    pub depth: &'a [f32],
    /// Mask in `[0, 1]`.
    pub mask: &'a [f32],
    /// Camera-space normals, 3 per pixel (zero where nothing was rendered; premultiplied
    /// normals do), for [`crate::MeshConfig::shading_normals_rendered`]; may be empty otherwise.
    pub normal: &'a [f32],
}

/// Everything [`crate::extract_mesh`] reads besides the settings.
#[derive(Clone, Copy, Debug)]
pub struct FusionInputs<'a> {
    /// The depth maps and masks, one per training view.
    pub views: &'a [FusionView<'a>],
    /// Whether every view's mask is a real mask (not the coverage).
    pub masked: bool,
    /// The masks at the dataset's resolution (with [`crate::Fusion::Carve`] on a masked scene).
    pub masks: Option<&'a MasksAlone>,
    /// The cameras whose pixel footprint sets the TSDF truncation (the training cameras).
    pub footprint_cameras: &'a [Camera],
    /// The box the mesh is extracted in.
    pub bounds: (Vec3, Vec3),
    /// A quicker, coarser TSDF (2.5 times the voxel), for evaluations during training (the
    /// carving's shading refinement is made quicker by the settings:
    /// [`crate::MeshConfig::with_shading_rounds`]).
    pub coarse: bool,
}

/// What [`prepare_depth`] reads beside a depth map: the surface's blended normal and plane
/// distance, the pixels' ray directions (camera frame) and the render's coverage.
#[derive(Clone, Copy, Debug)]
pub struct DepthGeometry<'a> {
    /// Normals, `3 * width * height` (need not be unit).
    pub normal: &'a [f32],
    /// The blended plane distance per pixel (for the depth edges).
    pub plane: &'a [f32],
    /// Ray directions, `3 * width * height`.
    pub rays: &'a [f32],
    /// Coverage per pixel; `None`: full coverage (a ground truth's depth).
    pub coverage: Option<&'a [f32]>,
}

/// Keeps in a rendered (or any) depth map only what the fusion may trust, in place: pixels
/// whose mask and coverage are at least 0.5, whose depth is finite and whose normal faces the
/// ray ([`faces_ray`]), and, with `drop_edges`, off depth edges ([`drop_depth_edges`]); the
/// rest become 0.
pub fn prepare_depth(
    camera: &Camera,
    depth: &mut [f32],
    geometry: &DepthGeometry,
    mask: &[f32],
    drop_edges: bool,
) -> Result<()> {
    let DepthGeometry {
        normal,
        plane,
        rays,
        coverage,
    } = *geometry;
    let n = camera.width as usize * camera.height as usize;
    for (what, len, want) in [
        ("depth", depth.len(), n),
        ("normal", normal.len(), 3 * n),
        ("plane", plane.len(), n),
        ("rays", rays.len(), 3 * n),
        ("mask", mask.len(), n),
        ("coverage", coverage.map_or(n, <[f32]>::len), n),
    ] {
        if len != want {
            return Err(MeshError::size(what, want, len));
        }
    }
    for (p, d) in depth.iter_mut().enumerate() {
        let nrm = Vec3::from_slice(&normal[3 * p..3 * p + 3]);
        let ray = Vec3::from_slice(&rays[3 * p..3 * p + 3]);
        let covered = coverage.is_none_or(|c| c[p] >= 0.5);
        if !(covered && mask[p] >= 0.5 && d.is_finite() && faces_ray(nrm, ray)) {
            *d = 0.0;
        }
    }
    if drop_edges {
        let (w, h) = (camera.width as usize, camera.height as usize);
        drop_depth_edges(depth, normal, plane, rays, w, h, camera.fx)?;
    }
    Ok(())
}

/// Each view's depth map for the carving, with the bound's own depth (`hulls`, one per view;
/// none when empty) where `with_hull`.
pub(crate) fn depth_maps<'a>(
    views: &'a [FusionView<'a>],
    maps: &'a [Vec<f32>],
    hulls: &'a [Vec<f32>],
    with_hull: bool,
) -> Vec<DepthMap<'a>> {
    views
        .iter()
        .zip(maps)
        .enumerate()
        .map(|(k, (v, depth))| DepthMap {
            camera: v.camera,
            depth,
            hull_depth: hulls.get(k).filter(|_| with_hull).map(Vec::as_slice),
        })
        .collect()
}
