//! The light scattered under a translucent surface, as the images show it, and its inversion
//! before the shading fit ([`crate::shading`]).
//!
//! Light that enters a translucent object leaves it around where it entered. Seen in an image
//! under a light at the camera, the shading of the surface is blurred: a dent's darkened walls
//! read as a soft, shallow patch, and Lambert's fit of each face's normal ([`crate::shading`])
//! finds almost no tilt there. The model here is the simplest that has that effect:
//!
//! `I = a (P * L) + b (G_s * P * L)`
//!
//! with `L` the Lambertian radiance `(n . w) / r^2` of the object (0 off it), `P` a Gaussian of
//! a pixel or so (the images' own pixel filter, and the ray cast's sampling of `L`), `G_s` a
//! Gaussian of `s` pixels and `(a, b, s)` one triple for the scene. [`fit_scatter`] fits it on
//! a mesh that is right where it is trusted (the masks' hull where it lies tight), and
//! [`deconvolve`] inverts the scattering per image, not the pixel filter: it solves
//! `(a + b G_s) x = I` over the object's pixels by conjugate gradients. The operator is
//! symmetric and at least `a`, so the noise grows by at most `(a + b) / a`. [`unscatter`] puts
//! the two together: it fits `P`'s width with `b = 0` first, so that a pixel's worth of blur
//! is not mistaken for scattering (and inverted, amplifying the noise for nothing).
//!
//! ```
//! use gtsr_mesh::scatter::{Scatter, deconvolve, gaussian_blur};
//!
//! // A bright square, blurred by scattering as `0.5 L + 0.5 G_3 * L`.
//! let (w, h) = (32, 32);
//! let sharp: Vec<f32> = (0..w * h)
//!     .map(|p| if (8..24).contains(&(p % w)) && (8..24).contains(&(p / w)) { 1.0 } else { 0.2 })
//!     .collect();
//! let blurred = gaussian_blur(&sharp, w, h, 3.0);
//! let image: Vec<f32> = sharp.iter().zip(&blurred).map(|(s, b)| 0.5 * s + 0.5 * b).collect();
//! let model = Scatter { sharp: 0.5, blurred: 0.5, sigma: 3.0, pixel: 0.0, residual: 0.0 };
//! let restored = deconvolve(&image, None, w, h, &model, 200).unwrap();
//! assert!((restored[16 * w + 16] - 1.0).abs() < 1e-3);
//! assert!((restored[16 * w + 9] - 1.0).abs() < 1e-3);
//! ```

use glam::Vec3;
use gtsr_data::Camera;
use gtsr_data::ply::TriMesh;
use rayon::prelude::*;

use crate::error::{MeshError, Result};
use crate::shading::ShadingImage;

/// The widths (pixels) of the pixel filter `P` [`unscatter`] tries, with `b = 0`.
pub const PIXEL_SIGMAS: [f32; 5] = [0.0, 0.5, 1.0, 1.5, 2.0];

/// The scattering's blur widths (pixels) [`unscatter`] tries, those wider than `P`'s.
pub const SCATTER_SIGMAS: [f32; 8] = [2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0];

/// The most [`unscatter`]'s model may amplify the images' noise ([`Scatter::amplification`]):
/// the fit keeps `b <= (A - 1) a`.
pub const SCATTER_MAX_AMPLIFICATION: f32 = 2.0;

/// Conjugate-gradient iterations of [`unscatter`]'s inversion.
pub const SCATTER_ITERATIONS: usize = 60;

/// The scene's scattering model `I = a L + b (G_s * L)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scatter {
    /// `a`: the light leaving where it entered.
    pub sharp: f32,
    /// `b`: the light leaving blurred.
    pub blurred: f32,
    /// `s`: the blur's width (pixels; 0 with `b` = 0: no blur).
    pub sigma: f32,
    /// The width of the pixel filter `P` the model was fitted with (pixels; not inverted).
    pub pixel: f32,
    /// The fit's residual, relative to the readings' sum of squares.
    pub residual: f64,
}

impl Scatter {
    /// Whether the model blurs at all.
    pub fn blurs(&self) -> bool {
        self.sigma > 0.0 && self.blurred > 0.0
    }

    /// How much [`deconvolve`] can amplify noise: `(a + b) / a`.
    pub fn amplification(&self) -> f32 {
        (self.sharp + self.blurred) / self.sharp
    }

