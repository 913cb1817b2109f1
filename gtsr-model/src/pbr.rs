//! The Schlick Fresnel term and the deferred Disney-style shading of C_PBR under a point light
//! at the camera (so light, view and half vectors coincide).
//!
//! Per pixel, with `c = n . v` clamped to `[COS_MIN, 1]`, `a = r^2` for the clamped roughness
//! `r`, `k = (r + 1)^2 / 8` and `dist^2 = (Z |ray|)^2` clamped below by `DIST2_MIN`:
//! - `F = F0 + (1 - F0) (1 - c)^5`
//! - `D = a^2 / (pi ((a^2 - 1) c^2 + 1)^2)`, `G = (c / (c (1 - k) + k))^2`
//! - `C_s = F D G / (4 c^2) * L / dist^2`, `C_d = base / pi * F^2 * L / dist^2` (the paper's F^2)
//! - `C_PBR = A (C_s + gamma C_d) + (1 - A F) C_scatter`, with `A` the surface coverage (alpha of
//!   the surface pass): on covered pixels (`A = 1`) this is the paper's
//!   `C_s + gamma C_d + (1 - F) C_scatter`; where there is no surface only scattering remains.
//! - With [`ShadingParams::scatter_srgb`] (off by default in training) `C_scatter` is the
//!   scattering map decoded from the sRGB curve: the interior set's colours are the ones C_SH
//!   blends and compares with the sRGB images, so the map is sRGB-encoded, while the sum
//!   above adds linear radiance (and is sRGB-encoded again when it is compared with images).
//! - With [`ShadingParams::scatter_lambert`] (an experiment, off by default) `C_scatter` is
//!   lit as a diffuse lobe: multiplied by `A c L / dist^2 + (1 - A)`.
//!
//! Material maps arrive premultiplied by coverage; they are divided by `max(A, COVER_MIN)`.

use burn::tensor::Tensor;

/// Lower clamp of `n . v` (grazing angles).
pub const COS_MIN: f64 = 0.02;
/// Lower clamp of the squared light distance.
pub const DIST2_MIN: f64 = 1e-4;
/// Lower clamp of the coverage used to un-premultiply material maps.
pub const COVER_MIN: f64 = 1e-2;

/// Schlick's approximation `F0 + (1 - F0) (1 - c)^5` for `c` in `[0, 1]` (clamped).
pub fn schlick<const D: usize>(cos: Tensor<D>, f0: f64) -> Tensor<D> {
    let m = (cos.clamp(0.0, 1.0).neg() + 1.0).powi_scalar(5);
    m * (1.0 - f0) + f0
}

/// Inputs of the deferred shading, all per pixel.
#[derive(Clone, Debug)]
pub struct GBuffer {
    /// `[H, W, 3]` blended camera-space normal (premultiplied by coverage).
    pub normal: Tensor<3>,
    /// `[H, W]` unbiased z-depth.
    pub depth: Tensor<2>,
    /// `[H, W]` surface coverage.
    pub coverage: Tensor<2>,
    /// `[H, W, 3]` blended base colour (premultiplied).
    pub base: Tensor<3>,
    /// `[H, W]` blended roughness (premultiplied).
    pub roughness: Tensor<2>,
    /// `[H, W, 3]` scattering map from the interior set (`None` without interior set).
    pub scatter: Option<Tensor<3>>,
    /// `[H, W, 3]` camera-space pixel rays (z = 1).
    pub rays: Tensor<3>,
}

/// Shading constants.
#[derive(Clone, Copy, Debug)]
pub struct ShadingParams {
    /// Schlick F0.
    pub f0: f64,
    /// Diffuse weight gamma.
    pub gamma: f64,
    /// Lower roughness clamp.
    pub min_roughness: f64,
    /// Shade the scattering map as a diffuse lobe lit by the point light: on covered pixels
    /// multiply it by `c L / dist^2`, the irradiance the light at the camera gives a surface of
    /// normal `n` (`c = n . v`), and let the model render it from the interior set's
    /// view-independent (degree 0) colour. Off: the paper's scattering map, the interior set's
    /// view-dependent SH colour as it is, which can itself carry the `c` of every view (over
    /// the views that see a surface point, its `c` is a degree-1 SH of the view direction), so
    /// the normals need not explain the shading.
    pub scatter_lambert: bool,
    /// Decode the scattering map from the sRGB curve ([`srgb_to_linear`]) before it is added
    /// to the linear specular and diffuse terms: the map holds the interior set's colours as
    /// C_SH blends them against sRGB images. Off: the map is taken as linear radiance, which
    /// makes C_PBR, once encoded, brighter than C_SH with the same interior colours.
    pub scatter_srgb: bool,
}

/// The shading terms, kept apart for inspection and tests.
#[derive(Clone, Debug)]
pub struct Shaded {
    /// `[H, W, 3]` C_PBR (linear).
    pub colour: Tensor<3>,
    /// `[H, W]` per-pixel Fresnel.
    pub fresnel: Tensor<2>,
    /// `[H, W]` specular `F D G / (4 c^2) * L / dist^2`.
    pub specular: Tensor<2>,
}

