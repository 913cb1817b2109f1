//! Deferred per-pixel shading under a point light at the camera (GGX specular, a Fresnel-weighted
//! diffuse term and an optional scattering map), differentiable in every map and the light.
//!
//! Per pixel, from the blended maps (normal `N`, base colour `B` and roughness `R` premultiplied
//! by the coverage `A`), the z-depth `Z`, the scattering map `S`, the camera-space ray `r` (no
//! gradient) and the light intensity `L` (one value for the image):
//! - `d = max(A, COVER_MIN)`, `n = N / sqrt(max(|N|^2, 1e-12))`, `v = -r / |r|`,
//!   `c = clamp(n . v, COS_MIN, 1)`, `rho = clamp(R / d, min_roughness, 1)`;
//! - `F = F0 + (1 - F0) (1 - c)^5`, `a2 = rho^4`,
//!   `D = a2 / (pi ((a2 - 1) c^2 + 1)^2)`, `k = (rho + 1)^2 / 8`, `G = (c / (c (1 - k) + k))^2`;
//! - `E = L / max(Z^2 |r|^2, DIST2_MIN)` (the light's irradiance at the point);
//! - `colour = A (F D G / (4 c^2) E + gamma B / d F^2 E / pi) + (1 - A F) s lit`, where `s` is
//!   `S` (or `S` decoded from the sRGB curve, [`ShadeParams::scatter_srgb`]) and `lit` is 1 (or
//!   `A c E + 1 - A`, [`ShadeParams::scatter_lambert`]);
//! - with `encode_srgb` the colour is clamped to `[0, 1]` and sRGB-encoded.
//!
//! Clamps pass the gradient where their input lies within the bounds (ends included) and stop it
//! outside, as Burn's `clamp` does. On NdArray the shading is one backend op
//! ([`ShadeBackend`]): one pass over the pixels forward and one backward, parallel over rows,
//! where the same expression in Burn ops takes about fifty tensor ops and their autodiff nodes.
//! Other devices take [`shade_by_tensor_ops`].

use burn::backend::{
    Autodiff, Backend, Dispatch, ExtensionType, NdArray, backend_extension, tensor::FloatTensor,
};
use burn::tensor::{DType, Tensor};
use burn_autodiff::{
    checkpoint::{base::Checkpointer, strategy::CheckpointStrategy},
    grads::Gradients,
    ops::{Backward, Ops, OpsKind},
};
use burn_ndarray::NdArrayTensor;
use rayon::prelude::*;

use crate::autodiff::backward_step;
use crate::backend::{host_slice, is_f64, on_ndarray, to_nd};
use crate::scalar::Real;

/// Lower clamp of `n . v` (grazing angles).
pub const COS_MIN: f64 = 0.02;
/// Lower clamp of the squared light distance.
pub const DIST2_MIN: f64 = 1e-4;
/// Lower clamp of the coverage that un-premultiplies the material maps.
pub const COVER_MIN: f64 = 1e-2;
/// Lower clamp of the squared length of the blended normal.
const NORMAL2_MIN: f64 = 1e-12;
/// The sRGB curve's linear toe ends here (linear side).
const SRGB_ENCODE_TOE: f64 = 0.003_130_8;
/// The sRGB curve's linear toe ends here (encoded side).
const SRGB_DECODE_TOE: f64 = 0.040_45;

/// The shading constants.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShadeParams {
    /// Schlick's reflectance at normal incidence, `F0`.
    pub f0: f64,
    /// Weight of the diffuse term, `gamma`.
    pub gamma: f64,
    /// Lower clamp of the roughness (keeps GGX finite).
    pub min_roughness: f64,
    /// Shade the scattering map as a diffuse lobe lit by the point light: on covered pixels
    /// multiply it by `c E`, the irradiance the light at the camera gives a surface of normal
    /// `n` (`c = n . v`; `A c E + 1 - A` in all). Off: the scattering map as it is (the
    /// paper's), which can itself carry the `c` of every view (over the views that see a
    /// surface point, its `c` is a degree-1 SH of the view direction), so the normals need not
    /// explain the shading.
    pub scatter_lambert: bool,
    /// Decode the scattering map from the sRGB curve before it is added to the linear specular
    /// and diffuse terms (a map of colours blended against sRGB images is sRGB-encoded). Off:
    /// the map is taken as linear radiance.
    pub scatter_srgb: bool,
}

