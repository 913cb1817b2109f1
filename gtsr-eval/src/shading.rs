//! Normals from the images' shading under a light at the camera (photometric stereo whose
//! light moves with each view), for the refinement of the masks' mesh ([`crate::refine`]).
//!
//! With a point light at the camera, a Lambertian surface point `x` of normal `n` and albedo
//! `rho` seen from the eye `e` has the linear radiance `I = rho L (n . w) / r^2`, with
//! `w = (e - x) / r` and `r = |e - x|`. So `I r^2 = b . w` with `b = rho L n`: every view that
//! sees a face gives one linear equation in `b`, and the light directions of the views that see
//! it span a cone wide enough to solve for `b` by least squares. The normal is `b / |b|`; the
//! albedo drops out. A face whose centroid lies off the true surface (a lid of the masks' mesh
//! over a dent) reads, in each view, the shading of the surface point its pixel shows; those
//! points differ a little from view to view (the parallax of the lid's height), so the normal
//! it gets is the truth's blurred over that parallax.
//!
//! Two things break the model. Light scattered under the surface leaves it away from where it
//! entered, which blurs the shading and flattens its fall-off with the angle
//! (`ShadingSettings::response` learns that fall-off for the scene). And where other parts of
//! the object face a face, they light it too, in the views that light them: that light does
//! not follow `n . w`, and Lambert's fit leans towards the eyes that add it
//! (`ShadingSettings::interreflection` models it from the images, one bounce).
//!
//! [`refine_by_shading`] puts it together: the shading normals of a mesh, with the
//! interreflection modelled, and the mesh refined by them.

use glam::{Mat3, Mat4, Vec3, Vec4};
use gtsr_data::Camera;
use gtsr_data::image_io::srgb_to_linear;
use gtsr_data::ply::TriMesh;

use crate::error::{EvalError, Result};
use crate::mesh::{face_centroid, face_normal_scaled};
use crate::refine::{
    DepthTargets, FaceNormals, NormalView, RefineSettings, observed_normals, refine_anchored,
    visible_faces,
};

/// One view for [`shading_normals`].
pub struct ShadingView<'a> {
    /// The camera; the light sits at its centre.
    pub camera: &'a Camera,
    /// Linear radiance, one value per pixel (the mean of the channels), row-major.
    pub radiance: &'a [f32],
    /// Object mask per pixel (`None`: every pixel counts).
    pub mask: Option<&'a [f32]>,
    /// The mesh's own z-depth through each pixel centre (`0` on a miss), for visibility.
    pub mesh_depth: &'a [f32],
}

/// Settings of [`shading_normals`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShadingSettings {
    /// The smallest cosine between a face's normal and its direction to the camera.
    pub min_cos: f32,
    /// The fewest views that must see a face.
    pub min_views: usize,
    /// The least mask value of a pixel that counts (pixels on the silhouette mix background).
    pub min_mask: f32,
    /// Ridge weight, relative to the mean eigenvalue of the normal equations, pulling the
    /// solution towards the face's own normal at the albedo that fits it best: it keeps the
    /// solve stable where the views' directions span a narrow cone.
    pub ridge: f32,
    /// Fit `I r^2 = b . w + a` instead: the constant `a` takes the light that comes out of the
    /// face whatever its angle to the light (scattered under the surface from around it).
    pub ambient: bool,
    /// Knots of a response to the angle fitted on the scene (0: Lambert's cosine). With the
    /// light at the camera, any isotropic reflectance gives `I r^2 = rho g(n . w)` for one
    /// function `g` of the angle; the fit learns `g` (piecewise linear over `[min_cos, 1]`,
    /// `g(1) = 1`) from every face with its own normal, then solves each face's normal and
    /// albedo under it (Gauss-Newton from the Lambertian solution).
    pub response: usize,
    /// Model the light the rest of the object sends each face (needs the `surroundings` of
    /// [`shading_normals`]).
    pub interreflection: bool,
    /// With `interreflection`: this constant `c` instead of the calibrated one.
    pub interreflection_c: Option<f32>,
    /// Shrink each face's normal towards its own by how far the readings' scatter leaves it
    /// uncertain (empirical Bayes): the weight of a face's correction is `s^2 / (s^2 + v)`,
    /// with `v` the variance of its solved normal's angle (the fit's residual variance
    /// through the normal equations) and `s^2` the spread of the true corrections over the
    /// mesh (the mean squared correction less the mean `v`). Noisy or poorly resolved shading
    /// then leaves the mesh as it was. Lambertian fits only (`response` < 2).
    pub shrink: bool,
}

impl Default for ShadingSettings {
    fn default() -> Self {
        ShadingSettings {
            min_cos: 0.3,
            min_views: 6,
            min_mask: 0.99,
            ridge: 0.05,
            ambient: false,
            response: 0,
            interreflection: false,
            interreflection_c: None,
            shrink: false,
        }
    }
}

/// What [`shading_normals`] solves.
pub struct ShadingFit {
    /// Per face, the normal that the shading explains, weight 1 where solved, else 0.
    pub normals: FaceNormals,
    /// Per face, the mean unit direction to the eyes of the views that see it (zero where none
    /// does).
    pub eyes: Vec<Vec3>,
    /// The fitted response `g` at its knots (`ShadingSettings::response`), empty under
    /// Lambert's cosine.
    pub response: Vec<f32>,
    /// The interreflection constant `c` used (`ShadingSettings::interreflection`; 0 off).
    pub interreflection: f32,
    /// Per solved face, the share of its correction kept by `ShadingSettings::shrink` (1
    /// without it; 0 where not solved).
    pub confidence: Vec<f32>,
}

impl ShadingFit {
    /// The faces whose normal was solved.
    pub fn solved(&self) -> usize {
        self.normals.weight.iter().filter(|w| **w > 0.0).count()
    }

    /// The mean share of the solved faces' corrections kept ([`ShadingFit::confidence`]).
    pub fn mean_confidence(&self) -> f32 {
        self.confidence.iter().sum::<f32>() / self.solved().max(1) as f32
    }
}

/// A piecewise-linear function of the cosine on `knots` evenly spaced points of
/// `[lo, 1]`, extended linearly beyond them and never negative.
struct Response {
    lo: f32,
    g: Vec<f32>,
}

impl Response {
    /// The segment of `c` and its weight on the segment's upper knot.
    fn locate(&self, c: f32) -> (usize, f32) {
        let k = self.g.len() - 1;
        let x = (c - self.lo) / (1.0 - self.lo) * k as f32;
        let i = (x.floor().max(0.0) as usize).min(k - 1);
        (i, x - i as f32)
    }

    /// `g(c)` and `g'(c)`.
    fn eval(&self, c: f32) -> (f32, f32) {
        let (i, t) = self.locate(c);
        let h = (1.0 - self.lo) / (self.g.len() - 1) as f32;
        let v = self.g[i] + t * (self.g[i + 1] - self.g[i]);
        if v <= 0.0 {
            (0.0, 0.0)
        } else {
            (v, (self.g[i + 1] - self.g[i]) / h)
        }
    }
}

/// One view's reading of one face: the direction to the eye and `I r^2`.
#[derive(Clone, Copy)]
struct Sample {
    w: Vec3,
    y: f32,
    /// The interreflected irradiance times `r^2` (0 when not modelled).
    e: f32,
}

/// Fits the response on every face's samples with the faces' own normals (`own`), the
/// albedos and the knots in turn (least squares each), normalised to `g(1) = 1`.
fn fit_response(
    start: &[usize],
    samples: &[Sample],
    own: &[Vec3],
    lo: f32,
    knots: usize,
) -> Response {
    let mut resp = Response {
        lo,
        g: (0..knots)
            .map(|k| lo + (1.0 - lo) * k as f32 / (knots - 1) as f32)
            .collect(),
    };
    let nf = own.len();
    let mut rho = vec![0.0f64; nf];
    for _ in 0..20 {
        for f in 0..nf {
            let (mut num, mut den) = (0.0f64, 0.0f64);
            for s in &samples[start[f]..start[f + 1]] {
                let g = f64::from(resp.eval(own[f].dot(s.w)).0);
                num += g * f64::from(s.y);
                den += g * g;
            }
            rho[f] = if den > 0.0 { num / den } else { 0.0 };
        }
        // Knots: y = rho sum_k B_k(c) g_k; neighbouring hats alone overlap, so the normal
        // equations are tridiagonal.
        let mut diag = vec![0.0f64; knots];
        let mut off = vec![0.0f64; knots - 1];
        let mut atb = vec![0.0f64; knots];
        for f in 0..nf {
            if rho[f] <= 0.0 {
                continue;
            }
            for s in &samples[start[f]..start[f + 1]] {
                let (i, t) = resp.locate(own[f].dot(s.w));
                let (a, b) = (rho[f] * f64::from(1.0 - t), rho[f] * f64::from(t));
                diag[i] += a * a;
                off[i] += a * b;
                diag[i + 1] += b * b;
                atb[i] += a * f64::from(s.y);
                atb[i + 1] += b * f64::from(s.y);
            }
        }
        let trace = diag.iter().sum::<f64>() / knots as f64;
        for d in &mut diag {
            *d += 1e-9 * trace.max(f64::MIN_POSITIVE);
        }
        let Some(g) = solve_tridiagonal(diag, &off, atb) else {
            break;
        };
        let top = g[knots - 1];
        if !(top > 0.0 && top.is_finite()) {
            break;
        }
        resp.g = g.iter().map(|v| (*v / top) as f32).collect();
    }
    resp
}

