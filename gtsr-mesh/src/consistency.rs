//! Multi-view depth consistency: keep a depth sample only where other views' depth maps agree
//! with it, as multi-view stereo systems filter their depth maps before fusion.
//!
//! A TSDF averages its votes, so it is not robust to a few far-off samples: one depth far
//! behind the surface carves everything in front of it along its ray, within the truncation.
//! Gaussian-splatting depth has such tails (mixed pixels, a faint front layer that one view
//! sees through and its neighbours do not). A sample `X` of view `i` (the back-projection of
//! its depth through the pixel centre) is checked against each of the `neighbours` views whose
//! optical axes are nearest to view `i`'s: projected into view `j`, at depth `z_j`, it
//! **agrees** when `j`'s depth at the pixel containing the projection is within `footprints`
//! pixel footprints of `z_j` (`footprints * z_j / fx_j`). Views that do not see `X` (behind
//! the camera, outside the image) or hold no depth there do not vote. The sample is kept
//! when at least `min_agree` neighbours agree.
//!
//! The filter reads the unfiltered maps only, so its result does not depend on the order of
//! the views.

use glam::Vec3;
use gtsr_data::Camera;
use rayon::prelude::*;

use crate::error::{MeshError, Result};

/// Settings of [`filter_consistent`].
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ConsistencySettings {
    /// How many views, those with the nearest optical axes, check each view.
    pub neighbours: usize,
    /// How many of them must agree for a sample to be kept.
    pub min_agree: usize,
    /// The agreement tolerance, in the checking view's pixel footprints at the sample.
    pub footprints: f32,
}

impl Default for ConsistencySettings {
    /// Eight neighbours, two agreeing, within one footprint.
    fn default() -> Self {
        Self {
            neighbours: 8,
            min_agree: 2,
            footprints: 1.0,
        }
    }
}

impl ConsistencySettings {
    fn check(&self) -> Result<()> {
        if self.neighbours == 0 || self.min_agree == 0 || self.min_agree > self.neighbours {
            return Err(MeshError::InvalidArgument(format!(
                "depth consistency needs 1 <= min_agree ({}) <= neighbours ({})",
                self.min_agree, self.neighbours
            )));
        }
        if !(self.footprints.is_finite() && self.footprints > 0.0) {
            return Err(MeshError::InvalidArgument(format!(
                "depth consistency tolerance must be positive and finite, got {} footprints",
                self.footprints
            )));
        }
        Ok(())
    }
}

/// One view's depth map: z-depth per pixel (row-major `width x height` of the camera; `<= 0`
/// or non-finite: none).
#[derive(Clone, Copy, Debug)]
pub struct DepthView<'a> {
    /// The view's camera.
    pub camera: &'a Camera,
    /// The depth map.
    pub depth: &'a [f32],
}

/// What [`filter_consistent`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ConsistencyStats {
    /// Samples with a depth before the filter.
    pub samples: usize,
    /// Samples dropped.
    pub dropped: usize,
}

/// The indices of the `k` views whose optical axes are nearest to view `i`'s (largest dot
/// product of the viewing directions; ties by index), `i` left out.
pub fn nearest_views(cameras: &[&Camera], i: usize, k: usize) -> Vec<usize> {
    let a = cameras[i].forward();
    let mut others: Vec<(f32, usize)> = (0..cameras.len())
        .filter(|&j| j != i)
        .map(|j| (-a.dot(cameras[j].forward()), j))
        .collect();
    others.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
    others.into_iter().take(k).map(|(_, j)| j).collect()
}

/// Filters every view's depth map against its neighbours' (module documentation), returning
/// the filtered maps (dropped samples set to `0`) in the order given, and the counts. Errors
/// on a map of the wrong size, invalid settings, or a non-invertible camera.
pub fn filter_consistent(
    views: &[DepthView<'_>],
    settings: &ConsistencySettings,
) -> Result<(Vec<Vec<f32>>, ConsistencyStats)> {
    settings.check()?;
    for (k, v) in views.iter().enumerate() {
        let n = v.camera.width as usize * v.camera.height as usize;
        if v.depth.len() != n {
            return Err(MeshError::size(
                &format!("depth map of view {k}"),
                format!("{}x{} = {n}", v.camera.width, v.camera.height),
                v.depth.len(),
            ));
        }
        if v.camera.world_to_camera.matrix3.determinant().abs() < 1e-12 {
            return Err(MeshError::InvalidArgument(format!(
                "view {k}: the camera's rotation is singular"
            )));
        }
    }
    let cameras: Vec<&Camera> = views.iter().map(|v| v.camera).collect();
    let k = settings.neighbours.min(views.len().saturating_sub(1));
    let filtered: Vec<(Vec<f32>, usize, usize)> = (0..views.len())
        .into_par_iter()
        .map(|i| {
            let near = nearest_views(&cameras, i, k);
            filter_view(views, i, &near, settings)
        })
        .collect();
    let mut stats = ConsistencyStats::default();
    let maps = filtered
        .into_iter()
        .map(|(m, s, d)| {
            stats.samples += s;
            stats.dropped += d;
            m
        })
        .collect();
    Ok((maps, stats))
}

/// One view's filtered map, its sample count and how many it dropped.
fn filter_view(
    views: &[DepthView<'_>],
    i: usize,
    near: &[usize],
    settings: &ConsistencySettings,
) -> (Vec<f32>, usize, usize) {
    let view = views[i];
    let cam = view.camera;
    let (w, h) = (cam.width as usize, cam.height as usize);
    let to_world = cam.world_to_camera.inverse();
    let mut out = view.depth.to_vec();
    let (mut samples, mut dropped) = (0, 0);
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            let d = view.depth[p];
            if !(d.is_finite() && d > 0.0) {
                continue;
            }
            samples += 1;
            let ray = cam.camera_direction(x as f32 + 0.5, y as f32 + 0.5);
            let world = to_world.transform_point3(ray * d);
            let agree = near
                .iter()
                .filter(|&&j| agrees(&views[j], world, settings.footprints))
                .count();
            if agree < settings.min_agree {
                out[p] = 0.0;
                dropped += 1;
            }
        }
    }
    (out, samples, dropped)
}

/// Whether view `other` holds a depth within `footprints` pixel footprints of the point's.
fn agrees(other: &DepthView<'_>, world: Vec3, footprints: f32) -> bool {
    let c = other.camera;
    let Some((uv, z)) = c.project(world) else {
        return false;
    };
    if !(uv.x >= 0.0 && uv.y >= 0.0 && uv.x < c.width as f32 && uv.y < c.height as f32) {
        return false;
    }
    let q = (uv.y as usize).min(c.height as usize - 1) * c.width as usize
        + (uv.x as usize).min(c.width as usize - 1);
    let dq = other.depth[q];
    dq.is_finite() && dq > 0.0 && (dq - z).abs() <= footprints * z / c.fx
}