/// The per-pixel maps of one image, `[H, W, ..]`.
#[derive(Clone, Debug)]
pub struct ShadeMaps {
    /// `[H, W, 3]` blended normal, premultiplied by coverage.
    pub normal: Tensor<3>,
    /// `[H, W]` z-depth.
    pub depth: Tensor<2>,
    /// `[H, W]` coverage `A`.
    pub coverage: Tensor<2>,
    /// `[H, W, 3]` blended base colour, premultiplied.
    pub base: Tensor<3>,
    /// `[H, W]` blended roughness, premultiplied.
    pub roughness: Tensor<2>,
    /// `[H, W, 3]` scattering map; `None`: no scattering term.
    pub scatter: Option<Tensor<3>>,
    /// `[H, W, 3]` camera-space rays (z = 1); not differentiated.
    pub rays: Tensor<3>,
}

/// The shading as a backend op (NdArray, and autodiff over it). Use [`shade`], which picks this
/// op or the tensor ops by device.
#[backend_extension(Autodiff, NdArray)]
pub trait ShadeBackend: Backend {
    /// The colour `[H, W, 3]` from the maps (`scatter` is read only with
    /// [`ShadeConfig::has_scatter`]), the rays (not differentiated) and the light.
    fn shade_pixels(
        #[extension_type] inputs: ShadeInputs<Self>,
        config: ShadeConfig,
    ) -> FloatTensor<Self>;
}

/// What [`ShadeBackend::shade_pixels`] needs besides the tensors.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShadeConfig {
    /// The constants.
    pub params: ShadeParams,
    /// Whether the scattering map is used.
    pub has_scatter: bool,
    /// Encode the colour with the sRGB curve (after clamping it to `[0, 1]`).
    pub encode_srgb: bool,
}

/// The kernels behind [`ShadeBackend`]: forward, and backward into the seven differentiable
/// inputs (normal, depth, coverage, base, roughness, scatter, light) given the colour's
/// gradient.
pub trait ShadeKernels: Backend {
    /// The forward pass.
    fn shade_forward(inputs: &ShadeInputs<Self>, config: ShadeConfig) -> FloatTensor<Self>;

    /// The gradients of the seven differentiable inputs, in their order.
    fn shade_backward(
        inputs: &ShadeInputs<Self>,
        config: ShadeConfig,
        grad: FloatTensor<Self>,
    ) -> [FloatTensor<Self>; 7];
}

/// The primitives of one shading op: the seven differentiable inputs and the rays.
#[derive(Clone, Debug, ExtensionType)]
pub struct ShadeInputs<B: Backend> {
    /// `[H, W, 3]`.
    pub normal: FloatTensor<B>,
    /// `[H, W]`.
    pub depth: FloatTensor<B>,
    /// `[H, W]`.
    pub coverage: FloatTensor<B>,
    /// `[H, W, 3]`.
    pub base: FloatTensor<B>,
    /// `[H, W]`.
    pub roughness: FloatTensor<B>,
    /// `[H, W, 3]`.
    pub scatter: FloatTensor<B>,
    /// `[1, 1]`.
    pub light: FloatTensor<B>,
    /// `[H, W, 3]`.
    pub rays: FloatTensor<B>,
}

impl ShadeKernels for NdArray {
    fn shade_forward(inputs: &ShadeInputs<Self>, config: ShadeConfig) -> NdArrayTensor {
        if is_f64(&inputs.normal) {
            nd_forward::<f64>(inputs, config)
        } else {
            nd_forward::<f32>(inputs, config)
        }
    }

    fn shade_backward(
        inputs: &ShadeInputs<Self>,
        config: ShadeConfig,
        grad: NdArrayTensor,
    ) -> [NdArrayTensor; 7] {
        if is_f64(&inputs.normal) {
            nd_backward::<f64>(inputs, config, &grad)
        } else {
            nd_backward::<f32>(inputs, config, &grad)
        }
    }
}

impl ShadeBackend for NdArray {
    fn shade_pixels(inputs: ShadeInputs<Self>, config: ShadeConfig) -> NdArrayTensor {
        Self::shade_forward(&inputs, config)
    }
}

/// The image size `(H, W)` of a `[H, W, ..]` primitive.
fn image_size(t: &NdArrayTensor) -> (usize, usize) {
    let s = burn::backend::TensorMetadata::shape(t).to_vec();
    (s[0], s[1])
}

