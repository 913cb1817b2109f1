//! Visual hull by silhouette carving: the set of points whose projection lies inside the
//! object mask in every view that sees them.
//!
//! The field handed to marching cubes is `max over views of (0.5 - mask(u, v))`, with the
//! mask bilinearly interpolated between pixel centres (clamped at the image border), so the
//! surface passes where the interpolated mask crosses 0.5 (sub-voxel placement). A view
//! constrains only the points in front of it that project inside its image. Points seen by
//! no view, and the faces of the bounding box, count as outside, so the hull is closed.

use glam::Vec3;
use gtsr_data::Camera;
use gtsr_data::ply::TriMesh;

use crate::error::{EvalError, Result};
use crate::marching::{Grid, marching_cubes};

/// Bilinear sample of a `w x h` single-channel image at continuous pixel coordinates
/// (pixel centres at `i + 0.5`), clamped at the border.
pub(crate) fn bilinear(img: &[f32], w: usize, h: usize, u: f32, v: f32) -> f32 {
    let x = (u - 0.5).clamp(0.0, (w - 1) as f32);
    let y = (v - 0.5).clamp(0.0, (h - 1) as f32);
    let (x0, y0) = (x as usize, y as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
    let at = |i: usize, j: usize| img[j * w + i];
    let top = at(x0, y0) * (1.0 - fx) + at(x1, y0) * fx;
    let bottom = at(x0, y1) * (1.0 - fx) + at(x1, y1) * fx;
    top * (1.0 - fy) + bottom * fy
}

/// The carving field over the box `[min, max]`, `resolution` voxels along its longest side:
/// negative inside the hull, positive outside (see the module documentation).
pub fn hull_grid(
    views: &[(Camera, &[f32])],
    min: Vec3,
    max: Vec3,
    resolution: usize,
) -> Result<Grid> {
    if views.is_empty() {
        return Err(EvalError::InvalidArgument(
            "visual hull needs at least one view".into(),
        ));
    }
    if !(min.is_finite() && max.is_finite() && max.cmpgt(min).all()) {
        return Err(EvalError::InvalidArgument(format!(
            "visual hull box [{min}, {max}] is empty or not finite"
        )));
    }
    if !(2..=2048).contains(&resolution) {
        return Err(EvalError::InvalidArgument(format!(
            "visual hull resolution {resolution} is outside 2..=2048"
        )));
    }
    for (k, (cam, mask)) in views.iter().enumerate() {
        let n = cam.width as usize * cam.height as usize;
        if mask.len() != n || n == 0 {
            return Err(EvalError::size(
                &format!("mask of view {k}"),
                format!("{}x{} = {n} (non-zero)", cam.width, cam.height),
                mask.len(),
            ));
        }
    }
    let voxel = (max - min).max_element() / resolution as f32;
    let cells = ((max - min) / voxel).ceil();
    let dims = [cells.x, cells.y, cells.z].map(|c| c as usize + 1);
    let mut grid = Grid::from_fn(min, voxel, dims, |p| {
        let mut field = f32::NEG_INFINITY;
        for (cam, mask) in views {
            let Some((uv, _)) = cam.project(p) else {
                continue;
            };
            let (w, h) = (cam.width as usize, cam.height as usize);
            if !(uv.x >= 0.0 && uv.y >= 0.0 && uv.x < w as f32 && uv.y < h as f32) {
                continue;
            }
            field = field.max(0.5 - bilinear(mask, w, h, uv.x, uv.y));
        }
        // Seen by no view: outside.
        if field == f32::NEG_INFINITY {
            0.5
        } else {
            field
        }
    });
    // The box faces are outside, so the extracted hull is closed.
    let [nx, ny, nz] = dims;
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                if i == 0 || j == 0 || k == 0 || i == nx - 1 || j == ny - 1 || k == nz - 1 {
                    let id = grid.index(i, j, k);
                    grid.values[id] = grid.values[id].max(0.5);
                }
            }
        }
    }
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
        return Err(EvalError::InvalidArgument(
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
    let in_frustum = |cam: &Camera, p: Vec3| {
        cam.project(p).is_some_and(|(uv, _)| {
            uv.x >= 0.0 && uv.y >= 0.0 && uv.x < cam.width as f32 && uv.y < cam.height as f32
        })
    };
    let [nx, ny, nz] = grid.dims;
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let p = grid.point(i, j, k);
                let inside = grid.values[grid.index(i, j, k)] < 0.0
                    && 2 * views.iter().filter(|(cam, _)| in_frustum(cam, p)).count()
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
