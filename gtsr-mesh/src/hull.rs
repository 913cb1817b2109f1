//! Visual hull by silhouette carving: the set of points whose projection lies inside the
//! object mask in every view that sees them.
//!
//! The field handed to marching cubes is `max over views of (0.5 - mask(u, v))`, with the
//! mask bilinearly interpolated between pixel centres (clamped at the image border), so the
//! surface passes where the interpolated mask crosses 0.5 (sub-voxel placement). A view
//! constrains only the points in front of it that project inside its image. Points seen by
//! no view, and the faces of the bounding box, count as outside, so the hull is closed.
//!
//! [`coverage_to_distance_with`] turns a mask into an image the same functions read as the
//! signed distance to the mask's edge, by the mask's [`EdgeProfile`] (a box-filtered pixel, or
//! a smooth pixel filter whose width [`edge_width`] measures on the masks themselves); the
//! hull of those images ([`crate::MasksAlone::with_edge_distance`]) does not collect every
//! view's inward miss of the edge as the hull of the interpolated masks does.
//!
//! [`hull_slack`] bounds, at each point of the hull, how far the object can lie from it
//! whatever its shape: a few pixel footprints where the silhouettes hold the hull, the width of
//! a concavity no silhouette shows.

use glam::Vec3;
use gtsr_data::Camera;
use gtsr_data::ply::TriMesh;
use rayon::prelude::*;

use crate::error::{MeshError, Result};
use crate::marching::{Grid, marching_cubes};
use crate::pixels::{bilinear, median_pixel_footprint};

/// The signed distance, in pixels, from a pixel's centre to an edge that cuts the pixel
/// square into a covered part of area `coverage`, given the coverage gradient `(gx, gy)` (the
/// edge's normal); positive when less than half is covered. A straight edge through a square
/// pixel: a triangle at a corner for small (or large) coverage, a trapezoid between, where the
/// distance is linear in the coverage. Without a gradient, `0.5 - coverage`.
fn edge_distance(gx: f32, gy: f32, coverage: f32) -> f32 {
    let a = coverage.clamp(0.0, 1.0);
    let len = (gx * gx + gy * gy).sqrt();
    if len <= 1e-6 {
        return 0.5 - a;
    }
    let (mut nx, mut ny) = (gx.abs() / len, gy.abs() / len);
    if nx < ny {
        std::mem::swap(&mut nx, &mut ny);
    }
    if ny < 1e-6 {
        return 0.5 - a;
    }
    let corner = 0.5 * ny / nx;
    if a < corner {
        0.5 * (nx + ny) - (2.0 * nx * ny * a).sqrt()
    } else if a <= 1.0 - corner {
        (0.5 - a) * nx
    } else {
        -0.5 * (nx + ny) + (2.0 * nx * ny * (1.0 - a)).sqrt()
    }
}

/// How a mask's value falls across its edge: what [`coverage_to_distance_with`] inverts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum EdgeProfile {
    /// A box-filtered pixel: the fraction of the pixel's square the object covers (a straight
    /// edge cuts a trapezoid or a corner triangle).
    Box,
    /// A smooth pixel filter wider than the pixel (Blender Cycles' Blackman-Harris, say): the
    /// value at signed distance `d` from the edge (pixels, positive outside) is
    /// `Phi(-d / sigma)`, `Phi` the standard normal distribution function.
    Gaussian {
        /// The filter's standard deviation across the edge, in pixels.
        sigma: f32,
    },
}

/// The Sobel gradient `(x, y)` at pixel `(i, j)` of an image read through `at` (8 times the
/// gradient per pixel).
fn sobel(at: &impl Fn(isize, isize) -> f32, i: isize, j: isize) -> (f32, f32) {
    let gx = at(i + 1, j - 1) + 2.0 * at(i + 1, j) + at(i + 1, j + 1)
        - at(i - 1, j - 1)
        - 2.0 * at(i - 1, j)
        - at(i - 1, j + 1);
    let gy = at(i - 1, j + 1) + 2.0 * at(i, j + 1) + at(i + 1, j + 1)
        - at(i - 1, j - 1)
        - 2.0 * at(i, j - 1)
        - at(i + 1, j - 1);
    (gx, gy)
}

/// [`edge_width`] of a box-filtered straight edge along a pixel axis.
pub const BOX_EDGE_WIDTH: f32 = 1.0 / 6.0;

