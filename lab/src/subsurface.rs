//! Light scattered under a translucent surface, gathered over the surface in 3D, and the depth
//! of a concavity read from how little light it gathers.
//!
//! Under the light at the camera, the lit surface is exactly the surface the camera sees, and
//! each pixel's patch takes the same power: its irradiance `cos / r^2` times its area
//! `r^2 / (f^2 cos)` is the pixel's solid angle `1 / f^2`. Light leaves the surface around
//! where it entered, with a profile `R(d)` of the distance `d` *in 3D*. So the scattered
//! radiance of a pixel `p` is
//!
//! `S(p) = sum_q R(|X_p - X_q|) / f^2`
//!
//! over the pixels `q` the camera sees, with `X` their points. On a wide flat patch facing the
//! camera `S = 1 / r^2`, as Lambert's `L = cos / r^2` at normal incidence. The model
//!
//! `I = a (P * L) + sum_k b_k S_k`
//!
//! takes `R` as a non-negative sum of normalised Gaussians of the widths `s_k` (world units),
//! beside the sharp part `a (P * L)` of [`gtsr_mesh::scatter`]. Its difference from that module's
//! image-space blur is the whole point: a groove's floor lies *behind* its rims, farther from
//! them in 3D than in the image, and gathers less of their light; the deeper the floor, the
//! darker, until the floor is past the profile's reach. [`fit_surface_scatter`] fits `a` and
//! `b_k` (non-negative least squares) on a mesh that is right where it is trusted;
//! [`dark_depths`] then moves the pixels the mesh cannot explain ([`gtsr_mesh::scatter::unexplained_dark`])
//! back along their rays until the model is as dark as the image.
//!
//! The sums run on a pyramid of the point map: a width of `s` pixels reads blocks of about
//! `s / 2` pixels (their count and mean point), so every width costs about the same.
//!
//! ```
//! use lab::subsurface::SurfaceMap;
//!
//! // A flat patch facing the camera at depth 2 (f = 100 px): S = 1 / r^2 away from its border.
//! let (w, h, f) = (64usize, 64usize, 100.0f32);
//! let map = SurfaceMap::new(w, h, f, f, w as f32 / 2.0, h as f32 / 2.0, &vec![2.0; w * h]).unwrap();
//! let p = 32 * w + 32;
//! let s = map.gather(p, map.point(p), 0.05);
//! assert!((s * 4.0 - 1.0).abs() < 0.02, "{s}");
//! ```

use glam::Vec3;
use gtsr_data::Camera;
use rayon::prelude::*;

use gtsr_mesh::scatter::{gaussian_blur, lambert_of_depth};
use gtsr_mesh::shading::ShadingImage;
use gtsr_mesh::{MeshError, Result};

/// The profile's widths [`fit_surface_scatter`] fits, in footprints at the views' median
/// depth.
pub const SURFACE_WIDTHS_FP: [f32; 6] = [1.0, 2.0, 4.0, 8.0, 16.0, 32.0];

/// The most a pyramid block spans (pixels).
const MAX_BLOCK: usize = 16;

/// One level of a [`SurfaceMap`]'s pyramid: per block of `block x block` pixels, the count of
/// surface pixels and the sum of their points.
#[derive(Clone, Debug)]
struct Level {
    block: usize,
    bw: usize,
    bh: usize,
    count: Vec<f32>,
    sum: Vec<Vec3>,
}

/// One view's visible surface: the camera-space point per pixel, and a pyramid of it.
#[derive(Clone, Debug)]
pub struct SurfaceMap {
    width: usize,
    height: usize,
    fx: f32,
    fy: f32,
    cx: f32,
    cy: f32,
    depth: Vec<f32>,
    levels: Vec<Level>,
}