/// Runs `f` on the inputs as host slices (borrowed where they are contiguous and of precision
/// `F`).
fn with_pixels<F: Real, R>(
    i: &ShadeInputs<NdArray>,
    has_scatter: bool,
    f: impl FnOnce(&Pixels<'_, F>) -> R,
) -> R {
    let (normal, depth, coverage) = (
        host_slice::<F>(&i.normal),
        host_slice::<F>(&i.depth),
        host_slice::<F>(&i.coverage),
    );
    let (base, roughness, rays) = (
        host_slice::<F>(&i.base),
        host_slice::<F>(&i.roughness),
        host_slice::<F>(&i.rays),
    );
    let scatter = has_scatter.then(|| host_slice::<F>(&i.scatter));
    f(&Pixels {
        normal: &normal,
        depth: &depth,
        coverage: &coverage,
        base: &base,
        roughness: &roughness,
        scatter: scatter.as_deref(),
        rays: &rays,
        light: host_slice::<F>(&i.light)[0],
    })
}

fn nd_forward<F: Real + burn::tensor::Element>(
    inputs: &ShadeInputs<NdArray>,
    config: ShadeConfig,
) -> NdArrayTensor {
    let (h, w) = image_size(&inputs.normal);
    let colour = with_pixels::<F, _>(inputs, config.has_scatter, |m| {
        forward_host(m, config.params, config.encode_srgb)
    });
    to_nd(colour, &[h, w, 3])
}

fn nd_backward<F: Real + burn::tensor::Element>(
    inputs: &ShadeInputs<NdArray>,
    config: ShadeConfig,
    grad: &NdArrayTensor,
) -> [NdArrayTensor; 7] {
    let (h, w) = image_size(&inputs.normal);
    let g = with_pixels::<F, _>(inputs, config.has_scatter, |m| {
        backward_host(m, config.params, config.encode_srgb, &host_slice::<F>(grad))
    });
    [
        to_nd(g.normal, &[h, w, 3]),
        to_nd(g.depth, &[h, w]),
        to_nd(g.coverage, &[h, w]),
        to_nd(g.base, &[h, w, 3]),
        to_nd(g.roughness, &[h, w]),
        to_nd(g.scatter, &[h, w, 3]),
        to_nd(vec![g.light], &[1, 1]),
    ]
}

/// The maps of one image as host slices (`[P, 3]` or `[P]` for `P` pixels), and the light.
#[derive(Clone, Copy, Debug)]
pub struct Pixels<'a, F> {
    /// `[P, 3]` premultiplied normal.
    pub normal: &'a [F],
    /// `[P]` z-depth.
    pub depth: &'a [F],
    /// `[P]` coverage.
    pub coverage: &'a [F],
    /// `[P, 3]` premultiplied base colour.
    pub base: &'a [F],
    /// `[P]` premultiplied roughness.
    pub roughness: &'a [F],
    /// `[P, 3]` scattering map, if any.
    pub scatter: Option<&'a [F]>,
    /// `[P, 3]` rays.
    pub rays: &'a [F],
    /// The light intensity.
    pub light: F,
}

/// Pixels per parallel chunk.
const CHUNK: usize = 1024;

/// A clamp's value and whether it passes the gradient (input within the bounds, ends included).
#[inline(always)]
fn clamp_pass<F: Real>(x: F, lo: F, hi: F) -> (F, bool) {
    if x < lo {
        (lo, false)
    } else if x > hi {
        (hi, false)
    } else {
        (x, true)
    }
}

/// [`clamp_pass`] with no upper bound.
#[inline(always)]
fn clamp_min_pass<F: Real>(x: F, lo: F) -> (F, bool) {
    if x < lo { (lo, false) } else { (x, true) }
}

/// The sRGB encoding of a linear value clamped to `[0, 1]`, and its derivative.
#[inline(always)]
fn encode<F: Real>(x: F) -> (F, F) {
    let (xc, pass) = clamp_pass(x, F::zero(), F::one());
    if xc <= F::c(SRGB_ENCODE_TOE) {
        (xc * F::c(12.92), if pass { F::c(12.92) } else { F::zero() })
    } else {
        let p = xc.powf(F::c(1.0 / 2.4));
        let d = F::c(1.055 / 2.4) * p / xc;
        (
            p * F::c(1.055) - F::c(0.055),
            if pass { d } else { F::zero() },
        )
    }
}

/// The sRGB decoding of a value clamped below at 0 (extended past 1 by the same power), and its
/// derivative.
#[inline(always)]
fn decode<F: Real>(x: F) -> (F, F) {
    let (xc, pass) = clamp_min_pass(x, F::zero());
    if xc <= F::c(SRGB_DECODE_TOE) {
        (
            xc / F::c(12.92),
            if pass { F::c(1.0 / 12.92) } else { F::zero() },
        )
    } else {
        let b = (xc + F::c(0.055)) / F::c(1.055);
        let p = b.powf(F::c(2.4));
        let d = F::c(2.4 / 1.055) * p / b;
        (p, if pass { d } else { F::zero() })
    }
}

