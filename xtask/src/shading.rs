//! `shading-stereo`: normals from the images' shading under the light at the camera
//! (photometric stereo whose light moves with each view), and how far they refine the masks'
//! mesh ([`crate::refine`]).
//!
//! With a point light at the camera, a Lambertian surface point `x` of normal `n` and albedo
//! `rho` seen from the eye `e` has the linear radiance `I = rho L (n . w) / r^2`, with
//! `w = (e - x) / r` and `r = |e - x|`. So `I r^2 = b . w` with `b = rho L n`: every view that
//! sees a face gives one linear equation in `b`, and the light directions of the views that see
//! it span a cone wide enough to solve for `b` by least squares. The normal is `b / |b|`; the
//! albedo drops out. A face whose centroid lies off the true surface (a lid of the masks' mesh
//! over a dent) reads, in each view, the shading of the surface point its pixel shows; those
//! points differ a little from view to view (the parallax of the lid's height), so the normal
//! it gets is the truth's blurred over that parallax. After a refinement the faces lie closer
//! to the surface, and the normals are observed again on the refined mesh (`--rounds`).
//!
//! Two things break the model. Light scattered under the surface leaves it away from where it
//! entered, which blurs the shading and flattens its fall-off with the angle
//! (`ShadingSettings::response` learns that fall-off for the scene). And where other parts of
//! the object face a face, they light it too, in the views that light them: that light does
//! not follow `n . w`, and Lambert's fit leans towards the eyes that add it
//! (`ShadingSettings::interreflection` models it from the images, one bounce). The images are
//! the only input; the ground truth only scores the result and, with it, each round prints how
//! far the shading normals lie from the truth's and how they lean towards the eyes that see
//! each face, overall and by how open each face is to the rest of the object.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Args;
use glam::{Mat3, Mat4, Vec3, Vec4};
use gtsr_data::Camera;
use gtsr_data::image_io::srgb_to_linear;
use gtsr_data::ply::TriMesh;
use gtsr_eval::mesh::{face_centroid, face_normal_scaled};
use gtsr_eval::tsdf::median_pixel_footprint;

use crate::refine::{FaceNormals, NormalView, RefineSettings, observed_normals, visible_faces};

