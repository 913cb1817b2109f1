//! Regularisers: edge-aware material smoothness, flattening, mask supervision, opacity
//! binarisation and layer spread.

use burn::tensor::ops::PadMode;
use burn::tensor::{Bool, Tensor};

/// Edge-aware smoothness (Relightable 3DGS): mean over pixel pairs inside the mask of
/// `|grad M| * exp(-|grad I_gt|)`, with precomputed `[H, W-1]` / `[H-1, W]` weights (the
/// exponential times the mask of both pixels). `map` is `[H, W, C]`.
pub fn edge_aware_smoothness(map: &Tensor<3>, wx: &Tensor<2>, wy: &Tensor<2>) -> Tensor<1> {
    let [h, w, c] = map.dims();
    let m = h * w;
    // Pixels in row-major order: x neighbours are one row of the list apart, y neighbours w
    // rows (differences of contiguous row ranges). The x pairs that wrap from one image row to
    // the next get weight 0.
    let px = map.clone().reshape([m, c]);
    let mean_abs = |d: Tensor<2>, len: usize| d.abs().sum_dim(1).reshape([len]) / c as f64;
    let gx = mean_abs(
        crate::layout::rows(&px, 1..m) - crate::layout::rows(&px, 0..m - 1),
        m - 1,
    );
    let gy = mean_abs(
        crate::layout::rows(&px, w..m) - crate::layout::rows(&px, 0..m - w),
        m - w,
    );
    let wx_rows = crate::layout::rows(
        &wx.clone()
            .pad([(0, 0), (0, 1)], PadMode::Constant(0.0))
            .reshape([m]),
        0..m - 1,
    );
    let wy_rows = wy.clone().reshape([m - w]);
    let count = (wx.clone().sum() + wy.clone().sum()).clamp_min(1.0);
    ((gx * wx_rows).sum() + (gy * wy_rows).sum()) / count
}

/// PGSR flattening: the mean of each Gaussian's smallest scale.
pub fn flatten(scales: &Tensor<2>) -> Tensor<1> {
    scales.clone().min_dim(1).mean()
}

/// Mean `|alpha - mask|`.
pub fn mask_l1(alpha: &Tensor<2>, mask: &Tensor<2>) -> Tensor<1> {
    (alpha.clone() - mask.clone()).abs().mean()
}

/// 1 where a pixel lies more than `band` pixels from the silhouette, 0 within it (`edge_px`:
/// [`crate::views::mask_edge_distance`]): the pixels the banded mask and image terms keep.
pub fn outside_band(edge_px: &Tensor<2>, band: f64) -> Tensor<2> {
    edge_px.clone().greater_elem(band).float()
}

/// [`mask_l1`] with the pixels within `band` pixels of the silhouette left out (`edge_px`:
/// [`crate::views::mask_edge_distance`]); still the mean over every pixel, so that the term's
/// scale does not depend on the band. There a surface Gaussian that lies on the surface but is
/// seen at a grazing angle spills part of its footprint past the silhouette, and the plain term
/// pulls it inward and fades it.
pub fn mask_l1_outside_band(
    alpha: &Tensor<2>,
    mask: &Tensor<2>,
    edge_px: &Tensor<2>,
    band: f64,
) -> Tensor<1> {
    ((alpha.clone() - mask.clone()).abs() * outside_band(edge_px, band)).mean()
}

/// [`mask_l1_outside_band`], with the pixels within `band` pixels of the silhouette kept by a
/// hinge at 0.5 instead of left out: there the rendered coverage need only lie on the mask's
/// side of 0.5 (`max(0.5 - alpha, 0)` where the mask is at least 0.5, `max(alpha - 0.5, 0)`
/// where it is below). The silhouette's 0.5 crossing stays between the mask's own pixel
/// centres, while the width of the rendered edge (the splats' tails past a surface layer
/// seen at a grazing angle) is free.
pub fn mask_l1_band_hinge(
    alpha: &Tensor<2>,
    mask: &Tensor<2>,
    edge_px: &Tensor<2>,
    band: f64,
) -> Tensor<1> {
    let keep = outside_band(edge_px, band);
    let in_band = keep.clone().neg() + 1.0;
    // -1 where the mask is at least 0.5, +1 below: `(alpha - 0.5) side` is how far the
    // coverage lies on the wrong side of 0.5.
    let side = mask.clone().greater_equal_elem(0.5).float() * -2.0 + 1.0;
    let hinge = ((alpha.clone() - 0.5) * side).clamp_min(0.0);
    ((alpha.clone() - mask.clone()).abs() * keep + hinge * in_band).mean()
}

/// Mean `max(mask - alpha, 0)`: only missing coverage inside the mask counts, not coverage
/// spilling past it (which a Gaussian centred on the surface does in grazing views).
pub fn mask_deficit(alpha: &Tensor<2>, mask: &Tensor<2>) -> Tensor<1> {
    (mask.clone() - alpha.clone()).clamp_min(0.0).mean()
}