impl SurfaceMap {
    /// The map of a z-depth image (`0`: no surface) of a pinhole camera of focal lengths
    /// `fx, fy` and centre `cx, cy` (pixels). Errors on a size mismatch, a non-positive focal
    /// length or a negative or non-finite depth.
    pub fn new(
        width: usize,
        height: usize,
        fx: f32,
        fy: f32,
        cx: f32,
        cy: f32,
        depth: &[f32],
    ) -> Result<Self> {
        if depth.len() != width * height || width == 0 || height == 0 {
            return Err(MeshError::InvalidArgument(format!(
                "surface map: a {width}x{height} view needs {} depths, got {}",
                width * height,
                depth.len()
            )));
        }
        if !(fx.is_finite() && fx > 0.0 && fy.is_finite() && fy > 0.0) {
            return Err(MeshError::InvalidArgument(format!(
                "surface map: focal lengths must be positive, got {fx} and {fy}"
            )));
        }
        if let Some(z) = depth.iter().find(|z| !(z.is_finite() && **z >= 0.0)) {
            return Err(MeshError::InvalidArgument(format!(
                "surface map: depths must be finite and non-negative, got {z}"
            )));
        }
        let mut map = Self {
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            depth: depth.to_vec(),
            levels: Vec::new(),
        };
        map.rebuild();
        Ok(map)
    }

    /// The map of `camera`'s z-depth image `depth`.
    pub fn of_camera(camera: &Camera, depth: &[f32]) -> Result<Self> {
        Self::new(
            camera.width as usize,
            camera.height as usize,
            camera.fx,
            camera.fy,
            camera.cx,
            camera.cy,
            depth,
        )
    }

    /// The z-depth per pixel (`0`: none).
    pub fn depth(&self) -> &[f32] {
        &self.depth
    }