/// Everything the backward pass reads of one pixel's forward pass.
#[derive(Clone, Copy, Debug, Default)]
struct Pixel<F> {
    cover_div: F,
    cover_pass: bool,
    normal_len: F,
    normal_pass: bool,
    view: [F; 3],
    cos_raw: F,
    cos: F,
    cos_pass: bool,
    rough_raw: F,
    rough: F,
    rough_pass: bool,
    a2: F,
    den: F,
    d: F,
    k: F,
    h: F,
    g1: F,
    g: F,
    f: F,
    dist2: F,
    dist_pass: bool,
    irradiance: F,
    spec: F,
    diffuse_factor: F,
    lit: F,
    /// The scattering term's colour `s` (decoded when asked) and its derivative in `S`.
    s: [F; 3],
    ds: [F; 3],
    /// The colour before the encoding.
    colour: [F; 3],
}

/// One pixel's forward pass (`p` its index).
#[inline(always)]
fn pixel<F: Real>(m: &Pixels<'_, F>, prm: &ShadeParams, p: usize) -> Pixel<F> {
    let c = |v: f64| F::c(v);
    let a = m.coverage[p];
    let (cover_div, cover_pass) = clamp_min_pass(a, c(COVER_MIN));
    let nv = [m.normal[3 * p], m.normal[3 * p + 1], m.normal[3 * p + 2]];
    let (n2, normal_pass) = clamp_min_pass(
        nv[0] * nv[0] + nv[1] * nv[1] + nv[2] * nv[2],
        c(NORMAL2_MIN),
    );
    let normal_len = n2.sqrt();
    let r = [m.rays[3 * p], m.rays[3 * p + 1], m.rays[3 * p + 2]];
    let rl2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
    let rl = rl2.sqrt();
    let view = [-r[0] / rl, -r[1] / rl, -r[2] / rl];
    let cos_raw = (nv[0] * view[0] + nv[1] * view[1] + nv[2] * view[2]) / normal_len;
    let (cos, cos_pass) = clamp_pass(cos_raw, c(COS_MIN), F::one());
    let rough_raw = m.roughness[p] / cover_div;
    let (rough, rough_pass) = clamp_pass(rough_raw, c(prm.min_roughness), F::one());
    let a2 = rough * rough * rough * rough;
    let c2 = cos * cos;
    let den = (a2 - F::one()) * c2 + F::one();
    let d = a2 / (den * den * c(std::f64::consts::PI));
    let k = (rough + F::one()) * (rough + F::one()) / c(8.0);
    let h = cos * (F::one() - k) + k;
    let g1 = cos / h;
    let g = g1 * g1;
    let one_c = F::one() - cos;
    let f = one_c * one_c * one_c * one_c * one_c * c(1.0 - prm.f0) + c(prm.f0);
    let z = m.depth[p];
    let (dist2, dist_pass) = clamp_min_pass(z * z * rl2, c(DIST2_MIN));
    let irradiance = m.light / dist2;
    let spec = f * d * g / (c2 * c(4.0)) * irradiance;
    let diffuse_factor = f * f * irradiance / c(std::f64::consts::PI);
    let lit = if prm.scatter_lambert {
        (cos * irradiance - F::one()) * a + F::one()
    } else {
        F::one()
    };
    let mut s = [F::zero(); 3];
    let mut ds = [F::zero(); 3];
    if let Some(sc) = m.scatter {
        for ch in 0..3 {
            let v = sc[3 * p + ch];
            (s[ch], ds[ch]) = if prm.scatter_srgb {
                decode(v)
            } else {
                (v, F::one())
            };
        }
    }
    let colour = std::array::from_fn(|ch| {
        let base = m.base[3 * p + ch] / cover_div;
        let surface = (base * diffuse_factor * c(prm.gamma) + spec) * a;
        surface + s[ch] * lit * (F::one() - f * a)
    });
    Pixel {
        cover_div,
        cover_pass,
        normal_len,
        normal_pass,
        view,
        cos_raw,
        cos,
        cos_pass,
        rough_raw,
        rough,
        rough_pass,
        a2,
        den,
        d,
        k,
        h,
        g1,
        g,
        f,
        dist2,
        dist_pass,
        irradiance,
        spec,
        diffuse_factor,
        lit,
        s,
        ds,
        colour,
    }
}

/// The forward pass on host slices: the colour `[P, 3]`.
pub fn forward_host<F: Real>(m: &Pixels<'_, F>, prm: ShadeParams, encode_srgb: bool) -> Vec<F> {
    let n = m.depth.len();
    let mut out = vec![F::zero(); 3 * n];
    out.par_chunks_mut(3 * CHUNK)
        .enumerate()
        .for_each(|(chunk, o)| {
            for (j, oc) in o.chunks_mut(3).enumerate() {
                let px = pixel(m, &prm, chunk * CHUNK + j);
                for (o, c) in oc.iter_mut().zip(px.colour) {
                    *o = if encode_srgb { encode(c).0 } else { c };
                }
            }
        });
    out
}