    /// The image the model predicts from a mesh's Lambertian radiance `lambert`
    /// ([`lambert_image`], `width x height`): `a (P * L) + b (G_s * L)`. Read beside the image,
    /// it shows what the mesh's shape cannot explain: a concavity the mesh lids over is darker
    /// in the image than in the prediction from the lid.
    pub fn predict(&self, lambert: &[f32], width: usize, height: usize) -> Vec<f32> {
        let sharp = gaussian_blur(lambert, width, height, self.pixel);
        if !self.blurs() {
            return sharp.iter().map(|x| self.sharp * x).collect();
        }
        let wide = gaussian_blur(lambert, width, height, self.sigma.hypot(self.pixel));
        sharp
            .iter()
            .zip(&wide)
            .map(|(a, b)| self.sharp * a + self.blurred * b)
            .collect()
    }
}

/// Lambert's radiance `(n . w) / r^2` of `mesh` under a unit light at the camera, per pixel
/// centre (0 where the ray misses the mesh), and the cosine `n . w`.
pub fn lambert_image(
    caster: &crate::raycast::MeshRaycaster<'_>,
    camera: &Camera,
) -> (Vec<f32>, Vec<f32>) {
    lambert_of_depth(&caster.render(camera), camera)
}

/// [`lambert_image`] from a render `camera` already made (its depth and normals).
pub fn lambert_of_depth(r: &crate::raycast::MeshDepth, camera: &Camera) -> (Vec<f32>, Vec<f32>) {
    let w = camera.width as usize;
    (0..r.depth.len())
        .map(|p| {
            let z = r.depth[p];
            if z <= 0.0 {
                return (0.0, 0.0);
            }
            let q: Vec3 = z * camera.camera_direction((p % w) as f32 + 0.5, (p / w) as f32 + 0.5);
            let r2 = q.length_squared();
            let c = r.normal[p].dot(-q / r2.sqrt()).max(0.0);
            (c / r2, c)
        })
        .unzip()
}

/// A separable Gaussian blur of `sigma` pixels (truncated at three widths; a copy when `sigma`
/// is 0), zero beyond the
/// image: a pixel near the border gathers less, as a surface point near the object's edge
/// gathers less scattered light.
pub fn gaussian_blur(img: &[f32], w: usize, h: usize, sigma: f32) -> Vec<f32> {
    if sigma <= 0.0 || img.is_empty() {
        return img.to_vec();
    }
    let rad = (3.0 * sigma).ceil() as usize;
    let k: Vec<f32> = (0..=2 * rad)
        .map(|i| (-0.5 * ((i as f32 - rad as f32) / sigma).powi(2)).exp())
        .collect();
    let sum: f32 = k.iter().sum();
    let k: Vec<f32> = k.iter().map(|x| x / sum).collect();
    // Along each row.
    let mut rows = vec![0.0f32; img.len()];
    for (src, out) in img.chunks_exact(w).zip(rows.chunks_exact_mut(w)) {
        for (i, o) in out.iter_mut().enumerate() {
            let (lo, hi) = (i.saturating_sub(rad), (i + rad).min(w - 1));
            let mut acc = 0.0;
            for j in lo..=hi {
                acc += k[j + rad - i] * src[j];
            }
            *o = acc;
        }
    }
    // Along each column, a whole row of sums at a time (contiguous reads).
    let mut out = vec![0.0f32; img.len()];
    for (i, o) in out.chunks_exact_mut(w).enumerate() {
        let (lo, hi) = (i.saturating_sub(rad), (i + rad).min(h - 1));
        for j in lo..=hi {
            let kj = k[j + rad - i];
            for (x, r) in o.iter_mut().zip(&rows[j * w..(j + 1) * w]) {
                *x += kj * r;
            }
        }
    }
    out
}

/// One view for [`fit_scatter`].
#[derive(Clone, Copy)]
pub struct ScatterView<'a> {
    /// The image's size.
    pub width: usize,
    /// The image's height.
    pub height: usize,
    /// Linear radiance per pixel.
    pub radiance: &'a [f32],
    /// Object mask per pixel (`None`: every pixel counts).
    pub mask: Option<&'a [f32]>,
    /// A mesh's Lambertian radiance and cosine per pixel ([`lambert_image`]).
    pub lambert: &'a [f32],
    /// The cosine `n . w` per pixel.
    pub cosine: &'a [f32],
    /// Pixels left out of the fit (`None`: none).
    pub skip: Option<&'a [bool]>,
}