    /// The camera-space point of pixel `p` at z-depth `z`.
    pub fn point_at(&self, p: usize, z: f32) -> Vec3 {
        let (u, v) = ((p % self.width) as f32 + 0.5, (p / self.width) as f32 + 0.5);
        z * Vec3::new((u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0)
    }

    /// The camera-space point of pixel `p` (the origin where it has none).
    pub fn point(&self, p: usize) -> Vec3 {
        self.point_at(p, self.depth[p])
    }

    /// Replaces the depths (same size) and rebuilds the pyramid.
    pub fn set_depth(&mut self, depth: &[f32]) -> Result<()> {
        if depth.len() != self.depth.len() {
            return Err(MeshError::InvalidArgument(format!(
                "surface map: {} depths for a map of {}",
                depth.len(),
                self.depth.len()
            )));
        }
        if let Some(z) = depth.iter().find(|z| !(z.is_finite() && **z >= 0.0)) {
            return Err(MeshError::InvalidArgument(format!(
                "surface map: depths must be finite and non-negative, got {z}"
            )));
        }
        self.depth.copy_from_slice(depth);
        self.rebuild();
        Ok(())
    }

    fn rebuild(&mut self) {
        self.levels.clear();
        let mut block = 1;
        while block <= MAX_BLOCK {
            let (bw, bh) = (self.width.div_ceil(block), self.height.div_ceil(block));
            let mut count = vec![0f32; bw * bh];
            let mut sum = vec![Vec3::ZERO; bw * bh];
            for p in 0..self.depth.len() {
                if self.depth[p] > 0.0 {
                    let b = (p / self.width / block) * bw + (p % self.width) / block;
                    count[b] += 1.0;
                    sum[b] += self.point(p);
                }
            }
            self.levels.push(Level {
                block,
                bw,
                bh,
                count,
                sum,
            });
            block *= 2;
        }
    }

    /// `S_s(p)` with pixel `p`'s own point put at `x`: the sum over the map's surface pixels of
    /// the normalised Gaussian of width `s` (world units) of their distance to `x`, over `f^2`.
    /// Pixel `p` counts once, at distance 0; `0` when `p` has no surface or `s` is not
    /// positive.
    pub fn gather(&self, p: usize, x: Vec3, s: f32) -> f32 {
        self.gather_through(p, x, s, false)
    }

    /// Whether the point `y` (camera space) lies in front of the view's surface: in the air
    /// between the camera and the surface, or beside the object.
    fn in_air(&self, y: Vec3) -> bool {
        if y.z <= 0.0 {
            return true;
        }
        let u = self.fx * y.x / y.z + self.cx;
        let v = self.fy * y.y / y.z + self.cy;
        if u < 0.0 || v < 0.0 || u >= self.width as f32 || v >= self.height as f32 {
            return true;
        }
        let z = self.depth[v as usize * self.width + u as usize];
        z <= 0.0 || y.z < z - 0.5 * z / self.fx
    }

    /// [`SurfaceMap::gather`], and with `medium` only through the medium: a pixel counts only
    /// when the segment from `x` to its point stays behind the view's surface at its quarter,
    /// half and three-quarter points (light that would cross a concavity's air does not).
    pub fn gather_through(&self, p: usize, x: Vec3, s: f32, medium: bool) -> f32 {
        if self.depth[p] <= 0.0 || s.is_nan() || s <= 0.0 || x.z <= 0.0 {
            return 0.0;
        }
        let s_px = s * self.fx / x.z;
        let want = (s_px / 2.0).max(1.0) as usize;
        let level = (self.levels.iter().rev())
            .find(|l| l.block <= want)
            .unwrap_or(&self.levels[0]);
        let b = level.block;
        let (u, v) = (p % self.width / b, p / self.width / b);
        let r = (3.0 * s_px / b as f32).ceil() as usize + 1;
        let inv = -0.5 / (s * s);
        let own = self.point(p);
        let mut acc = 1.0f32;
        for j in v.saturating_sub(r)..(v + r + 1).min(level.bh) {
            for i in u.saturating_sub(r)..(u + r + 1).min(level.bw) {
                let k = j * level.bw + i;
                let (mut c, mut sum) = (level.count[k], level.sum[k]);
                if i == u && j == v {
                    c -= 1.0;
                    sum -= own;
                }
                if c < 0.5 {
                    continue;
                }
                let y = sum / c;
                let d = x - y;
                let g = (inv * d.length_squared()).exp();
                if g < 1e-6 {
                    continue;
                }
                if medium && [0.25f32, 0.5, 0.75].iter().any(|f| self.in_air(x - *f * d)) {
                    continue;
                }
                acc += c * g;
            }
        }
        acc / (std::f32::consts::TAU * s * s * self.fx * self.fy)
    }
}

/// The scene's surface-space scattering model `I = a (P * L) + sum_k b_k S_k`.
#[derive(Clone, Debug, PartialEq)]
pub struct SurfaceScatter {
    /// `a`: the light leaving where it entered.
    pub sharp: f32,
    /// The width of the pixel filter `P` (pixels).
    pub pixel: f32,
    /// The profile's widths `s_k` (world units).
    pub widths: Vec<f32>,
    /// Their weights `b_k` (non-negative).
    pub weights: Vec<f32>,
    /// The fit's residual, relative to the readings' sum of squares.
    pub residual: f64,
    /// The pixels the fit read.
    pub samples: usize,
    /// Whether the light travels only through the medium ([`SurfaceMap::gather_through`]).
    pub medium: bool,
}

impl SurfaceScatter {
    /// The model's radiance at pixel `p` of `map` with its point put at `x`, given the sharp
    /// part's `P * L` there.
    pub fn predict(&self, map: &SurfaceMap, p: usize, x: Vec3, sharp_lambert: f32) -> f32 {
        self.sharp * sharp_lambert
            + (self.widths.iter().zip(&self.weights))
                .filter(|(_, b)| **b > 0.0)
                .map(|(s, b)| b * map.gather_through(p, x, *s, self.medium))
                .sum::<f32>()
    }
}

/// One view for [`fit_surface_scatter`] and [`dark_depths`].
pub struct SurfaceView<'a> {
    /// The view's surface (a mesh's depth).
    pub map: SurfaceMap,
    /// Linear radiance per pixel.
    pub radiance: &'a [f32],
    /// `P * L`: the mesh's Lambertian radiance through the pixel filter.
    pub sharp_lambert: Vec<f32>,
    /// The mesh's cosine `n . w` per pixel.
    pub cosine: Vec<f32>,
    /// Object mask per pixel (`None`: every pixel counts).
    pub mask: Option<&'a [f32]>,
}