/// Solves the symmetric positive definite tridiagonal system with diagonal `diag` and
/// off-diagonal `off` (`off[k]` couples `k` and `k + 1`) by elimination (`None` when singular).
fn solve_tridiagonal(mut diag: Vec<f64>, off: &[f64], mut rhs: Vec<f64>) -> Option<Vec<f64>> {
    let n = diag.len();
    for k in 1..n {
        if diag[k - 1].abs() <= f64::MIN_POSITIVE {
            return None;
        }
        let m = off[k - 1] / diag[k - 1];
        diag[k] -= m * off[k - 1];
        rhs[k] -= m * rhs[k - 1];
    }
    let mut x = vec![0.0; n];
    for k in (0..n).rev() {
        let next = if k + 1 < n { off[k] * x[k + 1] } else { 0.0 };
        x[k] = (rhs[k] - next) / diag[k];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// The normal (and albedo) that minimise `sum (y - rho g(n . w))^2` plus a ridge of weight
/// `ridge` (relative to the tangent curvature) towards `n0`, by Gauss-Newton from `n`.
fn fit_normal(samples: &[Sample], resp: &Response, mut n: Vec3, n0: Vec3, ridge: f32) -> Vec3 {
    let mut rho = {
        let (mut num, mut den) = (0.0f32, 0.0f32);
        for s in samples {
            let g = resp.eval(n.dot(s.w)).0;
            num += g * s.y;
            den += g * g;
        }
        if den <= 0.0 {
            return Vec3::ZERO;
        }
        num / den
    };
    for _ in 0..10 {
        let (e1, e2) = n.any_orthonormal_pair();
        let mut m = Mat3::ZERO;
        let mut rhs = Vec3::ZERO;
        for s in samples {
            let (g, dg) = resp.eval(n.dot(s.w));
            let j = Vec3::new(g, rho * dg * e1.dot(s.w), rho * dg * e2.dot(s.w));
            let r = s.y - rho * g;
            m += Mat3::from_cols(j * j.x, j * j.y, j * j.z);
            rhs += r * j;
        }
        let lambda = ridge * 0.5 * (m.y_axis.y + m.z_axis.z);
        m += Mat3::from_diagonal(Vec3::new(0.0, lambda, lambda));
        rhs += lambda * Vec3::new(0.0, e1.dot(n0 - n), e2.dot(n0 - n));
        if m.determinant().abs() <= f32::MIN_POSITIVE {
            return Vec3::ZERO;
        }
        let d = m.inverse() * rhs;
        rho += d.x;
        let next = (n + d.y * e1 + d.z * e2).normalize_or_zero();
        let moved = next.distance(n);
        n = next;
        if moved < 1e-6 || !n.is_finite() {
            break;
        }
    }
    n
}

/// Where `f`, falling on `[0, 1]`, crosses zero: bracketed on steps of 0.05, narrowed by four
/// bisections, interpolated within the bracket. 0 where `f(0) <= 0`; without a crossing, the
/// step of the least `|f|`.
fn falling_zero(f: impl Fn(f32) -> f64) -> f32 {
    let mut lo = (0.0f32, f(0.0));
    if lo.1 <= 0.0 {
        return 0.0;
    }
    let mut best = lo;
    for k in 1..=20 {
        let x = 0.05 * k as f32;
        let y = f(x);
        if y <= 0.0 {
            let mut hi = (x, y);
            for _ in 0..4 {
                let x = 0.5 * (lo.0 + hi.0);
                let y = f(x);
                if y <= 0.0 {
                    hi = (x, y);
                } else {
                    lo = (x, y);
                }
            }
            let t = lo.1 / (lo.1 - hi.1).max(f64::MIN_POSITIVE);
            return lo.0 + (hi.0 - lo.0) * t as f32;
        }
        if y.abs() < best.1.abs() {
            best = (x, y);
        }
        lo = (x, y);
    }
    best.0
}

/// What the rest of the object shows each face: where rays cast over the face's outer
/// hemisphere (cosine-weighted) first hit the mesh again.
pub struct Surroundings {
    /// Rays cast per face.
    pub rays: usize,
    /// Face `f`'s hits are `points[start[f]..start[f + 1]]`.
    pub start: Vec<usize>,
    /// The hit points.
    pub points: Vec<Vec3>,
}

impl Surroundings {
    /// Per face, the fraction of its rays that leave the mesh (1: nothing faces it).
    pub fn openness(&self) -> Vec<f32> {
        self.start
            .windows(2)
            .map(|w| 1.0 - (w[1] - w[0]) as f32 / self.rays as f32)
            .collect()
    }
}

/// Casts `rays` cosine-weighted rays over each face's outer hemisphere from its centroid.
pub fn surroundings(mesh: &TriMesh, rays: usize) -> Result<Surroundings> {
    let caster = crate::MeshRaycaster::new(mesh, "the mesh")?;
    Ok(surroundings_cast(mesh, &caster, rays))
}

/// [`surroundings`] with the mesh's ray caster already built.
fn surroundings_cast(mesh: &TriMesh, caster: &crate::MeshRaycaster, rays: usize) -> Surroundings {
    use rayon::prelude::*;
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    let hits: Vec<Vec<Vec3>> = mesh
        .triangles
        .par_iter()
        .enumerate()
        .map(|(f, t)| {
            let n = face_normal_scaled(mesh, *t).normalize_or_zero();
            if n == Vec3::ZERO {
                return Vec::new();
            }
            let (e1, e2) = n.any_orthonormal_pair();
            let o = face_centroid(mesh, *t) + 1e-4 * n;
            let spin = (f as f32 * 0.618_034).fract() * std::f32::consts::TAU;
            (0..rays)
                .filter_map(|k| {
                    // Uniform on the disc, lifted onto the hemisphere.
                    let r = ((k as f32 + 0.5) / rays as f32).sqrt();
                    let a = k as f32 * golden + spin;
                    let d = (r * a.cos()) * e1 + (r * a.sin()) * e2 + (1.0 - r * r).sqrt() * n;
                    let d = d.normalize();
                    caster.first_hit(o, d).map(|(t, _)| o + t * d)
                })
                .collect()
        })
        .collect();
    let mut start = Vec::with_capacity(hits.len() + 1);
    start.push(0);
    for h in &hits {
        start.push(start.last().copied().unwrap_or(0) + h.len());
    }
    Surroundings {
        rays,
        start,
        points: hits.into_iter().flatten().collect(),
    }
}

/// Per face of `mesh`, the normal that the shading of the views explains best (module
/// documentation), with weight 1 where at least `min_views` views see the face and the solved
/// normal faces outward (towards the face's own normal), else 0; and the mean direction to
/// the eyes that see it. Visibility as in [`crate::refine::observed_normals`].
///
/// With `surroundings` and `ShadingSettings::interreflection`, each reading also gets the
/// light the rest of the object sends the face in that view: the irradiance `E` from the
/// surrounding points the view shows (their radiance read in the image, as if they glowed
/// alike in every direction; points the view does not show are unlit, the light being at the
/// camera), so `I r^2 = b . w + c |b| E r^2`, with one constant `c` for the scene (the
/// inverse of `pi` times the light's power). Unless `ShadingSettings::interreflection_c`
/// gives it, `c` is calibrated on the images and the masks' mesh alone: the value at which, on
/// the faces less than 90 % open, the solved normals lean neither towards nor away from the
/// eyes that see them, relative to the faces' own normals where the two agree within 10
/// degrees, searched in `[0, 1]` (0 where no face is that closed or nothing leans; without a
/// zero, the least lean).
///
/// With `ShadingSettings::shrink`, each solved normal is then shrunk towards the face's own by
/// its uncertainty; `ShadingFit::confidence` gives the share of each correction kept.
pub fn shading_normals(
    mesh: &TriMesh,
    views: &[ShadingView<'_>],
    surroundings: Option<&Surroundings>,
    settings: &ShadingSettings,
) -> Result<ShadingFit> {
    let nf = mesh.triangles.len();
    for v in views {
        let n = v.camera.width as usize * v.camera.height as usize;
        if v.radiance.len() != n || v.mesh_depth.len() != n || v.mask.is_some_and(|m| m.len() != n)
        {
            return Err(EvalError::InvalidArgument(format!(
                "shading view: expected {n} radiances, depths and mask values, got {}, {} and {:?}",
                v.radiance.len(),
                v.mesh_depth.len(),
                v.mask.map(<[f32]>::len)
            )));
        }
    }
    if let Some(s) = surroundings
        && s.start.len() != nf + 1
    {
        return Err(EvalError::InvalidArgument(format!(
            "shading: surroundings of {} faces for a mesh of {nf}",
            s.start.len().saturating_sub(1)
        )));
    }
    let own = own_normals(mesh).normal;
    let centroids: Vec<Vec3> = mesh
        .triangles
        .iter()
        .map(|t| face_centroid(mesh, *t))
        .collect();
    let interreflection = surroundings.filter(|_| settings.interreflection);
    let mut eyes = vec![Vec3::ZERO; nf];
    let mut readings: Vec<(u32, Sample)> = Vec::new();
    for v in views {
        let cam = v.camera;
        let eye = cam.centre();
        let (w, h) = (cam.width as usize, cam.height as usize);
        // The radiance of a surrounding point in this view, 0 where the view does not show it.
        let shown = |q: Vec3| -> f32 {
            let Some((uv, depth)) = cam.project(q) else {
                return 0.0;
            };
            if !(uv.x >= 0.0 && uv.y >= 0.0 && (uv.x as usize) < w && (uv.y as usize) < h) {
                return 0.0;
            }
            let p = uv.y as usize * w + uv.x as usize;
            let z = v.mesh_depth[p];
            if z > 0.0 && (depth - z).abs() <= 2.0 * depth / cam.fx && v.radiance[p].is_finite() {
                v.radiance[p]
            } else {
                0.0
            }
        };
        for (f, p, _) in visible_faces(mesh, cam, v.mesh_depth, settings.min_cos) {
            let d = eye - centroids[f];
            let r2 = d.length_squared();
            let w = d / r2.sqrt();
            eyes[f] += w;
            if v.mask.is_some_and(|m| m[p] < settings.min_mask) {
                continue;
            }
            let i = v.radiance[p];
            if !i.is_finite() {
                continue;
            }
            let e = interreflection.map_or(0.0, |s| {
                let pts = &s.points[s.start[f]..s.start[f + 1]];
                std::f32::consts::PI / s.rays as f32 * pts.iter().map(|q| shown(*q)).sum::<f32>()
            });
            readings.push((
                f as u32,
                Sample {
                    w,
                    y: i * r2,
                    e: e * r2,
                },
            ));
        }
    }
    // Each face's readings, contiguous.
    let mut start = vec![0usize; nf + 1];
    for (f, _) in &readings {
        start[*f as usize + 1] += 1;
    }
    for f in 0..nf {
        start[f + 1] += start[f];
    }
    let mut samples = vec![
        Sample {
            w: Vec3::ZERO,
            y: 0.0,
            e: 0.0,
        };
        readings.len()
    ];
    let mut next = start.clone();
    for (f, s) in readings {
        samples[next[f as usize]] = s;
        next[f as usize] += 1;
    }
    drop(next);
    // The linear fit of one face with the interreflected part `c |b| E r^2` taken off at the
    // `|b|` given, and, with `with_var` and the shrinkage, the variance of the angle of its
    // direction (the residual variance through the inverse normal matrix, on the plane across
    // `b`; else 0).
    let solve = |f: usize, c: f32, b_prev: f32, with_var: bool| -> Option<(Vec3, f32)> {
        let s = &samples[start[f]..start[f + 1]];
        if s.len() < settings.min_views.max(3) {
            return None;
        }
        let n0 = own[f];
        let mut ata = Mat4::ZERO;
        let mut atb = Vec4::ZERO;
        let (mut c2, mut cy) = (0.0f32, 0.0f32);
        for x in s {
            let y = x.y - c * b_prev * x.e;
            let a = x.w.extend(1.0);
            ata += Mat4::from_cols(a * a.x, a * a.y, a * a.z, a * a.w);
            atb += y * a;
            let cw = n0.dot(x.w);
            c2 += cw * cw;
            cy += cw * y;
        }
        if c2 <= 0.0 {
            return None;
        }
        let albedo = cy / c2;
        let lambda = settings.ridge * (ata.x_axis.x + ata.y_axis.y + ata.z_axis.z) / 3.0;
        let params = if settings.ambient { 4 } else { 3 };
        let (b, a, inv) = if settings.ambient {
            // The constant gets a ridge towards 0 as well.
            let m = ata + Mat4::from_diagonal(Vec4::splat(lambda));
            if m.determinant().abs() <= f32::EPSILON * lambda.powi(4).max(f32::MIN_POSITIVE) {
                return None;
            }
            let inv = m.inverse();
            let x = inv * (atb + lambda * albedo * n0.extend(0.0));
            (x.truncate(), x.w, Mat3::from_mat4(inv))
        } else {
            let m = Mat3::from_mat4(ata) + Mat3::from_diagonal(Vec3::splat(lambda));
            if m.determinant().abs() <= f32::EPSILON * lambda.powi(3).max(f32::MIN_POSITIVE) {
                return None;
            }
            let inv = m.inverse();
            (inv * (atb.truncate() + lambda * albedo * n0), 0.0, inv)
        };
        let var = if with_var && settings.shrink && s.len() > params {
            let rss: f32 = (s.iter())
                .map(|x| (x.y - c * b_prev * x.e - x.w.dot(b) - a).powi(2))
                .sum();
            let sigma2 = rss / (s.len() - params) as f32;
            let (e1, e2) = b.normalize_or_zero().any_orthonormal_pair();
            sigma2 * (e1.dot(inv * e1) + e2.dot(inv * e2))
                / b.length_squared().max(f32::MIN_POSITIVE)
        } else {
            0.0
        };
        Some((b, var))
    };
    let lambert: Vec<Option<(Vec3, f32)>> = (0..nf).map(|f| solve(f, 0.0, 0.0, true)).collect();
    // The faces' fits at a given `c` (each face's `|b|` in turn), with the variances of the
    // last round when `with_var`.
    let at = |c: f32, with_var: bool| -> Vec<Option<(Vec3, f32)>> {
        let mut b = lambert.clone();
        for round in 0..4 {
            let var = with_var && round == 3;
            b = (0..nf)
                .map(|f| b[f].and_then(|(bf, _)| solve(f, c, bf.length(), var)))
                .collect();
        }
        b
    };
    let eyes: Vec<Vec3> = eyes.into_iter().map(Vec3::normalize_or_zero).collect();
    let (b, c) = match (interreflection, settings.interreflection_c) {
        (None, _) => (lambert, 0.0),
        (Some(_), Some(c)) => (at(c, true), c),
        (Some(s), None) => {
            // `c` such that, on the faces other parts of the object face (less than 90 %
            // open), the normals lean neither towards nor away from the eyes that see them,
            // measured against the faces' own normals where the two agree within 10 degrees.
            let open = s.openness();
            let lean = |b: &[Option<(Vec3, f32)>]| -> f64 {
                let agree = 10f32.to_radians().cos();
                let (mut sum, mut n) = (0.0f64, 0usize);
                for f in 0..nf {
                    let Some((bf, _)) = b[f] else { continue };
                    let (x, o) = (bf.normalize_or_zero(), own[f]);
                    let m = eyes[f] - eyes[f].dot(o) * o;
                    if open[f] >= 0.9 || x.dot(o) < agree || m.length() < 1e-3 {
                        continue;
                    }
                    sum += f64::from((x - o).dot(m.normalize()));
                    n += 1;
                }
                if n == 0 { 0.0 } else { sum / n as f64 }
            };
            // The lean falls as `c` grows.
            let c = falling_zero(|c| {
                if c == 0.0 {
                    lean(&lambert)
                } else {
                    lean(&at(c, false))
                }
            });
            (at(c, true), c)
        }
    };
    if interreflection.is_some() {
        // The readings less their interreflected part, for the response's fit.
        for f in 0..nf {
            let m = b[f].map_or(0.0, |(bf, _)| bf.length());
            for x in &mut samples[start[f]..start[f + 1]] {
                x.y -= c * m * x.e;
            }
        }
    }
    let resp = (settings.response >= 2)
        .then(|| fit_response(&start, &samples, &own, settings.min_cos, settings.response));
    // The spread of the true corrections: the mean squared correction less its mean variance.
    let shrink = (settings.shrink && resp.is_none()).then(|| {
        let (mut sq, mut var, mut n) = (0.0f64, 0.0f64, 0usize);
        for f in 0..nf {
            let Some((bf, v)) = b[f] else { continue };
            let x = bf.normalize_or_zero();
            if x.dot(own[f]) > 0.0 && v.is_finite() {
                sq += f64::from((x - own[f]).length_squared());
                var += f64::from(v);
                n += 1;
            }
        }
        ((sq - var) / n.max(1) as f64).max(0.0) as f32
    });
    let mut out = FaceNormals {
        normal: vec![Vec3::ZERO; nf],
        weight: vec![0.0; nf],
    };
    let mut confidence = vec![0.0f32; nf];
    for f in 0..nf {
        let Some((bf, v)) = b[f] else { continue };
        let n0 = own[f];
        let mut n = bf.normalize_or_zero();
        let mut k = 1.0;
        if let Some(resp) = &resp {
            let from = if n.dot(n0) > 0.0 { n } else { n0 };
            n = fit_normal(
                &samples[start[f]..start[f + 1]],
                resp,
                from,
                n0,
                settings.ridge,
            );
        } else if let Some(s2) = shrink {
            k = if s2 + v > 0.0 && v.is_finite() {
                s2 / (s2 + v)
            } else {
                0.0
            };
            if n.dot(n0) > 0.0 {
                n = (n0 + k * (n - n0)).normalize_or_zero();
            }
        }
        if n.dot(n0) > 0.0 && n.is_finite() {
            out.normal[f] = n;
            out.weight[f] = 1.0;
            confidence[f] = k;
        }
    }
    Ok(ShadingFit {
        normals: out,
        confidence,
        eyes,
        response: resp.map(|r| r.g).unwrap_or_default(),
        interreflection: c,
    })
}

/// The mesh's own face normals, weight 1.
pub fn own_normals(mesh: &TriMesh) -> FaceNormals {
    let normal: Vec<Vec3> = mesh
        .triangles
        .iter()
        .map(|t| face_normal_scaled(mesh, *t).normalize_or_zero())
        .collect();
    FaceNormals {
        weight: vec![1.0; normal.len()],
        normal,
    }
}

/// One channel of an RGB image (`Some(0..3)`) or the mean of the three (`None`), linear
/// (sRGB-decoded when `srgb`).
pub fn linear_radiance(rgb: &[f32], srgb: bool, channel: Option<usize>) -> Vec<f32> {
    let lin = |x: f32| if srgb { srgb_to_linear(x) } else { x };
    rgb.chunks_exact(3)
        .map(|c| match channel {
            Some(k) => lin(c[k]),
            None => (lin(c[0]) + lin(c[1]) + lin(c[2])) / 3.0,
        })
        .collect()
}

/// A view's image as [`linear_radiance`] reads it (sRGB-decoded when the view is sRGB).
pub fn view_radiance(view: &gtsr_data::View, channel: Option<usize>) -> Vec<f32> {
    linear_radiance(
        &view.rgb,
        view.encoding == gtsr_data::Encoding::Srgb,
        channel,
    )
}

/// One view for [`refine_by_shading`].
#[derive(Clone, Copy, Debug)]
pub struct ShadingImage<'a> {
    /// The camera; the light sits at its centre.
    pub camera: &'a Camera,
    /// Linear radiance per pixel, row-major ([`linear_radiance`]).
    pub radiance: &'a [f32],
    /// Object mask per pixel (`None`: every pixel counts).
    pub mask: Option<&'a [f32]>,
}

/// Steps per [`ShadingRefinement::slack_reference`] in the search for a vertex's slack.
const SLACK_STEPS: usize = 32;
/// The shortest anchor the slack gives a vertex, as a share of the anchor (a vertex the
/// hull holds exactly still has a positive anchor length).
const SLACK_FLOOR: f32 = 1e-3;
/// The power of the slack in the anchor length.
const SLACK_POWER: f32 = 4.0;
/// The largest slack, as a share of the reference, of the vertices of the faces the
/// scattering's model is fitted on ([`scatter_held_faces`]).
pub const SCATTER_HELD_SLACK: f32 = 0.25;

/// Per vertex, the factor on the refinement's anchor weight ([`crate::refine::refine_anchored`])
/// that holds it by its slack (any length unit, the same for `reference`): the anchor length is
/// the anchor times `min(1, slack / reference)^power`, at least a thousandth of it, and the
/// weight goes as one over the length squared.
pub fn slack_anchor_scale(slack: &[f32], reference: f32, power: f32) -> Vec<f32> {
    slack
        .iter()
        .map(|s| {
            let m = (s / reference).min(1.0).powf(power).max(SLACK_FLOOR);
            1.0 / (m * m)
        })
        .collect()
}

/// Per face of `mesh`, the sine of the largest tilt the refinement trusts
/// ([`crate::refine::refine_anchored`]), by how much room the masks leave it: a face whose
/// least vertex slack (any length unit, the same for the positive `reference`) is at most
/// `reference` gets `base` (a sine), one whose slack reaches twice `reference` gets `steep`,
/// and the angle ramps linearly between. Where the hull lies tight on the object a steep
/// target can only be the shading's error; over a concavity the masks cannot see, the
/// object's walls may be steep.
pub fn slack_tilt_limits(
    mesh: &TriMesh,
    slack: &[f32],
    reference: f32,
    base: f32,
    steep: f32,
) -> Vec<f32> {
    let (a0, a1) = (base.clamp(0.0, 1.0).asin(), steep.clamp(0.0, 1.0).asin());
    mesh.triangles
        .iter()
        .map(|t| {
            let s = t
                .iter()
                .map(|i| slack.get(*i as usize).copied().unwrap_or(0.0))
                .fold(f32::INFINITY, f32::min);
            let share = ((s - reference) / reference).clamp(0.0, 1.0);
            (a0 + share * (a1 - a0))
                .sin()
                .clamp(1e-6, MAX_TRUSTED_TILT_SINE)
        })
        .collect()
}

/// Per face of `mesh`, whether the masks' hull holds it: every vertex's slack (any length
/// unit, the same for `reference`) at most [`SCATTER_HELD_SLACK`] of `reference`. There the
/// mesh is right, and [`refine_by_shading`] fits the scattering's model on those faces
/// ([`crate::scatter::unscatter`]). A vertex without a slack counts as held.
pub fn scatter_held_faces(mesh: &TriMesh, slack: &[f32], reference: f32) -> Vec<bool> {
    (mesh.triangles.iter())
        .map(|t| {
            t.iter().all(|v| {
                slack
                    .get(*v as usize)
                    .is_none_or(|s| *s <= SCATTER_HELD_SLACK * reference)
            })
        })
        .collect()
}

/// The largest tilt limit [`slack_tilt_limits`] gives (a sine below 1: a target at a right
/// angle to its face has no slope).
const MAX_TRUSTED_TILT_SINE: f32 = 0.999;

/// The shading normals of `mesh` in `images` ([`shading_normals`]): each image sees the faces
/// that `caster` (built on `mesh`) hits first, and with `settings.interreflection` the light
/// of the surroundings is modelled from `rays` rays a face. Also returns the casts' z-depths,
/// one map per image.
pub(crate) fn observe_shading(
    mesh: &TriMesh,
    caster: &crate::MeshRaycaster,
    images: &[ShadingImage<'_>],
    settings: &ShadingSettings,
    rays: usize,
) -> Result<(ShadingFit, Vec<Vec<f32>>)> {
    let depths: Vec<Vec<f32>> = images
        .iter()
        .map(|v| caster.render(v.camera).depth)
        .collect();
    let views: Vec<ShadingView<'_>> = images
        .iter()
        .zip(&depths)
        .map(|(v, d)| ShadingView {
            camera: v.camera,
            radiance: v.radiance,
            mask: v.mask,
            mesh_depth: d,
        })
        .collect();
    let around = settings
        .interreflection
        .then(|| surroundings_cast(mesh, caster, rays));
    let fit = shading_normals(mesh, &views, around.as_ref(), settings)?;
    Ok((fit, depths))
}

/// Settings of [`refine_by_shading`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShadingRefinement {
    /// How the normals are solved (the interreflection is modelled when
    /// `ShadingSettings::interreflection` is set).
    pub shading: ShadingSettings,
    /// The length over which the displacements return to zero where the shading says nothing
    /// (scene units; [`RefineSettings::anchor`]).
    pub anchor: f32,
    /// The farthest a vertex may move outward (scene units).
    pub max_outward: f32,
    /// Rays cast per face for the surroundings the interreflection reads.
    pub surrounding_rays: usize,
    /// Observe-and-refine rounds: each observes the normals on the last round's mesh (the
    /// first on `mesh`) and refines `mesh` by them, so that the faces of a sunken lid are seen
    /// where they now are (at least 1; fewer run when a round leaves the mesh it observed
    /// where it was).
    pub rounds: usize,
    /// Hold each vertex by its slack on the hull of the images' masks
    /// ([`crate::hull_slack`]): the anchor length is [`ShadingRefinement::anchor`] times
    /// `min(1, slack / reference)^4` (at least a thousandth of it), so that only where the
    /// masks leave room (over a concavity they cannot see) the normals move the mesh far;
    /// scene units (`None`: one anchor for all). Needs the images' masks.
    pub slack_reference: Option<f32>,
    /// With [`ShadingRefinement::slack_reference`]: the sine of the largest tilt of a target
    /// normal trusted on the faces whose slack reaches twice the reference
    /// ([`slack_tilt_limits`], from [`RefineSettings::max_tilt`] at the reference and below).
    pub steep_tilt: f32,
    /// Invert the light scattered under the surface in the images before the shading fit
    /// ([`crate::scatter::unscatter`]), its model fitted on `mesh`'s faces that the masks'
    /// hull holds within a quarter of [`ShadingRefinement::slack_reference`] (on every face
    /// without it).
    pub unscatter: bool,
}

impl Default for ShadingRefinement {
    fn default() -> Self {
        ShadingRefinement {
            shading: ShadingSettings {
                interreflection: true,
                shrink: true,
                ..ShadingSettings::default()
            },
            anchor: 0.01,
            max_outward: 0.0,
            surrounding_rays: 32,
            rounds: 1,
            slack_reference: None,
            steep_tilt: crate::refine::MAX_TILT_SINE,
            unscatter: false,
        }
    }
}

/// What [`refine_by_shading`] returns.
#[derive(Clone, Debug)]
pub struct ShadingRefined {
    /// The refined mesh (same triangles, moved vertices).
    pub mesh: TriMesh,
    /// Per vertex, the displacement along its normal (scene units, negative: inward).
    pub moves: Vec<f32>,
    /// Faces whose normal the shading solved.
    pub solved: usize,
    /// The interreflection constant used (0: not modelled).
    pub interreflection: f32,
    /// The mean share of the solved faces' corrections kept ([`ShadingFit::confidence`]).
    pub confidence: f32,
    /// Per vertex, its slack on the masks' hull (scene units, at most twice the reference) when
    /// [`ShadingRefinement::slack_reference`] is set.
    pub slack: Option<Vec<f32>>,
    /// Per round after the first, how much it changed the vertices' moves: the root mean
    /// square of the difference from the round before (scene units). Shorter than
    /// `rounds - 1` when a round left the mesh it observed unmoved (a fixed point).
    pub round_changes: Vec<f32>,
    /// The scattering model inverted in the images ([`ShadingRefinement::unscatter`]).
    pub scatter: Option<crate::scatter::Scatter>,
}

/// Normal maps that share each face's target normal with the shading's in
/// [`refine_by_shading`] (a trained model's rendered normals, say).
#[derive(Clone, Copy)]
pub struct NormalPrior<'a> {
    /// One camera and its camera-space normal map (3 per pixel, zero where nothing was
    /// rendered) per view.
    pub views: &'a [(&'a Camera, &'a [f32])],
    /// The share in `[0, 1]` of each face's target taken from these maps where they observe
    /// it ([`crate::refine::observed_normals`]); the rest is the shading's.
    pub share: f32,
}

/// Per face, `(1 - share) a + share b` of the two weighted normals, renormalised, with the
/// weights mixed alike; a face only one of them observes keeps that one's at its share.
pub fn blend_face_normals(a: &FaceNormals, b: &FaceNormals, share: f32) -> FaceNormals {
    let mut out = FaceNormals {
        normal: Vec::with_capacity(a.normal.len()),
        weight: Vec::with_capacity(a.normal.len()),
    };
    for f in 0..a.normal.len() {
        let (wa, wb) = ((1.0 - share) * a.weight[f], share * b.weight[f]);
        let m = wa * a.normal[f] + wb * b.normal[f];
        let n = m.normalize_or_zero();
        out.normal.push(n);
        out.weight.push(if n == Vec3::ZERO { 0.0 } else { wa + wb });
    }
    out
}

/// Refines `mesh` (a mesh around the object, such as the masks') by the normals its faces'
/// shading explains in `images` ([`shading_normals`], with the light the rest of the object
/// sends each face when `settings.shading.interreflection` is set): the vertices move along
/// their normals so that the faces' normals follow the shading's ([`crate::refine`]), within
/// `settings.anchor` of where they were, and, with `depth`, each face's mean displacement
/// pulled towards an observed offset ([`crate::refine::refine`]). With `prior`, each face's
/// target is the shading's normal blended with the prior's maps' ([`blend_face_normals`]).
pub fn refine_by_shading(
    mesh: &TriMesh,
    images: &[ShadingImage<'_>],
    depth: Option<&DepthTargets>,
    prior: Option<NormalPrior<'_>>,
    settings: &ShadingRefinement,
) -> Result<ShadingRefined> {
    if let Some(p) = prior
        && !(p.share.is_finite() && (0.0..=1.0).contains(&p.share))
    {
        return Err(EvalError::InvalidArgument(format!(
            "shading refinement: the prior normals' share must lie in [0, 1], got {}",
            p.share
        )));
    }
    let valid = settings.anchor.is_finite()
        && settings.anchor > 0.0
        && settings.max_outward.is_finite()
        && settings.max_outward >= 0.0
        && settings.surrounding_rays > 0
        && settings.rounds > 0
        && settings
            .slack_reference
            .is_none_or(|r| r.is_finite() && r > 0.0)
        && settings.steep_tilt > 0.0
        && settings.steep_tilt < 1.0;
    if !valid {
        return Err(EvalError::InvalidArgument(format!(
            "shading refinement: the anchor and the slack's reference must be positive, the \
             outward bound non-negative, at least one surrounding ray cast and one round run, \
             the steep tilt a sine in (0, 1) (got {}, {:?}, {}, {}, {}, {})",
            settings.anchor,
            settings.slack_reference,
            settings.max_outward,
            settings.surrounding_rays,
            settings.rounds,
            settings.steep_tilt
        )));
    }
    let slack = match settings.slack_reference {
        Some(reference) => {
            let masks: Vec<(Camera, &[f32])> = images
                .iter()
                .filter_map(|v| v.mask.map(|m| (*v.camera, m)))
                .collect();
            if masks.is_empty() {
                return Err(EvalError::InvalidArgument(
                    "shading refinement: holding the vertices by their slack needs the masks"
                        .into(),
                ));
            }
            // Up to twice the reference: the anchor is whole from the reference, the
            // trusted tilt from twice it.
            Some(crate::hull_slack(
                &masks,
                &mesh.positions,
                reference / SLACK_STEPS as f32,
                2.0 * reference,
            )?)
        }
        None => None,
    };
    let unscattered = if settings.unscatter {
        let held: Option<Vec<bool>> = (slack.as_ref().zip(settings.slack_reference))
            .map(|(s, r)| scatter_held_faces(mesh, s, r));
        Some(crate::scatter::unscatter(
            mesh,
            held.as_deref(),
            images,
            settings.shading.min_cos,
        )?)
    } else {
        None
    };
    let owned: Vec<ShadingImage<'_>>;
    let images = match &unscattered {
        Some(u) if u.model.blurs() => {
            owned = (images.iter().zip(&u.radiance))
                .map(|(v, r)| ShadingImage { radiance: r, ..*v })
                .collect();
            &owned[..]
        }
        _ => images,
    };
    let refine_settings = RefineSettings {
        anchor: settings.anchor,
        max_outward: settings.max_outward,
        ..RefineSettings::default()
    };
    let scale: Option<Vec<f32>> = (slack.as_ref().zip(settings.slack_reference))
        .map(|(s, r)| slack_anchor_scale(s, r, SLACK_POWER));
    let tilt: Option<Vec<f32>> = (slack.as_ref().zip(settings.slack_reference))
        .filter(|_| settings.steep_tilt != refine_settings.max_tilt)
        .map(|(s, r)| slack_tilt_limits(mesh, s, r, refine_settings.max_tilt, settings.steep_tilt));
    // A round observes the normals on `on` (the last round's mesh) and refines `mesh` by them.
    let round = |on: &TriMesh| -> Result<(TriMesh, Vec<f32>, ShadingFit)> {
        let caster = crate::MeshRaycaster::new(on, "the mesh to refine")?;
        let (fit, depths) = observe_shading(
            on,
            &caster,
            images,
            &settings.shading,
            settings.surrounding_rays,
        )?;
        let targets = match prior {
            Some(p) => {
                // A prior view at an image's camera reads that image's ray cast.
                let own = |c: &Camera| images.iter().position(|v| v.camera == c);
                let maps: Vec<Option<Vec<f32>>> = (p.views.iter())
                    .map(|(c, _)| own(c).is_none().then(|| caster.render(c).depth))
                    .collect();
                let nv: Vec<NormalView<'_>> = (p.views.iter().zip(&maps))
                    .map(|((camera, normal), cast)| NormalView {
                        camera,
                        normal,
                        mesh_depth: match cast {
                            Some(d) => d,
                            None => &depths[own(camera).expect("an image's camera")],
                        },
                    })
                    .collect();
                let seen = observed_normals(on, &nv, 1, settings.shading.min_cos)?;
                blend_face_normals(&fit.normals, &seen, p.share)
            }
            None => fit.normals.clone(),
        };
        let (refined, moves) = refine_anchored(
            mesh,
            &targets,
            depth,
            &refine_settings,
            scale.as_deref(),
            tilt.as_deref(),
        )?;
        Ok((refined, moves, fit))
    };
    let (mut refined, mut moves, mut fit) = round(mesh)?;
    let mut round_changes = Vec::with_capacity(settings.rounds.saturating_sub(1));
    // The moves of the mesh the last round observed (`mesh` itself: none).
    let mut last = vec![0.0; moves.len()];
    for _ in 1..settings.rounds {
        // A round that leaves the mesh it observed where it was has reached a fixed point:
        // the next would observe the same mesh and return the same.
        if moves == last {
            break;
        }
        last = moves;
        (refined, moves, fit) = round(&refined)?;
        round_changes.push(rms_difference(&moves, &last));
    }
    Ok(ShadingRefined {
        mesh: refined,
        moves,
        solved: fit.solved(),
        interreflection: fit.interreflection,
        confidence: fit.mean_confidence(),
        slack,
        round_changes,
        scatter: unscattered.map(|u| u.model),
    })
}

/// The root mean square of `a - b` (0 when empty).
fn rms_difference(a: &[f32], b: &[f32]) -> f32 {
    let n = a.len().min(b.len()).max(1);
    let sum: f64 = a.iter().zip(b).map(|(x, y)| f64::from(x - y).powi(2)).sum();
    (sum / n as f64).sqrt() as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The views of rendered radiance and depth maps, without masks.
    fn unmasked_views<'a>(
        cams: &'a [Camera],
        rads: &'a [Vec<f32>],
        depths: &'a [Vec<f32>],
    ) -> Vec<ShadingView<'a>> {
        cams.iter()
            .zip(rads)
            .zip(depths)
            .map(|((c, r), d)| ShadingView {
                camera: c,
                radiance: r,
                mask: None,
                mesh_depth: d,
            })
            .collect()
    }

    /// The trusted tilt follows a face's least vertex slack: the base up to the reference, the
    /// steep limit from twice it, the angle linear between.
    #[test]
    fn the_trusted_tilt_ramps_with_the_least_slack_of_a_face() {
        // Four faces over five vertices; the reference slack is 2.
        let mesh = TriMesh {
            positions: vec![Vec3::ZERO; 5],
            triangles: vec![[0, 1, 2], [1, 2, 3], [2, 3, 4], [1, 2, 4]],
        };
        let slack = [0.5, 9.0, 9.0, 3.0, 4.0];
        let (base, steep) = (30f32.to_radians().sin(), 60f32.to_radians().sin());
        let t = slack_tilt_limits(&mesh, &slack, 2.0, base, steep);
        let deg: Vec<f32> = t.iter().map(|s| s.asin().to_degrees()).collect();
        // Slack 0.5 (under the reference): the base; 3 (halfway to twice it): 45 degrees;
        // 4 (twice it) and beyond: the steep limit.
        for (got, want) in deg.iter().zip([30.0, 45.0, 45.0, 60.0]) {
            assert!((got - want).abs() < 1e-3, "{deg:?}");
        }
        // Never a right angle, whatever the steep limit asked.
        let t = slack_tilt_limits(&mesh, &slack, 2.0, base, 1.0);
        assert!(t.iter().all(|s| *s > 0.0 && *s < 1.0));
    }

    /// The calibration's root finder: a crossing inside a step, past the old scan's 0.4, none
    /// (the least value), and none to find (0).
    #[test]
    fn the_zero_of_a_falling_function() {
        for root in [0.0123f32, 0.37, 0.52, 0.999] {
            let got = falling_zero(|c| f64::from(root - c) * (1.0 + f64::from(c)));
            assert!((got - root).abs() < 1e-3, "root {root}: got {got}");
        }
        assert_eq!(falling_zero(|c| f64::from(2.0 - c)), 1.0);
        assert_eq!(falling_zero(|c| f64::from(-0.1 - c)), 0.0);
    }

    /// A flat square facing +z (two faces).
    fn square() -> TriMesh {
        TriMesh {
            positions: vec![
                Vec3::new(-0.1, -0.1, 0.0),
                Vec3::new(0.1, -0.1, 0.0),
                Vec3::new(0.1, 0.1, 0.0),
                Vec3::new(-0.1, 0.1, 0.0),
            ],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
        }
    }

    /// Renders the square as a surface of normal `truth` and albedo 0.7 whose radiance under
    /// the light at the camera is `0.7 g(n . w) / r^2`, solves its normals and returns each
    /// face's angle to `truth` (degrees).
    fn solve(
        cams: &[Camera],
        truth: Vec3,
        g: impl Fn(f32) -> f32,
        settings: &ShadingSettings,
    ) -> Vec<f32> {
        let mesh = square();
        let (w, h) = (64usize, 64usize);
        let mut rads = Vec::new();
        let mut depths = Vec::new();
        for c in cams {
            let eye = c.centre();
            let mut rad = vec![0.0f32; w * h];
            let mut dep = vec![0.0f32; w * h];
            for j in 0..h {
                for i in 0..w {
                    let (o, d) = c.pixel_ray(i as u32, j as u32);
                    let t = -o.z / d.z;
                    let x = o + d * t;
                    if t > 0.0 && x.x.abs() < 0.1 && x.y.abs() < 0.1 {
                        let to = eye - x;
                        let r2 = to.length_squared();
                        rad[j * w + i] = 0.7 * g(truth.dot(to / r2.sqrt()).max(0.0)) / r2;
                        dep[j * w + i] = c.world_to_camera.transform_point3(x).z;
                    }
                }
            }
            rads.push(rad);
            depths.push(dep);
        }
        let views = unmasked_views(cams, &rads, &depths);
        let got = shading_normals(&mesh, &views, None, settings)
            .unwrap()
            .normals;
        (0..2)
            .map(|f| {
                assert_eq!(got.weight[f], 1.0);
                got.normal[f]
                    .dot(truth)
                    .clamp(-1.0, 1.0)
                    .acos()
                    .to_degrees()
            })
            .collect()
    }

    /// A flat square facing +z, seen by cameras around it, shaded by the Lambertian law with
    /// a tilted normal: the solve recovers the tilt.
    #[test]
    fn recovers_a_tilted_lambertian_normal_from_views_with_the_light_at_the_camera() {
        let truth = Vec3::new(0.3, -0.2, 1.0).normalize();
        let cams: Vec<Camera> = (0..12)
            .map(|k| {
                let a = k as f32 * std::f32::consts::TAU / 12.0;
                let eye = Vec3::new(1.5 * a.cos(), 1.5 * a.sin(), 3.0) * (1.0 + 0.05 * k as f32);
                Camera::look_at(eye, Vec3::ZERO, Vec3::Y, 0.3, 64, 64)
            })
            .collect();
        let settings = ShadingSettings {
            ridge: 1e-4,
            ..ShadingSettings::default()
        };
        for (f, angle) in solve(&cams, truth, |c| c, &settings).iter().enumerate() {
            assert!(*angle < 0.5, "face {f}: {angle} degrees off");
        }
    }

    /// A surface whose shading is flatter than Lambert's cosine (wrap lighting), seen only
    /// from one side: Lambert's fit leans towards the eyes, the fitted response does not.
    #[test]
    fn a_fitted_response_removes_the_lean_of_a_flatter_shading() {
        let truth = Vec3::Z;
        let cams: Vec<Camera> = (0..24)
            .map(|k| {
                let dir = direction(5.0 + 3.0 * k as f32, k as f32 * 7.0);
                Camera::look_at(3.0 * dir, Vec3::ZERO, Vec3::Y, 0.3, 64, 64)
            })
            .collect();
        let wrap = |c: f32| (c + 0.5) / 1.5;
        let lambert = ShadingSettings {
            ridge: 1e-4,
            min_views: 6,
            ..ShadingSettings::default()
        };
        let leaning = solve(&cams, truth, wrap, &lambert);
        assert!(
            leaning.iter().all(|a| *a > 2.0),
            "Lambert's fit: {leaning:?}"
        );
        let fitted = solve(
            &cams,
            truth,
            wrap,
            &ShadingSettings {
                response: 4,
                ..lambert
            },
        );
        assert!(
            fitted.iter().all(|a| *a < 0.5),
            "fitted response: {fitted:?}"
        );
    }

    /// A floor beside a lit wall, each lit by the other (one bounce): the wall's light adds
    /// to the floor's shading in the views that light it, and Lambert's fit leans; with the
    /// interreflected light modelled, at the scene's constant (`1 / pi` for Lambertian
    /// renders) or at the one calibrated on the images, the floor's normal is recovered.
    #[test]
    fn modelling_the_light_of_a_facing_wall_removes_its_lean() {
        let k = std::f32::consts::FRAC_1_PI;
        let (leaning, modelled, calibrated, c) = floor_beside_a_wall(k);
        assert!(
            leaning.iter().all(|a| *a > 2.0),
            "Lambert's fit: {leaning:?}"
        );
        assert!(modelled.iter().all(|a| *a < 0.5), "modelled: {modelled:?}");
        assert!(
            calibrated.iter().all(|a| *a < 0.5),
            "calibrated: {calibrated:?}"
        );
        assert!(
            (c / k - 1.0).abs() < 0.2,
            "calibrated c = {c}, the renders' {k}"
        );
    }

    /// The same with a much stronger interreflection (the renders' constant 0.6, as a very
    /// translucent object shows): the calibration looks past small constants and removes the
    /// lean. (The renders' second bounce, which the model reads from the images as well, is
    /// then no longer small, so the constant found lies below the renders'.)
    #[test]
    fn a_strong_interreflection_is_calibrated_too() {
        let (leaning, _, calibrated, c) = floor_beside_a_wall(0.6);
        assert!(
            leaning.iter().all(|a| *a > 4.0),
            "Lambert's fit: {leaning:?}"
        );
        assert!(
            calibrated.iter().all(|a| *a < 0.5),
            "calibrated: {calibrated:?} at c = {c}"
        );
        assert!(c > 0.4, "calibrated c = {c}");
    }

    /// Renders the floor and the wall with the interreflected light scaled by `k` (the
    /// albedo times `k` times the irradiance) and returns the floor faces' angles to their
    /// normal (degrees) under Lambert's fit, the model at `k` and the calibrated model, and
    /// the calibrated constant.
    fn floor_beside_a_wall(k: f32) -> (Vec<f32>, Vec<f32>, Vec<f32>, f32) {
        let mesh = TriMesh {
            positions: vec![
                Vec3::new(-0.1, -0.1, 0.0),
                Vec3::new(0.1, -0.1, 0.0),
                Vec3::new(0.1, 0.1, 0.0),
                Vec3::new(-0.1, 0.1, 0.0),
                Vec3::new(0.1, -0.1, 0.2),
                Vec3::new(0.1, 0.1, 0.2),
            ],
            // The floor (+z) and the wall at x = 0.1 facing -x.
            triangles: vec![[0, 1, 2], [0, 2, 3], [1, 5, 2], [1, 4, 5]],
        };
        let (rho_floor, rho_wall) = (0.6f32, 0.9f32);
        let wall_n = Vec3::NEG_X;
        let cams: Vec<Camera> = (0..24)
            .map(|k| {
                let dir = direction(
                    20.0 + 40.0 * (k % 6) as f32 / 5.0,
                    120.0 + 120.0 * (k / 6) as f32 / 3.0,
                );
                Camera::look_at(3.0 * dir, Vec3::new(0.0, 0.0, 0.05), Vec3::Z, 0.2, 64, 64)
            })
            .collect();
        let caster = crate::MeshRaycaster::new(&mesh, "test scene").unwrap();
        // The wall on a 20 x 20 grid of cells for the floor's irradiance.
        let cells: Vec<Vec3> = (0..400)
            .map(|k| {
                let (a, b) = ((k % 20) as f32 + 0.5, (k / 20) as f32 + 0.5);
                Vec3::new(0.1, -0.1 + 0.01 * a, 0.01 * b)
            })
            .collect();
        let floor: Vec<Vec3> = (0..400)
            .map(|k| {
                let (a, b) = ((k % 20) as f32 + 0.5, (k / 20) as f32 + 0.5);
                Vec3::new(-0.1 + 0.01 * a, -0.1 + 0.01 * b, 0.0)
            })
            .collect();
        let (mut rads, mut depths) = (Vec::new(), Vec::new());
        for c in &cams {
            let eye = c.centre();
            let lit = |y: Vec3, n: Vec3, rho: f32| {
                let to = eye - y;
                let r2 = to.length_squared();
                rho * n.dot(to / r2.sqrt()).max(0.0) / r2
            };
            let mut rad = vec![0.0f32; 64 * 64];
            let mut dep = vec![0.0f32; 64 * 64];
            for j in 0..64u32 {
                for i in 0..64u32 {
                    let (o, d) = c.pixel_ray(i, j);
                    let Some((t, n)) = caster.first_hit(o, d) else {
                        continue;
                    };
                    let x = o + t * d;
                    let p = (j * 64 + i) as usize;
                    dep[p] = c.world_to_camera.transform_point3(x).z;
                    // The irradiance at `x` (normal `nx`) from the lit cells of the other
                    // plane (normal `ny`, albedo `rho`, 1e-4 each).
                    let irradiance = |nx: Vec3, cells: &[Vec3], ny: Vec3, rho: f32| -> f32 {
                        cells
                            .iter()
                            .map(|y| {
                                let to = *y - x;
                                let d2 = to.length_squared();
                                let u = to / d2.sqrt();
                                lit(*y, ny, rho) * nx.dot(u).max(0.0) * (-ny.dot(u)).max(0.0) * 1e-4
                                    / d2
                            })
                            .sum()
                    };
                    rad[p] = if n.z > 0.9 {
                        let e = irradiance(Vec3::Z, &cells, wall_n, rho_wall);
                        lit(x, Vec3::Z, rho_floor) + rho_floor * k * e
                    } else {
                        let e = irradiance(wall_n, &floor, Vec3::Z, rho_floor);
                        lit(x, wall_n, rho_wall) + rho_wall * k * e
                    };
                }
            }
            rads.push(rad);
            depths.push(dep);
        }
        let views = unmasked_views(&cams, &rads, &depths);
        let around = surroundings(&mesh, 256).unwrap();
        let floor_error = |settings: &ShadingSettings| -> (Vec<f32>, f32) {
            let fit = shading_normals(&mesh, &views, Some(&around), settings).unwrap();
            let angles = (0..2)
                .map(|f| {
                    assert_eq!(fit.normals.weight[f], 1.0);
                    fit.normals.normal[f]
                        .dot(Vec3::Z)
                        .clamp(-1.0, 1.0)
                        .acos()
                        .to_degrees()
                })
                .collect();
            (angles, fit.interreflection)
        };
        let lambert = ShadingSettings {
            ridge: 1e-4,
            ..ShadingSettings::default()
        };
        let (leaning, _) = floor_error(&lambert);
        let (modelled, _) = floor_error(&ShadingSettings {
            interreflection: true,
            interreflection_c: Some(k),
            ..lambert
        });
        let (calibrated, c) = floor_error(&ShadingSettings {
            interreflection: true,
            ..lambert
        });
        (leaning, modelled, calibrated, c)
    }

    /// A grid over `[-0.2, 0.2]^2` with `n` cells a side, at height `z(x, y)`.
    fn height_grid(n: usize, z: impl Fn(f32, f32) -> f32) -> TriMesh {
        crate::mesh::height_grid(n, glam::Vec2::splat(-0.2), glam::Vec2::splat(0.2), z)
    }

    /// The unit direction at `polar` from +z and `azimuth` about it (degrees).
    fn direction(polar: f32, azimuth: f32) -> Vec3 {
        let (p, a) = (polar.to_radians(), azimuth.to_radians());
        Vec3::new(p.sin() * a.cos(), p.sin() * a.sin(), p.cos())
    }

    /// The bowl of depth `BOWL.0` and radius `BOWL.1` in a flat floor.
    const BOWL: (f32, f32) = (0.02, 0.12);

    fn bowl(x: f32, y: f32) -> f32 {
        let (depth, radius) = BOWL;
        -depth * (1.0 - (x * x + y * y) / (radius * radius)).max(0.0)
    }

    /// A flat lid over [`bowl`] refined by the bowl's Lambertian shading (the light at each
    /// of 24 cameras, 96 px), each pixel's radiance scaled by `1 + noise u` with `u` uniform
    /// in `[-1, 1)` (seeded).
    fn refine_lid_over_bowl(noise: f32, settings: &ShadingRefinement) -> (TriMesh, ShadingRefined) {
        refine_lid_over_bowl_with_prior(noise, settings, None)
    }

    /// [`refine_lid_over_bowl`], with the lid's own (flat) normals rendered in every view as a
    /// [`NormalPrior`] of this share.
    fn refine_lid_over_bowl_with_prior(
        noise: f32,
        settings: &ShadingRefinement,
        prior_share: Option<f32>,
    ) -> (TriMesh, ShadingRefined) {
        let truth = height_grid(48, bowl);
        let lid = height_grid(24, |_, _| 0.0);
        let cams: Vec<Camera> = (0..24)
            .map(|k| {
                let dir = direction(10.0 + 40.0 * (k % 4) as f32 / 3.0, k as f32 * 15.0 + 7.0);
                Camera::look_at(1.5 * dir, Vec3::ZERO, Vec3::Z, 0.35, 96, 96)
            })
            .collect();
        let caster = crate::MeshRaycaster::new(&truth, "the bowl").unwrap();
        let mut rng = crate::mesh::SplitMix64::new(0);
        let rads: Vec<Vec<f32>> = (cams.iter())
            .map(|c| {
                let eye = c.centre();
                (0..96 * 96u32)
                    .map(|p| {
                        let (o, d) = c.pixel_ray(p % 96, p / 96);
                        let u = 2.0 * rng.next_f64() as f32 - 1.0;
                        caster.first_hit(o, d).map_or(0.0, |(t, n)| {
                            let to = eye - (o + t * d);
                            let r2 = to.length_squared();
                            0.7 * n.dot(to / r2.sqrt()).max(0.0) / r2 * (1.0 + noise * u)
                        })
                    })
                    .collect()
            })
            .collect();
        let images: Vec<ShadingImage<'_>> = cams
            .iter()
            .zip(&rads)
            .map(|(camera, radiance)| ShadingImage {
                camera,
                radiance,
                mask: None,
            })
            .collect();
        let lid_caster = crate::MeshRaycaster::new(&lid, "the lid").unwrap();
        let flat: Vec<Vec<f32>> = (cams.iter())
            .map(|c| {
                let n = c.world_to_camera.transform_vector3(Vec3::Z);
                (0..96 * 96u32)
                    .flat_map(|p| {
                        let (o, d) = c.pixel_ray(p % 96, p / 96);
                        let hit = lid_caster.first_hit(o, d).is_some();
                        if hit { n.to_array() } else { [0.0; 3] }
                    })
                    .collect()
            })
            .collect();
        let maps: Vec<(&Camera, &[f32])> =
            cams.iter().zip(&flat).map(|(c, n)| (c, &n[..])).collect();
        let prior = prior_share.map(|share| NormalPrior {
            views: &maps,
            share,
        });
        let refined = refine_by_shading(&lid, &images, None, prior, settings).unwrap();
        (lid, refined)
    }

    /// The lid's own flat normals as a prior hold it: at share 1 the bowl's shading moves
    /// nothing, at one half the centre sinks part of the way; a share outside [0, 1] is refused.
    #[test]
    fn a_prior_of_flat_normals_holds_the_lid_by_its_share() {
        let settings = ShadingRefinement {
            anchor: 0.5,
            ..ShadingRefinement::default()
        };
        let centre = |r: &ShadingRefined, lid: &TriMesh| {
            let k = (lid.positions.iter().enumerate())
                .min_by(|a, b| a.1.length().total_cmp(&b.1.length()))
                .map(|(k, _)| k)
                .unwrap();
            r.moves[k]
        };
        let (lid, none) = refine_lid_over_bowl_with_prior(0.0, &settings, None);
        let (_, zero) = refine_lid_over_bowl_with_prior(0.0, &settings, Some(0.0));
        let (_, half) = refine_lid_over_bowl_with_prior(0.0, &settings, Some(0.5));
        let (_, all) = refine_lid_over_bowl_with_prior(0.0, &settings, Some(1.0));
        let (d0, dz, dh, d1) = (
            centre(&none, &lid),
            centre(&zero, &lid),
            centre(&half, &lid),
            centre(&all, &lid),
        );
        assert!((d0 - dz).abs() < 1e-6, "share 0: {dz} against {d0}");
        assert!(d0 < -0.5 * BOWL.0, "no prior: {d0}");
        assert!(d1.abs() < 0.05 * BOWL.0, "share 1: {d1}");
        assert!(
            dh < 0.8 * d1 + 0.2 * d0 && dh > 0.9 * d0,
            "share 0.5: {dh} ({d0} .. {d1})"
        );
        let cam = Camera::look_at(1.5 * Vec3::Z, Vec3::ZERO, Vec3::Y, 0.35, 8, 8);
        let (rad, normal) = (vec![0.5f32; 64], vec![0.0f32; 192]);
        let images = [ShadingImage {
            camera: &cam,
            radiance: &rad,
            mask: None,
        }];
        let maps = [(&cam, &normal[..])];
        for share in [-0.1, 1.5, f32::NAN] {
            let prior = Some(NormalPrior {
                views: &maps,
                share,
            });
            let err = refine_by_shading(&square(), &images, None, prior, &settings).unwrap_err();
            assert!(err.to_string().contains("share"), "{err}");
        }
    }

    /// Half and half of two observed normals is their bisector; a face only one set observes
    /// keeps that one's normal at its share of the weight.
    #[test]
    fn blended_face_normals_mix_by_the_share() {
        let a = FaceNormals {
            normal: vec![Vec3::X, Vec3::X, Vec3::ZERO],
            weight: vec![1.0, 1.0, 0.0],
        };
        let b = FaceNormals {
            normal: vec![Vec3::Y, Vec3::ZERO, Vec3::Z],
            weight: vec![1.0, 0.0, 0.8],
        };
        let m = blend_face_normals(&a, &b, 0.5);
        assert!((m.normal[0] - Vec3::new(1.0, 1.0, 0.0).normalize()).length() < 1e-6);
        assert!((m.weight[0] - 1.0).abs() < 1e-6);
        assert_eq!((m.normal[1], m.weight[1]), (Vec3::X, 0.5));
        assert_eq!((m.normal[2], m.weight[2]), (Vec3::Z, 0.4));
        let only_a = blend_face_normals(&a, &b, 0.0);
        assert_eq!(only_a.normal[0], Vec3::X);
        assert_eq!((only_a.normal[2], only_a.weight[2]), (Vec3::ZERO, 0.0));
    }

    /// Holding the vertices by their slack needs a positive reference and the masks; the
    /// steep tilt it allows must be a sine in (0, 1).
    #[test]
    fn the_slack_needs_masks_and_a_positive_reference() {
        let mesh = square();
        let cam = Camera::look_at(1.5 * Vec3::Z, Vec3::ZERO, Vec3::Y, 0.35, 8, 8);
        let rad = vec![0.5f32; 64];
        let images = [ShadingImage {
            camera: &cam,
            radiance: &rad,
            mask: None,
        }];
        let with = |slack_reference| ShadingRefinement {
            slack_reference,
            ..ShadingRefinement::default()
        };
        for r in [0.0, -1.0, f32::NAN, f32::INFINITY] {
            assert!(refine_by_shading(&mesh, &images, None, None, &with(Some(r))).is_err());
        }
        let err = refine_by_shading(&mesh, &images, None, None, &with(Some(0.1))).unwrap_err();
        assert!(err.to_string().contains("masks"), "{err}");
        // The steep limit is the sine of a tilt short of a right angle.
        for steep_tilt in [0.0, 1.0, -0.5, f32::NAN] {
            let settings = ShadingRefinement {
                steep_tilt,
                ..ShadingRefinement::default()
            };
            let err = refine_by_shading(&mesh, &images, None, None, &settings).unwrap_err();
            assert!(err.to_string().contains("steep tilt"), "{err}");
        }
    }

    /// A bowl the silhouettes cannot see, under a lid: the lid refined by the shading of the
    /// bowl (Lambertian, the light at each camera) sinks to the bowl's depth in the middle and
    /// stays where the surface is flat.
    #[test]
    fn the_shading_of_a_hidden_bowl_sinks_the_lid_over_it() {
        let (depth, radius) = BOWL;
        let settings = ShadingRefinement {
            anchor: 0.5,
            ..ShadingRefinement::default()
        };
        let (lid, refined) = refine_lid_over_bowl(0.0, &settings);
        assert!(
            refined.solved > lid.triangles.len() / 2,
            "{}",
            refined.solved
        );
        // Clean images: the shrinkage keeps nearly all of each correction.
        assert!(refined.confidence > 0.99, "{}", refined.confidence);
        for (v, d) in lid.positions.iter().zip(&refined.moves) {
            let want = bowl(v.x, v.y);
            let r = v.truncate().length();
            if r < 0.2 * radius {
                assert!(*d < 0.7 * want, "centre {v}: moved {d}, the bowl at {want}");
            }
            if r > 1.3 * radius && v.x.abs() < 0.18 && v.y.abs() < 0.18 {
                assert!(d.abs() < 0.2 * depth, "flat {v}: moved {d}");
            }
        }
        // Inward only, up to the default's zero outward bound.
        assert!(refined.moves.iter().all(|d| *d <= 0.0));
    }

    /// A round that moves nothing is a fixed point: no view sees the mesh, so no normal is
    /// solved, nothing moves, and the later rounds are not run.
    #[test]
    fn rounds_stop_at_a_fixed_point() {
        let mesh = square();
        // Behind the square's plane, looking away from it.
        let cam = Camera::look_at(-1.5 * Vec3::Z, -3.0 * Vec3::Z, Vec3::Y, 0.35, 8, 8);
        let rad = vec![0.5f32; 64];
        let images = [ShadingImage {
            camera: &cam,
            radiance: &rad,
            mask: None,
        }];
        let settings = ShadingRefinement {
            rounds: 4,
            ..ShadingRefinement::default()
        };
        let refined = refine_by_shading(&mesh, &images, None, None, &settings).unwrap();
        assert_eq!(refined.solved, 0);
        assert!(refined.moves.iter().all(|d| *d == 0.0));
        assert!(
            refined.round_changes.is_empty(),
            "{:?}",
            refined.round_changes
        );
    }

    /// Rounds observe the normals again where the lid has sunk: over the hidden bowl the
    /// centre sinks deeper than after one round, and each later round reports how much it
    /// changed the moves, less each time.
    #[test]
    fn later_rounds_sink_the_lid_deeper_and_report_their_changes() {
        let one = ShadingRefinement {
            anchor: 0.5,
            ..ShadingRefinement::default()
        };
        let three = ShadingRefinement { rounds: 3, ..one };
        let centre = |refined: &ShadingRefined, lid: &TriMesh| -> f32 {
            let (mut sum, mut n) = (0.0f32, 0usize);
            for (v, d) in lid.positions.iter().zip(&refined.moves) {
                if v.truncate().length() < 0.3 * BOWL.1 {
                    sum += d;
                    n += 1;
                }
            }
            sum / n as f32
        };
        let (lid, first) = refine_lid_over_bowl(0.0, &one);
        let (_, last) = refine_lid_over_bowl(0.0, &three);
        assert!(first.round_changes.is_empty());
        assert_eq!(last.round_changes.len(), 2);
        let c = &last.round_changes;
        assert!(c.iter().all(|x| x.is_finite() && *x >= 0.0), "{c:?}");
        assert!(c[1] <= c[0], "{c:?}");
        let (a, b) = (centre(&first, &lid), centre(&last, &lid));
        assert!(b < a - 0.05 * BOWL.0, "one round {a}, three {b}");
    }

    /// The same bowl under noisy images (each pixel off by up to 30 %): shrinking each face's
    /// normal by its uncertainty (`ShadingSettings::shrink`) keeps the flat floor much flatter
    /// than the plain solve does, and the lid still sinks over the bowl, if less deep.
    #[test]
    fn shrinking_noisy_normals_keeps_the_flat_floor_flat() {
        let shrunk = ShadingRefinement {
            anchor: 0.5,
            ..ShadingRefinement::default()
        };
        assert!(shrunk.shading.shrink);
        let plain = ShadingRefinement {
            shading: ShadingSettings {
                shrink: false,
                ..shrunk.shading
            },
            ..shrunk
        };
        let (depth, radius) = BOWL;
        // Per run: the RMS move on the flat floor, the mean move at the bowl's centre and the
        // share of the corrections kept.
        let score = |settings: &ShadingRefinement| -> (f32, f32, f32) {
            let (lid, refined) = refine_lid_over_bowl(0.3, settings);
            let (mut flat, mut nf, mut centre, mut nc) = (0.0f32, 0usize, 0.0f32, 0usize);
            for (v, d) in lid.positions.iter().zip(&refined.moves) {
                let r = v.truncate().length();
                if r > 1.3 * radius && v.x.abs() < 0.18 && v.y.abs() < 0.18 {
                    flat += d * d;
                    nf += 1;
                }
                if r < 0.3 * radius {
                    centre += d;
                    nc += 1;
                }
            }
            (
                (flat / nf as f32).sqrt(),
                centre / nc as f32,
                refined.confidence,
            )
        };
        let (flat_plain, _, kept_plain) = score(&plain);
        let (flat_shrunk, centre, kept) = score(&shrunk);
        assert_eq!(kept_plain, 1.0);
        assert!(kept > 0.1 && kept < 0.9, "share kept {kept}");
        assert!(
            flat_shrunk < 0.5 * flat_plain,
            "RMS move on the floor: shrunk {flat_shrunk}, plain {flat_plain}"
        );
        assert!(centre < -0.25 * depth, "the centre moved {centre}");
    }
}