/// Fits `a` and `b` (least squares, both non-negative, `(a + b) / a` at most
/// `max_amplification`) at each blur width of `sigmas` (0: `b = 0`, Lambert's law alone) with
/// the pixel filter of width `pixel`, on the pixels of `views` whose mask is at least 0.99,
/// whose cosine is at least `min_cos` and that are not skipped; one model per width, in order.
/// Errors on views whose maps differ in size, on a negative or non-finite width, or on a
/// largest amplification below 1.
pub fn fit_scatter(
    views: &[ScatterView<'_>],
    pixel: f32,
    sigmas: &[f32],
    min_cos: f32,
    max_amplification: f32,
) -> Result<Vec<Scatter>> {
    if max_amplification.is_nan() || max_amplification < 1.0 {
        return Err(MeshError::InvalidArgument(format!(
            "scatter fit: the largest amplification must be at least 1, got {max_amplification}"
        )));
    }
    for v in views {
        let n = v.width * v.height;
        if v.radiance.len() != n
            || v.lambert.len() != n
            || v.cosine.len() != n
            || v.mask.is_some_and(|m| m.len() != n)
            || v.skip.is_some_and(|s| s.len() != n)
        {
            return Err(MeshError::InvalidArgument(format!(
                "scatter fit: a {}x{} view needs {n} values in every map",
                v.width, v.height
            )));
        }
    }
    if let Some(s) = (sigmas.iter().chain([&pixel])).find(|s| !(s.is_finite() && **s >= 0.0)) {
        return Err(MeshError::InvalidArgument(format!(
            "scatter fit: blur widths must be finite and non-negative, got {s}"
        )));
    }
    // Per view, `P * L`: the same for every width.
    let bases: Vec<Vec<f32>> = views
        .iter()
        .map(|v| gaussian_blur(v.lambert, v.width, v.height, pixel))
        .collect();
    Ok(sigmas
        .par_iter()
        .map(|&s| {
            // Sums of L L, L B, B B, L I, B I, I I.
            let mut m = [0f64; 6];
            for (v, base) in views.iter().zip(&bases) {
                // `G_s * P` is the Gaussian of the widths' root sum of squares.
                let bl = if s > 0.0 {
                    gaussian_blur(v.lambert, v.width, v.height, s.hypot(pixel))
                } else {
                    vec![0.0; base.len()]
                };
                for p in 0..v.radiance.len() {
                    let i = v.radiance[p];
                    if v.cosine[p] < min_cos
                        || v.lambert[p] <= 0.0
                        || v.mask.is_some_and(|k| k[p] < 0.99)
                        || v.skip.is_some_and(|k| k[p])
                        || !i.is_finite()
                    {
                        continue;
                    }
                    let (l, b, i) = (f64::from(base[p]), f64::from(bl[p]), f64::from(i));
                    m[0] += l * l;
                    m[1] += l * b;
                    m[2] += b * b;
                    m[3] += l * i;
                    m[4] += b * i;
                    m[5] += i * i;
                }
            }
            let [ll, lb, bb, li, bi, ii] = m;
            let lambert_only = || (li / ll.max(f64::MIN_POSITIVE), 0.0);
            let det = ll * bb - lb * lb;
            let (mut a, mut b) = if s > 0.0 && det > 1e-9 * ll * bb {
                ((li * bb - bi * lb) / det, (bi * ll - li * lb) / det)
            } else {
                lambert_only()
            };
            if b < 0.0 {
                (a, b) = lambert_only();
            }
            // Past the largest amplification (or `a < 0`), the best on its bound `b = k a`.
            let k = f64::from(max_amplification) - 1.0;
            if b > k * a {
                a = (li + k * bi) / (ll + 2.0 * k * lb + k * k * bb).max(f64::MIN_POSITIVE);
                b = k * a;
            }
            let res = ii - 2.0 * (a * li + b * bi) + a * a * ll + 2.0 * a * b * lb + b * b * bb;
            Scatter {
                sharp: a as f32,
                blurred: if s > 0.0 { b as f32 } else { 0.0 },
                sigma: s,
                pixel,
                residual: res / ii.max(f64::MIN_POSITIVE),
            }
        })
        .collect())
}

/// Solves `(a + b G_s) x = I` over the pixels whose mask is at least 0.5 (`x` = 0 elsewhere)
/// by at most `iterations` conjugate-gradient steps and returns `(a + b) x`: the radiance with
/// the scattered light put back where it entered, on the scale of `radiance` (a wide uniform
/// region keeps its value), negative values clipped to 0. Non-finite radiances count as 0.
/// Errors when the maps differ in size or the model's `a` is not positive.
pub fn deconvolve(
    radiance: &[f32],
    mask: Option<&[f32]>,
    w: usize,
    h: usize,
    model: &Scatter,
    iterations: usize,
) -> Result<Vec<f32>> {
    if radiance.len() != w * h || mask.is_some_and(|m| m.len() != w * h) {
        return Err(MeshError::InvalidArgument(format!(
            "deconvolve: a {w}x{h} image needs {} radiances and mask values",
            w * h
        )));
    }
    if !(model.sharp.is_finite() && model.sharp > 0.0 && model.blurred.is_finite()) {
        return Err(MeshError::InvalidArgument(format!(
            "deconvolve: the model's sharp part must be positive and its blurred part finite, \
             got {} and {}",
            model.sharp, model.blurred
        )));
    }
    let inside: Vec<bool> = (0..w * h)
        .map(|p| mask.is_none_or(|k| k[p] >= 0.5))
        .collect();
    let total = model.sharp + model.blurred;
    let rhs: Vec<f32> = (radiance.iter().zip(&inside))
        .map(|(v, i)| if *i && v.is_finite() { *v } else { 0.0 })
        .collect();
    if !model.blurs() {
        return Ok(rhs.into_iter().map(|v| v.max(0.0)).collect());
    }
    let apply = |x: &[f32]| -> Vec<f32> {
        let mut y = gaussian_blur(x, w, h, model.sigma);
        for ((yv, xv), i) in y.iter_mut().zip(x).zip(&inside) {
            *yv = if *i {
                model.sharp * xv + model.blurred * *yv
            } else {
                0.0
            };
        }
        y
    };
    let dot = |u: &[f32], v: &[f32]| u.iter().zip(v).map(|(a, b)| f64::from(a * b)).sum::<f64>();
    let mut x: Vec<f32> = rhs.iter().map(|v| v / total).collect();
    let ax = apply(&x);
    let mut r: Vec<f32> = rhs.iter().zip(&ax).map(|(b, a)| b - a).collect();
    let mut p = r.clone();
    let mut rr = dot(&r, &r);
    let stop = 1e-12 * dot(&rhs, &rhs);
    for _ in 0..iterations {
        if rr <= stop {
            break;
        }
        let ap = apply(&p);
        let alpha = (rr / dot(&p, &ap).max(f64::MIN_POSITIVE)) as f32;
        for ((xi, ri), (pi, api)) in x.iter_mut().zip(r.iter_mut()).zip(p.iter().zip(&ap)) {
            *xi += alpha * pi;
            *ri -= alpha * api;
        }
        let rr_new = dot(&r, &r);
        let beta = (rr_new / rr) as f32;
        for (pi, ri) in p.iter_mut().zip(&r) {
            *pi = ri + beta * *pi;
        }
        rr = rr_new;
    }
    Ok(x.iter().map(|v| (total * v).max(0.0)).collect())
}

/// What [`unscatter`] returns.
#[derive(Clone, Debug)]
pub struct Unscattered {
    /// The model kept: the least residual over [`SCATTER_SIGMAS`] wider than the pixel
    /// filter, and Lambert's law alone.
    pub model: Scatter,
    /// Lambert's law alone with each pixel filter of [`PIXEL_SIGMAS`], then the scattering's
    /// fits with the best of them.
    pub fits: Vec<Scatter>,
    /// Per image, the radiance with the scattering inverted ([`deconvolve`]; the images' own
    /// when the model does not blur).
    pub radiance: Vec<Vec<f32>>,
}

/// Fits the scattering model on `mesh` (the masks' hull, say) over the pixels of the faces
/// marked in `held` (where that mesh is known to be right; `None`, or none of them seen: every
/// face) and inverts it in every image. The pixels that show a face not held are left out of
/// the fit; the fit reads the pixels whose cosine is at least `min_cos`. Errors when no image
/// shows the mesh.
pub fn unscatter(
    mesh: &TriMesh,
    held: Option<&[bool]>,
    images: &[ShadingImage<'_>],
    min_cos: f32,
) -> Result<Unscattered> {
    let (model, fits) = fit_scatter_on_mesh(mesh, held, images, min_cos)?;
    let radiance = if model.blurs() {
        images
            .par_iter()
            .map(|v| {
                deconvolve(
                    v.radiance,
                    v.mask,
                    v.camera.width as usize,
                    v.camera.height as usize,
                    &model,
                    SCATTER_ITERATIONS,
                )
            })
            .collect::<Result<Vec<_>>>()?
    } else {
        images.iter().map(|v| v.radiance.to_vec()).collect()
    };
    Ok(Unscattered {
        model,
        fits,
        radiance,
    })
}

/// [`unscatter`]'s fit without the inversion: the model kept and every fit tried (as
/// [`Unscattered::model`] and [`Unscattered::fits`]).
pub fn fit_scatter_on_mesh(
    mesh: &TriMesh,
    held: Option<&[bool]>,
    images: &[ShadingImage<'_>],
    min_cos: f32,
) -> Result<(Scatter, Vec<Scatter>)> {
    if held.is_some_and(|h| h.len() != mesh.triangles.len()) {
        return Err(MeshError::InvalidArgument(format!(
            "unscatter: {} held flags for a mesh of {} faces",
            held.map_or(0, <[bool]>::len),
            mesh.triangles.len()
        )));
    }
    let caster = crate::raycast::MeshRaycaster::new(mesh, "the mesh the scattering is fitted on")?;
    // Per image: the mesh's Lambertian radiance, its cosine, the pixels left out.
    let maps: Vec<(Vec<f32>, Vec<f32>, Vec<bool>)> = images
        .par_iter()
        .map(|v| {
            let cam = v.camera;
            let (lam, cos) = lambert_image(&caster, cam);
            let mut skip = vec![false; lam.len()];
            if let Some(held) = held {
                let depth = caster.render(cam).depth;
                for (f, p, _) in crate::refine::visible_faces(mesh, cam, &depth, 0.0) {
                    if !held[f] {
                        skip[p] = true;
                    }
                }
            }
            (lam, cos, skip)
        })
        .collect();
    // The fits over the held faces' pixels (`held_only`) or over every pixel.
    let fit_all = |held_only: bool| -> Result<(Scatter, Vec<Scatter>)> {
        let views: Vec<ScatterView<'_>> = (images.iter().zip(&maps))
            .map(|(v, (lam, cos, skip))| ScatterView {
                width: v.camera.width as usize,
                height: v.camera.height as usize,
                radiance: v.radiance,
                mask: v.mask,
                lambert: lam,
                cosine: cos,
                skip: held_only.then_some(&skip[..]),
            })
            .collect();
        let least = |fits: &[Scatter]| -> Result<Scatter> {
            fits.iter()
                .filter(|f| f.sharp > 0.0)
                .min_by(|x, y| x.residual.total_cmp(&y.residual))
                .copied()
                .ok_or_else(|| {
                    MeshError::InvalidArgument(
                        "unscatter: no view shows the mesh lit by its own light".into(),
                    )
                })
        };
        let mut fits = Vec::new();
        for p in PIXEL_SIGMAS {
            fits.extend(fit_scatter(&views, p, &[0.0], min_cos, 1.0)?);
        }
        let lambert = least(&fits)?;
        let wider: Vec<f32> = (SCATTER_SIGMAS.iter().copied())
            .filter(|s| *s > lambert.pixel)
            .collect();
        let scattered = fit_scatter(
            &views,
            lambert.pixel,
            &wider,
            min_cos,
            SCATTER_MAX_AMPLIFICATION,
        )?;
        fits.extend(&scattered);
        Ok((least(&[&[lambert][..], &scattered].concat())?, fits))
    };
    // Where the mesh shows no held face, every pixel counts.
    match fit_all(held.is_some()) {
        Err(_) if held.is_some() => fit_all(false),
        r => r,
    }
}

/// The least cosine on the mesh at which [`unexplained_dark`] reads a pixel.
pub const DARK_MIN_COS: f32 = 0.2;

/// Per image, the pixels that `mesh`'s shape cannot explain as dark as they are: the image is
/// below `below` times the scattering model's prediction from the mesh ([`Scatter::predict`];
/// the model fitted on the mesh over every image, [`fit_scatter_on_mesh`]), where the mesh's
/// cosine is at least [`DARK_MIN_COS`] and the mask (when given) at least 0.99. Over a
/// concavity the masks' mesh lids over, the image is darker than the lid would be: under the
/// light at the camera, light reaches a narrow groove's floor and walls at grazing angles and
/// scatters out over less of the lit surface. Returns the model and the flags.
pub fn unexplained_dark(
    mesh: &TriMesh,
    images: &[ShadingImage<'_>],
    below: f32,
) -> Result<(Scatter, Vec<Vec<bool>>)> {
    if !(below.is_finite() && below > 0.0) {
        return Err(MeshError::InvalidArgument(format!(
            "unexplained darkness: the share of the prediction must be positive, got {below}"
        )));
    }
    let (model, _) = fit_scatter_on_mesh(mesh, None, images, DARK_MIN_COS)?;
    let caster = crate::raycast::MeshRaycaster::new(mesh, "the mesh the darkness is judged on")?;
    let dark = images
        .par_iter()
        .map(|v| {
            let (w, h) = (v.camera.width as usize, v.camera.height as usize);
            let (lambert, cosine) = lambert_image(&caster, v.camera);
            let predicted = model.predict(&lambert, w, h);
            (0..w * h)
                .map(|p| {
                    cosine[p] >= DARK_MIN_COS
                        && v.mask.is_none_or(|m| m[p] >= 0.99)
                        && predicted[p] > 0.0
                        && v.radiance[p] < below * predicted[p]
                })
                .collect()
        })
        .collect();
    Ok((model, dark))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::icosphere;

    /// The prediction of a uniform radiance is `(a + b)` times it away from the border, and
    /// the model's fit reproduces an image made by the model.
    #[test]
    fn the_prediction_is_the_model_applied_and_its_own_fit() {
        let (w, h) = (48, 40);
        let model = Scatter {
            sharp: 0.6,
            blurred: 0.3,
            sigma: 3.0,
            pixel: 0.5,
            residual: 0.0,
        };
        let flat = vec![2.0f32; w * h];
        let p = model.predict(&flat, w, h);
        assert!((p[20 * w + 24] - 1.8).abs() < 1e-4, "{}", p[20 * w + 24]);
        assert!(p[0] < 1.8, "the border gathers less");
        // A textured Lambert map, the image the model makes of it, and the fit at the
        // model's widths: the same coefficients.
        let lambert: Vec<f32> = (0..w * h)
            .map(|i| 1.0 + 0.5 * ((i % w) as f32 * 0.7).sin() * ((i / w) as f32 * 0.4).cos())
            .collect();
        let image = model.predict(&lambert, w, h);
        let cosine = vec![1.0f32; w * h];
        let view = ScatterView {
            width: w,
            height: h,
            radiance: &image,
            mask: None,
            lambert: &lambert,
            cosine: &cosine,
            skip: None,
        };
        let fit = fit_scatter(&[view], 0.5, &[3.0], 0.0, 4.0).unwrap()[0];
        assert!(
            (fit.sharp - 0.6).abs() < 1e-3 && (fit.blurred - 0.3).abs() < 1e-3,
            "{fit:?}"
        );
        assert!(fit.residual < 1e-6);
    }

    /// A unit impulse blurred keeps its sum, its centre and a variance of `sigma^2` per axis
    /// (within the 3 % the kernel's truncation at three widths takes).
    #[test]
    fn the_blur_is_a_normalised_gaussian_of_its_width() {
        let (w, h) = (61, 61);
        let mut img = vec![0.0f32; w * h];
        img[30 * w + 30] = 1.0;
        let out = gaussian_blur(&img, w, h, 4.0);
        let sum: f32 = out.iter().sum();
        assert!((sum - 1.0).abs() < 1e-4, "sum {sum}");
        let var: f32 = (0..w * h)
            .map(|p| out[p] * ((p % w) as f32 - 30.0).powi(2))
            .sum();
        assert!((var - 16.0).abs() < 0.5, "variance {var}");
        assert_eq!(out[30 * w + 29], out[30 * w + 31]);
        assert_eq!(out[29 * w + 30], out[30 * w + 29]);
        assert_eq!(gaussian_blur(&img, w, h, 0.0), img);
    }

    /// One map per view.
    type Maps = Vec<Vec<f32>>;

    /// A sphere's Lambertian images under the light at the camera, with masks.
    fn sphere_views() -> (TriMesh, Vec<Camera>, Maps, Maps) {
        let mesh = icosphere(Vec3::ZERO, 0.5, 4);
        let cams: Vec<Camera> = (0..6)
            .map(|k| {
                let a = k as f32 * 1.1;
                let eye = Vec3::new(2.5 * a.cos(), 0.8 * (k as f32 - 2.5) / 2.5, 2.5 * a.sin());
                Camera::look_at(eye, Vec3::ZERO, Vec3::Y, 0.6, 48, 48)
            })
            .collect();
        let caster = crate::raycast::MeshRaycaster::new(&mesh, "sphere").unwrap();
        let (mut lam, mut masks) = (Vec::new(), Vec::new());
        for c in &cams {
            let d = caster.render(c).depth;
            lam.push(lambert_image(&caster, c).0);
            masks.push(d.iter().map(|z| if *z > 0.0 { 1.0 } else { 0.0 }).collect());
        }
        (mesh, cams, lam, masks)
    }

    /// Each image as `a L + b (G_s * L)`.
    fn scattered(lam: &[Vec<f32>], sigma: f32, a: f32, b: f32) -> Maps {
        lam.iter()
            .map(|l| {
                let g = gaussian_blur(l, 48, 48, sigma);
                l.iter().zip(&g).map(|(x, y)| a * x + b * y).collect()
            })
            .collect()
    }

    /// The views of `rads` with their masks.
    fn images<'a>(
        cams: &'a [Camera],
        rads: &'a [Vec<f32>],
        masks: &'a [Vec<f32>],
    ) -> Vec<ShadingImage<'a>> {
        cams.iter()
            .zip(rads)
            .zip(masks)
            .map(|((camera, radiance), m)| ShadingImage {
                camera,
                radiance,
                mask: Some(m),
            })
            .collect()
    }

    /// Images blurred by the model's scattering give back its width and shares, and the
    /// inversion gives back the sharp images; a stronger scattering is fitted within the
    /// largest amplification; sharp images get no blur inverted.
    #[test]
    fn the_scattering_of_a_sphere_is_fitted_and_inverted() {
        let (mesh, cams, lam, masks) = sphere_views();
        let blurred = scattered(&lam, 6.0, 0.55, 0.45);
        let u = unscatter(&mesh, None, &images(&cams, &blurred, &masks), 0.3).unwrap();
        let m = u.model;
        assert_eq!((m.pixel, m.sigma), (0.0, 6.0), "{m:?}");
        assert!(
            (m.sharp - 0.55).abs() < 1e-3 && (m.blurred - 0.45).abs() < 1e-3,
            "{m:?}"
        );
        assert!(m.residual < 1e-6, "{m:?}");
        // The inverted images match the sharp ones inside the masks.
        let (mut err, mut norm) = (0.0f64, 0.0f64);
        for ((r, l), k) in u.radiance.iter().zip(&lam).zip(&masks) {
            for p in 0..r.len() {
                if k[p] > 0.5 {
                    err += f64::from(r[p] - l[p]).powi(2);
                    norm += f64::from(l[p]).powi(2);
                }
            }
        }
        assert!(
            (err / norm).sqrt() < 1e-2,
            "relative error {}",
            (err / norm).sqrt()
        );
        // Scattering that would amplify the noise fourfold is fitted on the bound, twofold.
        let strong = scattered(&lam, 6.0, 0.25, 0.75);
        let m = unscatter(&mesh, None, &images(&cams, &strong, &masks), 0.3)
            .unwrap()
            .model;
        assert!(m.blurs() && m.sigma >= 6.0, "{m:?}");
        assert!(
            (m.amplification() - SCATTER_MAX_AMPLIFICATION).abs() < 1e-3,
            "{m:?}"
        );
        assert!(m.residual > 1e-4, "{m:?}");
        // The sharp images: no blur worth inverting.
        let u = unscatter(&mesh, None, &images(&cams, &lam, &masks), 0.3).unwrap();
        assert!(u.model.amplification() < 1.01, "{:?}", u.model);
        for (r, l) in u.radiance.iter().zip(&lam) {
            let d = r
                .iter()
                .zip(l)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f32::max);
            let top = l.iter().fold(0.0f32, |a, b| a.max(*b));
            assert!(d < 1e-2 * top, "{d} against {top}");
        }
    }

    /// A strip darkened in one view's image is the only unexplained darkness; the undarkened
    /// images have none.
    #[test]
    fn a_darkened_strip_is_unexplained_and_nothing_else_is() {
        let (mesh, cams, lam, masks) = sphere_views();
        let blurred = scattered(&lam, 4.0, 0.6, 0.4);
        let (_, dark) = unexplained_dark(&mesh, &images(&cams, &blurred, &masks), 0.6).unwrap();
        assert!(dark.iter().all(|d| d.iter().all(|x| !x)));
        let w = cams[0].width as usize;
        let mut darkened = blurred.clone();
        let strip = |p: usize| (w / 2 - 1..=w / 2).contains(&(p % w));
        for (p, v) in darkened[0].iter_mut().enumerate() {
            if strip(p) {
                *v *= 0.3;
            }
        }
        let (_, dark) = unexplained_dark(&mesh, &images(&cams, &darkened, &masks), 0.6).unwrap();
        let flagged: Vec<usize> = (0..dark[0].len()).filter(|p| dark[0][*p]).collect();
        assert!(
            !flagged.is_empty() && flagged.iter().all(|p| strip(*p)),
            "{flagged:?}"
        );
        let inside = (0..lam[0].len())
            .filter(|p| strip(*p) && masks[0][*p] >= 0.99 && lam[0][*p] > 0.0)
            .count();
        assert!(flagged.len() * 2 >= inside, "{} of {inside}", flagged.len());
        assert!(dark[1..].iter().all(|d| d.iter().all(|x| !x)));
        assert!(unexplained_dark(&mesh, &images(&cams, &blurred, &masks), 0.0).is_err());
    }

    /// The shading refinement inverts the scattering when asked, and says what it fitted; a
    /// sphere whose blurred images are inverted stays a sphere.
    #[test]
    fn the_refinement_inverts_the_scattering_when_asked() {
        use crate::shading::{ShadingRefinement, refine_by_shading};
        let (mesh, cams, lam, masks) = sphere_views();
        let blurred = scattered(&lam, 4.0, 0.5, 0.5);
        let views = images(&cams, &blurred, &masks);
        let settings = ShadingRefinement {
            unscatter: true,
            shading: crate::shading::ShadingSettings {
                min_views: 3,
                ..ShadingRefinement::default().shading
            },
            ..ShadingRefinement::default()
        };
        let out = refine_by_shading(&mesh, &views, None, None, &settings).unwrap();
        let m = out.scatter.expect("the fitted model");
        assert_eq!(m.sigma, 4.0, "{m:?}");
        assert!((m.sharp - 0.5).abs() < 1e-2, "{m:?}");
        let most = out.moves.iter().fold(0.0f32, |a, d| a.max(d.abs()));
        assert!(most < 0.01, "a vertex moved {most}");
        let plain = ShadingRefinement {
            unscatter: false,
            ..settings
        };
        let out = refine_by_shading(&mesh, &views, None, None, &plain).unwrap();
        assert!(out.scatter.is_none());
    }

    /// A pixel's worth of blur is fitted as the pixel filter, not inverted as scattering; with
    /// no face held, the fit reads every pixel.
    #[test]
    fn a_pixel_filter_is_not_taken_for_scattering() {
        let (mesh, cams, lam, masks) = sphere_views();
        let filtered: Vec<Vec<f32>> = lam.iter().map(|l| gaussian_blur(l, 48, 48, 1.0)).collect();
        let views = images(&cams, &filtered, &masks);
        let u = unscatter(&mesh, None, &views, 0.3).unwrap();
        assert_eq!(u.model.pixel, 1.0, "{:?}", u.model);
        assert!(u.model.amplification() < 1.01, "{:?}", u.model);
        // No face held: fitted on every pixel alike.
        let none = vec![false; mesh.triangles.len()];
        let v = unscatter(&mesh, Some(&none), &views, 0.3).unwrap();
        assert_eq!(v.model, u.model);
    }

    /// Bad input is refused with an error: maps of the wrong size, a negative width, a model
    /// without a sharp part, held flags that do not match the mesh, no image.
    #[test]
    fn bad_input_is_refused() {
        let v = ScatterView {
            width: 2,
            height: 2,
            radiance: &[1.0; 4],
            mask: None,
            lambert: &[1.0; 3],
            cosine: &[1.0; 4],
            skip: None,
        };
        assert!(fit_scatter(&[v], 0.0, &[2.0], 0.3, 2.0).is_err());
        let v = ScatterView {
            lambert: &[1.0; 4],
            ..v
        };
        assert!(fit_scatter(&[v], 0.0, &[-1.0], 0.3, 2.0).is_err());
        assert!(fit_scatter(&[v], f32::NAN, &[2.0], 0.3, 2.0).is_err());
        assert!(fit_scatter(&[v], 0.0, &[2.0], 0.3, 0.5).is_err());
        assert!(fit_scatter(&[v], 0.0, &[2.0], 0.3, f32::NAN).is_err());
        let model = Scatter {
            sharp: 0.0,
            blurred: 1.0,
            sigma: 2.0,
            pixel: 0.0,
            residual: 0.0,
        };
        assert!(deconvolve(&[1.0; 4], None, 2, 2, &model, 10).is_err());
        let model = Scatter {
            sharp: 1.0,
            ..model
        };
        assert!(deconvolve(&[1.0; 3], None, 2, 2, &model, 10).is_err());
        let mesh = icosphere(Vec3::ZERO, 0.5, 1);
        assert!(unscatter(&mesh, Some(&[true; 3]), &[], 0.3).is_err());
        // No image shows the mesh.
        assert!(unscatter(&mesh, None, &[], 0.3).is_err());
    }
}