/// Opacity binarisation: the mean over Gaussians of the binary entropy of their opacities,
/// `-(o ln o + (1 - o) ln(1 - o))` with `o = logistic(logits)` (in nats; 0 when every opacity
/// is 0 or 1, `ln 2` at 0.5). Its gradient on a logit `x` is `-x o (1 - o)`, so descent
/// pushes each opacity away from 0.5 towards the nearer end: with the mask term asking for
/// full coverage, a stack of faint layers gives way to one opaque layer and transparent ones
/// that densification prunes. Written in logits (`ln o = -softplus(-x)`), with the logits
/// clamped to `[-30, 30]` (where the entropy is below 1e-11), finite for any logit.
pub fn opacity_entropy(logits: &Tensor<2>) -> Tensor<1> {
    let x = logits.clone().clamp(-30.0, 30.0);
    let o = crate::gaussians::logistic(x.clone());
    // softplus(x) = ln(1 + e^x), computed stably as max(x, 0) + ln(1 + e^-|x|).
    let softplus = |t: Tensor<2>| t.clone().clamp_min(0.0) + (t.abs().neg().exp() + 1.0).log();
    // -ln o = softplus(-x), -ln(1 - o) = softplus(x).
    let h = o.clone() * softplus(x.clone().neg()) + (o.neg() + 1.0) * softplus(x);
    h.mean()
}

/// Opacity sparsity (not in the paper; 3DGS-MCMC's opacity regulariser): the mean opacity
/// `logistic(x)` of a set. Its gradient on a logit is `o (1 - o) / n`, small against what the
/// image, mask and geometric terms give the Gaussians they see; but under Adam (per-parameter
/// step sizes, epsilon 1e-15) a Gaussian that no other term reaches, a layer hidden behind
/// the front of the surface, fades at the full opacity rate, so what survives is what some
/// term needs. Logits are clamped to `[-30, 30]`, finite for any input.
pub fn opacity_l1(logits: &Tensor<2>) -> Tensor<1> {
    crate::gaussians::logistic(logits.clone().clamp(-30.0, 30.0)).mean()
}

/// The transmittance at which [`front_depth`]'s target is taken: the depth of the surface splat
/// whose blend first takes a pixel's transmittance to 0.9 or below.
pub const FRONT_TRANSMITTANCE: f64 = 0.9;

/// Front-layer depth (not in the paper): the mean over the `valid` pixels of `|D - D_front|`
/// in pixel footprints (`D_front / f`), with `D` the blended depth and `D_front` a constant:
/// the depth at which the surface set's transmittance first falls to [`FRONT_TRANSMITTANCE`]
/// ([`crate::model::Model::render_depth_crossing`]). A stack of faint layers blends a depth
/// behind its front; rendered with only the opacities differentiable
/// ([`crate::model::Model::render_depth_weights`]), descent makes the front layer more opaque
/// and fades the layers behind it, so that the blend becomes one layer where its front is.
/// (With the positions free it would draw every layer forward, the front with them, and the
/// front it is measured against would run away.) Pixels with a non-finite or non-positive
/// front depth do not count.
pub fn front_depth(
    depth: &Tensor<2>,
    front: &Tensor<2>,
    focal: f64,
    valid: &Tensor<2, Bool>,
) -> Tensor<1> {
    footprint_gap(depth, front, focal, valid)
}

/// The mean over the `valid` pixels where the reference depth `R` (detached) is finite and
/// positive of `|D - R|` in pixel footprints (`R / f`): the measure [`front_depth`],
/// [`hull_depth`] and [`interior_front`] share.
fn footprint_gap(
    depth: &Tensor<2>,
    reference: &Tensor<2>,
    focal: f64,
    valid: &Tensor<2, Bool>,
) -> Tensor<1> {
    let reference = reference.clone().detach();
    let usable = valid
        .clone()
        .bool_and(reference.clone().is_finite())
        .bool_and(reference.clone().greater_elem(0.0));
    let gap = signed_footprints(depth.clone(), reference, focal)
        .abs()
        .mask_fill(usable.clone().bool_not(), 0.0);
    let count = usable.float().sum().clamp_min(1.0);
    gap.sum() / count
}

/// `D - R` in pixel footprints at the reference depth (`R / f`, `R` clamped at 1e-6).
fn signed_footprints(depth: Tensor<2>, reference: Tensor<2>, focal: f64) -> Tensor<2> {
    let scale = reference.clone().clamp_min(1e-6).recip() * focal;
    (depth - reference) * scale
}

/// How far apart, in pixel footprints, the blended depth and the masks' bound's depth may lie
/// for [`hull_depth`] to count a pixel: farther, the view looks into a concavity the masks
/// cannot see (or the depth is not a surface there yet), and the bound says nothing.
pub const HULL_DEPTH_BAND: f64 = 3.0;

