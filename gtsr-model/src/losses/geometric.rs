//! PGSR's geometric terms for the surface set: the single-view depth-normal consistency, the
//! multi-view forward-backward reprojection error with a neighbour view, and (opt-in; the
//! GTSR paper leaves it out) the multi-view photometric consistency of patches carried into
//! the neighbour by the rendered plane.

use burn::tensor::{Bool, Int, Tensor, TensorData};

use gtsr_render_kernels::Camera;

use crate::geometry::{camera_tensors, normals_from_depth};
use crate::layout;

/// Single-view term: `sum_p w(p) |N_d(p) - N(p)|_1 / #valid`, with `N_d` the normal of the
/// depth map, `N` the rendered normal (normalised) and `w` the edge weight of the ground truth.
pub fn single_view(
    depth: &Tensor<2>,
    normal: &Tensor<3>,
    rays: &Tensor<3>,
    valid: &Tensor<2, Bool>,
    edge_weight: &Tensor<2>,
) -> Tensor<1> {
    let [h, w] = depth.dims();
    let (nd, inner) = normals_from_depth(depth, rays, valid);
    let len = normal
        .clone()
        .powf_scalar(2.0)
        .sum_dim(2)
        .clamp_min(1e-12)
        .sqrt();
    let n = normal.clone() / len;
    let diff = (nd - n).abs().sum_dim(2).reshape([h, w]);
    let weight = inner.clone() * edge_weight.clone();
    let count = inner.sum().clamp_min(1.0);
    (diff * weight).sum() / count
}

/// What the multi-view term measured.
#[derive(Clone, Debug)]
pub struct MultiViewTerm {
    /// The loss `mean_valid(exp(-phi) phi)`, weights detached.
    pub loss: Tensor<1>,
    /// Number of pixels that entered it.
    pub valid: usize,
    /// Their mean reprojection error in pixels.
    pub mean_error_px: f64,
    /// `[H * W]` each reference pixel's weight `exp(-phi)` (detached), 0 where left out: the
    /// pixels [`multi_view_ncc`] may compare, as PGSR takes them.
    pub pixel_weights: Tensor<1>,
}

fn pixel_grid(w: usize, h: usize, device: &burn::tensor::Device) -> (Tensor<1>, Tensor<1>) {
    let mut u = Vec::with_capacity(w * h);
    let mut v = Vec::with_capacity(w * h);
    for j in 0..h {
        for i in 0..w {
            u.push(i as f32 + 0.5);
            v.push(j as f32 + 0.5);
        }
    }
    (
        Tensor::from_data(TensorData::new(u, [w * h]), device),
        Tensor::from_data(TensorData::new(v, [w * h]), device),
    )
}

fn project(x: &Tensor<2>, cam: &Camera, near: f64) -> (Tensor<1>, Tensor<1>, Tensor<1>) {
    let z = layout::col(x, 2);
    let zc = z.clone().clamp_min(near);
    let u = layout::col(x, 0) / zc.clone() * cam.fx + cam.cx;
    let v = layout::col(x, 1) / zc * cam.fy + cam.cy;
    (u, v, z)
}

/// Both cameras' world-to-camera rotations and translations as tensors of `dtype`:
/// `[R_r, t_r, R_n, t_n]` ([`camera_tensors`]).
fn camera_pair(
    cam_r: &Camera,
    cam_n: &Camera,
    device: &burn::tensor::Device,
    dtype: burn::tensor::DType,
) -> [Tensor<2>; 4] {
    let (rr, tr) = camera_tensors(cam_r, device);
    let (rn, tn) = camera_tensors(cam_n, device);
    [rr, tr, rn, tn].map(|t| t.cast(dtype))
}

/// The samples at pixel positions `(u, v)` within the centres of an `[h, w]` image (where a
/// bilinear sample has its four corners) and at `z` beyond `near`; not differentiated.
fn on_image(
    u: &Tensor<1>,
    v: &Tensor<1>,
    z: &Tensor<1>,
    [h, w]: [usize; 2],
    near: f64,
) -> Tensor<1, Bool> {
    let (u, v) = (u.clone().detach(), v.clone().detach());
    u.clone()
        .greater_equal_elem(0.5)
        .bool_and(u.lower_equal_elem(w as f64 - 0.5))
        .bool_and(v.clone().greater_equal_elem(0.5))
        .bool_and(v.lower_equal_elem(h as f64 - 0.5))
        .bool_and(z.clone().detach().greater_elem(near))
}