/// The views of `images` on `mesh`: each image's point map, `P * L` with a pixel filter of
/// `pixel` pixels and cosine.
pub fn surface_views<'a>(
    mesh: &gtsr_data::ply::TriMesh,
    images: &[ShadingImage<'a>],
    pixel: f32,
) -> Result<Vec<SurfaceView<'a>>> {
    let caster =
        gtsr_mesh::raycast::MeshRaycaster::new(mesh, "the mesh the scattering is gathered on")?;
    images
        .par_iter()
        .map(|v| {
            let (w, h) = (v.camera.width as usize, v.camera.height as usize);
            if v.radiance.len() != w * h || v.mask.is_some_and(|m| m.len() != w * h) {
                return Err(MeshError::InvalidArgument(format!(
                    "surface scattering: a {w}x{h} view needs {} radiances and mask values",
                    w * h
                )));
            }
            let render = caster.render(v.camera);
            let (lambert, cosine) = lambert_of_depth(&render, v.camera);
            Ok(SurfaceView {
                map: SurfaceMap::of_camera(v.camera, &render.depth)?,
                radiance: v.radiance,
                sharp_lambert: gaussian_blur(&lambert, w, h, pixel),
                cosine,
                mask: v.mask,
            })
        })
        .collect()
}

/// The median z-depth of the views' surface pixels (0 when there are none).
pub fn median_depth(views: &[SurfaceView<'_>]) -> f32 {
    let mut z: Vec<f32> = (views.iter())
        .flat_map(|v| v.map.depth().iter().copied().filter(|z| *z > 0.0))
        .collect();
    if z.is_empty() {
        return 0.0;
    }
    let mid = z.len() / 2;
    *z.select_nth_unstable_by(mid, f32::total_cmp).1
}

/// Fits `a` and `b_k` (non-negative least squares) at the profile widths `widths` (world
/// units) on the pixels of `views` whose mask is at least 0.99, whose cosine is at least
/// `min_cos`, that are not in `skip` (per view; `None`: none) and that lie on the grid of
/// every `stride`-th pixel. Errors when no pixel qualifies or a width is not positive.
pub fn fit_surface_scatter(
    views: &[SurfaceView<'_>],
    skip: Option<&[Vec<bool>]>,
    widths: &[f32],
    pixel: f32,
    min_cos: f32,
    stride: usize,
    medium: bool,
) -> Result<SurfaceScatter> {
    if let Some(s) = widths.iter().find(|s| !(s.is_finite() && **s > 0.0)) {
        return Err(MeshError::InvalidArgument(format!(
            "surface scattering fit: profile widths must be positive, got {s}"
        )));
    }
    if skip.is_some_and(|s| s.len() != views.len()) {
        return Err(MeshError::InvalidArgument(
            "surface scattering fit: one skip map per view".into(),
        ));
    }
    let stride = stride.max(1);
    let n = widths.len() + 1;
    // The normal equations' sums, per view.
    let sums: Vec<(Vec<f64>, Vec<f64>, f64, usize)> = (views.par_iter().enumerate())
        .map(|(k, v)| {
            let w = v.map.width;
            let (mut ata, mut atb, mut bb, mut m) = (vec![0f64; n * n], vec![0f64; n], 0f64, 0);
            let mut row = vec![0f64; n];
            for p in 0..v.radiance.len() {
                let (x, y) = (p % w, p / w);
                let i = v.radiance[p];
                if x % stride != 0
                    || y % stride != 0
                    || v.map.depth[p] <= 0.0
                    || v.cosine[p] < min_cos
                    || v.mask.is_some_and(|m| m[p] < 0.99)
                    || skip.is_some_and(|s| s[k].get(p).copied().unwrap_or(false))
                    || !i.is_finite()
                {
                    continue;
                }
                let xp = v.map.point(p);
                row[0] = f64::from(v.sharp_lambert[p]);
                for (r, s) in row[1..].iter_mut().zip(widths) {
                    *r = f64::from(v.map.gather_through(p, xp, *s, medium));
                }
                for a in 0..n {
                    atb[a] += row[a] * f64::from(i);
                    for b in 0..n {
                        ata[a * n + b] += row[a] * row[b];
                    }
                }
                bb += f64::from(i) * f64::from(i);
                m += 1;
            }
            (ata, atb, bb, m)
        })
        .collect();
    let (mut ata, mut atb, mut bb, mut m) = (vec![0f64; n * n], vec![0f64; n], 0f64, 0usize);
    for (a, b, c, k) in sums {
        for (x, y) in ata.iter_mut().zip(a) {
            *x += y;
        }
        for (x, y) in atb.iter_mut().zip(b) {
            *x += y;
        }
        bb += c;
        m += k;
    }
    if m == 0 || bb <= 0.0 {
        return Err(MeshError::InvalidArgument(
            "surface scattering fit: no view shows the mesh lit by its own light".into(),
        ));
    }
    let coef = nnls(&ata, &atb, n);
    let mut res = bb;
    for a in 0..n {
        res -= 2.0 * coef[a] * atb[a];
        for b in 0..n {
            res += coef[a] * coef[b] * ata[a * n + b];
        }
    }
    Ok(SurfaceScatter {
        sharp: coef[0] as f32,
        pixel,
        widths: widths.to_vec(),
        weights: coef[1..].iter().map(|c| *c as f32).collect(),
        residual: res.max(0.0) / bb,
        samples: m,
        medium,
    })
}

/// Non-negative least squares from the normal equations `ata x = atb` (`n x n`), by cyclic
/// coordinate descent (exact for a positive definite `ata`; a zero diagonal keeps `x = 0`).
fn nnls(ata: &[f64], atb: &[f64], n: usize) -> Vec<f64> {
    let mut x = vec![0f64; n];
    for _ in 0..20_000 {
        let mut change = 0f64;
        for a in 0..n {
            let d = ata[a * n + a];
            if d <= 0.0 {
                continue;
            }
            let g: f64 = atb[a] - (0..n).map(|b| ata[a * n + b] * x[b]).sum::<f64>();
            let new = (x[a] + g / d).max(0.0);
            change = change.max((new - x[a]).abs() * d.sqrt());
            x[a] = new;
        }
        if change < 1e-12 * atb.iter().fold(0f64, |m, v| m.max(v.abs())).max(1e-300) {
            break;
        }
    }
    x
}

/// How [`dark_depths`] searches.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DarkDepthSettings {
    /// The deepest offset tried (footprints behind the mesh's depth).
    pub max_footprints: f32,
    /// The offsets' step (footprints).
    pub step_footprints: f32,
    /// Sweeps over the pixels (each sees the others' offsets of the sweep before).
    pub sweeps: usize,
    /// The median filter's radius over the dark pixels' offsets (pixels; 0: none).
    pub median_radius: usize,
}

impl Default for DarkDepthSettings {
    fn default() -> Self {
        Self {
            max_footprints: 60.0,
            step_footprints: 2.0,
            sweeps: 6,
            median_radius: 2,
        }
    }
}

/// Per view, the offset (footprints `z / fx` behind the view's depth) at which `model`'s
/// radiance first falls to the image's at each pixel flagged in `dark` (0 elsewhere;
/// `max_footprints` where it never does): the depth of a concavity the mesh lids over, from
/// how little light it gathers. Each sweep moves every flagged pixel with the others where the
/// sweep before put them; the offsets are then median-filtered over the flagged pixels.
/// Errors on a flag map of the wrong size or a non-positive step.
pub fn dark_depths(
    model: &SurfaceScatter,
    views: &[SurfaceView<'_>],
    dark: &[Vec<bool>],
    settings: &DarkDepthSettings,
) -> Result<Vec<Vec<f32>>> {
    if !(settings.step_footprints > 0.0 && settings.max_footprints >= 0.0) {
        return Err(MeshError::InvalidArgument(format!(
            "dark depths: the step must be positive and the deepest offset non-negative, got \
             {} and {}",
            settings.step_footprints, settings.max_footprints
        )));
    }
    if dark.len() != views.len()
        || (dark.iter().zip(views)).any(|(d, v)| d.len() != v.map.depth.len())
    {
        return Err(MeshError::InvalidArgument(
            "dark depths: one flag per pixel of every view".into(),
        ));
    }
    let steps = (settings.max_footprints / settings.step_footprints).floor() as usize;
    views
        .par_iter()
        .zip(dark)
        .map(|(v, flags)| {
            let lid = v.map.depth.clone();
            let pixels: Vec<usize> = (0..lid.len())
                .filter(|p| flags[*p] && lid[*p] > 0.0)
                .collect();
            let mut offset = vec![0f32; lid.len()];
            if pixels.is_empty() {
                return Ok(offset);
            }
            let mut map = v.map.clone();
            for _ in 0..settings.sweeps {
                let found: Vec<f32> = pixels
                    .iter()
                    .map(|&p| {
                        let target = v.radiance[p];
                        (0..=steps)
                            .map(|k| k as f32 * settings.step_footprints)
                            .find(|t| {
                                let x = map.point_at(p, lid[p] * (1.0 + t / map.fx));
                                model.predict(&map, p, x, v.sharp_lambert[p]) <= target
                            })
                            .unwrap_or(steps as f32 * settings.step_footprints)
                    })
                    .collect();
                for (&p, t) in pixels.iter().zip(found) {
                    offset[p] = t;
                }
                let moved: Vec<f32> = (lid.iter().zip(&offset))
                    .map(|(z, t)| z * (1.0 + t / map.fx))
                    .collect();
                map.set_depth(&moved)?;
            }
            Ok(median_over(
                &offset,
                flags,
                map.width,
                settings.median_radius,
            ))
        })
        .collect()
}

/// The median of `values` over the flagged pixels within `radius` of each flagged pixel.
fn median_over(values: &[f32], flags: &[bool], w: usize, radius: usize) -> Vec<f32> {
    if radius == 0 {
        return values.to_vec();
    }
    let h = values.len() / w;
    let mut out = values.to_vec();
    let mut window = Vec::new();
    for p in 0..values.len() {
        if !flags[p] {
            continue;
        }
        let (x, y) = (p % w, p / w);
        window.clear();
        for j in y.saturating_sub(radius)..(y + radius + 1).min(h) {
            for i in x.saturating_sub(radius)..(x + radius + 1).min(w) {
                if flags[j * w + i] {
                    window.push(values[j * w + i]);
                }
            }
        }
        let mid = window.len() / 2;
        out[p] = *window.select_nth_unstable_by(mid, f32::total_cmp).1;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    const F: f32 = 100.0;

    fn plane(w: usize, h: usize, z: f32) -> SurfaceMap {
        SurfaceMap::new(w, h, F, F, w as f32 / 2.0, h as f32 / 2.0, &vec![z; w * h]).unwrap()
    }

    /// On a wide flat patch facing the camera, every width gathers `1 / z^2`, whichever pyramid
    /// level reads it; at the patch's edge about half of it.
    #[test]
    fn a_flat_patch_gathers_its_lambertian_radiance_at_every_width() {
        let (w, h, z) = (160, 160, 2.0);
        let map = plane(w, h, z);
        let p = 80 * w + 80;
        for s in [0.01f32, 0.03, 0.1, 0.2] {
            let g = map.gather(p, map.point(p), s) * z * z;
            assert!((g - 1.0).abs() < 0.03, "width {s}: {g}");
            if s < 0.1 {
                // The edge pixel's centre lies half a pixel in: `Phi(0.5 / width)`, near a
                // half only for widths of several pixels.
                continue;
            }
            let edge = 80 * w;
            let e = map.gather(edge, map.point(edge), s) * z * z;
            assert!((e - 0.52).abs() < 0.04, "width {s} at the edge: {e}");
        }
    }

    /// A pixel moved back along its ray gathers less; far past the profile, only itself.
    #[test]
    fn a_point_behind_the_surface_gathers_less_the_deeper_it_lies() {
        let (w, h, z) = (96, 96, 2.0);
        let map = plane(w, h, z);
        let p = 48 * w + 48;
        let s = 0.05;
        let at = |t: f32| map.gather(p, map.point_at(p, z + t), s);
        let (g0, g1, g2, g9) = (at(0.0), at(0.03), at(0.06), at(1.0));
        assert!(g0 > g1 && g1 > g2 && g2 > g9, "{g0} {g1} {g2} {g9}");
        let alone = 1.0 / (std::f32::consts::TAU * s * s * F * F);
        assert!((g9 - alone).abs() < 1e-3 * alone, "{g9} against {alone}");
    }

    /// Through the medium only, a flat patch gathers as much as through anything; the floor of
    /// a deep pit gathers less, its rims' light crossing the pit's air.
    #[test]
    fn light_through_the_medium_only_skips_a_pits_air() {
        let (w, h, z) = (96, 96, 2.0);
        let flat = plane(w, h, z);
        let p = 48 * w + 48;
        let s = 0.1;
        let (a, b) = (
            flat.gather(p, flat.point(p), s),
            flat.gather_through(p, flat.point(p), s, true),
        );
        assert!((a - b).abs() < 1e-6 * a, "{a} {b}");
        let pit = |q: usize| (43..53).contains(&(q % w)) && (43..53).contains(&(q / w));
        let depth: Vec<f32> = (0..w * h)
            .map(|q| if pit(q) { z + 0.3 } else { z })
            .collect();
        let map = SurfaceMap::new(w, h, F, F, 48.0, 48.0, &depth).unwrap();
        let (all, medium) = (
            map.gather(p, map.point(p), s),
            map.gather_through(p, map.point(p), s, true),
        );
        assert!(
            medium < 0.9 * all,
            "through the medium {medium}, through anything {all}"
        );
        assert!(medium > 0.0);
    }

    /// Images made by a known model on a flat patch with a sunken square are fitted back to
    /// that model off the square, and the square's depth is read back from its darkness.
    #[test]
    fn a_groove_is_read_back_from_the_darkness_it_makes() {
        let (w, h, z) = (96usize, 96usize, 2.0f32);
        let fp = z / F;
        let widths = [3.0 * fp, 8.0 * fp];
        let truth = SurfaceScatter {
            sharp: 0.5,
            pixel: 0.0,
            widths: widths.to_vec(),
            weights: vec![0.3, 0.4],
            residual: 0.0,
            samples: 0,
            medium: false,
        };
        // The truth: a 12 px square 10 fp behind a plane; a second view: a tilted plane.
        let sunk = |p: usize| (36..48).contains(&(p % w)) && (40..52).contains(&(p / w));
        let deep: Vec<f32> = (0..w * h)
            .map(|p| if sunk(p) { z * (1.0 + 10.0 / F) } else { z })
            .collect();
        let tilt: Vec<f32> = (0..w * h).map(|p| z + 0.004 * (p % w) as f32).collect();
        let mut views = Vec::new();
        let mut images = Vec::new();
        for d in [&deep, &tilt] {
            let map = SurfaceMap::new(w, h, F, F, 48.0, 48.0, d).unwrap();
            let lam: Vec<f32> = d.iter().map(|z| 1.0 / (z * z)).collect();
            images.push(
                (0..w * h)
                    .map(|p| truth.predict(&map, p, map.point(p), lam[p]))
                    .collect::<Vec<f32>>(),
            );
        }
        // The lid: the plane over the square, with its Lambert map (as a mesh's would be).
        let lid = vec![z; w * h];
        for (k, d) in [&lid, &tilt].into_iter().enumerate() {
            views.push(SurfaceView {
                map: SurfaceMap::new(w, h, F, F, 48.0, 48.0, d).unwrap(),
                radiance: &images[k],
                sharp_lambert: d.iter().map(|z| 1.0 / (z * z)).collect(),
                cosine: vec![1.0; w * h],
                mask: None,
            });
        }
        // The fit, away from the square's reach.
        let near = |p: usize| (4..80).contains(&(p % w)) && (8..84).contains(&(p / w));
        let skip: Vec<Vec<bool>> = vec![(0..w * h).map(near).collect(), vec![false; w * h]];
        let fit = fit_surface_scatter(&views, Some(&skip), &widths, 0.0, 0.0, 2, false).unwrap();
        assert!(fit.residual < 1e-6, "{fit:?}");
        assert!((fit.sharp - 0.5).abs() < 0.01, "{fit:?}");
        assert!(
            (fit.weights.iter().sum::<f32>() - 0.7).abs() < 0.01,
            "{fit:?}"
        );
        // The dark square's depth, from the image alone.
        let dark = vec![(0..w * h).map(sunk).collect(), vec![false; w * h]];
        let settings = DarkDepthSettings {
            max_footprints: 30.0,
            step_footprints: 1.0,
            sweeps: 8,
            median_radius: 1,
        };
        let off = dark_depths(&fit, &views, &dark, &settings).unwrap();
        let inner: Vec<f32> = (0..w * h).filter(|p| sunk(*p)).map(|p| off[0][p]).collect();
        let mean = inner.iter().sum::<f32>() / inner.len() as f32;
        assert!((mean - 10.0).abs() < 1.5, "mean offset {mean} fp, truth 10");
        assert!(off[1].iter().all(|t| *t == 0.0));
        assert!(off[0].iter().enumerate().all(|(p, t)| sunk(p) || *t == 0.0));
    }

    #[test]
    fn bad_inputs_are_errors() {
        assert!(SurfaceMap::new(4, 4, F, F, 2.0, 2.0, &[1.0; 15]).is_err());
        assert!(SurfaceMap::new(4, 4, 0.0, F, 2.0, 2.0, &[1.0; 16]).is_err());
        assert!(SurfaceMap::new(4, 4, F, F, 2.0, 2.0, &[f32::NAN; 16]).is_err());
        let mut m = plane(4, 4, 1.0);
        assert!(m.set_depth(&[-1.0; 16]).is_err());
        let model = SurfaceScatter {
            sharp: 1.0,
            pixel: 0.0,
            widths: vec![0.1],
            weights: vec![1.0],
            residual: 0.0,
            samples: 0,
            medium: false,
        };
        let bad = DarkDepthSettings {
            step_footprints: 0.0,
            ..DarkDepthSettings::default()
        };
        assert!(dark_depths(&model, &[], &[], &bad).is_err());
        assert!(fit_surface_scatter(&[], None, &[0.0], 0.0, 0.0, 1, false).is_err());
        assert!(fit_surface_scatter(&[], None, &[0.1], 0.0, 0.0, 1, false).is_err());
    }
}
