//! Mesh extraction for masked scenes: the masks bound the object, the rendered depth carves
//! inside that bound where enough views agree, or (with the concavity gate) where a view looks
//! into a concavity the masks cannot see.
//!
//! The field handed to marching cubes, per grid point `p` (world units, positive outside):
//!
//! * `hull(p)`: the masks' signed distance ([`crate::hull::silhouette_distance`]), from the
//!   masks at the dataset's own resolution. Where it is positive (outside some mask) it is the
//!   field, so the surface never leaves the masks' hull, and it is placed between voxels with
//!   the masks' sub-pixel edge.
//! * inside the hull, each depth view that sees `p` in its image, at a pixel with a depth `d`
//!   (`> 0`; nearest pixel), offers `d - z(p) - margin`: positive when `p` lies in front of
//!   the rendered surface by more than `margin` ([`CarveSettings::margin_footprints`] of that
//!   view's pixel footprint at `p`), i.e. in the free space the view looked through. Views
//!   that see `p` behind their surface (occluded, or inside) offer a negative value. With
//!   [`CarveSettings::slope_margin`] the margin also grows with the depth step from the pixel
//!   to its steepest neighbour (where a surface is seen at a grazing angle the nearest pixel's
//!   depth can be that far off at `p`), and pixels beside one without depth do not vote.
//! * With [`CarveSettings::concavity_gate`], a view's free vote counts only where its depth at
//!   that pixel lies more than the gate (in footprints, stretched where the masks' surface is
//!   seen at a grazing angle) behind the masks' own depth on the same ray
//!   ([`DepthMap::hull_depth`]): where the view looks into a concavity the masks cannot see.
//!   Elsewhere the masks place the surface better than a rendered depth that runs a footprint
//!   or two behind it, and a single view may carve a concavity that only it sees without
//!   eroding the rest.
//! * The views then fall in three groups by `s = d - z(p)`: *free* (`s > margin`: the view
//!   looked through `p`), *near* (`|s| <= margin`: `p` is where the view saw its surface) and
//!   *occluded* (`s < -margin`: something in front hides `p`, which says nothing about it).
//!   `p` is carved when at least [`CarveSettings::min_views`] views are free and they are at
//!   least [`CarveSettings::min_free_ratio`] of the free and near ones together: a point just
//!   under the true surface, which the views that see that surface put *near*, survives the
//!   few views whose rendered depth runs too deep there, while a point in a concavity, near no
//!   surface, has no near votes against its free ones (the stability test of multi-view depth
//!   fusion, as in Merrell et al. 2007).
//! * Where carved, the field is `max(hull(p), carve(p))` with `carve(p)` the
//!   `min_views`-th largest `s - margin` (positive), so the carved surface lies `margin` in
//!   front of the rendered depth; elsewhere it is `hull(p)`. Where no depth says otherwise the
//!   masks decide.
//!
//! Silhouettes cannot see concavities (the moat around a dome, the inside of a cup); rendered
//! depth can, and carving is the only thing it may do here: it never adds volume beyond the
//! masks. The margin trades how much of a concavity is recovered (the carved surface lies
//! `margin` in front of the rendered depth) against the rendered depth's own error.

use glam::Vec3;
use gtsr_data::Camera;
use gtsr_data::ply::TriMesh;

use crate::error::{MeshError, Result};
use crate::hull::{close_box, grid_dims, in_image, silhouette_distance};
use crate::marching::{Grid, marching_cubes};
use crate::mesh::largest_component;
use rayon::prelude::*;

/// The most views [`CarveSettings::min_views`] may ask for.
pub const MAX_CARVE_VIEWS: usize = 16;