/// The gradients of [`backward_host`], laid out as its inputs.
#[derive(Clone, Debug)]
pub struct ShadeGrads<F> {
    /// `[P, 3]`.
    pub normal: Vec<F>,
    /// `[P]`.
    pub depth: Vec<F>,
    /// `[P]`.
    pub coverage: Vec<F>,
    /// `[P, 3]`.
    pub base: Vec<F>,
    /// `[P]`.
    pub roughness: Vec<F>,
    /// `[P, 3]` (zero without a scattering map).
    pub scatter: Vec<F>,
    /// The light's gradient (summed over the pixels).
    pub light: F,
}

/// The backward pass on host slices, given the colour's gradient `grad` `[P, 3]`.
pub fn backward_host<F: Real>(
    m: &Pixels<'_, F>,
    prm: ShadeParams,
    encode_srgb: bool,
    grad: &[F],
) -> ShadeGrads<F> {
    let n = m.depth.len();
    let mut g = ShadeGrads {
        normal: vec![F::zero(); 3 * n],
        depth: vec![F::zero(); n],
        coverage: vec![F::zero(); n],
        base: vec![F::zero(); 3 * n],
        roughness: vec![F::zero(); n],
        scatter: vec![F::zero(); 3 * n],
        light: F::zero(),
    };
    let light_parts: Vec<F> = (
        g.normal.par_chunks_mut(3 * CHUNK),
        g.depth.par_chunks_mut(CHUNK),
        g.coverage.par_chunks_mut(CHUNK),
        g.base.par_chunks_mut(3 * CHUNK),
        g.roughness.par_chunks_mut(CHUNK),
        g.scatter.par_chunks_mut(3 * CHUNK),
    )
        .into_par_iter()
        .enumerate()
        .map(|(chunk, (gn, gz, ga, gb, gr, gs))| {
            let mut light = F::zero();
            for j in 0..gz.len() {
                let p = chunk * CHUNK + j;
                let go = [grad[3 * p], grad[3 * p + 1], grad[3 * p + 2]];
                let out = pixel_backward(m, &prm, encode_srgb, p, go);
                gn[3 * j..3 * j + 3].copy_from_slice(&out.normal);
                gz[j] = out.depth;
                ga[j] = out.coverage;
                gb[3 * j..3 * j + 3].copy_from_slice(&out.base);
                gr[j] = out.roughness;
                gs[3 * j..3 * j + 3].copy_from_slice(&out.scatter);
                light = light + out.light;
            }
            light
        })
        .collect();
    // Summed in chunk order, so the result does not depend on the thread count.
    g.light = light_parts.into_iter().fold(F::zero(), |a, b| a + b);
    g
}

/// One pixel's input gradients.
struct PixelGrads<F> {
    normal: [F; 3],
    depth: F,
    coverage: F,
    base: [F; 3],
    roughness: F,
    scatter: [F; 3],
    light: F,
}