/// Options of `shading-stereo`.
#[derive(Args, Debug)]
pub struct ShadingStereoArgs {
    /// The scene (Blender/NeRF with masks; with `mesh.ply` the rows are scored against it).
    #[arg(long)]
    pub data: PathBuf,
    /// The refinement's anchor lengths (scene units): one row each.
    #[arg(long, num_args = 1.., default_values_t = vec![0.02])]
    pub anchors: Vec<f32>,
    /// Observe-and-refine rounds per anchor (the normals of round `k` are observed on the mesh
    /// of round `k - 1`).
    #[arg(long, default_value_t = 3)]
    pub rounds: usize,
    /// The smallest cosine between a face's normal and its direction to a camera for that view
    /// to count.
    #[arg(long, default_value_t = 0.3)]
    pub min_cos: f32,
    /// The fewest views that must see a face for its normal to be solved.
    #[arg(long, default_value_t = 6)]
    pub min_views: usize,
    /// The farthest a vertex may move inward, in scene units.
    #[arg(long, default_value_t = 0.2)]
    pub max_depth: f32,
    /// The farthest a vertex may move outward, in training pixel footprints.
    #[arg(long, default_value_t = 0.25)]
    pub max_outward: f32,
    /// Conjugate-gradient iterations per solve of the refinement.
    #[arg(long, default_value_t = 400)]
    pub cg_iterations: usize,
    /// Trust a face's shading normal only where it departs from the face's own normal by
    /// more than this many degrees; elsewhere the face keeps its own (0: everywhere).
    #[arg(long, default_value_t = 0.0)]
    pub depart_deg: f32,
    /// Fit a constant beside the Lambertian term (`ShadingSettings::ambient`).
    #[arg(long)]
    pub ambient: bool,
    /// With `--depart-deg`: the anchor is this many times stronger at the vertices farther
    /// than `--free-radius` from every face whose shading normal departs (1: uniform).
    #[arg(long, default_value_t = 1.0)]
    pub pin: f32,
    /// With `--pin`: the distance (scene units) around the departing faces within which the
    /// anchor keeps its weight.
    #[arg(long, default_value_t = 0.1)]
    pub free_radius: f32,
    /// Remove a scene-wide tilt of the shading normals towards the eyes, proportional to how
    /// lopsided the eyes that see each face are, fitted on the faces where the shading normals
    /// and the mesh's own agree within 10 degrees (the images and the masks alone, no ground
    /// truth).
    #[arg(long)]
    pub debias: bool,
    /// The image channel whose shading is read.
    #[arg(long, value_enum, default_value_t = Channel::Mean)]
    pub channel: Channel,
    /// Fit the scene's response to the angle on this many knots instead of Lambert's cosine
    /// (`ShadingSettings::response`; 0: Lambert).
    #[arg(long, default_value_t = 0)]
    pub response: usize,
    /// Keep only the shading normals' detail shorter than this length (scene units): their
    /// variation over longer lengths is replaced by the masks' mesh's own, as in Nehab et
    /// al. 2005's combination of positions and normals (0: off).
    #[arg(long, default_value_t = 0.0)]
    pub low_pass: f32,
    /// Remove the shading normals' bias as a function of their direction (degrees of the
    /// kernel over directions): per direction, the rotation that takes the mean shading normal
    /// of the faces pointing that way to their mean own normal (0: off).
    #[arg(long, default_value_t = 0.0)]
    pub orient_debias: f32,
    /// Model the light the rest of the object sends each face
    /// (`ShadingSettings::interreflection`).
    #[arg(long)]
    pub interreflection: bool,
    /// With `--interreflection`: hold its constant `c` at this value instead of calibrating it.
    #[arg(long)]
    pub interreflection_c: Option<f32>,
    /// Keep the shading normal only on faces at least this open to the outside (the fraction
    /// of their hemisphere no other part of the object faces); the others keep their own
    /// (0: everywhere).
    #[arg(long, default_value_t = 0.0)]
    pub min_openness: f32,
    /// Refine with the truth's normals instead (the ceiling of the refinement; needs
    /// `mesh.ply`).
    #[arg(long)]
    pub truth_normals: bool,
    /// Write the last refined mesh of the first anchor here.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Which of an image's channels [`shading_normals`] reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Channel {
    /// The mean of the three.
    Mean,
    /// Red.
    R,
    /// Green.
    G,
    /// Blue.
    B,
}

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
    use rayon::prelude::*;
    let caster = gtsr_eval::MeshRaycaster::new(mesh, "the mesh")?;
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
    Ok(Surroundings {
        rays,
        start,
        points: hits.into_iter().flatten().collect(),
    })
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
/// degrees (0 where no face is that closed).
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
            bail!(
                "shading view: expected {n} radiances, depths and mask values, got {}, {} and {:?}",
                v.radiance.len(),
                v.mesh_depth.len(),
                v.mask.map(<[f32]>::len)
            );
        }
    }
    if let Some(s) = surroundings
        && s.start.len() != nf + 1
    {
        bail!(
            "shading: surroundings of {} faces for a mesh of {nf}",
            s.start.len().saturating_sub(1)
        );
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
    // `|b|` given.
    let solve = |f: usize, c: f32, b_prev: f32| -> Option<Vec3> {
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
        if settings.ambient {
            // The constant gets a ridge towards 0 as well.
            let m = ata + Mat4::from_diagonal(Vec4::splat(lambda));
            if m.determinant().abs() <= f32::EPSILON * lambda.powi(4).max(f32::MIN_POSITIVE) {
                return None;
            }
            Some((m.inverse() * (atb + lambda * albedo * n0.extend(0.0))).truncate())
        } else {
            let m = Mat3::from_mat4(ata) + Mat3::from_diagonal(Vec3::splat(lambda));
            if m.determinant().abs() <= f32::EPSILON * lambda.powi(3).max(f32::MIN_POSITIVE) {
                return None;
            }
            Some(m.inverse() * (atb.truncate() + lambda * albedo * n0))
        }
    };
    let lambert: Vec<Option<Vec3>> = (0..nf).map(|f| solve(f, 0.0, 0.0)).collect();
    // The faces' fits at a given `c` (each face's `|b|` in turn).
    let at = |c: f32| -> Vec<Option<Vec3>> {
        let mut b = lambert.clone();
        for _ in 0..4 {
            b = (0..nf)
                .map(|f| b[f].and_then(|bf| solve(f, c, bf.length())))
                .collect();
        }
        b
    };
    let eyes: Vec<Vec3> = eyes.into_iter().map(Vec3::normalize_or_zero).collect();
    let (b, c) = match (interreflection, settings.interreflection_c) {
        (None, _) => (lambert, 0.0),
        (Some(_), Some(c)) => (at(c), c),
        (Some(s), None) => {
            // `c` such that, on the faces other parts of the object face (less than 90 %
            // open), the normals lean neither towards nor away from the eyes that see them,
            // measured against the faces' own normals where the two agree within 10 degrees.
            let open = s.openness();
            let lean = |b: &[Option<Vec3>]| -> f64 {
                let agree = 10f32.to_radians().cos();
                let (mut sum, mut n) = (0.0f64, 0usize);
                for f in 0..nf {
                    let Some(bf) = b[f] else { continue };
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
            let mut prev = (0.0f32, lean(&lambert));
            let mut chosen = None;
            for k in 1..=40 {
                let c = 0.01 * k as f32;
                let l = lean(&at(c));
                if l <= 0.0 {
                    let t = prev.1 / (prev.1 - l).max(f64::MIN_POSITIVE);
                    chosen = Some(prev.0 + (c - prev.0) * t as f32);
                    break;
                }
                prev = (c, l);
            }
            let c = chosen.unwrap_or(0.0);
            (at(c), c)
        }
    };
    if interreflection.is_some() {
        // The readings less their interreflected part, for the response's fit.
        for f in 0..nf {
            let m = b[f].map_or(0.0, Vec3::length);
            for x in &mut samples[start[f]..start[f + 1]] {
                x.y -= c * m * x.e;
            }
        }
    }
    let resp = (settings.response >= 2)
        .then(|| fit_response(&start, &samples, &own, settings.min_cos, settings.response));
    let mut out = FaceNormals {
        normal: vec![Vec3::ZERO; nf],
        weight: vec![0.0; nf],
    };
    for f in 0..nf {
        let Some(bf) = b[f] else { continue };
        let n0 = own[f];
        let mut n = bf.normalize_or_zero();
        if let Some(resp) = &resp {
            let from = if n.dot(n0) > 0.0 { n } else { n0 };
            n = fit_normal(
                &samples[start[f]..start[f + 1]],
                resp,
                from,
                n0,
                settings.ridge,
            );
        }
        if n.dot(n0) > 0.0 && n.is_finite() {
            out.normal[f] = n;
            out.weight[f] = 1.0;
        }
    }
    Ok(ShadingFit {
        normals: out,
        eyes,
        response: resp.map(|r| r.g).unwrap_or_default(),
        interreflection: c,
    })
}

/// Per vertex of `mesh`: 1 within `radius` (along the edges) of a face marked in `free`,
/// `pin` elsewhere.
fn pin_scale(mesh: &TriMesh, free: &[bool], radius: f32, pin: f32) -> Vec<f32> {
    let nv = mesh.positions.len();
    let mut adj: Vec<Vec<u32>> = vec![Vec::new(); nv];
    for t in &mesh.triangles {
        for k in 0..3 {
            adj[t[k] as usize].push(t[(k + 1) % 3]);
            adj[t[(k + 1) % 3] as usize].push(t[k]);
        }
    }
    // Dijkstra from the free faces' vertices, up to `radius` (non-negative distances order
    // as their bit patterns).
    let mut dist = vec![f32::INFINITY; nv];
    let mut heap = std::collections::BinaryHeap::new();
    for (f, t) in mesh.triangles.iter().enumerate() {
        if free[f] {
            for &i in t {
                if dist[i as usize] > 0.0 {
                    dist[i as usize] = 0.0;
                    heap.push((std::cmp::Reverse(0u32), i));
                }
            }
        }
    }
    while let Some((std::cmp::Reverse(dbits), i)) = heap.pop() {
        let d = f32::from_bits(dbits);
        if d > dist[i as usize] {
            continue;
        }
        for &j in &adj[i as usize] {
            let nd = d + (mesh.positions[i as usize] - mesh.positions[j as usize]).length();
            if nd < dist[j as usize] && nd <= radius {
                dist[j as usize] = nd;
                heap.push((std::cmp::Reverse(nd.to_bits()), j));
            }
        }
    }
    dist.iter()
        .map(|d| if d.is_finite() { 1.0 } else { pin })
        .collect()
}

/// Fits a scene-wide tilt of `shading` from `own` proportional to the lopsidedness of the
/// eyes that see each face: `s_t = k m_t`, with `m_t` the part of `eyes` (per face, the mean
/// unit direction to the eyes that see it) tangent to the face, by least squares over the
/// faces where the two normals agree within 10 degrees; then removes `k m_t` from every solved
/// shading normal. Returns `k`.
fn debias(shading: &mut FaceNormals, own: &FaceNormals, eyes: &[Vec3]) -> f32 {
    let agree = 10f32.to_radians().cos();
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (f, e) in eyes.iter().enumerate() {
        let (s, n) = (shading.normal[f], own.normal[f]);
        if shading.weight[f] <= 0.0 || s.dot(n) < agree {
            continue;
        }
        let m = *e - e.dot(n) * n;
        num += f64::from(s.dot(m));
        den += f64::from(m.length_squared());
    }
    if den <= 0.0 {
        return 0.0;
    }
    let k = (num / den) as f32;
    for (f, e) in eyes.iter().enumerate() {
        if shading.weight[f] > 0.0 {
            let s = shading.normal[f];
            let m = *e - e.dot(s) * s;
            shading.normal[f] = (s - k * m).normalize_or_zero();
        }
    }
    k
}

/// Per face, the faces that share an edge with it.
fn face_neighbours(mesh: &TriMesh) -> Vec<Vec<u32>> {
    let mut edges: std::collections::HashMap<(u32, u32), Vec<u32>> =
        std::collections::HashMap::with_capacity(mesh.triangles.len() * 3 / 2);
    for (f, t) in mesh.triangles.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            edges
                .entry((a.min(b), a.max(b)))
                .or_default()
                .push(f as u32);
        }
    }
    let mut out = vec![Vec::new(); mesh.triangles.len()];
    for faces in edges.values() {
        for &f in faces {
            out[f as usize].extend(faces.iter().filter(|g| **g != f));
        }
    }
    out
}