/// How many depth views must agree, and by how much, before a point inside the masks' hull is
/// carved.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CarveSettings {
    /// Views that must each put the point in front of their rendered surface (1 to
    /// [`MAX_CARVE_VIEWS`]).
    pub min_views: usize,
    /// How far in front, in that view's pixel footprints at the point (finite, `>= 0`).
    pub margin_footprints: f32,
    /// The least share of free views among the free and near ones (in `[0, 1]`).
    pub min_free_ratio: f32,
    /// Added to the margin: this many times the depth step to the pixel's steepest
    /// 4-neighbour, the most a nearest-pixel depth can be off where the surface is seen at a
    /// grazing angle (finite, `>= 0`; 0 leaves the margin as it is). With it, a pixel beside
    /// one without depth (the silhouette) does not vote.
    #[serde(default)]
    pub slope_margin: f32,
    /// Read each view's depth at the point's projection bilinearly between the four pixel
    /// centres around it (where all four have depth) instead of at the nearest pixel: on a
    /// surface seen at a grazing angle the nearest pixel's depth is off by up to half the step
    /// to its neighbour, the bilinear one by the surface's curvature only. A view where one of
    /// the four has no depth (beside the silhouette) does not vote.
    #[serde(default)]
    pub bilinear: bool,
    /// A view's free vote counts only where, at the point's pixel, its depth lies more than
    /// this many footprints behind the masks' hull's depth ([`DepthMap::hull_depth`]): where
    /// the view looks into a concavity the masks cannot see. Elsewhere the masks already place
    /// the surface better than a rendered depth can, and the view does not vote (finite,
    /// `>= 0`; 0: off).
    #[serde(default)]
    pub concavity_gate: f32,
    /// With the concavity gate: the pixels this far on both sides of the pixel along one of
    /// the four lines through it (row, column, diagonals) must pass it too, so that a lone
    /// pixel whose depth ran deep does not carve; a slot one pixel wide still passes.
    #[serde(default)]
    pub gate_radius: usize,
}

/// The rule that needs no hull depth: three agreeing views, three footprints, no gate.
/// gtsr-train's default extraction (`MeshConfig::default().carve()`) is the gated single-view
/// rule, which [`crate::extract_mesh`] feeds with the masks' own depth.
impl Default for CarveSettings {
    fn default() -> Self {
        CarveSettings {
            min_views: 3,
            margin_footprints: 3.0,
            min_free_ratio: 0.5,
            slope_margin: 0.0,
            bilinear: false,
            concavity_gate: 0.0,
            gate_radius: 0,
        }
    }
}

impl CarveSettings {
    /// Checks the ranges documented on the fields.
    pub fn validate(&self) -> Result<()> {
        if !(1..=MAX_CARVE_VIEWS).contains(&self.min_views) {
            return Err(MeshError::InvalidArgument(format!(
                "carving needs 1 to {MAX_CARVE_VIEWS} agreeing views, not {}",
                self.min_views
            )));
        }
        // Each of these must be finite and >= 0: (value, what, unit).
        for (value, what, unit) in [
            (self.margin_footprints, "the carving margin", " footprints"),
            (self.slope_margin, "the carving's slope margin", ""),
            (
                self.concavity_gate,
                "the carving's concavity gate",
                " footprints",
            ),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(MeshError::InvalidArgument(format!(
                    "{what} must be finite and >= 0{unit}, not {value}"
                )));
            }
        }
        if !(0.0..=1.0).contains(&self.min_free_ratio) {
            return Err(MeshError::InvalidArgument(format!(
                "the carving's free share must be in [0, 1], not {}",
                self.min_free_ratio
            )));
        }
        Ok(())
    }
}

/// One rendered depth map: z-depth along the camera axis, row-major `width * height` of its
/// camera, `<= 0` or non-finite where there is none.
#[derive(Clone, Copy, Debug)]
pub struct DepthMap<'a> {
    /// The camera the depth was rendered from.
    pub camera: &'a Camera,
    /// The depth values.
    pub depth: &'a [f32],
    /// The masks' hull's own depth from the same camera (same layout, `<= 0` where a pixel's
    /// ray misses it), which [`CarveSettings::concavity_gate`] compares the depth with.
    pub hull_depth: Option<&'a [f32]>,
}

/// Per pixel of `dm`, the largest depth difference to its 4-neighbours in the image; NaN
/// where one of them (or the pixel itself) has no depth. On the masks' own depth, the step
/// by which [`CarveSettings::concavity_gate`] stretches its footprint.
pub fn depth_steps(dm: &DepthMap) -> Vec<f32> {
    let (w, h) = (dm.camera.width as usize, dm.camera.height as usize);
    let valid = |d: f32| d.is_finite() && d > 0.0;
    (0..w * h)
        .map(|pix| {
            let (x, y) = (pix % w, pix / w);
            let d = dm.depth[pix];
            if !valid(d) {
                return f32::NAN;
            }
            let mut step = 0.0f32;
            for (nx, ny) in [
                (x.wrapping_sub(1), y),
                (x + 1, y),
                (x, y.wrapping_sub(1)),
                (x, y + 1),
            ] {
                if nx < w && ny < h {
                    let dn = dm.depth[ny * w + nx];
                    if !valid(dn) {
                        return f32::NAN;
                    }
                    step = step.max((dn - d).abs());
                }
            }
            step
        })
        .collect()
}