/// Bilinear sample of `map` `[H, W]` at continuous pixel positions (centres at `i + 0.5`),
/// differentiable in the map values and the positions; also returns the four corner indices.
fn bilinear(
    map: &Tensor<2>,
    u: &Tensor<1>,
    v: &Tensor<1>,
) -> (Tensor<1>, [Tensor<1, Int>; 4], [Tensor<1>; 4]) {
    let [h, w] = map.dims();
    let x = u.clone() - 0.5;
    let y = v.clone() - 0.5;
    let x0 = x.clone().detach().floor().clamp(0.0, (w - 2) as f64);
    let y0 = y.clone().detach().floor().clamp(0.0, (h - 2) as f64);
    let fx = (x - x0.clone()).clamp(0.0, 1.0);
    let fy = (y - y0.clone()).clamp(0.0, 1.0);
    let xi = x0.int();
    let yi = y0.int();
    let i00 = yi.clone() * (w as i64) + xi.clone();
    let i10 = i00.clone() + 1;
    let i01 = i00.clone() + (w as i64);
    let i11 = i01.clone() + 1;
    let flat = map.clone().reshape([h * w]);
    let g = |i: &Tensor<1, Int>| flat.clone().gather(0, i.clone());
    let wts = [
        (fx.clone().neg() + 1.0) * (fy.clone().neg() + 1.0),
        fx.clone() * (fy.clone().neg() + 1.0),
        (fx.clone().neg() + 1.0) * fy.clone(),
        fx * fy,
    ];
    let val = g(&i00) * wts[0].clone()
        + g(&i10) * wts[1].clone()
        + g(&i01) * wts[2].clone()
        + g(&i11) * wts[3].clone();
    (val, [i00, i10, i01, i11], wts)
}

/// Multi-view geometric term between a reference view and a neighbour.
///
/// Each reference pixel's unbiased-depth point is carried into the neighbour, the neighbour's
/// depth is sampled there (bilinear), and that point is carried back; `phi` is the distance in
/// pixels to where it started. Pixels that leave the neighbour's image, fall behind its camera,
/// land on its invalid pixels or have `phi >= max_error_px` are left out; the rest are weighted
/// by `exp(-phi)` (detached), as PGSR does. Gradients reach both depth maps.
#[allow(clippy::too_many_arguments)]
pub fn multi_view(
    depth_r: &Tensor<2>,
    rays_r: &Tensor<3>,
    valid_r: &Tensor<2, Bool>,
    cam_r: &Camera,
    depth_n: &Tensor<2>,
    valid_n: &Tensor<2, Bool>,
    cam_n: &Camera,
    max_error_px: f64,
) -> MultiViewTerm {
    let [h, w] = depth_r.dims();
    let m = h * w;
    let device = depth_r.device();
    let dtype = depth_r.dtype();
    let [rr, tr, rn, tn] = camera_pair(cam_r, cam_n, &device, dtype);
    let xr = rays_r.clone().reshape([m, 3]) * depth_r.clone().reshape([m, 1]);
    let xw = (xr - tr.clone()).matmul(rr.clone());
    let xn = xw.matmul(rn.clone().transpose()) + tn.clone();
    let (un, vn, zn) = project(&xn, cam_n, cam_n.near);
    let [hn, wn] = depth_n.dims();
    let (dn, corners, _) = bilinear(depth_n, &un, &vn);
    let vflat = valid_n.clone().float().cast(dtype).reshape([hn * wn]);
    let corner_valid = corners
        .iter()
        .map(|i| vflat.clone().gather(0, i.clone()))
        .reduce(|a, b| a * b)
        .expect("four corners");
    let ray_n = layout::cat_cols(vec![
        ((un.clone() - cam_n.cx) / cam_n.fx).reshape([m, 1]),
        ((vn.clone() - cam_n.cy) / cam_n.fy).reshape([m, 1]),
        Tensor::ones([m, 1], (&device, dtype)),
    ]);
    let xn2 = ray_n * dn.reshape([m, 1]);
    let xw2 = (xn2 - tn).matmul(rn);
    let xr2 = xw2.matmul(rr.transpose()) + tr;
    let (ur2, vr2, zr2) = project(&xr2, cam_r, cam_r.near);
    let (u0, v0) = pixel_grid(w, h, &device);
    let (u0, v0) = (u0.cast(dtype), v0.cast(dtype));
    let phi = ((ur2 - u0).powf_scalar(2.0) + (vr2 - v0).powf_scalar(2.0) + 1e-12).sqrt();
    let inside = on_image(&un, &vn, &zn, [hn, wn], cam_n.near)
        .bool_and(zr2.detach().greater_elem(cam_r.near));
    let keep = inside
        .bool_and(corner_valid.greater_elem(0.5))
        .bool_and(valid_r.clone().reshape([m]))
        .bool_and(phi.clone().detach().lower_elem(max_error_px));
    let keepf = keep.float().cast(dtype);
    let count = keepf.clone().sum().into_scalar::<f64>();
    let weight = phi.clone().detach().neg().exp() * keepf.clone();
    let mean_error_px = if count > 0.0 {
        (phi.clone().detach() * keepf).sum().into_scalar::<f64>() / count
    } else {
        0.0
    };
    let loss = (weight.clone() * phi).sum() / count.max(1.0);
    MultiViewTerm {
        loss,
        valid: count as usize,
        mean_error_px,
        pixel_weights: weight,
    }
}

