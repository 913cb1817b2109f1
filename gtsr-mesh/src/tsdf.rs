//! Truncated signed distance fusion of depth maps (KinectFusion-style), as used to turn
//! rendered Gaussian-splatting depth into a mesh.
//!
//! # Conventions
//!
//! * Grid points (the "voxels") are at `min + voxel * (i, j, k)`; the grid covers
//!   `[min, max]` (rounded up to whole voxels).
//! * The stored value is a distance in world units, clamped to `[-truncation, truncation]`:
//!   **positive in front of the surface (outside, free space), negative behind it (inside)**,
//!   matching [`crate::marching`] (normals point outward).
//! * Per view and voxel projecting to pixel `(i, j)` (the pixel containing the projection):
//!   with a mask and `mask < 0.5` the voxel is free space: observation `+truncation`, weight 1
//!   (this carves the silhouette). Otherwise, when the depth `d` is finite and positive, the
//!   observation is `sdf = d - z` (z-depth difference along the camera axis); voxels with
//!   `sdf < -truncation` (far behind the surface) are not updated; the rest are updated with
//!   `sdf` clamped to `truncation`, weight 1. Depth `0` or non-finite means no measurement.
//! * Voxels with zero total weight stay unobserved; marching cubes makes no triangles next
//!   to them, so unseen space never becomes a false wall.
//! * With [`TsdfVolume::with_silhouette_carving`], the volume also keeps the visual-hull
//!   field `max over views of (0.5 - mask(u, v)) * z / fx` (mask bilinear between pixel
//!   centres, as [`crate::hull`]; scaled by the pixel footprint to approximate a distance).
//!   The extracted field is the larger of the two, so the surface stays inside every
//!   silhouette (the object is inside each of them) and is placed between voxels there as the
//!   hull is; the depth maps add what silhouettes cannot see (concavities). Masked-out pixels
//!   then update only the hull field, not the TSDF average (their `+truncation` votes would pull
//!   the average positive near every silhouette). Points inside the hull that no depth map measured
//!   count as inside (`-truncation`): where depth is missing the hull is the surface.

use glam::Vec3;
use gtsr_data::Camera;
use gtsr_data::ply::TriMesh;
use rayon::prelude::*;

use crate::error::{MeshError, Result};
use crate::marching::{Grid, marching_cubes};
use crate::pixels::bilinear;

/// Default truncation distance in voxels ([`TsdfVolume::new`] takes it in world units).
pub const DEFAULT_TRUNCATION_VOXELS: f32 = 4.0;

/// A voxel size for an object of bounding radius `radius`: 512 voxels across its diameter
/// (`radius / 256`; 0.0039 for the unit sphere, inside PGSR's 0.002..0.004 range for
/// normalised scenes); finer grids cost time without a better mesh (`docs/results.md`).
pub fn default_voxel_for_radius(radius: f32) -> f32 {
    radius / 256.0
}

/// The finest default voxel in pixel footprints ([`default_voxel`]).
pub const MIN_VOXEL_FOOTPRINTS: f32 = 0.25;

/// The default voxel for an object of bounding radius `radius` seen with pixel footprint
/// `footprint` at the object: [`default_voxel_for_radius`], but no finer than
/// [`MIN_VOXEL_FOOTPRINTS`] of a footprint. Depth maps sample the surface once per pixel, so
/// a grid much finer than their footprint holds no more of it and only costs time (a few
/// dozen pixels across the object would otherwise get the grid of a full-size image). A
/// footprint that is not positive and finite leaves the radius's voxel.
pub fn default_voxel(radius: f32, footprint: f32) -> f32 {
    let by_radius = default_voxel_for_radius(radius);
    if footprint.is_finite() && footprint > 0.0 {
        by_radius.max(MIN_VOXEL_FOOTPRINTS * footprint)
    } else {
        by_radius
    }
}

/// Mesh-box radii in the default truncation with free-space votes ([`default_truncation`]).
pub const TRUNCATION_RADII: f32 = 0.75;

/// Pixel footprints in the default truncation with free-space votes ([`default_truncation`]).
pub const TRUNCATION_FOOTPRINTS: f32 = 6.0;

/// Pixel footprints in the default truncation without free-space votes
/// ([`default_truncation`]).
pub const DEPTH_ONLY_TRUNCATION_FOOTPRINTS: f32 = 2.0;