/// Per pixel of `dm`, whether its depth lies more than `gate` footprints behind the hull's
/// depth on the same ray (where the view looks into a concavity the masks cannot see; the
/// footprint stretched by the hull's depth step to its neighbours where the view sees it at a
/// grazing angle, and no pass beside a pixel off the hull), and so
/// do the `radius` pixels on both sides of it along one of the four lines through it (the
/// row, the column, a diagonal): a slot one pixel wide passes along its length, an isolated
/// pixel whose depth ran deep does not. All false without a hull depth.
fn concavity_open(dm: &DepthMap, gate: f32, radius: usize) -> Vec<bool> {
    let (w, h) = (dm.camera.width as usize, dm.camera.height as usize);
    let Some(hull) = dm.hull_depth else {
        return vec![false; w * h];
    };
    let fx = dm.camera.fx;
    // The hull seen at a grazing angle: its depth steps from pixel to pixel, and a small
    // error across the ray is a large one along it. The gap is measured against the
    // footprint stretched by that step (`footprint / cos` of the angle, roughly).
    let steps = depth_steps(&DepthMap {
        camera: dm.camera,
        depth: hull,
        hull_depth: None,
    });
    let pass: Vec<bool> = (0..w * h)
        .map(|pix| {
            let (d, hd, step) = (dm.depth[pix], hull[pix], steps[pix]);
            let footprint = d / fx;
            d.is_finite()
                && d > 0.0
                && hd > 0.0
                && step.is_finite()
                && d - hd > gate * (footprint * footprint + step * step).sqrt()
        })
        .collect();
    if radius == 0 {
        return pass;
    }
    let r = radius as isize;
    let at = |x: isize, y: isize| {
        x >= 0
            && y >= 0
            && (x as usize) < w
            && (y as usize) < h
            && pass[y as usize * w + x as usize]
    };
    (0..w * h)
        .map(|pix| {
            let (x, y) = ((pix % w) as isize, (pix / w) as isize);
            pass[pix]
                && [(1, 0), (0, 1), (1, 1), (1, -1)].iter().any(|&(dx, dy)| {
                    (1..=r).all(|k| at(x + k * dx, y + k * dy) && at(x - k * dx, y - k * dy))
                })
        })
        .collect()
}

/// How far the depth maps lie behind the masks' hull where both see the object, in each
/// sample's pixel footprint (`(d - hull) fx / d`): its quartiles over every sample of every
/// map with a depth and a hull depth. Where the masks' hull is flush with the object (most of
/// a convex-ish object's surface) an unbiased depth lies at 0; a depth that runs behind the
/// surface everywhere lies at its bias, which [`debias_depth`] takes out. `None` without a
/// hull depth or a shared sample.
pub fn hull_offset(depths: &[DepthMap]) -> Option<[f32; 3]> {
    let mut offsets: Vec<f32> = depths
        .iter()
        .filter_map(|dm| dm.hull_depth.map(|h| (dm, h)))
        .flat_map(|(dm, h)| {
            dm.depth
                .iter()
                .zip(h)
                .filter(|(d, hd)| d.is_finite() && **d > 0.0 && **hd > 0.0)
                .map(move |(d, hd)| (d - hd) * dm.camera.fx / d)
        })
        .collect();
    if offsets.is_empty() {
        return None;
    }
    offsets.sort_unstable_by(f32::total_cmp);
    let q = |p: f64| offsets[((offsets.len() - 1) as f64 * p) as usize];
    Some([q(0.25), q(0.5), q(0.75)])
}

/// Moves each depth sample `footprints` of its own pixel footprint towards the camera
/// (`d (1 - footprints / fx)`), in place; samples without depth stay as they are. With the
/// median of [`hull_offset`] this takes out a bias that the depth shows over the whole object,
/// so that the concavity gate and the carved surface measure from where the depth says the
/// flush surface is.
pub fn debias_depth(camera: &Camera, depth: &mut [f32], footprints: f32) {
    let scale = 1.0 - footprints / camera.fx;
    for d in depth.iter_mut().filter(|d| d.is_finite() && **d > 0.0) {
        *d *= scale;
    }
}