/// Hull depth (not in the paper): the mean, over the `valid` pixels where the masks' bound
/// has a depth `H > 0` and the blended depth `D` lies within [`HULL_DEPTH_BAND`] footprints
/// of it, of `|D - H|` in footprints (`H / f`). Where the object is flush with the masks'
/// hull (most of a convex-ish object's surface) the bound is the surface to a fraction of a
/// footprint, and this asks the surface set's blended depth to be there rather than behind
/// it; where the two lie farther apart it leaves the depth free. Which pixels count is
/// decided on the detached depth.
///
/// With `occluders` (the bound's depth at a neighbour in front of an occluding edge of the
/// bound, `0` elsewhere; `gtsr_mesh::raycast::MeshDepth::occluders` gives them) a pixel also counts, still
/// against `H`, where `D` lies within the band of that occluder's depth: the nearer surface
/// spills past the edge onto a pixel that the bound places behind it.
pub fn hull_depth(
    depth: &Tensor<2>,
    hull: &Tensor<2>,
    occluders: Option<&Tensor<2>>,
    focal: f64,
    valid: &Tensor<2, Bool>,
) -> Tensor<1> {
    let hull = hull.clone().detach();
    let detached = depth.clone().detach();
    // A NaN gap compares false: such a pixel does not count.
    let within = |reference: Tensor<2>| {
        signed_footprints(detached.clone(), reference.clone(), focal)
            .abs()
            .lower_elem(HULL_DEPTH_BAND)
            .bool_and(reference.greater_elem(0.0))
    };
    let mut near = within(hull.clone());
    if let Some(o) = occluders {
        near = near.bool_or(within(o.clone().detach()));
    }
    footprint_gap(depth, &hull, focal, &valid.clone().bool_and(near))
}

/// How far, in pixel footprints, the interior set's front may lie behind the surface set's
/// blended depth before [`interior_front`] counts a pixel.
pub const INTERIOR_FRONT_BAND: f64 = 3.0;

/// The interior set's transmittance at which [`interior_front`] reads its front
/// ([`crate::model::Model::render_interior_front`]).
pub const INTERIOR_FRONT_TRANSMITTANCE: f64 = 0.5;

/// Interior front (not in the paper): the mean, over the `valid` pixels where the interior
/// set's front `F` (detached; the depth of the interior splat at which the interior set's
/// transmittance first falls to [`INTERIOR_FRONT_TRANSMITTANCE`]) lies more than
/// [`INTERIOR_FRONT_BAND`] footprints behind the surface set's blended depth `D`, of
/// `|D - F|` in footprints (`F / f`). The surface is the boundary of the scattering medium:
/// the interior containment keeps the medium behind the surface, and this keeps the surface
/// from floating in front of the medium over an empty gap, such as a lid over a cup whose
/// inside the interior set paints from where the views place it. Which pixels count is
/// decided on the detached depth.
pub fn interior_front(
    depth: &Tensor<2>,
    front: &Tensor<2>,
    focal: f64,
    valid: &Tensor<2, Bool>,
) -> Tensor<1> {
    let front = front.clone().detach();
    // A NaN gap compares false: such a pixel does not count.
    let behind = signed_footprints(depth.clone().detach(), front.clone(), focal)
        .lower_elem(-INTERIOR_FRONT_BAND)
        .bool_and(front.clone().greater_elem(0.0));
    footprint_gap(depth, &front, focal, &valid.clone().bool_and(behind))
}

/// Softening of [`layer_spread`]'s square root, in pixels: keeps its gradient bounded where
/// the spread is 0.
pub const LAYER_SPREAD_EPS_PX: f64 = 0.05;

/// Layer spread: the mean over the `valid` pixels of `sqrt(var (z f)^2 + e^2) - e`, with `var`
/// the inverse-depth variance of the blend ([`crate::model::GeometryMaps::spread`]), `z` the
/// rendered depth (detached), `f` the focal length in pixels and `e` =
/// [`LAYER_SPREAD_EPS_PX`]: the standard deviation of the depths at which the blended splats
/// cross the pixel's ray (about `z^2 sqrt(var)`), in pixel footprints (`z / f`). 0 when every
/// pixel blends one layer.
pub fn layer_spread(
    spread: &Tensor<2>,
    depth: &Tensor<2>,
    focal: f64,
    valid: &Tensor<2, Bool>,
) -> Tensor<1> {
    let e = LAYER_SPREAD_EPS_PX;
    let scale = depth.clone().detach().clamp_min(1e-6) * focal;
    let px2 = spread.clone() * scale.powi_scalar(2);
    let std_px = (px2 + e * e).sqrt() - e;
    let inner = valid.clone().float();
    let count = inner.clone().sum().clamp_min(1.0);
    (std_px * inner).sum() / count
}