/// The default truncation for fusing rendered depth (gtsr-train's), from the radius of the
/// mesh box and the median pixel footprint of the *training* images at its centre
/// ([`crate::pixels::median_pixel_footprint`]).
///
/// * With free-space votes (silhouette carving, or scenes without masks): the larger of
///   [`TRUNCATION_RADII`] radii and [`TRUNCATION_FOOTPRINTS`] footprints. Rendered depth lies
///   about a footprint behind the true surface, and KinectFusion drops votes far behind the
///   measured depth: a short truncation puts the surface at the rendered depth and erodes the
///   object, a long one lets the "inside" votes of the views that see a point from the far
///   side outweigh the "free" votes of the views that see it, so the field ends at the masks'
///   visual hull rather than inside it.
/// * Without free-space votes (depth alone on a masked scene): [`DEPTH_ONLY_TRUNCATION_FOOTPRINTS`]
///   footprints; a long truncation there swells the surface past the object.
///
/// The measurements behind both choices are in `docs/results.md`.
pub fn default_truncation(radius: f32, footprint: f32, free_space_votes: bool) -> f32 {
    if free_space_votes {
        (TRUNCATION_RADII * radius).max(TRUNCATION_FOOTPRINTS * footprint)
    } else {
        DEPTH_ONLY_TRUNCATION_FOOTPRINTS * footprint
    }
}

/// Depth whose surface normal makes a cosine below this with the viewing ray is not fused
/// ([`faces_ray`]).
pub const GRAZING_COS: f32 = 0.2;

/// Whether a depth sample with surface normal `normal`, seen along `ray` (neither needs unit
/// length), faces the ray enough to be fused: cosine at least [`GRAZING_COS`]. Gaussian
/// splatting's unbiased depth divides by `-(N . r)`; where the normal is nearly perpendicular
/// to the ray (silhouettes, mixed pixels) it runs far behind the surface, and fusing it would
/// carve the surface away along that ray. Zero or non-finite normals do not face the ray.
pub fn faces_ray(normal: Vec3, ray: Vec3) -> bool {
    let cos = -normal.dot(ray) / (normal.length() * ray.length()).max(1e-12);
    cos >= GRAZING_COS
}

/// Depth discontinuities wider than this many pixel footprints are not fused.
pub const EDGE_FOOTPRINTS: f32 = 2.0;

/// Zeroes the depth of pixels on a depth edge: where a 4-neighbour's depth is off the
/// pixel's own blended plane (intersected with the neighbour's ray) by more than
/// [`EDGE_FOOTPRINTS`] pixel footprints. A pixel that straddles an occlusion boundary (one
/// strand of a knot in front of another) blends two surfaces into a depth between them, well
/// behind the front one, and would carve it; a slanted but continuous surface is predicted by
/// its plane and stays. Neighbours without depth (the silhouette) are not edges.
///
/// The maps are row-major `w x h`: `depth` z-depth (`<= 0`: none), `normal` and `rays` three
/// floats a pixel in camera space (rays `((u - cx) / fx, (v - cy) / fy, 1)` through the pixel
/// centres, normals facing the camera), `plane` the plane's distance `-n . X` (for a surface
/// point `X = depth * ray`: `depth * -(n . ray)`); `fx` the focal length in pixels. A map of
/// the wrong size is an error, and nothing is changed.
pub fn drop_depth_edges(
    depth: &mut [f32],
    normal: &[f32],
    plane: &[f32],
    rays: &[f32],
    w: usize,
    h: usize,
    fx: f32,
) -> Result<()> {
    let n = w * h;
    for (what, len, per_pixel) in [
        ("depth map", depth.len(), 1),
        ("normal map", normal.len(), 3),
        ("plane map", plane.len(), 1),
        ("ray map", rays.len(), 3),
    ] {
        if len != per_pixel * n {
            return Err(MeshError::size(
                what,
                format!("{per_pixel} x {w}x{h} = {}", per_pixel * n),
                len,
            ));
        }
    }
    let orig = depth.to_vec();
    let at = |v: &[f32], p: usize| [v[3 * p], v[3 * p + 1], v[3 * p + 2]];
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            let d = orig[p];
            if d <= 0.0 {
                continue;
            }
            let n = at(normal, p);
            let tol = EDGE_FOOTPRINTS * d / fx;
            let neighbours = [
                (x > 0).then(|| p - 1),
                (x + 1 < w).then(|| p + 1),
                (y > 0).then(|| p - w),
                (y + 1 < h).then(|| p + w),
            ];
            let edge = neighbours.into_iter().flatten().any(|q| {
                let dq = orig[q];
                if dq <= 0.0 {
                    return false;
                }
                let r = at(rays, q);
                let ndr = -(n[0] * r[0] + n[1] * r[1] + n[2] * r[2]);
                let predicted = plane[p] / ndr.max(1e-6);
                !(predicted.is_finite() && (dq - predicted).abs() <= tol)
            });
            if edge {
                depth[p] = 0.0;
            }
        }
    }
    Ok(())
}