/// How wide the masks' edges are, in pixels: the sum over pixels of `a (1 - a)` over the sum of
/// the value's gradient length (Sobel, per pixel), pooled over every `(mask, w, h)`. The
/// gradient sums to the edge's length whatever the profile, so this is `int F (1 - F)` across
/// the edge for a profile `F`: [`BOX_EDGE_WIDTH`] for a box-filtered edge along an axis (less
/// when slanted), `sigma / sqrt(pi)` for a Gaussian. `None` when no mask has an edge.
pub fn edge_width(masks: &[(&[f32], usize, usize)]) -> Option<f32> {
    let (mut spread, mut length) = (0.0f64, 0.0f64);
    for &(mask, w, h) in masks {
        if w < 3 || h < 3 || mask.len() != w * h {
            continue;
        }
        let at = |i: isize, j: isize| mask[j as usize * w + i as usize].clamp(0.0, 1.0);
        for j in 1..h as isize - 1 {
            for i in 1..w as isize - 1 {
                let a = f64::from(at(i, j));
                spread += a * (1.0 - a);
                let (gx, gy) = sobel(&at, i, j);
                length += 0.125 * f64::from(gx.hypot(gy));
            }
        }
    }
    (length > 0.0 && spread > 0.0).then(|| (spread / length) as f32)
}

impl std::fmt::Display for EdgeProfile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            EdgeProfile::Box => write!(f, "box-filtered"),
            EdgeProfile::Gaussian { sigma } => write!(f, "a filter of {sigma:.3} px"),
        }
    }
}

impl EdgeProfile {
    /// The profile of masks whose edges are `width` wide ([`edge_width`]): a box when within
    /// 15 % of a box-filtered edge's width, else the Gaussian of that width.
    pub fn from_width(width: f32) -> EdgeProfile {
        if !(width.is_finite() && width > BOX_EDGE_WIDTH * 1.15) {
            EdgeProfile::Box
        } else {
            EdgeProfile::Gaussian {
                sigma: width * std::f32::consts::PI.sqrt(),
            }
        }
    }
}

/// The standard normal quantile: `x` with `Phi(x) = p`, `p` in `(0, 1)` (Newton's method on
/// `erfc` from a logistic start; a few ulps in f64).
fn normal_quantile(p: f64) -> f64 {
    let p = p.clamp(1e-12, 1.0 - 1e-12);
    let mut x = (p / (1.0 - p)).ln() / 1.702;
    for _ in 0..50 {
        let cdf = 0.5 * libm::erfc(-x / std::f64::consts::SQRT_2);
        let pdf = (-0.5 * x * x).exp() / (2.0 * std::f64::consts::PI).sqrt();
        if pdf <= 0.0 {
            break;
        }
        let step = ((cdf - p) / pdf).clamp(-1.0, 1.0);
        x -= step;
        if step.abs() < 1e-12 {
            break;
        }
    }
    x
}

/// [`coverage_to_distance_with`] for box-filtered masks ([`EdgeProfile::Box`]).
pub fn coverage_to_distance(mask: &[f32], w: usize, h: usize) -> Result<Vec<f32>> {
    coverage_to_distance_with(mask, w, h, EdgeProfile::Box)
}

