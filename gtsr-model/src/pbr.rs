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
//!
//! The formula lives in [`gtsr_render_kernels::shade`], which runs it as one op with its
//! backward pass on the CPU ([`c_pbr`]) and as Burn's ops elsewhere ([`shade`] keeps the terms
//! apart for inspection); [`shade_pixel`] evaluates it directly, for the tests.

use burn::tensor::Tensor;
use gtsr_render_kernels::shade as kernel;

pub use gtsr_render_kernels::shade::{
    COS_MIN, COVER_MIN, DIST2_MIN, ShadeMaps as GBuffer, ShadeParams as ShadingParams,
    ShadeTerms as Shaded, linear_to_srgb, schlick, srgb_to_linear,
};

/// Deferred C_PBR for a light of intensity `light` (`[1, 1]`, positive) at the camera,
/// sRGB-encoded with `encode_srgb`: what training compares with the images. One fused op on
/// the CPU ([`gtsr_render_kernels::shade::shade`]), Burn's ops elsewhere.
pub fn c_pbr(g: &GBuffer, light: Tensor<2>, p: ShadingParams, encode_srgb: bool) -> Tensor<3> {
    kernel::shade(g, light, p, encode_srgb)
}

/// Deferred C_PBR (linear) with its Fresnel and specular terms apart, in Burn's ops: the same
/// colour as [`c_pbr`] without the encoding.
pub fn shade(g: &GBuffer, light: Tensor<2>, p: ShadingParams) -> Shaded {
    kernel::shade_terms_by_tensor_ops(g, light, p, false)
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