/// The depth at continuous pixel coordinates `uv`, interpolated bilinearly between the four
/// pixel centres around it; `None` when one of them has no depth or lies outside the image.
fn bilinear_depth(dm: &DepthMap, uv: glam::Vec2) -> Option<f32> {
    let (w, h) = (dm.camera.width as usize, dm.camera.height as usize);
    let (x, y) = (uv.x - 0.5, uv.y - 0.5);
    let (x0, y0) = (x.floor(), y.floor());
    if x0 < 0.0 || y0 < 0.0 || x0 as usize + 1 >= w || y0 as usize + 1 >= h {
        return None;
    }
    let (fx, fy) = (x - x0, y - y0);
    let (i, j) = (x0 as usize, y0 as usize);
    let at = |i: usize, j: usize| {
        let d = dm.depth[j * w + i];
        (d.is_finite() && d > 0.0).then_some(d)
    };
    let (d00, d10, d01, d11) = (at(i, j)?, at(i + 1, j)?, at(i, j + 1)?, at(i + 1, j + 1)?);
    Some((d00 * (1.0 - fx) + d10 * fx) * (1.0 - fy) + (d01 * (1.0 - fx) + d11 * fx) * fy)
}

/// The carving value at `p` (module documentation): the `min_views`-th largest `s - margin`
/// over the free views when `p` is carved, `None` when it is not. `steps`: each view's
/// [`depth_steps`] when the settings have a slope margin.
fn carve_at(
    depths: &[DepthMap],
    steps: &[Vec<f32>],
    open: &[Vec<bool>],
    p: Vec3,
    settings: &CarveSettings,
) -> Option<f32> {
    let k = settings.min_views;
    // The k largest free offers so far, descending.
    let mut top = [f32::NEG_INFINITY; MAX_CARVE_VIEWS];
    let (mut free, mut near) = (0usize, 0usize);
    for (k_view, dm) in depths.iter().enumerate() {
        let cam = dm.camera;
        let Some((uv, z)) = in_image(cam, p) else {
            continue;
        };
        let pix = (uv.y as usize).min(cam.height as usize - 1) * cam.width as usize
            + (uv.x as usize).min(cam.width as usize - 1);
        let mut d = dm.depth[pix];
        if !(d.is_finite() && d > 0.0) {
            continue;
        }
        if settings.bilinear {
            match bilinear_depth(dm, uv) {
                Some(b) => d = b,
                None => continue, // beside a pixel without depth
            }
        }
        let mut margin = settings.margin_footprints * z / cam.fx;
        if settings.slope_margin > 0.0 {
            let step = steps[k_view][pix];
            if step.is_nan() {
                continue; // beside a pixel without depth
            }
            margin += settings.slope_margin * step;
        }
        let s = d - z;
        if s < -margin {
            continue;
        }
        if s <= margin {
            near += 1;
            continue;
        }
        if settings.concavity_gate > 0.0 && !open[k_view][pix] {
            continue;
        }
        free += 1;
        let offer = s - margin;
        if offer > top[k - 1] {
            let mut i = k - 1;
            while i > 0 && top[i - 1] < offer {
                top[i] = top[i - 1];
                i -= 1;
            }
            top[i] = offer;
        }
    }
    let carved = free >= k && free as f32 >= settings.min_free_ratio * (free + near) as f32;
    carved.then(|| top[k - 1])
}

/// The carved field over `[min, max]` at spacing `voxel` (module documentation): `masks` the
/// views' cameras and masks (`mask >= 0.5` is the object; any resolution, the dataset's own
/// is best), `depths` the rendered depth maps (any number, any resolution). Points no mask
/// sees and the box faces are outside. Errors on empty masks, mismatched sizes, an empty or
/// non-finite box, a bad voxel or settings, or a grid over 2^31 points.
pub fn carve_grid(
    masks: &[(Camera, &[f32])],
    depths: &[DepthMap],
    min: Vec3,
    max: Vec3,
    voxel: f32,
    settings: &CarveSettings,
) -> Result<Grid> {
    Ok(carve_field(masks, depths, min, max, voxel, settings)?.grid)
}

/// How many depth samples the concavity gate let vote, of how many ([`carve_field`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct GateCount {
    /// Samples that passed the gate.
    pub open: usize,
    /// Samples with a depth.
    pub samples: usize,
}