/// A coverage mask (`w x h`, row-major, values in `[0, 1]`: the fraction of each pixel the
/// object covers) turned into `0.5 - d`, where `d` is the signed distance in pixels from each
/// pixel's centre to the silhouette (positive outside). Interpolated bilinearly, it crosses
/// 0.5 where that distance field crosses 0: on the edge the mask encodes under `profile`. The
/// coverage itself, interpolated between pixel centres, misses that edge by up to about a
/// tenth of a pixel (the line between a covered pixel's value and a partly covered one's is
/// not the coverage's profile across the edge), inward or outward by where the edge falls in
/// the pixel, and the intersection of the views' cones keeps every view's inward miss. Binary
/// masks keep their edge on the pixel boundary. Partly covered pixels get the distance the
/// profile gives their value (a box: a straight edge with the coverage's Sobel gradient as its
/// normal); binary pixels beside a pixel of the other side half a pixel; the rest the nearest
/// of those plus the chamfer distance to it (two raster passes, steps 1 and sqrt 2, each side
/// from its own side). Errors on a size that is not `w * h`, a value that is not finite or a
/// Gaussian profile whose width is not a positive number.
pub fn coverage_to_distance_with(
    mask: &[f32],
    w: usize,
    h: usize,
    profile: EdgeProfile,
) -> Result<Vec<f32>> {
    if let EdgeProfile::Gaussian { sigma } = profile
        && !(sigma.is_finite() && sigma > 0.0)
    {
        return Err(MeshError::InvalidArgument(format!(
            "an edge profile's width must be a positive number of pixels, got {sigma}"
        )));
    }
    if w == 0 || h == 0 || mask.len() != w * h {
        return Err(MeshError::size("coverage mask", w * h, mask.len()));
    }
    if mask.iter().any(|a| !a.is_finite()) {
        return Err(MeshError::NonFinite {
            what: "coverage mask".into(),
        });
    }
    let at = |i: isize, j: isize| -> f32 {
        let i = i.clamp(0, w as isize - 1) as usize;
        let j = j.clamp(0, h as isize - 1) as usize;
        mask[j * w + i].clamp(0.0, 1.0)
    };
    let binary = |a: f32| a <= 0.0 || a >= 1.0;
    let mut d = vec![0.0f32; w * h];
    let mut seed = vec![false; w * h];
    for j in 0..h as isize {
        for i in 0..w as isize {
            let k = j as usize * w + i as usize;
            let a = at(i, j);
            let inside = a >= 0.5;
            d[k] = if inside {
                f32::NEG_INFINITY
            } else {
                f32::INFINITY
            };
            if !binary(a) {
                d[k] = match profile {
                    EdgeProfile::Box => {
                        let (gx, gy) = sobel(&at, i, j);
                        edge_distance(gx, gy, a)
                    }
                    EdgeProfile::Gaussian { sigma } => {
                        (-f64::from(sigma) * normal_quantile(f64::from(a))) as f32
                    }
                };
                seed[k] = true;
            } else {
                let across = [(1, 0), (-1, 0), (0, 1), (0, -1)].iter().any(|(di, dj)| {
                    let (ni, nj) = (i + di, j + dj);
                    if ni < 0 || nj < 0 || ni >= w as isize || nj >= h as isize {
                        return false;
                    }
                    let b = at(ni, nj);
                    binary(b) && (b >= 0.5) != inside
                });
                if across {
                    d[k] = if inside { -0.5 } else { 0.5 };
                    seed[k] = true;
                }
            }
        }
    }
    let diag = std::f32::consts::SQRT_2;
    // Each side takes its distances from the edge's pixels and from its own side only.
    let inside: Vec<bool> = mask.iter().map(|a| *a >= 0.5).collect();
    let relax = |k: usize, n: usize, step: f32, d: &mut [f32]| {
        if seed[k] || !d[n].is_finite() || !(seed[n] || inside[n] == inside[k]) {
            return;
        }
        if inside[k] {
            d[k] = d[k].max(d[n] - step);
        } else {
            d[k] = d[k].min(d[n] + step);
        }
    };
    let forward = [
        (-1isize, -1isize, diag),
        (0, -1, 1.0),
        (1, -1, diag),
        (-1, 0, 1.0),
    ];
    // The forward pass in raster order with the neighbours before each pixel, then the
    // backward pass in reverse order with the mirrored neighbours.
    for sign in [1isize, -1] {
        for k in 0..w * h {
            let k = if sign > 0 { k } else { w * h - 1 - k };
            let (i, j) = ((k % w) as isize, (k / w) as isize);
            for (di, dj, step) in forward {
                let (ni, nj) = (i + sign * di, j + sign * dj);
                if ni >= 0 && nj >= 0 && ni < w as isize && nj < h as isize {
                    relax(k, nj as usize * w + ni as usize, step, &mut d);
                }
            }
        }
    }
    // A mask without an edge: all inside or all outside, a pixel's size from the border.
    Ok(d.iter()
        .map(|x| {
            0.5 - if x.is_finite() {
                *x
            } else {
                x.signum() * (w.max(h) as f32)
            }
        })
        .collect())
}

/// `p` projected into `cam`: pixel coordinates and camera-space depth, when `p` is in front of
/// the camera and inside its image.
pub(crate) fn in_image(cam: &Camera, p: Vec3) -> Option<(glam::Vec2, f32)> {
    let (uv, z) = cam.project(p)?;
    (uv.x >= 0.0 && uv.y >= 0.0 && uv.x < cam.width as f32 && uv.y < cam.height as f32)
        .then_some((uv, z))
}