/// Replaces each depth sample that lies less than `footprints` pixel footprints behind the
/// masks' hull along its ray (or in front of it) by the hull's depth, and returns how many it
/// replaced. The object lies inside the hull, so where the rendered depth does not go
/// clearly deeper it says nothing the hull does not, and the hull, cut by every view's
/// silhouette, is the sharper of the two; what stays is the depth of concavities that no
/// silhouette sees. `depth` and `hull` (from [`TsdfVolume::hull_depth`]) are z-depth maps of
/// the same size (`<= 0`: none; samples whose ray misses the hull stay), `fx` the focal
/// length in pixels. Errors on mismatched sizes or a tolerance that is not finite and
/// non-negative.
pub fn snap_to_hull(depth: &mut [f32], hull: &[f32], fx: f32, footprints: f32) -> Result<usize> {
    if depth.len() != hull.len() {
        return Err(MeshError::size("hull depth map", depth.len(), hull.len()));
    }
    if !(footprints.is_finite() && footprints >= 0.0 && fx.is_finite() && fx > 0.0) {
        return Err(MeshError::InvalidArgument(format!(
            "snapping to the hull needs a finite tolerance >= 0 and a focal length > 0, got \
             {footprints} footprints and fx {fx}"
        )));
    }
    let mut snapped = 0;
    for (d, &hd) in depth.iter_mut().zip(hull) {
        if *d > 0.0 && hd > 0.0 && *d - hd < footprints * *d / fx {
            *d = hd;
            snapped += 1;
        }
    }
    Ok(snapped)
}

/// A TSDF volume: a [`Grid`] of clamped signed distances plus the fusion weights.
#[derive(Clone, Debug)]
pub struct TsdfVolume {
    grid: Grid,
    weights: Vec<f32>,
    truncation: f32,
    /// With silhouette carving, per grid point: the visual-hull distance (positive outside
    /// some mask).
    hull: Option<Vec<f32>>,
    /// Inside the hull where no depth map measured: the hull's own (negative) distance
    /// instead of `-truncation`.
    hull_inside_distance: bool,
}

impl TsdfVolume {
    /// An empty (all unobserved) volume covering `[min, max]` with grid spacing `voxel` and
    /// truncation distance `truncation` (world units; typically
    /// [`DEFAULT_TRUNCATION_VOXELS`]` * voxel`). Errors when the box is empty, the sizes are
    /// not positive and finite, or the grid would exceed 2^31 points.
    pub fn new(min: Vec3, max: Vec3, voxel: f32, truncation: f32) -> Result<Self> {
        if !(min.is_finite() && max.is_finite() && max.cmpgt(min).all()) {
            return Err(MeshError::InvalidArgument(format!(
                "TSDF box [{min}, {max}] is empty or not finite"
            )));
        }
        if !(voxel > 0.0 && voxel.is_finite() && truncation > 0.0 && truncation.is_finite()) {
            return Err(MeshError::InvalidArgument(format!(
                "TSDF voxel {voxel} and truncation {truncation} must be positive and finite"
            )));
        }
        let cells = ((max - min) / voxel).ceil();
        let dims = [cells.x, cells.y, cells.z].map(|c| c as usize + 1);
        let n = dims.iter().try_fold(1usize, |a, &d| a.checked_mul(d));
        match n {
            Some(n) if n <= (1 << 31) => {}
            _ => {
                return Err(MeshError::InvalidArgument(format!(
                    "TSDF grid {dims:?} is too large (voxel {voxel})"
                )));
            }
        }
        let grid = Grid::new(min, voxel, dims);
        let n = grid.values.len();
        let weights = vec![0.0; n];
        Ok(TsdfVolume {
            grid,
            weights,
            truncation,
            hull: None,
            hull_inside_distance: false,
        })
    }