/// [`carve_grid`], and with the concavity gate on, how many samples passed it.
pub(crate) fn carve_field(
    masks: &[(Camera, &[f32])],
    depths: &[DepthMap],
    min: Vec3,
    max: Vec3,
    voxel: f32,
    settings: &CarveSettings,
) -> Result<Carving> {
    settings.validate()?;
    let dims = grid_dims(masks, min, max, voxel)?;
    for (k, dm) in depths.iter().enumerate() {
        let n = dm.camera.width as usize * dm.camera.height as usize;
        if dm.depth.len() != n || n == 0 {
            return Err(MeshError::size(
                &format!("depth map {k}"),
                format!("{}x{} = {n} (non-zero)", dm.camera.width, dm.camera.height),
                dm.depth.len(),
            ));
        }
        match dm.hull_depth {
            Some(h) if h.len() != n => {
                return Err(MeshError::size(&format!("hull depth map {k}"), n, h.len()));
            }
            None if settings.concavity_gate > 0.0 => {
                return Err(MeshError::InvalidArgument(format!(
                    "the carving's concavity gate needs the hull's depth, and depth map {k} has none"
                )));
            }
            _ => {}
        }
    }
    // Each view's gate and depth steps, once (not per grid point).
    let open: Vec<Vec<bool>> = if settings.concavity_gate > 0.0 {
        depths
            .iter()
            .map(|dm| concavity_open(dm, settings.concavity_gate, settings.gate_radius))
            .collect()
    } else {
        Vec::new()
    };
    let gate_count = (settings.concavity_gate > 0.0).then(|| GateCount {
        open: open.iter().flatten().filter(|o| **o).count(),
        samples: depths
            .iter()
            .flat_map(|dm| dm.depth)
            .filter(|d| **d > 0.0)
            .count(),
    });
    let steps: Vec<Vec<f32>> = if settings.slope_margin > 0.0 {
        depths.iter().map(depth_steps).collect()
    } else {
        Vec::new()
    };
    let mut grid = Grid::new(min, voxel, dims);
    let plane = dims[0] * dims[1];
    // Per plane of grid points, those the depth carved away, with the masks' own value.
    let carved: Vec<Vec<(usize, f32)>> = (grid.values.par_chunks_mut(plane).enumerate())
        .map(|(k, slice)| {
            let mut carved = Vec::new();
            for (n, value) in slice.iter_mut().enumerate() {
                let (i, j) = (n % dims[0], n / dims[0]);
                let p = min + voxel * Vec3::new(i as f32, j as f32, k as f32);
                *value = match silhouette_distance(masks, p) {
                    None => voxel,
                    Some(hull) if hull >= 0.0 => hull,
                    Some(hull) => match carve_at(depths, &steps, &open, p, settings) {
                        Some(c) if c > 0.0 => {
                            carved.push((k * plane + n, hull));
                            c
                        }
                        _ => hull,
                    },
                };
            }
            carved
        })
        .collect();
    grid.observed.fill(true);
    close_box(&mut grid, voxel);
    Ok(Carving {
        grid,
        carved: carved.into_iter().flatten().collect(),
        gate: gate_count,
    })
}

/// The carved field of [`carve_field`] and what the depth did to it.
pub(crate) struct Carving {
    /// The field handed to marching cubes (box faces closed).
    pub grid: Grid,
    /// The carved-away grid points (inside the masks' hull, raised to a positive field by
    /// the depth), ascending, with the masks' own value there.
    pub carved: Vec<(usize, f32)>,
    /// What the concavity gate let vote, when there is a gate.
    pub gate: Option<GateCount>,
}

impl Carving {
    /// The carved-away regions: the 6-connected components of [`Carving::carved`], as a
    /// label per point and the number of regions.
    pub fn regions(&self) -> CarvedRegions {
        let points: Vec<usize> = self.carved.iter().map(|(i, _)| *i).collect();
        let [nx, ny, nz] = self.grid.dims;
        let slot = |i: usize| points.binary_search(&i).ok();
        let mut label = vec![u32::MAX; points.len()];
        let mut count = 0u32;
        let mut stack = Vec::new();
        for seed in 0..points.len() {
            if label[seed] != u32::MAX {
                continue;
            }
            label[seed] = count;
            stack.push(seed);
            while let Some(s) = stack.pop() {
                let i = points[s];
                let (x, y, z) = (i % nx, (i / nx) % ny, i / (nx * ny));
                let neighbours = [
                    (x > 0).then(|| i - 1),
                    (x + 1 < nx).then(|| i + 1),
                    (y > 0).then(|| i - nx),
                    (y + 1 < ny).then(|| i + nx),
                    (z > 0).then(|| i - nx * ny),
                    (z + 1 < nz).then(|| i + nx * ny),
                ];
                for n in neighbours.into_iter().flatten().filter_map(slot) {
                    if label[n] == u32::MAX {
                        label[n] = count;
                        stack.push(n);
                    }
                }
            }
            count += 1;
        }
        CarvedRegions {
            points,
            label,
            count: count as usize,
        }
    }