/// The carving field over the box `[min, max]`, `resolution` voxels along its longest side:
/// negative inside the hull, positive outside (see the module documentation).
pub fn hull_grid(
    views: &[(Camera, &[f32])],
    min: Vec3,
    max: Vec3,
    resolution: usize,
) -> Result<Grid> {
    if !(2..=2048).contains(&resolution) {
        return Err(MeshError::InvalidArgument(format!(
            "visual hull resolution {resolution} is outside 2..=2048"
        )));
    }
    let voxel = (max - min).max_element() / resolution as f32;
    let dims = grid_dims(views, min, max, voxel)?;
    let mut grid = Grid::from_fn(min, voxel, dims, |p| {
        let mut field = f32::NEG_INFINITY;
        for (cam, mask) in views {
            let Some((uv, _)) = in_image(cam, p) else {
                continue;
            };
            let (w, h) = (cam.width as usize, cam.height as usize);
            field = field.max(0.5 - bilinear(mask, w, h, uv.x, uv.y));
            if field >= 0.5 {
                // Outside some mask entirely: no view can raise it further.
                break;
            }
        }
        // Seen by no view: outside.
        if field == f32::NEG_INFINITY {
            0.5
        } else {
            field
        }
    });
    // The box faces are outside, so the extracted hull is closed.
    close_box(&mut grid, 0.5);
    Ok(grid)
}

/// The visual hull of the masks (`mask >= 0.5` is the object; each mask `width * height`
/// values, row-major, matching its camera) over the box `[min, max]` at `resolution` voxels
/// along the longest side, as a closed, outward-oriented mesh.
pub fn visual_hull(
    views: &[(Camera, &[f32])],
    min: Vec3,
    max: Vec3,
    resolution: usize,
) -> Result<TriMesh> {
    Ok(marching_cubes(
        &hull_grid(views, min, max, resolution)?,
        0.0,
    ))
}

/// The masks' signed distance at `p`, in world units: the largest over the views that see `p`
/// of `(0.5 - mask(u, v)) * z / fx` (the mask bilinear between pixel centres, scaled by the
/// view's pixel footprint at `p`), positive outside some mask. `None` when no view has `p` in
/// front of it and inside its image. Inside every mask it is at most half a footprint deep.
/// A view whose mask is 0 at `p` ends the search: the point is outside, and the other views
/// could only change how far by a view's difference in footprint.
pub fn silhouette_distance(views: &[(Camera, &[f32])], p: Vec3) -> Option<f32> {
    let mut field = f32::NEG_INFINITY;
    for (cam, mask) in views {
        let Some((uv, z)) = in_image(cam, p) else {
            continue;
        };
        let (w, h) = (cam.width as usize, cam.height as usize);
        let footprint = z / cam.fx;
        let m = bilinear(mask, w, h, uv.x, uv.y);
        field = field.max((0.5 - m) * footprint);
        if m <= 0.0 {
            break;
        }
    }
    (field > f32::NEG_INFINITY).then_some(field)
}

/// Per point on the masks' hull, its slack: how far the hull could lie from the object there,
/// whatever the object's shape. The view whose mask is lowest at the point bounds the hull
/// there, and its ray through the point grazes the object at some point the hull holds; the
/// slack is the distance from the point to the farther end of the stretch of that ray inside
/// every other view's mask (`mask >= 0.5`), searched in steps of `step` up to `max_len` in
/// each direction (scene units). Where the hull hugs a convex part it is a fraction of the
/// part's radius; over a concavity the masks cannot see it is the concavity's width. Points
/// no view sees get `max_len`.
pub fn hull_slack(
    views: &[(Camera, &[f32])],
    points: &[Vec3],
    step: f32,
    max_len: f32,
) -> Result<Vec<f32>> {
    if !(step.is_finite() && step > 0.0 && max_len.is_finite() && max_len >= step) {
        return Err(MeshError::InvalidArgument(format!(
            "hull slack: the step must be positive and at most the length (got {step}, {max_len})"
        )));
    }
    for (cam, mask) in views {
        if mask.len() != cam.width as usize * cam.height as usize {
            return Err(MeshError::InvalidArgument(format!(
                "hull slack: a mask of {} values for a {}x{} camera",
                mask.len(),
                cam.width,
                cam.height
            )));
        }
    }
    let mask_at = |k: usize, p: Vec3| -> Option<f32> {
        let (cam, mask) = &views[k];
        let (uv, _) = in_image(cam, p)?;
        Some(bilinear(
            mask,
            cam.width as usize,
            cam.height as usize,
            uv.x,
            uv.y,
        ))
    };
    let steps = (max_len / step).floor() as usize;
    Ok(points
        .par_iter()
        .map(|&p| {
            // The bounding view: the lowest mask at `p`.
            let Some((g, _)) = (0..views.len())
                .filter_map(|k| mask_at(k, p).map(|m| (k, m)))
                .min_by(|a, b| a.1.total_cmp(&b.1))
            else {
                return max_len;
            };
            let dir = (p - views[g].0.centre()).normalize_or_zero();
            let inside = |q: Vec3| {
                (0..views.len())
                    .filter(|k| *k != g)
                    .all(|k| mask_at(k, q).is_none_or(|m| m >= 0.5))
            };
            let mut slack = 0.0f32;
            for sign in [1.0f32, -1.0] {
                let mut run = 0.0f32;
                for i in 1..=steps {
                    let t = i as f32 * step;
                    if !inside(p + dir * (sign * t)) {
                        break;
                    }
                    run = t;
                }
                slack = slack.max(run);
            }
            slack
        })
        .collect())
}