    /// With carving: where no depth map measured a point inside the hull, keep the hull's own
    /// distance there (negative: `(0.5 - mask) * z / fx`, at most half a pixel footprint deep)
    /// instead of `-truncation`. Marching cubes then places the surface between the voxels
    /// on either side of the hull's boundary from the hull field's values on both sides,
    /// not at the outside voxel (a full `-truncation` inside pulls the crossing to it).
    pub fn with_hull_inside_distance(mut self) -> Self {
        self.hull_inside_distance = true;
        self
    }

    /// Turns on silhouette carving (see the module documentation): a grid point outside any
    /// view's mask ends up free space in [`TsdfVolume::extract_mesh`] and
    /// [`TsdfVolume::carved_grid`].
    pub fn with_silhouette_carving(mut self) -> Self {
        self.hull = Some(vec![f32::NEG_INFINITY; self.grid.values.len()]);
        self
    }

    /// The fused field with silhouette carving applied (the same as [`TsdfVolume::grid`]
    /// without it): the larger of the TSDF and the hull distance (clamped to the truncation),
    /// points outside the hull observed, and points inside the hull that no depth map measured
    /// at `-truncation` (inside: where depth is missing the hull is the surface).
    pub fn carved_grid(&self) -> Grid {
        let mut g = self.grid.clone();
        if let Some(hull) = &self.hull {
            for ((v, o), &d) in g.values.iter_mut().zip(&mut g.observed).zip(hull) {
                if d > 0.0 {
                    *v = if *o { v.max(d) } else { d }.min(self.truncation);
                    *o = true;
                } else if !*o && d.is_finite() {
                    // Inside every silhouette that sees it and never measured by a depth map:
                    // the hull is the best bound there is, so it counts as inside.
                    *v = if self.hull_inside_distance {
                        d.max(-self.truncation)
                    } else {
                        -self.truncation
                    };
                    *o = true;
                }
            }
        }
        g
    }

    /// With silhouette carving, the z-depth at which each pixel centre's ray first enters the
    /// masks' hull as fused so far (its field, sampled at the nearest grid point every half
    /// voxel from the camera through the box, the crossing placed linearly between the last
    /// sample outside and the first inside); `0` where the ray misses it. `None` without
    /// carving. Integrate every view's mask first: the hull is the intersection over the
    /// views seen so far.
    pub fn hull_depth(&self, camera: &Camera) -> Option<Vec<f32>> {
        let hull = self.hull.as_ref()?;
        let g = &self.grid;
        let (w, h) = (camera.width as usize, camera.height as usize);
        let to_world = camera.world_to_camera.inverse();
        let eye = to_world.transform_point3(Vec3::ZERO);
        let lo = g.origin;
        let hi = g.origin
            + g.voxel
                * Vec3::new(
                    (g.dims[0] - 1) as f32,
                    (g.dims[1] - 1) as f32,
                    (g.dims[2] - 1) as f32,
                );
        let sample = |p: Vec3| -> Option<f32> {
            let c = ((p - lo) / g.voxel).round();
            if c.min_element() < 0.0 {
                return None;
            }
            let (i, j, k) = (c.x as usize, c.y as usize, c.z as usize);
            if i >= g.dims[0] || j >= g.dims[1] || k >= g.dims[2] {
                return None;
            }
            let v = hull[g.index(i, j, k)];
            // Never seen by a mask: no bound.
            v.is_finite().then_some(v)
        };
        let depth = (0..w * h)
            .into_par_iter()
            .map(|p| {
                let (x, y) = ((p % w) as f32 + 0.5, (p / w) as f32 + 0.5);
                // t is the z-depth: the camera-space ray has z = 1.
                let dir = to_world.transform_vector3(camera.camera_direction(x, y));
                // The ray's span inside the box (slab test).
                let inv = dir.recip();
                let (t0, t1) = ((lo - eye) * inv, (hi - eye) * inv);
                let enter = t0.min(t1).max_element().max(1e-6);
                let exit = t0.max(t1).min_element();
                if !(enter.is_finite() && exit.is_finite()) || enter >= exit {
                    return 0.0;
                }
                let dt = 0.5 * g.voxel / dir.length();
                let mut prev: Option<(f32, f32)> = None;
                let mut t = enter;
                while t <= exit {
                    if let Some(v) = sample(eye + t * dir) {
                        if v <= 0.0 {
                            return match prev {
                                Some((tp, vp)) if vp > 0.0 => tp + (t - tp) * vp / (vp - v),
                                _ => t,
                            };
                        }
                        prev = Some((t, v));
                    }
                    t += dt;
                }
                0.0
            })
            .collect();
        Some(depth)
    }