/// One pixel's backward pass given the colour's gradient `go`.
#[inline(always)]
fn pixel_backward<F: Real>(
    m: &Pixels<'_, F>,
    prm: &ShadeParams,
    encode_srgb: bool,
    p: usize,
    go: [F; 3],
) -> PixelGrads<F> {
    let c = |v: f64| F::c(v);
    let zero = F::zero();
    let one = F::one();
    let px = pixel(m, prm, p);
    let a = m.coverage[p];
    // Through the encoding.
    let gcol: [F; 3] = std::array::from_fn(|ch| {
        if encode_srgb {
            go[ch] * encode(px.colour[ch]).1
        } else {
            go[ch]
        }
    });
    let base: [F; 3] = std::array::from_fn(|ch| m.base[3 * p + ch] / px.cover_div);
    // colour = (gamma base df + spec) A + s lit (1 - F A).
    let mut g_a = zero;
    let mut g_spec = zero;
    let mut g_f = zero;
    let mut g_df = zero;
    let mut g_lit = zero;
    let mut g_base = [zero; 3];
    let mut g_scatter = [zero; 3];
    for ch in 0..3 {
        let gc = gcol[ch];
        let surface = base[ch] * px.diffuse_factor * c(prm.gamma) + px.spec;
        g_a = g_a + gc * surface;
        g_spec = g_spec + gc * a;
        let g_diff = gc * a * c(prm.gamma);
        g_base[ch] = g_diff * px.diffuse_factor;
        g_df = g_df + g_diff * base[ch];
        let keep = one - px.f * a;
        let sl = px.s[ch] * px.lit;
        g_a = g_a - gc * sl * px.f;
        g_f = g_f - gc * sl * a;
        g_lit = g_lit + gc * keep * px.s[ch];
        g_scatter[ch] = gc * keep * px.lit * px.ds[ch];
    }
    let mut g_cos = zero;
    let mut g_irr = zero;
    if prm.scatter_lambert && m.scatter.is_some() {
        // lit = (c E - 1) A + 1.
        g_cos = g_cos + g_lit * px.irradiance * a;
        g_irr = g_irr + g_lit * px.cos * a;
        g_a = g_a + g_lit * (px.cos * px.irradiance - one);
    }
    // base = B / d.
    let mut g_cover_div = zero;
    let mut g_b = [zero; 3];
    for ch in 0..3 {
        g_b[ch] = g_base[ch] / px.cover_div;
        g_cover_div = g_cover_div - g_base[ch] * base[ch] / px.cover_div;
    }
    // df = F^2 E / pi.
    g_f = g_f + g_df * c(2.0) * px.f * px.irradiance / c(std::f64::consts::PI);
    g_irr = g_irr + g_df * px.f * px.f / c(std::f64::consts::PI);
    // spec = F D G E / (4 c^2).
    let c2 = px.cos * px.cos;
    let q = g_spec / (c2 * c(4.0));
    g_f = g_f + q * px.d * px.g * px.irradiance;
    let g_d = q * px.f * px.g * px.irradiance;
    let g_g = q * px.f * px.d * px.irradiance;
    g_irr = g_irr + q * px.f * px.d * px.g;
    let mut g_c2 = -g_spec * px.spec / c2;
    // E = L / dist2.
    let g_light = g_irr / px.dist2;
    let g_dist2 = -g_irr * m.light / (px.dist2 * px.dist2);
    let rl2 = {
        let r = &m.rays[3 * p..3 * p + 3];
        r[0] * r[0] + r[1] * r[1] + r[2] * r[2]
    };
    let z = m.depth[p];
    let g_z = if px.dist_pass {
        g_dist2 * c(2.0) * z * rl2
    } else {
        zero
    };
    // F = F0 + (1 - F0) (1 - c)^5.
    let one_c = one - px.cos;
    g_cos = g_cos - g_f * c(5.0 * (1.0 - prm.f0)) * one_c * one_c * one_c * one_c;
    // G = g1^2, g1 = c / h, h = c (1 - k) + k.
    let g_g1 = g_g * c(2.0) * px.g1;
    g_cos = g_cos + g_g1 / px.h;
    let g_h = -g_g1 * px.cos / (px.h * px.h);
    g_cos = g_cos + g_h * (one - px.k);
    let g_k = g_h * (one - px.cos);
    let mut g_rough = g_k * (px.rough + one) / c(4.0);
    // D = a2 / (pi den^2), den = (a2 - 1) c^2 + 1.
    let pi = c(std::f64::consts::PI);
    let mut g_a2 = g_d / (px.den * px.den * pi);
    let g_den = -g_d * c(2.0) * px.a2 / (px.den * px.den * px.den * pi);
    g_a2 = g_a2 + g_den * c2;
    g_c2 = g_c2 + g_den * (px.a2 - one);
    g_cos = g_cos + g_c2 * c(2.0) * px.cos;
    g_rough = g_rough + g_a2 * c(4.0) * px.rough * px.rough * px.rough;
    // rho = clamp(R / d).
    let g_rough_raw = if px.rough_pass { g_rough } else { zero };
    let g_r = g_rough_raw / px.cover_div;
    g_cover_div = g_cover_div - g_rough_raw * px.rough_raw / px.cover_div;
    if px.cover_pass {
        g_a = g_a + g_cover_div;
    }
    // c = clamp((N . v) / |N|).
    let g_cos_raw = if px.cos_pass { g_cos } else { zero };
    let nv = &m.normal[3 * p..3 * p + 3];
    let g_len = -g_cos_raw * px.cos_raw / px.normal_len;
    let g_n2 = if px.normal_pass {
        g_len / (c(2.0) * px.normal_len)
    } else {
        zero
    };
    let g_n =
        std::array::from_fn(|k| g_cos_raw * px.view[k] / px.normal_len + g_n2 * c(2.0) * nv[k]);
    PixelGrads {
        normal: g_n,
        depth: g_z,
        coverage: g_a,
        base: g_b,
        roughness: g_r,
        scatter: g_scatter,
        light: g_light,
    }
}

#[derive(Debug)]
struct ShadeBackwardStep;

impl<B: ShadeKernels> Backward<B, 7> for ShadeBackwardStep {
    type State = (ShadeInputs<B>, ShadeConfig);

    fn backward(self, ops: Ops<Self::State, 7>, grads: &mut Gradients, _: &mut Checkpointer) {
        backward_step::<B, _, 7>(ops, grads, |(inputs, config), grad| {
            B::shade_backward(&inputs, config, grad)
        });
    }
}