/// Pixel footprints of the masks (at the mesh box's centre, median over the views) in a voxel
/// of [`masks_mesh`]: finer than a pixel, so that the bilinear masks' sub-pixel crossing
/// survives marching cubes.
pub const MASKS_VOXEL_FOOTPRINTS: f32 = 0.75;

/// The box radius over this is the coarsest voxel of [`masks_mesh`], whatever the masks'
/// resolution: small masks have large footprints, and thin parts need the grid.
pub const MASKS_VOXEL_RADIUS_DIVISOR: f32 = 128.0;

/// Pixel footprints in the finest voxel of [`masks_mesh`]: the radius cap stops here on small
/// masks, where a finer grid only multiplies the triangles (the bilinear masks are placed
/// alike from a sixth of a footprint down).
pub const MASKS_VOXEL_MIN_FOOTPRINTS: f32 = 1.0 / 6.0;

/// The grid spacing of [`masks_mesh`] for the box `[lo, hi]`: [`MASKS_VOXEL_FOOTPRINTS`] of
/// the masks' median pixel footprint at its centre, at most the box radius over
/// [`MASKS_VOXEL_RADIUS_DIVISOR`], at least [`MASKS_VOXEL_MIN_FOOTPRINTS`] of the footprint.
pub fn masks_voxel(views: &[(Camera, &[f32])], lo: Vec3, hi: Vec3) -> f32 {
    let footprint = median_pixel_footprint(views.iter().map(|(c, _)| c), 0.5 * (lo + hi));
    let radius = 0.5 * (hi - lo).max_element();
    (MASKS_VOXEL_FOOTPRINTS * footprint)
        .min(radius / MASKS_VOXEL_RADIUS_DIVISOR)
        .max(MASKS_VOXEL_MIN_FOOTPRINTS * footprint)
}

/// The masks alone, done well: the surface where the bilinearly interpolated masks cross 0.5
/// ([`silhouette_distance`]), extracted by marching cubes in the box of [`hull_box`] at
/// [`masks_voxel`] (`voxel` overrides it), the largest component. Pass the masks at the dataset's own resolution: the training size
/// throws away the sub-pixel edge. `None` when the masks are empty. Errors as [`hull_grid`].
pub fn masks_mesh(views: &[(Camera, &[f32])], voxel: Option<f32>) -> Result<Option<TriMesh>> {
    let Some((lo, hi)) = hull_box(views)? else {
        return Ok(None);
    };
    let voxel = voxel.unwrap_or_else(|| masks_voxel(views, lo, hi));
    let grid = masks_grid(views, lo, hi, voxel)?;
    let mesh = crate::mesh::largest_component(&marching_cubes(&grid, 0.0));
    Ok((!mesh.triangles.is_empty()).then_some(mesh))
}

/// [`silhouette_distance`] on the grid over `[min, max]` with spacing `voxel`, the box faces
/// and points no view sees outside (so the surface is closed). Errors as [`hull_grid`] does,
/// and on a voxel that is not positive or a grid over 2^31 points.
pub fn masks_grid(views: &[(Camera, &[f32])], min: Vec3, max: Vec3, voxel: f32) -> Result<Grid> {
    let dims = grid_dims(views, min, max, voxel)?;
    let mut grid = Grid::from_fn(min, voxel, dims, |p| {
        silhouette_distance(views, p).unwrap_or(voxel)
    });
    close_box(&mut grid, voxel);
    Ok(grid)
}