    /// The fused field (values and observed flags).
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// Fusion weight of every grid point (number of views that updated it), x-fastest.
    pub fn weights(&self) -> &[f32] {
        &self.weights
    }

    /// The truncation distance (world units).
    pub fn truncation(&self) -> f32 {
        self.truncation
    }

    /// Fuses one view: `depth` holds the z-depth (camera-axis distance) of each pixel,
    /// row-major `width * height`, `0` or non-finite where there is no measurement; `mask`
    /// (same size, optional) marks the object, pixels with `mask < 0.5` carving free space.
    /// See the module documentation for the update rule. Parallel over z-slices.
    pub fn integrate(
        &mut self,
        camera: &Camera,
        depth: &[f32],
        mask: Option<&[f32]>,
    ) -> Result<()> {
        let (w, h) = (camera.width as usize, camera.height as usize);
        if depth.len() != w * h {
            return Err(MeshError::size(
                "depth map",
                format!("{w}x{h} = {}", w * h),
                depth.len(),
            ));
        }
        if let Some(m) = mask
            && m.len() != w * h
        {
            return Err(MeshError::size(
                "mask",
                format!("{w}x{h} = {}", w * h),
                m.len(),
            ));
        }
        let [nx, ny, _] = self.grid.dims;
        let plane = nx * ny;
        let (origin, voxel, trunc) = (self.grid.origin, self.grid.voxel, self.truncation);
        let m = camera.world_to_camera;
        let (wf, hf) = (w as f32, h as f32);
        let carving = self.hull.is_some();
        // One hull slice per z-slice when carving, none otherwise.
        let mut hull_slices: Vec<Option<&mut [f32]>> = match &mut self.hull {
            Some(hull) => hull.chunks_mut(plane).map(Some).collect(),
            None => (0..self.grid.dims[2]).map(|_| None).collect(),
        };
        self.grid
            .values
            .par_chunks_mut(plane)
            .zip(self.weights.par_chunks_mut(plane))
            .zip(self.grid.observed.par_chunks_mut(plane))
            .zip(hull_slices.par_iter_mut())
            .enumerate()
            .for_each(|(k, (((values, weights), observed), hull))| {
                let step = Vec3::from(m.matrix3.x_axis) * voxel;
                for j in 0..ny {
                    let row = origin + voxel * Vec3::new(0.0, j as f32, k as f32);
                    let mut pc = m.transform_point3(row);
                    for i in 0..nx {
                        let p = pc;
                        pc += step;
                        if p.z <= 1e-8 {
                            continue;
                        }
                        let inv_z = 1.0 / p.z;
                        let u = camera.fx * p.x * inv_z + camera.cx;
                        let v = camera.fy * p.y * inv_z + camera.cy;
                        if !(u >= 0.0 && v >= 0.0 && u < wf && v < hf) {
                            continue;
                        }
                        let pix = (v as usize).min(h - 1) * w + (u as usize).min(w - 1);
                        if let (Some(m), Some(hull)) = (mask, hull.as_deref_mut()) {
                            let d = (0.5 - bilinear(m, w, h, u, v)) * p.z / camera.fx;
                            let id = i + nx * j;
                            hull[id] = hull[id].max(d);
                        }
                        let sdf = if mask.is_some_and(|m| m[pix] < 0.5) {
                            if carving {
                                // The hull field has it; a +truncation vote here would pull
                                // every surface voxel near some view's silhouette outward.
                                continue;
                            }
                            trunc
                        } else {
                            let d = depth[pix];
                            if !(d.is_finite() && d > 0.0) {
                                continue;
                            }
                            let s = d - p.z;
                            if s < -trunc {
                                continue;
                            }
                            s.min(trunc)
                        };
                        let id = i + nx * j;
                        let wt = weights[id];
                        values[id] += (sdf - values[id]) / (wt + 1.0);
                        weights[id] = wt + 1.0;
                        observed[id] = true;
                    }
                }
            });
        Ok(())
    }

    /// The zero level set as a welded, outward-oriented mesh (empty when nothing crosses
    /// zero). Apply [`crate::mesh::largest_component`] to drop floaters.
    pub fn extract_mesh(&self) -> TriMesh {
        if self.hull.is_some() {
            marching_cubes(&self.carved_grid(), 0.0)
        } else {
            marching_cubes(&self.grid, 0.0)
        }
    }
}