/// Half the side of [`multi_view_ncc`]'s patches (PGSR's 7x7).
pub const NCC_HALF: usize = 3;

/// [`multi_view_ncc`] leaves out the patches whose `1 - cc^2` is this or more: untextured, or
/// matched nowhere near (PGSR's threshold).
pub const NCC_MAX: f64 = 0.9;

/// What the multi-view photometric term measured.
#[derive(Clone, Debug)]
pub struct NccTerm {
    /// The loss: the weighted mean of `1 - cc^2` over the patches kept.
    pub loss: Tensor<1>,
    /// Patches kept.
    pub patches: usize,
    /// Their mean `1 - cc^2`.
    pub mean: f64,
}

/// Grey `[H, W]` of an `[H, W, 3]` image (Rec. 601 luma weights, as PGSR).
pub fn grey(rgb: &Tensor<3>) -> Tensor<2> {
    let c = |k: usize| layout::channel(rgb, k);
    c(0) * 0.299 + c(1) * 0.587 + c(2) * 0.114
}

/// PGSR's multi-view photometric consistency (which the GTSR paper leaves out): each chosen
/// reference pixel's rendered plane (through its unbiased-depth point, with its normal)
/// carries the `(2 NCC_HALF + 1)^2` patch around the pixel into the neighbour, where
/// `grey_n` is sampled (bilinear); the loss is `1 - cc^2` of the two patches' normalised
/// cross-correlation, weighted per pixel, over the patches that stay inside the neighbour in
/// front of its camera, whose rays meet the plane at a cosine of at least 0.05, and whose
/// `1 - cc^2` is below [`NCC_MAX`]. Gradients reach the reference depth and normal maps only.
///
/// `pixels`: `(index into the reference's H * W, weight)`; those within `NCC_HALF` of the
/// border are skipped. `normal_r` may be premultiplied by coverage (it is normalised).
#[allow(clippy::too_many_arguments)]
pub fn multi_view_ncc(
    depth_r: &Tensor<2>,
    normal_r: &Tensor<3>,
    grey_r: &Tensor<2>,
    cam_r: &Camera,
    grey_n: &Tensor<2>,
    cam_n: &Camera,
    pixels: &[(usize, f32)],
) -> NccTerm {
    let [h, w] = depth_r.dims();
    let device = depth_r.device();
    let dtype = depth_r.dtype();
    let side = 2 * NCC_HALF + 1;
    let per = side * side;
    let half = NCC_HALF as i64;
    let inner = |i: usize, n: usize| i >= NCC_HALF && i + NCC_HALF < n;
    let chosen: Vec<(usize, f32)> = pixels
        .iter()
        .copied()
        .filter(|(k, _)| *k < h * w && inner(k % w, w) && inner(k / w, h))
        .collect();
    let s = chosen.len();
    if s == 0 {
        return NccTerm {
            loss: Tensor::zeros([1], (&device, dtype)),
            patches: 0,
            mean: 0.0,
        };
    }
    let ray = |u: f64, v: f64| {
        [
            ((u - cam_r.cx) / cam_r.fx) as f32,
            ((v - cam_r.cy) / cam_r.fy) as f32,
            1.0f32,
        ]
    };
    let (mut centres, mut weights, mut rays_p) = (Vec::new(), Vec::new(), Vec::new());
    let (mut patch_idx, mut rays_q) =
        (Vec::with_capacity(s * per), Vec::with_capacity(s * per * 3));
    for (k, wt) in &chosen {
        let (i, j) = ((k % w) as i64, (k / w) as i64);
        centres.push(*k as i64);
        weights.push(*wt);
        rays_p.extend(ray(i as f64 + 0.5, j as f64 + 0.5));
        for dj in -half..=half {
            for di in -half..=half {
                let (qi, qj) = (i + di, j + dj);
                patch_idx.push(qj * w as i64 + qi);
                rays_q.extend(ray(qi as f64 + 0.5, qj as f64 + 0.5));
            }
        }
    }
    let float = |v: Vec<f32>, shape: Vec<usize>| {
        Tensor::<1>::from_data(
            TensorData::new(v, [shape.iter().product::<usize>()]),
            &device,
        )
        .cast(dtype)
    };
    let int = |v: Vec<i64>| {
        let n = v.len();
        Tensor::<1, Int>::from_data(TensorData::new(v, [n]), &device)
    };
    let m = h * w;
    let idx = int(centres);
    let d = depth_r.clone().reshape([m]).select(0, idx.clone());
    let nrm = normal_r.clone().reshape([m, 3]).select(0, idx);
    let len = nrm
        .clone()
        .powf_scalar(2.0)
        .sum_dim(1)
        .clamp_min(1e-12)
        .sqrt();
    let n = nrm / len;
    let xp = float(rays_p, vec![s, 3]).reshape([s, 3]) * d.reshape([s, 1]);
    let num = (n.clone() * xp).sum_dim(1);
    let n_q = n
        .reshape([s, 1, 3])
        .repeat_dim(1, per)
        .reshape([s * per, 3]);
    let num_q = num.reshape([s, 1]).repeat_dim(1, per).reshape([s * per, 1]);
    let rays_q = float(rays_q, vec![s * per, 3]).reshape([s * per, 3]);
    let ray_len = rays_q.clone().powf_scalar(2.0).sum_dim(1).sqrt();
    let den = (n_q * rays_q.clone()).sum_dim(1);
    // The rays that meet the plane at a grazing angle (or behind it) carry nothing.
    let grazing = (den.clone().detach().neg() / ray_len).lower_elem(0.05);
    let den = den.mask_fill(grazing.clone(), -1.0);
    let xq = rays_q * (num_q / den);
    let [rr, tr, rn, tn] = camera_pair(cam_r, cam_n, &device, dtype);
    let xn = (xq - tr).matmul(rr).matmul(rn.transpose()) + tn;
    let (un, vn, zn) = project(&xn, cam_n, cam_n.near);
    let [hn, wn] = grey_n.dims();
    let (b, _, _) = bilinear(grey_n, &un, &vn);
    let a = grey_r
        .clone()
        .detach()
        .reshape([m])
        .gather(0, int(patch_idx));
    let inside = on_image(&un, &vn, &zn, [hn, wn], cam_n.near)
        .bool_and(grazing.reshape([s * per]).bool_not());
    let patch_ok = inside
        .float()
        .cast(dtype)
        .reshape([s, per])
        .min_dim(1)
        .reshape([s]);
    let (a, b) = (a.reshape([s, per]), b.reshape([s, per]));
    let mean = |x: Tensor<2>| x.mean_dim(1).reshape([s]);
    let (ma, mb) = (mean(a.clone()), mean(b.clone()));
    let cov = mean(a.clone() * b.clone()) - ma.clone() * mb.clone();
    let va = mean(a.clone() * a) - ma.clone() * ma;
    let vb = mean(b.clone() * b) - mb.clone() * mb;
    let cc2 = cov.powf_scalar(2.0) / (va * vb + 1e-8);
    let ncc = (cc2.neg() + 1.0).clamp(0.0, 2.0);
    let keep = patch_ok * ncc.clone().detach().lower_elem(NCC_MAX).float().cast(dtype);
    let patches = keep.clone().sum().into_scalar::<f64>();
    let mean_ncc = if patches > 0.0 {
        (ncc.clone().detach() * keep.clone())
            .sum()
            .into_scalar::<f64>()
            / patches
    } else {
        0.0
    };
    let loss = (ncc * keep * float(weights, vec![s])).sum() / patches.max(1.0);
    NccTerm {
        loss,
        patches: patches as usize,
        mean: mean_ncc,
    }
}