/// Checks the views and the box for the grids built from masks; the grid's point counts.
pub(crate) fn grid_dims(
    views: &[(Camera, &[f32])],
    min: Vec3,
    max: Vec3,
    voxel: f32,
) -> Result<[usize; 3]> {
    if views.is_empty() {
        return Err(MeshError::InvalidArgument(
            "a grid from masks needs at least one view".into(),
        ));
    }
    if !(min.is_finite() && max.is_finite() && max.cmpgt(min).all()) {
        return Err(MeshError::InvalidArgument(format!(
            "grid box [{min}, {max}] is empty or not finite"
        )));
    }
    if !(voxel.is_finite() && voxel > 0.0) {
        return Err(MeshError::InvalidArgument(format!(
            "grid voxel {voxel} must be positive and finite"
        )));
    }
    for (k, (cam, mask)) in views.iter().enumerate() {
        let n = cam.width as usize * cam.height as usize;
        if mask.len() != n || n == 0 {
            return Err(MeshError::size(
                &format!("mask of view {k}"),
                format!("{}x{} = {n} (non-zero)", cam.width, cam.height),
                mask.len(),
            ));
        }
    }
    let cells = ((max - min) / voxel).ceil();
    let dims = [cells.x, cells.y, cells.z].map(|c| c as usize + 1);
    match dims.iter().try_fold(1usize, |a, &d| a.checked_mul(d)) {
        Some(n) if n <= (1 << 31) => Ok(dims),
        _ => Err(MeshError::InvalidArgument(format!(
            "grid {dims:?} is too large (voxel {voxel})"
        ))),
    }
}

/// Sets the grid's box faces to at least `outside`, so the extracted surface is closed.
pub(crate) fn close_box(grid: &mut Grid, outside: f32) {
    let [nx, ny, nz] = grid.dims;
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                if i == 0 || j == 0 || k == 0 || i == nx - 1 || j == ny - 1 || k == nz - 1 {
                    let id = grid.index(i, j, k);
                    grid.values[id] = grid.values[id].max(outside);
                }
            }
        }
    }
}

/// Voxels along the side of the cameras' box when [`hull_box`] carves the masks.
pub const HULL_BOX_RESOLUTION: usize = 128;

/// The box around the masks' visual hull: carved at [`HULL_BOX_RESOLUTION`] voxels inside the
/// cube that holds the ball of the cameras (centred on their mean), grown by two of those
/// voxels. The object is inside every mask, so the box cannot cut it off. Unlike
/// [`hull_grid`], a point must also lie in the frustum of at least half of the views: with
/// cameras all around an object that fills a fair part of each frame, a point right beside
/// one camera is seen only by the few cameras facing it across the object, through the
/// object's silhouette, and would otherwise count as inside and stretch the box to the
/// cameras. `None` when nothing is inside; errors as [`hull_grid`] does.
pub fn hull_box(views: &[(Camera, &[f32])]) -> Result<Option<(Vec3, Vec3)>> {
    if views.is_empty() {
        return Err(MeshError::InvalidArgument(
            "the hull box needs at least one view".into(),
        ));
    }
    let centres: Vec<Vec3> = views.iter().map(|(c, _)| c.centre()).collect();
    let mean = centres.iter().copied().sum::<Vec3>() / centres.len() as f32;
    let reach = centres
        .iter()
        .map(|c| c.distance(mean))
        .fold(0.0f32, f32::max)
        .max(1e-3);
    let grid = hull_grid(
        views,
        mean - Vec3::splat(reach),
        mean + Vec3::splat(reach),
        HULL_BOX_RESOLUTION,
    )?;
    let [nx, ny, nz] = grid.dims;
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let p = grid.point(i, j, k);
                let inside = grid.values[grid.index(i, j, k)] < 0.0
                    && 2 * views
                        .iter()
                        .filter(|(cam, _)| in_image(cam, p).is_some())
                        .count()
                        >= views.len();
                if inside {
                    lo = lo.min(p);
                    hi = hi.max(p);
                }
            }
        }
    }
    if !(lo.is_finite() && hi.is_finite()) {
        return Ok(None);
    }
    let pad = Vec3::splat(2.0 * grid.voxel);
    Ok(Some((lo - pad, hi + pad)))
}

#[cfg(test)]
mod coverage_tests {
    use super::*;
    use glam::Vec2;

    /// The box-filtered coverage of the region `inside` (pixel units), 32 x 32 samples a pixel.
    fn coverage(w: usize, inside: impl Fn(Vec2) -> bool) -> Vec<f32> {
        let n = 32;
        (0..w * w)
            .map(|k| {
                let (i, j) = ((k % w) as f32, (k / w) as f32);
                let mut hits = 0;
                for sj in 0..n {
                    for si in 0..n {
                        let s = Vec2::new(si as f32 + 0.5, sj as f32 + 0.5) / n as f32;
                        hits += inside(Vec2::new(i, j) + s) as u32;
                    }
                }
                hits as f32 / (n * n) as f32
            })
            .collect()
    }