/// The explicit diffusion steps of [`diffuse`] that average a face's value over about `sigma`
/// (scene units) around it: the mean squared distance between neighbouring centroids sets
/// the variance each step adds (step size 1/2), `2 sigma^2` over the surface's two dimensions.
fn diffusion_steps(mesh: &TriMesh, neighbours: &[Vec<u32>], sigma: f32) -> usize {
    let centroids: Vec<Vec3> = mesh
        .triangles
        .iter()
        .map(|t| face_centroid(mesh, *t))
        .collect();
    let (mut d2, mut n) = (0.0f64, 0usize);
    for (f, nb) in neighbours.iter().enumerate() {
        for &g in nb {
            d2 += f64::from(centroids[f].distance_squared(centroids[g as usize]));
            n += 1;
        }
    }
    let d2 = (d2 / n.max(1) as f64).max(f64::MIN_POSITIVE);
    (2.0 * f64::from(sigma).powi(2) / (0.5 * d2)).ceil() as usize
}

/// Smooths per-face vectors over the mesh by `steps` of explicit diffusion along shared
/// edges, and renormalises.
fn diffuse(neighbours: &[Vec<u32>], x: &[Vec3], steps: usize) -> Vec<Vec3> {
    let mut cur = x.to_vec();
    let mut next = cur.clone();
    for _ in 0..steps {
        for (f, nb) in neighbours.iter().enumerate() {
            if nb.is_empty() {
                next[f] = cur[f];
                continue;
            }
            let mean = nb.iter().map(|g| cur[*g as usize]).sum::<Vec3>() / nb.len() as f32;
            next[f] = 0.5 * (cur[f] + mean);
        }
        std::mem::swap(&mut cur, &mut next);
    }
    cur.into_iter().map(Vec3::normalize_or_zero).collect()
}