impl<B: ShadeKernels, C: CheckpointStrategy> ShadeBackend for Autodiff<B, C> {
    fn shade_pixels(i: ShadeInputs<Self>, config: ShadeConfig) -> FloatTensor<Self> {
        let guards = [
            i.normal.node(),
            i.depth.node(),
            i.coverage.node(),
            i.base.node(),
            i.roughness.node(),
            i.scatter.node(),
            i.light.node(),
        ];
        let inputs = ShadeInputs {
            normal: i.normal.into_primitive(),
            depth: i.depth.into_primitive(),
            coverage: i.coverage.into_primitive(),
            base: i.base.into_primitive(),
            roughness: i.roughness.into_primitive(),
            scatter: i.scatter.into_primitive(),
            light: i.light.into_primitive(),
            rays: i.rays.into_primitive(),
        };
        let out = B::shade_forward(&inputs, config);
        match ShadeBackwardStep
            .prepare::<C>(guards)
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish((inputs, config), out),
            OpsKind::UnTracked(prep) => prep.finish(out),
        }
    }
}

/// The shaded colour `[H, W, 3]` of `maps` under a light of intensity `light` (`[1, 1]`,
/// positive) at the camera, sRGB-encoded with `encode_srgb`; differentiable on an autodiff device in every map but the rays and
/// in the light (see the module docs). NdArray runs it as one op ([`ShadeBackend`]); other
/// devices, other dtypes and differentiable rays take [`shade_by_tensor_ops`].
///
/// ```
/// use burn::tensor::{Device, Tensor};
/// use gtsr_render_kernels::shade::{ShadeMaps, ShadeParams, shade};
///
/// let device = Device::ndarray();
/// let ray = Tensor::<3>::from_floats([[[0.0, 0.0, 1.0]]], &device);
/// let maps = ShadeMaps {
///     normal: Tensor::from_floats([[[0.0, 0.0, -1.0]]], &device),
///     depth: Tensor::from_floats([[2.0]], &device),
///     coverage: Tensor::from_floats([[1.0]], &device),
///     base: Tensor::from_floats([[[0.5, 0.5, 0.5]]], &device),
///     roughness: Tensor::from_floats([[0.5]], &device),
///     scatter: None,
///     rays: ray,
/// };
/// let params = ShadeParams {
///     f0: 0.04, gamma: 0.3, min_roughness: 0.08, scatter_lambert: false, scatter_srgb: false,
/// };
/// let colour = shade(&maps, Tensor::from_floats([[4.0]], &device), params, false);
/// assert_eq!(colour.dims(), [1, 1, 3]);
/// ```
pub fn shade(
    maps: &ShadeMaps,
    light: Tensor<2>,
    params: ShadeParams,
    encode_srgb: bool,
) -> Tensor<3> {
    let device = maps.normal.device();
    let dtype = maps.normal.dtype();
    let mut dtypes = vec![
        maps.depth.dtype(),
        maps.coverage.dtype(),
        maps.base.dtype(),
        maps.roughness.dtype(),
        maps.rays.dtype(),
        light.dtype(),
    ];
    dtypes.extend(maps.scatter.as_ref().map(|s| s.dtype()));
    let fused = matches!(dtype, DType::F32 | DType::F64)
        && dtypes.iter().all(|d| *d == dtype)
        && on_ndarray(&device)
        && !maps.rays.is_require_grad();
    if !fused {
        return shade_by_tensor_ops(maps, light, params, encode_srgb);
    }
    let config = ShadeConfig {
        params,
        has_scatter: maps.scatter.is_some(),
        encode_srgb,
    };
    // Without a scattering map the op reads none; any tensor of the shape fills the slot.
    let scatter = maps
        .scatter
        .clone()
        .unwrap_or_else(|| maps.base.clone().detach());
    let inputs = ShadeInputs {
        normal: maps.normal.clone().into_dispatch(),
        depth: maps.depth.clone().into_dispatch(),
        coverage: maps.coverage.clone().into_dispatch(),
        base: maps.base.clone().into_dispatch(),
        roughness: maps.roughness.clone().into_dispatch(),
        scatter: scatter.into_dispatch(),
        light: light.reshape([1, 1]).into_dispatch(),
        rays: maps.rays.clone().detach().into_dispatch(),
    };
    Tensor::from_dispatch(<Dispatch as ShadeBackend>::shade_pixels(inputs, config))
}

/// [`shade`] in Burn tensor ops (any backend).
pub fn shade_by_tensor_ops(
    maps: &ShadeMaps,
    light: Tensor<2>,
    params: ShadeParams,
    encode_srgb: bool,
) -> Tensor<3> {
    shade_terms_by_tensor_ops(maps, light, params, encode_srgb).colour
}