    /// Where the bilinear image crosses 0.5 on the segment `from + t dir`, `t` in `[lo, hi]`
    /// (inside at `lo`).
    fn crossing(img: &[f32], w: usize, from: Vec2, dir: Vec2, (mut lo, mut hi): (f32, f32)) -> f32 {
        for _ in 0..40 {
            let mid = 0.5 * (lo + hi);
            let p = from + dir * mid;
            if bilinear(img, w, w, p.x, p.y) >= 0.5 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    }

    /// How far the bilinear image's 0.5 crossing lies from the circle of radius `r` about `c`,
    /// along 360 rays from `c`: the mean (negative: inside) and the largest magnitude.
    fn disc_misses(img: &[f32], w: usize, c: Vec2, r: f32) -> (f32, f32) {
        let n = 360;
        let (mut mean, mut worst) = (0.0f32, 0.0f32);
        for k in 0..n {
            let a = k as f32 / n as f32 * std::f32::consts::TAU;
            let dir = Vec2::new(a.cos(), a.sin());
            let e = crossing(img, w, c, dir, (r - 3.0, r + 3.0)) - r;
            mean += e / n as f32;
            worst = worst.max(e.abs());
        }
        (mean, worst)
    }

    #[test]
    fn the_distance_field_finds_the_edge_the_coverage_misses() {
        let w = 32;
        let c = Vec2::new(15.37, 16.21);
        let r = 7.3;
        let cov = coverage(w, |p| p.distance(c) < r);
        let dist = coverage_to_distance(&cov, w, w).unwrap();
        let (e_cov, worst_cov) = disc_misses(&cov, w, c, r);
        let (e_dist, worst_dist) = disc_misses(&dist, w, c, r);
        // The coverage misses the circle by up to a tenth of a pixel, the distance field by
        // under half that; both lie about 0.016 inside on average (the edge's curvature).
        assert!(worst_cov > 0.08, "{worst_cov}");
        assert!(worst_dist < 0.05, "{worst_dist} vs {worst_cov}");
        assert!(e_dist.abs() < 0.025, "{e_dist} vs {e_cov}");
    }

    #[test]
    fn binary_masks_and_straight_edges_are_placed_on_their_edge() {
        let w = 16;
        let row = |img: &[f32], j: usize| {
            crossing(
                img,
                w,
                Vec2::new(0.0, j as f32 + 0.5),
                Vec2::X,
                (0.5, w as f32 - 0.5),
            )
        };
        // Binary: columns 0..7 covered, the edge at x = 7.
        let binary = coverage(w, |p| p.x < 7.0);
        assert!(binary.iter().all(|a| *a == 0.0 || *a == 1.0));
        let d = coverage_to_distance(&binary, w, w).unwrap();
        assert!((row(&d, 8) - 7.0).abs() < 1e-4);
        // The half-plane x < 6.3 + 0.3 (y - 8): the coverage interpolated between pixel
        // centres misses the edge by up to a tenth of a pixel, the distance field by far less.
        let edge = |y: f32| 6.3 + 0.3 * (y - 8.0);
        let cov = coverage(w, |p| p.x < edge(p.y));
        let d = coverage_to_distance(&cov, w, w).unwrap();
        let (mut worst_cov, mut worst_dist) = (0.0f32, 0.0f32);
        for j in 3..13 {
            let truth = edge(j as f32 + 0.5);
            worst_cov = worst_cov.max((row(&cov, j) - truth).abs());
            worst_dist = worst_dist.max((row(&d, j) - truth).abs());
        }
        assert!(worst_cov > 0.05, "{worst_cov}");
        assert!(worst_dist < 0.02, "{worst_dist} vs {worst_cov}");
    }

    /// The region `inside` filtered by a Gaussian of `sigma` pixels (truncated at 3 sigma,
    /// 1/16-pixel samples), as a renderer with a smooth pixel filter gives it.
    fn filtered(w: usize, sigma: f32, inside: impl Fn(Vec2) -> bool) -> Vec<f32> {
        let n = (6.0 * sigma * 16.0).ceil() as i32;
        (0..w * w)
            .map(|k| {
                let centre = Vec2::new((k % w) as f32 + 0.5, (k / w) as f32 + 0.5);
                let (mut hit, mut all) = (0.0f64, 0.0f64);
                for sj in 0..n {
                    for si in 0..n {
                        let o = (Vec2::new(si as f32, sj as f32) + 0.5) / 16.0 - 3.0 * sigma;
                        let wgt = f64::from((-0.5 * o.length_squared() / (sigma * sigma)).exp());
                        all += wgt;
                        if inside(centre + o) {
                            hit += wgt;
                        }
                    }
                }
                (hit / all) as f32
            })
            .collect()
    }

    #[test]
    fn smooth_filtered_masks_are_measured_and_read_with_their_profile() {
        let w = 32;
        let c = Vec2::new(15.37, 16.21);
        let r = 9.6;
        let sigma = 0.42;
        let smooth = filtered(w, sigma, |p| p.distance(c) < r);
        let boxed = coverage(w, |p| p.distance(c) < r);
        // The width statistic: sigma / sqrt(pi) for the Gaussian, a box's 1/6 for the box.
        let width = edge_width(&[(&smooth, w, w)]).unwrap();
        let EdgeProfile::Gaussian { sigma: found } = EdgeProfile::from_width(width) else {
            panic!("a Gaussian filter read as a box (width {width})");
        };
        assert!((found - sigma).abs() < 0.03, "{found} vs {sigma}");
        let box_width = edge_width(&[(&boxed, w, w)]).unwrap();
        assert!((box_width - BOX_EDGE_WIDTH).abs() < 0.02, "{box_width}");
        assert_eq!(EdgeProfile::from_width(box_width), EdgeProfile::Box);
        // Read as a box, the smooth mask's edge is missed; read with its profile, found.
        let as_box = coverage_to_distance(&smooth, w, w).unwrap();
        let as_measured =
            coverage_to_distance_with(&smooth, w, w, EdgeProfile::from_width(width)).unwrap();
        let (_, worst_box) = disc_misses(&as_box, w, c, r);
        let (mean_measured, worst_measured) = disc_misses(&as_measured, w, c, r);
        assert!(worst_box > 0.05, "{worst_box}");
        assert!(
            worst_measured < 0.5 * worst_box,
            "{worst_measured} vs {worst_box}"
        );
        assert!(mean_measured.abs() < 0.02, "{mean_measured}");
        // A width that is no number of pixels is refused.
        let bad = EdgeProfile::Gaussian { sigma: f32::NAN };
        let e = coverage_to_distance_with(&smooth, w, w, bad).unwrap_err();
        assert!(e.to_string().contains("width"), "{e}");
    }

    #[test]
    fn the_normal_quantile_inverts_the_distribution() {
        for p in [1e-6, 0.01, 0.2, 0.5, 0.7, 0.99, 1.0 - 1e-6] {
            let x = normal_quantile(p);
            let back = 0.5 * libm::erfc(-x / std::f64::consts::SQRT_2);
            assert!((back - p).abs() < 1e-9 * p.max(1e-3), "{p}: {x} -> {back}");
        }
        assert!(normal_quantile(0.5).abs() < 1e-12);
    }

    #[test]
    fn masks_without_an_edge_and_bad_masks() {
        let empty = coverage_to_distance(&[0.0; 12], 4, 3).unwrap();
        assert!(empty.iter().all(|m| *m < 0.0));
        let full = coverage_to_distance(&[1.0; 12], 4, 3).unwrap();
        assert!(full.iter().all(|m| *m > 1.0));
        let e = coverage_to_distance(&[0.5; 11], 4, 3).unwrap_err();
        assert!(e.to_string().contains("coverage mask"), "{e}");
        let mut nan = vec![0.5; 12];
        nan[3] = f32::NAN;
        let e = coverage_to_distance(&nan, 4, 3).unwrap_err();
        assert!(e.to_string().contains("non-finite"), "{e}");
    }

    /// The masks' voxel: three quarters of a footprint on large masks, the box radius over 128
    /// on middling ones, a sixth of a footprint on small ones.
    #[test]
    fn the_masks_voxel_follows_the_footprint_within_its_bounds() {
        let (lo, hi) = (Vec3::splat(-1.0), Vec3::splat(1.0));
        let voxel = |px: u32| {
            let cam = Camera::look_at(Vec3::new(0.0, 0.0, 4.0), Vec3::ZERO, Vec3::Y, 0.7, px, px);
            let mask = vec![1.0f32; (px * px) as usize];
            let fp = median_pixel_footprint([&cam], Vec3::ZERO);
            (masks_voxel(&[(cam, &mask)], lo, hi), fp)
        };
        let (v, fp) = voxel(1024);
        assert!(0.75 * fp < 1.0 / 128.0, "{fp}");
        assert!((v - 0.75 * fp).abs() < 1e-7, "{v} {fp}");
        let (v, fp) = voxel(128);
        assert!(0.75 * fp > 1.0 / 128.0 && fp / 6.0 < 1.0 / 128.0, "{fp}");
        assert!((v - 1.0 / 128.0).abs() < 1e-7, "{v} {fp}");
        let (v, fp) = voxel(24);
        assert!(fp / 6.0 > 1.0 / 128.0, "{fp}");
        assert!((v - fp / 6.0).abs() < 1e-7, "{v} {fp}");
    }
}