/// Replaces the variation of `shading` over lengths above `sigma` with that of `own`: each
/// solved normal is rotated by the rotation that takes the smoothed shading normals to the
/// smoothed own normals at its face (faces without a shading normal take their own in both
/// fields).
fn low_pass(mesh: &TriMesh, shading: &mut FaceNormals, own: &FaceNormals, sigma: f32) {
    let neighbours = face_neighbours(mesh);
    let s: Vec<Vec3> = (0..own.normal.len())
        .map(|f| {
            if shading.weight[f] > 0.0 {
                shading.normal[f]
            } else {
                own.normal[f]
            }
        })
        .collect();
    let steps = diffusion_steps(mesh, &neighbours, sigma);
    let s_bar = diffuse(&neighbours, &s, steps);
    let o_bar = diffuse(&neighbours, &own.normal, steps);
    for f in 0..s.len() {
        if shading.weight[f] > 0.0 && s_bar[f] != Vec3::ZERO && o_bar[f] != Vec3::ZERO {
            let q = glam::Quat::from_rotation_arc(s_bar[f], o_bar[f]);
            shading.normal[f] = (q * shading.normal[f]).normalize_or_zero();
        }
    }
}

/// Removes the part of `shading`'s departure from `own` that depends on the normal's direction
/// alone: directions are binned on a latitude-longitude grid, each bin's sums of shading and
/// own normals smoothed over directions by a Gaussian kernel of `tau_deg`, and every solved
/// normal rotated by its bin's rotation from the smoothed shading mean to the smoothed own one.
fn orient_debias(shading: &mut FaceNormals, own: &FaceNormals, tau_deg: f32) {
    const LAT: usize = 45;
    const LON: usize = 90;
    let bin = |n: Vec3| {
        let lat = ((n.z.clamp(-1.0, 1.0).acos() / std::f32::consts::PI) * LAT as f32) as usize;
        let lon = ((n.y.atan2(n.x) / std::f32::consts::TAU + 0.5) * LON as f32) as usize;
        lat.min(LAT - 1) * LON + lon.min(LON - 1)
    };
    let centre = |b: usize| {
        let (lat, lon) = (b / LON, b % LON);
        let t = (lat as f32 + 0.5) / LAT as f32 * std::f32::consts::PI;
        let p = ((lon as f32 + 0.5) / LON as f32 - 0.5) * std::f32::consts::TAU;
        Vec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos())
    };
    let mut s_sum = vec![Vec3::ZERO; LAT * LON];
    let mut o_sum = vec![Vec3::ZERO; LAT * LON];
    for f in 0..own.normal.len() {
        if shading.weight[f] > 0.0 {
            let b = bin(shading.normal[f]);
            s_sum[b] += shading.normal[f];
            o_sum[b] += own.normal[f];
        }
    }
    let centres: Vec<Vec3> = (0..LAT * LON).map(centre).collect();
    let tau = tau_deg.to_radians();
    let rot: Vec<glam::Quat> = centres
        .iter()
        .map(|c| {
            let (mut s, mut o) = (Vec3::ZERO, Vec3::ZERO);
            for (b, d) in centres.iter().enumerate() {
                let a = c.dot(*d).clamp(-1.0, 1.0).acos();
                if a < 3.0 * tau {
                    let k = (-0.5 * (a / tau).powi(2)).exp();
                    s += k * s_sum[b];
                    o += k * o_sum[b];
                }
            }
            let (s, o) = (s.normalize_or_zero(), o.normalize_or_zero());
            if s == Vec3::ZERO || o == Vec3::ZERO {
                glam::Quat::IDENTITY
            } else {
                glam::Quat::from_rotation_arc(s, o)
            }
        })
        .collect();
    for f in 0..own.normal.len() {
        if shading.weight[f] > 0.0 {
            let q = rot[bin(shading.normal[f])];
            shading.normal[f] = (q * shading.normal[f]).normalize_or_zero();
        }
    }
}

