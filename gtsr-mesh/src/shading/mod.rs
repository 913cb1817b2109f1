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

use crate::error::{MeshError, Result};
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
    let caster = crate::raycast::MeshRaycaster::new(mesh, "the mesh")?;
    Ok(surroundings_cast(mesh, &caster, rays))
}

/// [`surroundings`] with the mesh's ray caster already built.
fn surroundings_cast(
    mesh: &TriMesh,
    caster: &crate::raycast::MeshRaycaster,
    rays: usize,
) -> Surroundings {
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
            return Err(MeshError::InvalidArgument(format!(
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
        return Err(MeshError::InvalidArgument(format!(
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

mod refinement;
#[cfg(test)]
mod tests;

pub(crate) use refinement::observe_shading;
pub use refinement::{
    NormalPrior, SCATTER_HELD_SLACK, ShadingRefined, ShadingRefinement, blend_face_normals,
    refine_by_shading, scatter_held_faces, slack_anchor_scale, slack_tilt_limits,
};