/// Deferred C_PBR for a light of intensity `light` (`[1, 1]`, positive) at the camera.
pub fn shade(g: &GBuffer, light: Tensor<2>, p: ShadingParams) -> Shaded {
    let [h, w, _] = g.normal.dims();
    let cover_div = g.coverage.clone().clamp_min(COVER_MIN);
    let n_len = g
        .normal
        .clone()
        .powf_scalar(2.0)
        .sum_dim(2)
        .clamp_min(1e-12)
        .sqrt();
    let n = g.normal.clone() / n_len;
    let ray_len2 = g.rays.clone().powf_scalar(2.0).sum_dim(2).reshape([h, w]);
    let v = g.rays.clone().neg() / ray_len2.clone().sqrt().reshape([h, w, 1]);
    let c = (n * v).sum_dim(2).reshape([h, w]).clamp(COS_MIN, 1.0);
    let r = (g.roughness.clone() / cover_div.clone()).clamp(p.min_roughness, 1.0);
    let a2 = r.clone().powi_scalar(4);
    let c2 = c.clone() * c.clone();
    let denom = (a2.clone() - 1.0) * c2.clone() + 1.0;
    let d = a2 / (denom.clone() * denom * std::f64::consts::PI);
    let k = (r + 1.0).powi_scalar(2) / 8.0;
    let g1 = c.clone() / (c.clone() * (k.clone().neg() + 1.0) + k);
    let geo = g1.clone() * g1;
    let f = schlick(c.clone(), p.f0);
    let dist2 = (g.depth.clone() * g.depth.clone() * ray_len2).clamp_min(DIST2_MIN);
    let radiance = light.reshape([1, 1]) / dist2;
    let spec = f.clone() * d * geo / (c2 * 4.0) * radiance.clone();
    let base = g.base.clone() / cover_div.reshape([h, w, 1]);
    let diffuse =
        base * (f.clone() * f.clone() * radiance.clone() / std::f64::consts::PI).reshape([h, w, 1]);
    let cov = g.coverage.clone().reshape([h, w, 1]);
    let mut colour = (diffuse * p.gamma + spec.clone().reshape([h, w, 1])) * cov.clone();
    if let Some(s) = &g.scatter {
        let mut s = if p.scatter_srgb {
            srgb_to_linear(s.clone())
        } else {
            s.clone()
        };
        if p.scatter_lambert {
            // A (c L / dist^2) + (1 - A): lit where there is a surface, as it is elsewhere.
            let lit = (c.clone() * radiance.clone() - 1.0) * g.coverage.clone() + 1.0;
            s = s * lit.reshape([h, w, 1]);
        }
        colour = colour + s * ((f.clone().reshape([h, w, 1]) * cov).neg() + 1.0);
    }
    Shaded {
        colour,
        fresnel: f,
        specular: spec,
    }
}

/// The sRGB transfer curve (IEC 61966-2-1) on linear values, with the input clamped to
/// `[0, 1]` and the linear toe, so its gradient is bounded.
pub fn linear_to_srgb<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    let x = x.clamp(0.0, 1.0);
    let low = x.clone() * 12.92;
    let high = x.clone().clamp_min(0.003_130_8).powf_scalar(1.0 / 2.4) * 1.055 - 0.055;
    let is_low = x.lower_equal_elem(0.003_130_8);
    high.mask_where(is_low, low)
}

/// The inverse of [`linear_to_srgb`] on `[0, 1]`, extended past 1 by the same power (SH
/// colours are not bounded above); negative inputs give 0. Its gradient is bounded on any
/// bounded input.
pub fn srgb_to_linear<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    let x = x.clamp_min(0.0);
    let low = x.clone() / 12.92;
    let high = ((x.clone() + 0.055) / 1.055).powf_scalar(2.4);
    let is_low = x.lower_equal_elem(0.040_45);
    high.mask_where(is_low, low)
}

/// Host version of [`shade`] for one pixel (f64), used by tests as the direct evaluation.
#[allow(clippy::too_many_arguments)]
pub fn shade_pixel(
    normal: [f64; 3],
    depth: f64,
    coverage: f64,
    base: [f64; 3],
    roughness: f64,
    scatter: Option<[f64; 3]>,
    ray: [f64; 3],
    light: f64,
    p: ShadingParams,
) -> [f64; 3] {
    let cd = coverage.max(COVER_MIN);
    let nl = (normal.iter().map(|v| v * v).sum::<f64>())
        .max(1e-12)
        .sqrt();
    let rl2: f64 = ray.iter().map(|v| v * v).sum();
    let c = (0..3)
        .map(|k| normal[k] / nl * -ray[k] / rl2.sqrt())
        .sum::<f64>()
        .clamp(COS_MIN, 1.0);
    let r = (roughness / cd).clamp(p.min_roughness, 1.0);
    let a2 = r.powi(4);
    let den = (a2 - 1.0) * c * c + 1.0;
    let d = a2 / (std::f64::consts::PI * den * den);
    let k = (r + 1.0).powi(2) / 8.0;
    let g1 = c / (c * (1.0 - k) + k);
    let f = p.f0 + (1.0 - p.f0) * (1.0 - c).powi(5);
    let rad = light / (depth * depth * rl2).max(DIST2_MIN);
    let spec = f * d * g1 * g1 / (4.0 * c * c) * rad;
    let mut out = [0.0; 3];
    for k in 0..3 {
        let diff = base[k] / cd / std::f64::consts::PI * f * f * rad;
        out[k] = coverage * (spec + p.gamma * diff);
        if let Some(s) = scatter {
            let lit = if p.scatter_lambert {
                coverage * c * rad + 1.0 - coverage
            } else {
                1.0
            };
            let s = if p.scatter_srgb {
                gtsr_data::image_io::srgb_to_linear_f64(s[k].max(0.0))
            } else {
                s[k]
            };
            out[k] += (1.0 - coverage * f) * s * lit;
        }
    }
    out
}