    /// The field with the masks' own value restored over the regions `refused` marks (by
    /// label of `regions`): those regions are not carved, and the surface over them is the
    /// masks' again.
    pub fn restored(&self, regions: &CarvedRegions, refused: &[bool]) -> Grid {
        let mut grid = self.grid.clone();
        for (&(i, hull), label) in self.carved.iter().zip(&regions.label) {
            if refused[*label as usize] {
                grid.values[i] = hull;
            }
        }
        close_box(&mut grid, self.grid.voxel);
        grid
    }
}

/// The carved-away regions of a [`Carving`] ([`Carving::regions`]).
pub(crate) struct CarvedRegions {
    /// The carved-away grid points, ascending.
    pub points: Vec<usize>,
    /// Each point's region.
    pub label: Vec<u32>,
    /// How many regions.
    pub count: usize,
}

impl CarvedRegions {
    /// The region of the carved-away grid point nearest `p`, if that point is one.
    pub fn at(&self, grid: &Grid, p: Vec3) -> Option<u32> {
        let g = (p - grid.origin) / grid.voxel;
        let [nx, ny, nz] = grid.dims;
        let (x, y, z) = (g.x.round(), g.y.round(), g.z.round());
        if !(x >= 0.0 && y >= 0.0 && z >= 0.0) {
            return None;
        }
        let (x, y, z) = (x as usize, y as usize, z as usize);
        if x >= nx || y >= ny || z >= nz {
            return None;
        }
        (self.points.binary_search(&grid.index(x, y, z)).ok()).map(|s| self.label[s])
    }
}

/// [`carve_grid`] through marching cubes, the largest component: closed and outward oriented.
pub fn carve_mesh(
    masks: &[(Camera, &[f32])],
    depths: &[DepthMap],
    min: Vec3,
    max: Vec3,
    voxel: f32,
    settings: &CarveSettings,
) -> Result<TriMesh> {
    let carving = carve_field(masks, depths, min, max, voxel, settings)?;
    Ok(largest_component(&marching_cubes(&carving.grid, 0.0)))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The offsets are read in each sample's own footprint, over the samples that have both
    /// depths, and moving the maps by the median brings that median to 0.
    #[test]
    fn the_hull_offset_is_measured_in_footprints_and_taken_out() {
        // 64 x 64 pixels, of which the first 16 carry depths.
        let camera = Camera::look_at(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, Vec3::Y, 0.5, 64, 64);
        let hull: Vec<f32> = (0..64 * 64)
            .map(|k| if k < 16 { 2.0 + 0.01 * k as f32 } else { 0.0 })
            .collect();
        // Offsets 0..=11 footprints on 12 pixels; one pixel without depth, one without hull,
        // two non-finite.
        let mut depth: Vec<f32> = hull
            .iter()
            .enumerate()
            .map(|(k, h)| h / (1.0 - k as f32 / camera.fx))
            .collect();
        depth[12] = 0.0;
        depth[13] = f32::NAN;
        depth[14] = f32::INFINITY;
        let mut hull_missing = hull.clone();
        hull_missing[15] = 0.0;
        let map = |depth: &[f32]| -> Option<[f32; 3]> {
            hull_offset(&[DepthMap {
                camera: &camera,
                depth,
                hull_depth: Some(&hull_missing),
            }])
        };
        let [q1, median, q3] = map(&depth).expect("twelve shared samples");
        for (got, want) in [(q1, 2.0), (median, 5.0), (q3, 8.0)] {
            assert!((got - want).abs() < 1e-3, "{got} against {want}");
        }
        debias_depth(&camera, &mut depth, median);
        assert_eq!(depth[12], 0.0);
        assert!(depth[13].is_nan());
        let [q1, median, _] = map(&depth).unwrap();
        // Footprints are read at the moved depth, a few per cent smaller here.
        assert!(
            median.abs() < 1e-3 && (q1 + 3.0).abs() < 0.15,
            "{q1} {median}"
        );
        assert!(
            hull_offset(&[DepthMap {
                camera: &camera,
                depth: &depth,
                hull_depth: None,
            }])
            .is_none()
        );
    }
}