/// The mesh's own face normals, weight 1.
fn own_normals(mesh: &TriMesh) -> FaceNormals {
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
fn radiance(rgb: &[f32], srgb: bool, channel: Option<usize>) -> Vec<f32> {
    let lin = |x: f32| if srgb { srgb_to_linear(x) } else { x };
    rgb.chunks_exact(3)
        .map(|c| match channel {
            Some(k) => lin(c[k]),
            None => (lin(c[0]) + lin(c[1]) + lin(c[2])) / 3.0,
        })
        .collect()
}

/// Per face where both have a normal, the angle between two sets of face normals (degrees,
/// median / mean; NaN where none).
fn face_error(x: &FaceNormals, truth: &FaceNormals) -> (f32, f64) {
    crate::concavity::median_mean(&mut crate::refine::face_angles(x, truth))
}

/// Runs `shading-stereo`.
pub fn run(args: &ShadingStereoArgs) -> Result<()> {
    if args.rounds == 0 || args.anchors.iter().any(|a| !(a.is_finite() && *a > 0.0)) {
        bail!("--rounds must be at least 1 and every --anchors value positive");
    }
    let valid = (0.0..1.0).contains(&args.min_cos)
        && (0.0..180.0).contains(&args.depart_deg)
        && args.pin.is_finite()
        && args.pin > 0.0
        && args.free_radius.is_finite()
        && args.free_radius >= 0.0
        && args.max_depth.is_finite()
        && args.max_depth > 0.0
        && args.max_outward.is_finite()
        && args.max_outward >= 0.0
        && args.low_pass.is_finite()
        && args.low_pass >= 0.0
        && args.response != 1
        && args.orient_debias.is_finite()
        && args.orient_debias >= 0.0
        && (0.0..=1.0).contains(&args.min_openness)
        && args
            .interreflection_c
            .is_none_or(|c| c.is_finite() && c >= 0.0);
    if !valid {
        bail!(
            "--min-cos must be in [0, 1), --depart-deg in [0, 180), --pin and --max-depth \
             positive, --max-outward, --free-radius, --low-pass and --orient-debias non-negative, --response 0 or at least 2, --min-openness in [0, 1], --interreflection-c non-negative"
        );
    }
    let channel = match args.channel {
        Channel::Mean => None,
        Channel::R => Some(0),
        Channel::G => Some(1),
        Channel::B => Some(2),
    };
    let t0 = std::time::Instant::now();
    let (scene, hull) = crate::bench_recon::native_masks_mesh(&args.data)?;
    let gt = crate::bench_recon::ground_truth(&scene, &args.data).ok();
    let cameras: Vec<Camera> = scene.train.iter().map(|v| v.camera).collect();
    let footprint = median_pixel_footprint(cameras.iter(), Vec3::ZERO);
    let radiances: Vec<Vec<f32>> = scene
        .train
        .iter()
        .map(|v| radiance(&v.rgb, v.encoding == gtsr_data::Encoding::Srgb, channel))
        .collect();
    // Pixels of the object with a channel at the top of its range: their shading is clipped.
    let (mut object, mut clipped) = (0usize, 0usize);
    for v in &scene.train {
        for (p, c) in v.rgb.chunks_exact(3).enumerate() {
            if v.mask.as_ref().is_none_or(|m| m[p] >= 0.99) {
                object += 1;
                clipped += usize::from(c.iter().any(|x| *x >= 254.5 / 255.0));
            }
        }
    }
    println!(
        "{}: {} training views at {}x{}, masks' mesh {} faces, footprint {footprint:.4}, \
         clipped object pixels {:.3} % ({:.1} s)",
        args.data.display(),
        cameras.len(),
        cameras[0].width,
        cameras[0].height,
        hull.triangles.len(),
        100.0 * clipped as f64 / object.max(1) as f64,
        t0.elapsed().as_secs_f64()
    );
    let settings = ShadingSettings {
        min_cos: args.min_cos,
        min_views: args.min_views,
        ambient: args.ambient,
        response: args.response,
        interreflection: args.interreflection,
        interreflection_c: args.interreflection_c,
        ..ShadingSettings::default()
    };
    // The masks' mesh's surroundings: for the openness (the diagnostics, `--min-openness`) and
    // the first round's interreflection.
    let hull_around = if gt.is_some() || args.min_openness > 0.0 || args.interreflection {
        Some(surroundings(&hull, 32)?)
    } else {
        None
    };
    let open = hull_around
        .as_ref()
        .map_or_else(|| vec![1.0; hull.triangles.len()], Surroundings::openness);
    let score = |mesh: &TriMesh| -> Result<String> {
        let Some(gt) = &gt else {
            return Ok("- | - | - | -".into());
        };
        crate::refine::score_cells(mesh, gt, &cameras, &hull)
    };
    // The truth's normal maps (camera space, 3 per pixel) of the training views: they do not
    // depend on the mesh being refined.
    let truth_maps: Option<Vec<Vec<f32>>> = match &gt {
        Some(gt) => {
            let gt_caster = gtsr_eval::MeshRaycaster::new(gt, "ground-truth mesh")?;
            Some(
                cameras
                    .iter()
                    .map(|c| {
                        gt_caster
                            .render(c)
                            .normal
                            .iter()
                            .flat_map(|n| n.to_array())
                            .collect()
                    })
                    .collect(),
            )
        }
        None => None,
    };
    // The shading fit and (with the truth) the truth's normals, observed on `mesh`'s faces.
    let observe = |mesh: &TriMesh, round: usize| -> Result<(ShadingFit, Option<FaceNormals>)> {
        let caster = gtsr_eval::MeshRaycaster::new(mesh, "the refined mesh")?;
        let depths: Vec<Vec<f32>> = cameras.iter().map(|c| caster.render(c).depth).collect();
        let views: Vec<ShadingView<'_>> = scene
            .train
            .iter()
            .zip(&radiances)
            .zip(&depths)
            .map(|((v, r), d)| ShadingView {
                camera: &v.camera,
                radiance: r,
                mask: v.mask.as_deref(),
                mesh_depth: d,
            })
            .collect();
        let cast;
        let around = match (args.interreflection, round) {
            (false, _) => None,
            (true, 1) => hull_around.as_ref(),
            (true, _) => {
                cast = surroundings(mesh, 32)?;
                Some(&cast)
            }
        };
        let fit = shading_normals(mesh, &views, around, &settings)?;
        let truth = match &truth_maps {
            Some(normals) => {
                let nv: Vec<NormalView<'_>> = cameras
                    .iter()
                    .zip(normals)
                    .zip(&depths)
                    .map(|((c, n), d)| NormalView {
                        camera: c,
                        normal: n,
                        mesh_depth: d,
                    })
                    .collect();
                Some(observed_normals(mesh, &nv, 1, settings.min_cos)?)
            }
            None => None,
        };
        Ok((fit, truth))
    };
    println!(
        "\n| anchor | round | chamfer | accuracy | completeness | hull-blind | solved faces | \
         shading normals vs truth (deg) | moves mean / most |\n|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
    );
    println!("| - | masks alone | {} | - | - | - |", score(&hull)?);
    for (k, &anchor) in args.anchors.iter().enumerate() {
        let refine_settings = RefineSettings {
            anchor,
            max_depth: args.max_depth,
            max_outward: args.max_outward * footprint,
            iterations: args.cg_iterations,
            ..RefineSettings::default()
        };
        let mut mesh = hull.clone();
        for round in 1..=args.rounds {
            let t = std::time::Instant::now();
            let (
                ShadingFit {
                    normals: mut shading,
                    eyes,
                    response,
                    interreflection,
                },
                truth,
            ) = observe(&mesh, round)?;
            let own = own_normals(&mesh);
            if args.interreflection {
                println!("interreflection: c = {interreflection:.4}");
            }
            if !response.is_empty() {
                let r: Vec<String> = response.iter().map(|g| format!("{g:.3}")).collect();
                println!("response g at cos {}..1: {}", args.min_cos, r.join(" "));
            }
            if args.debias {
                let beta = debias(&mut shading, &own, &eyes);
                println!("debias: removed a tilt of {beta:+.3} times the lopsidedness of the eyes");
            }
            if args.min_openness > 0.0 {
                for (f, o) in open.iter().enumerate() {
                    if *o < args.min_openness && shading.weight[f] > 0.0 {
                        shading.normal[f] = own.normal[f];
                    }
                }
            }
            if args.orient_debias > 0.0 {
                orient_debias(&mut shading, &own, args.orient_debias);
            }
            if args.low_pass > 0.0 {
                low_pass(&mesh, &mut shading, &own, args.low_pass);
            }
            let solved = shading.weight.iter().filter(|w| **w > 0.0).count();
            let (em, ea) = truth
                .as_ref()
                .map_or((f32::NAN, f64::NAN), |t| face_error(&shading, t));
            if let Some(t) = &truth {
                // Where the mesh's own normals are more than 10 degrees off the truth's.
                let off: Vec<bool> = (0..own.normal.len())
                    .map(|f| {
                        t.weight[f] > 0.0
                            && own.normal[f].dot(t.normal[f]) < 10f32.to_radians().cos()
                    })
                    .collect();
                let only = |x: &FaceNormals| {
                    let mut y = x.clone();
                    for (f, o) in off.iter().enumerate() {
                        if !o {
                            y.weight[f] = 0.0;
                        }
                    }
                    y
                };
                let (om, oa) = face_error(&own, t);
                let (sm, sa) = face_error(&only(&shading), t);
                let (xm, xa) = face_error(&only(&own), t);
                println!(
                    "own normals vs truth {om:.1} / {oa:.1}; on the {} faces whose own normal is > 10 deg off: own {xm:.1} / {xa:.1}, shading {sm:.1} / {sa:.1}",
                    off.iter().filter(|o| **o).count()
                );
                // Elsewhere (the flush surface): the shading normal's tilt from the truth's,
                // split into its part towards the mean direction of the eyes that see the face
                // and the part across it.
                // Per face kept by `keep`, the tilt towards and (|.|) across, degrees.
                let tilts = |keep: &dyn Fn(usize) -> bool| -> (Vec<f32>, Vec<f32>) {
                    let (mut along, mut across) = (Vec::new(), Vec::new());
                    for f in 0..own.normal.len() {
                        let tn = t.normal[f];
                        let m = eyes[f] - eyes[f].dot(tn) * tn;
                        if off[f]
                            || t.weight[f] <= 0.0
                            || shading.weight[f] <= 0.0
                            || m.length() < 1e-3
                            || !keep(f)
                        {
                            continue;
                        }
                        let m = m.normalize();
                        let e = shading.normal[f] - shading.normal[f].dot(tn) * tn;
                        along.push(e.dot(m).clamp(-1.0, 1.0).asin().to_degrees());
                        across.push(e.dot(tn.cross(m)).abs().clamp(0.0, 1.0).asin().to_degrees());
                    }
                    (along, across)
                };
                let (along, across) = tilts(&|_| true);
                let mean =
                    |v: &[f32]| v.iter().map(|x| *x as f64).sum::<f64>() / v.len().max(1) as f64;
                println!(
                    "flush surface ({} faces): shading tilt towards the eyes' mean direction {:+.2} deg (mean), across it {:.2} deg (mean |.|)",
                    along.len(),
                    mean(&along),
                    mean(&across)
                );
                // The same tilt by how open the face is to the rest of the object.
                let bins = [0.0, 0.5, 0.75, 0.9, 0.97, 1.01];
                let row: Vec<String> = bins
                    .windows(2)
                    .map(|b| {
                        let (al, ac) = tilts(&|f| (b[0]..b[1]).contains(&open[f]));
                        format!(
                            "[{:.2}, {:.2}): {} faces {:+.2} / {:.2}",
                            b[0],
                            b[1].min(1.0),
                            al.len(),
                            mean(&al),
                            mean(&ac)
                        )
                    })
                    .collect();
                println!(
                    "by openness (faces, tilt towards / across): {}",
                    row.join("; ")
                );
            }
            let mut departs = vec![false; shading.normal.len()];
            let departing = if args.depart_deg > 0.0 {
                let cos = args.depart_deg.to_radians().cos();
                let mut x = shading.clone();
                for (f, dep) in departs.iter_mut().enumerate() {
                    if x.weight[f] > 0.0 && x.normal[f].dot(own.normal[f]) >= cos {
                        x.normal[f] = own.normal[f];
                    } else if x.weight[f] > 0.0 {
                        *dep = true;
                    }
                }
                x
            } else {
                shading.clone()
            };
            let scale = (args.pin != 1.0 && args.depart_deg > 0.0)
                .then(|| pin_scale(&hull, &departs, args.free_radius, args.pin));
            let filtered_truth = match (&truth, args.truth_normals && args.low_pass > 0.0) {
                (Some(t), true) => {
                    let mut t = t.clone();
                    low_pass(&mesh, &mut t, &own, args.low_pass);
                    Some(t)
                }
                _ => None,
            };
            let targets = match (
                filtered_truth.as_ref().or(truth.as_ref()),
                args.truth_normals,
            ) {
                (Some(t), true) => t,
                (None, true) => bail!("--truth-normals needs the scene's mesh.ply"),
                _ => &departing,
            };
            let (refined, d) = crate::refine::refine_anchored(
                &hull,
                targets,
                None,
                &refine_settings,
                scale.as_deref(),
            )?;
            let mean = d.iter().map(|v| *v as f64).sum::<f64>() / d.len().max(1) as f64;
            let most = d.iter().fold(0.0f32, |a, v| a.min(*v));
            mesh = refined;
            println!(
                "| {anchor} | {round} | {} | {solved} of {} | {em:.1} / {ea:.1} | {mean:.4} / {most:.4} | ({:.0} s)",
                score(&mesh)?,
                shading.weight.len(),
                t.elapsed().as_secs_f64()
            );
        }
        if let (0, Some(out)) = (k, &args.out) {
            gtsr_data::ply::write_ply(out, &mesh)
                .with_context(|| format!("writing {}", out.display()))?;
        }
    }
    Ok(())
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
                let polar = (5.0 + 3.0 * k as f32).to_radians();
                let azimuth = (k as f32 * 7.0).to_radians();
                let dir = Vec3::new(
                    polar.sin() * azimuth.cos(),
                    polar.sin() * azimuth.sin(),
                    polar.cos(),
                );
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

    /// A flat grid whose shading normals are all tilted by 5 degrees, and one face's by 20
    /// more: the low-pass removes the tilt and keeps most of the face's own departure.
    #[test]
    fn the_low_pass_removes_a_long_range_tilt_and_keeps_the_detail() {
        let n = 20usize;
        let mut mesh = TriMesh {
            positions: Vec::new(),
            triangles: Vec::new(),
        };
        for j in 0..=n {
            for i in 0..=n {
                mesh.positions
                    .push(Vec3::new(i as f32 * 0.01, j as f32 * 0.01, 0.0));
            }
        }
        let at = |i: usize, j: usize| (j * (n + 1) + i) as u32;
        for j in 0..n {
            for i in 0..n {
                mesh.triangles
                    .push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
                mesh.triangles
                    .push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
            }
        }
        let own = own_normals(&mesh);
        let tilt = glam::Quat::from_rotation_x(5f32.to_radians());
        let mut shading = FaceNormals {
            normal: vec![tilt * Vec3::Z; own.normal.len()],
            weight: vec![1.0; own.normal.len()],
        };
        let detail = 2 * (10 * n + 10);
        shading.normal[detail] = glam::Quat::from_rotation_y(20f32.to_radians()) * tilt * Vec3::Z;
        low_pass(&mesh, &mut shading, &own, 0.03);
        let angle = |v: Vec3| v.dot(Vec3::Z).clamp(-1.0, 1.0).acos().to_degrees();
        for (f, v) in shading.normal.iter().enumerate() {
            if f != detail {
                assert!(angle(*v) < 0.5, "face {f}: {} degrees", angle(*v));
            }
        }
        assert!(angle(shading.normal[detail]) > 15.0);
    }

    /// Shading normals tilted by an amount that depends on their direction alone lose the
    /// tilt through `orient_debias`.
    #[test]
    fn orient_debias_removes_a_direction_dependent_tilt() {
        let mut own = FaceNormals {
            normal: Vec::new(),
            weight: Vec::new(),
        };
        let mut rng = 12345u64;
        let mut next = || {
            rng = rng
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (rng >> 40) as f32 / (1u64 << 24) as f32
        };
        for _ in 0..200_000 {
            let z = 2.0 * next() - 1.0;
            let p = std::f32::consts::TAU * next();
            let r = (1.0 - z * z).max(0.0).sqrt();
            own.normal.push(Vec3::new(r * p.cos(), r * p.sin(), z));
            own.weight.push(1.0);
        }
        // A tilt of 3 degrees towards +z, fading to nothing at the poles.
        let tilt = |n: Vec3| {
            let t = (Vec3::Z - n.z * n).normalize_or_zero();
            (n + 3f32.to_radians().tan() * t).normalize()
        };
        let mut shading = FaceNormals {
            normal: own.normal.iter().map(|n| tilt(*n)).collect(),
            weight: own.weight.clone(),
        };
        let err = |x: &FaceNormals| {
            x.normal
                .iter()
                .zip(&own.normal)
                .map(|(a, b)| f64::from(a.dot(*b).clamp(-1.0, 1.0).acos().to_degrees()))
                .sum::<f64>()
                / own.normal.len() as f64
        };
        assert!(err(&shading) > 2.5);
        orient_debias(&mut shading, &own, 5.0);
        assert!(err(&shading) < 0.5, "{}", err(&shading));
    }

    /// A floor beside a lit wall, each lit by the other (one bounce): the wall's light adds
    /// to the floor's shading in the views that light it, and Lambert's fit leans; with the
    /// interreflected light modelled, at the scene's constant (`1 / pi` for these renders) or
    /// at the one calibrated on the images, the floor's normal is recovered.
    #[test]
    fn modelling_the_light_of_a_facing_wall_removes_its_lean() {
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
                let polar = (20.0 + 40.0 * (k % 6) as f32 / 5.0).to_radians();
                let azimuth = (120.0 + 120.0 * (k / 6) as f32 / 3.0).to_radians();
                let dir = Vec3::new(
                    polar.sin() * azimuth.cos(),
                    polar.sin() * azimuth.sin(),
                    polar.cos(),
                );
                Camera::look_at(3.0 * dir, Vec3::new(0.0, 0.0, 0.05), Vec3::Z, 0.2, 64, 64)
            })
            .collect();
        let caster = gtsr_eval::MeshRaycaster::new(&mesh, "test scene").unwrap();
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
                    let pi = std::f32::consts::PI;
                    rad[p] = if n.z > 0.9 {
                        let e = irradiance(Vec3::Z, &cells, wall_n, rho_wall);
                        lit(x, Vec3::Z, rho_floor) + rho_floor / pi * e
                    } else {
                        let e = irradiance(wall_n, &floor, Vec3::Z, rho_floor);
                        lit(x, wall_n, rho_wall) + rho_wall / pi * e
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
            interreflection_c: Some(std::f32::consts::FRAC_1_PI),
            ..lambert
        });
        let (calibrated, c) = floor_error(&ShadingSettings {
            interreflection: true,
            ..lambert
        });
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
            (c * std::f32::consts::PI - 1.0).abs() < 0.2,
            "calibrated c = {c}, the renders' 1 / pi = {}",
            std::f32::consts::FRAC_1_PI
        );
    }
}