/// The shading's terms, for inspection.
#[derive(Clone, Debug)]
pub struct ShadeTerms {
    /// `[H, W, 3]` the colour (sRGB-encoded when asked).
    pub colour: Tensor<3>,
    /// `[H, W]` the Fresnel term `F`.
    pub fresnel: Tensor<2>,
    /// `[H, W]` the specular term `F D G / (4 c^2) E`.
    pub specular: Tensor<2>,
}

/// [`shade`] in Burn tensor ops (any backend), with its Fresnel and specular terms.
pub fn shade_terms_by_tensor_ops(
    maps: &ShadeMaps,
    light: Tensor<2>,
    p: ShadeParams,
    encode_srgb: bool,
) -> ShadeTerms {
    let [h, w, _] = maps.normal.dims();
    let cover_div = maps.coverage.clone().clamp_min(COVER_MIN);
    let n_len = maps
        .normal
        .clone()
        .powf_scalar(2.0)
        .sum_dim(2)
        .clamp_min(NORMAL2_MIN)
        .sqrt();
    let n = maps.normal.clone() / n_len;
    let ray_len2 = maps
        .rays
        .clone()
        .powf_scalar(2.0)
        .sum_dim(2)
        .reshape([h, w]);
    let v = maps.rays.clone().neg() / ray_len2.clone().sqrt().reshape([h, w, 1]);
    let c = (n * v).sum_dim(2).reshape([h, w]).clamp(COS_MIN, 1.0);
    let r = (maps.roughness.clone() / cover_div.clone()).clamp(p.min_roughness, 1.0);
    let a2 = r.clone().powi_scalar(4);
    let c2 = c.clone() * c.clone();
    let denom = (a2.clone() - 1.0) * c2.clone() + 1.0;
    let d = a2 / (denom.clone() * denom * std::f64::consts::PI);
    let k = (r + 1.0).powi_scalar(2) / 8.0;
    let g1 = c.clone() / (c.clone() * (k.clone().neg() + 1.0) + k);
    let geo = g1.clone() * g1;
    let f = schlick(c.clone(), p.f0);
    let dist2 = (maps.depth.clone() * maps.depth.clone() * ray_len2).clamp_min(DIST2_MIN);
    let radiance = light.reshape([1, 1]) / dist2;
    let spec = f.clone() * d * geo / (c2 * 4.0) * radiance.clone();
    let base = maps.base.clone() / cover_div.reshape([h, w, 1]);
    let diffuse =
        base * (f.clone() * f.clone() * radiance.clone() / std::f64::consts::PI).reshape([h, w, 1]);
    let cov = maps.coverage.clone().reshape([h, w, 1]);
    let mut colour = (diffuse * p.gamma + spec.clone().reshape([h, w, 1])) * cov.clone();
    if let Some(s) = &maps.scatter {
        let mut s = if p.scatter_srgb {
            srgb_to_linear(s.clone())
        } else {
            s.clone()
        };
        if p.scatter_lambert {
            let lit = (c * radiance - 1.0) * maps.coverage.clone() + 1.0;
            s = s * lit.reshape([h, w, 1]);
        }
        colour = colour + s * ((f.clone().reshape([h, w, 1]) * cov).neg() + 1.0);
    }
    ShadeTerms {
        colour: if encode_srgb {
            linear_to_srgb(colour)
        } else {
            colour
        },
        fresnel: f,
        specular: spec,
    }
}

/// Schlick's approximation `F0 + (1 - F0) (1 - c)^5` for `c` in `[0, 1]` (clamped).
pub fn schlick<const D: usize>(cos: Tensor<D>, f0: f64) -> Tensor<D> {
    let m = (cos.clamp(0.0, 1.0).neg() + 1.0).powi_scalar(5);
    m * (1.0 - f0) + f0
}

/// The sRGB transfer curve (IEC 61966-2-1) on linear values, with the input clamped to
/// `[0, 1]` and the linear toe, so its gradient is bounded.
pub fn linear_to_srgb<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    let x = x.clamp(0.0, 1.0);
    let low = x.clone() * 12.92;
    let high = x.clone().clamp_min(SRGB_ENCODE_TOE).powf_scalar(1.0 / 2.4) * 1.055 - 0.055;
    let is_low = x.lower_equal_elem(SRGB_ENCODE_TOE);
    high.mask_where(is_low, low)
}

/// The inverse of [`linear_to_srgb`] on `[0, 1]`, extended past 1 by the same power; negative
/// inputs give 0. Its gradient is bounded on any bounded input.
pub fn srgb_to_linear<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    let x = x.clamp_min(0.0);
    let low = x.clone() / 12.92;
    let high = ((x.clone() + 0.055) / 1.055).powf_scalar(2.4);
    let is_low = x.lower_equal_elem(SRGB_DECODE_TOE);
    high.mask_where(is_low, low)
}