/// Interior containment `L_in`: interior Gaussians whose camera depth is smaller than the
/// surface depth at their projected pixel (they sit outside the surface) are pulled back by
/// `D[p] - d_i`; averaged over the whole interior set. The surface depth is not moved by it.
pub fn interior_containment(
    means: &Tensor<2>,
    cam: &Camera,
    depth: &Tensor<2>,
    valid: &Tensor<2, Bool>,
) -> Tensor<1> {
    let n = means.dims()[0];
    let [h, w] = depth.dims();
    let dtype = means.dtype();
    let (r, t) = camera_tensors(cam, &means.device());
    let pc = means.clone().matmul(r.cast(dtype).transpose()) + t.cast(dtype);
    let (u, v, z) = project(&pc, cam, cam.near);
    let on_screen = u
        .clone()
        .detach()
        .greater_equal_elem(0.0)
        .bool_and(u.clone().detach().lower_elem(w as f64))
        .bool_and(v.clone().detach().greater_equal_elem(0.0))
        .bool_and(v.clone().detach().lower_elem(h as f64))
        .bool_and(z.clone().detach().greater_elem(cam.near));
    let idx = crate::geometry::nearest_index(u.detach(), v.detach(), w, h);
    let d_at = depth
        .clone()
        .detach()
        .reshape([h * w])
        .gather(0, idx.clone());
    let ok = valid
        .clone()
        .float()
        .cast(dtype)
        .reshape([h * w])
        .gather(0, idx)
        * on_screen.float().cast(dtype);
    ((d_at - z).clamp_min(0.0) * ok).sum() / (n.max(1) as f64)
}
