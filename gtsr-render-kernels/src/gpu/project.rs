//! Projection of 3D Gaussians to screen-space conics (EWA splatting) and its vector-Jacobian
//! product, one thread per Gaussian: the CubeCL counterparts of the CPU's `project_one` and
//! `project_vjp`, sharing `project_core`.

// Kernel code is CubeCL's dialect of Rust: `div_ceil` is written out on purpose.
#![allow(clippy::manual_div_ceil)]

use burn_cubecl::cubecl;
use cubecl::prelude::*;

use super::common::{ALPHA_MIN, PROJ, ranked};
use crate::antialias::MIN_COMPENSATION;
use crate::config::TILE_SIZE;

const QUAT_MIN_NORM2: f32 = 1e-8;
/// The least ratio of the blur's compensation, `MIN_COMPENSATION^2`.
const MIN_RATIO: f32 = (MIN_COMPENSATION * MIN_COMPENSATION) as f32;

// Layout of the intermediate values of the projection (`core`).
const QN: usize = 0; // 4
const QNORM: usize = 4;
const RQ: usize = 5; // 9
const SC: usize = 14; // 9, Sigma_c
const P: usize = 23; // 3
const TX: usize = 26;
const TY: usize = 27;
const CLX: usize = 28;
const CLY: usize = 29;
const J00: usize = 30;
const J02: usize = 31;
const J11: usize = 32;
const J12: usize = 33;
const COV: usize = 34; // 3
const CON: usize = 37; // 3
const RAW: usize = 40; // 2, the covariance's diagonal without the blur
const RATIO: usize = 42; // det(cov - blur) / det(cov), 1 without compensation
const COMP: usize = 43; // the opacity's factor, sqrt of the clamped ratio
/// Size of the `core` array.
const CORE: usize = 44;

/// Whether `x` is neither infinite nor NaN, from its bits (robust to fast-math compilers).
#[cube]
fn finite(x: f32) -> bool {
    (u32::reinterpret(x) & 0x7f80_0000u32) != 0x7f80_0000u32
}

#[cube]
fn clampf(x: f32, lo: f32, hi: f32) -> f32 {
    let a = select(x < lo, lo, x);
    select(a > hi, hi, a)
}

/// The projection up to the conic (the CPU's `project_core`). Returns the status: 0 when the
/// splat survives, else `CLIPPED` (1), `NON_FINITE` (2) or `DEGENERATE` (3).
#[cube]
fn project_core(
    means: &[f32],
    quats: &[f32],
    scales: &[f32],
    opacities: &[f32],
    offsets: &[f32],
    cam: &[f32],
    i: u32,
    out: &mut Array<f32>,
) -> u32 {
    let i = i as usize;
    let m0 = means[3 * i];
    let m1 = means[3 * i + 1];
    let m2 = means[3 * i + 2];
    let q0 = quats[4 * i];
    let q1 = quats[4 * i + 1];
    let q2 = quats[4 * i + 2];
    let q3 = quats[4 * i + 3];
    let s0 = scales[3 * i];
    let s1 = scales[3 * i + 1];
    let s2 = scales[3 * i + 2];
    let mut fin = finite(m0) && finite(m1) && finite(m2);
    fin = fin && finite(q0) && finite(q1) && finite(q2) && finite(q3);
    fin = fin && finite(s0) && finite(s1) && finite(s2);
    fin = fin && finite(opacities[i]) && finite(offsets[2 * i]) && finite(offsets[2 * i + 1]);
    let mut status = 0u32;
    if !fin {
        status = 2u32;
    }
    let p0 = cam[0] * m0 + cam[1] * m1 + cam[2] * m2 + cam[9];
    let p1 = cam[3] * m0 + cam[4] * m1 + cam[5] * m2 + cam[10];
    let z = cam[6] * m0 + cam[7] * m1 + cam[8] * m2 + cam[11];
    out[P] = p0;
    out[P + 1] = p1;
    out[P + 2] = z;
    if status == 0u32 && !(finite(z) && z >= cam[16] && z <= cam[17]) {
        status = 1u32;
    }
    let n2 = q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3;
    if status == 0u32 && n2 < QUAT_MIN_NORM2 {
        status = 3u32;
    }
    let qnorm = n2.sqrt();
    let w = q0 / qnorm;
    let x = q1 / qnorm;
    let y = q2 / qnorm;
    let zq = q3 / qnorm;
    out[QN] = w;
    out[QN + 1] = x;
    out[QN + 2] = y;
    out[QN + 3] = zq;
    out[QNORM] = qnorm;
    out[RQ] = 1.0 - 2.0 * (y * y + zq * zq);
    out[RQ + 1] = 2.0 * (x * y - w * zq);
    out[RQ + 2] = 2.0 * (x * zq + w * y);
    out[RQ + 3] = 2.0 * (x * y + w * zq);
    out[RQ + 4] = 1.0 - 2.0 * (x * x + zq * zq);
    out[RQ + 5] = 2.0 * (y * zq - w * x);
    out[RQ + 6] = 2.0 * (x * zq - w * y);
    out[RQ + 7] = 2.0 * (y * zq + w * x);
    out[RQ + 8] = 1.0 - 2.0 * (x * x + y * y);
    // wm = W R_q diag(s); Sigma_c = wm wm^T.
    let mut wm = Array::<f32>::new(9usize);
    #[unroll]
    for a in 0..3usize {
        #[unroll]
        for b in 0..3usize {
            let v = cam[a * 3] * out[RQ + b]
                + cam[a * 3 + 1] * out[RQ + 3 + b]
                + cam[a * 3 + 2] * out[RQ + 6 + b];
            let s = if b == 0 {
                s0
            } else if b == 1 {
                s1
            } else {
                s2
            };
            wm[a * 3 + b] = v * s;
        }
    }
    #[unroll]
    for a in 0..3usize {
        #[unroll]
        for b in 0..3usize {
            out[SC + a * 3 + b] = wm[a * 3] * wm[b * 3]
                + wm[a * 3 + 1] * wm[b * 3 + 1]
                + wm[a * 3 + 2] * wm[b * 3 + 2];
        }
    }
    let xz = p0 / z;
    let yz = p1 / z;
    let cxz = clampf(xz, cam[18], cam[19]);
    let cyz = clampf(yz, cam[20], cam[21]);
    out[CLX] = select(cxz != xz, 1.0f32, 0.0f32);
    out[CLY] = select(cyz != yz, 1.0f32, 0.0f32);
    let tx = z * cxz;
    let ty = z * cyz;
    out[TX] = tx;
    out[TY] = ty;
    let iz = 1.0 / z;
    let iz2 = iz * iz;
    let j00 = cam[12] * iz;
    let j02 = -cam[12] * tx * iz2;
    let j11 = cam[13] * iz;
    let j12 = -cam[13] * ty * iz2;
    out[J00] = j00;
    out[J02] = j02;
    out[J11] = j11;
    out[J12] = j12;
    // js = J Sigma_c (rows 0 and 1).
    let js00 = j00 * out[SC] + j02 * out[SC + 6];
    let js01 = j00 * out[SC + 1] + j02 * out[SC + 7];
    let js02 = j00 * out[SC + 2] + j02 * out[SC + 8];
    let js11 = j11 * out[SC + 4] + j12 * out[SC + 7];
    let js12 = j11 * out[SC + 5] + j12 * out[SC + 8];
    let ra = js00 * j00 + js02 * j02;
    let cb = js01 * j11 + js02 * j12;
    let rc = js11 * j11 + js12 * j12;
    let ca = ra + cam[22];
    let cc = rc + cam[22];
    out[COV] = ca;
    out[COV + 1] = cb;
    out[COV + 2] = cc;
    out[RAW] = ra;
    out[RAW + 1] = rc;
    let det = ca * cc - cb * cb;
    // Mip-Splatting's 2D filter: the blurred splat keeps the unblurred one's integral.
    let ratio = select(cam[23] > 0.5, (ra * rc - cb * cb) / det, 1.0f32);
    out[RATIO] = ratio;
    out[COMP] = clampf(ratio, MIN_RATIO, 1.0).sqrt();
    if status == 0u32 && !(finite(det) && det > 0.0) {
        status = 3u32;
    }
    let ka = cc / det;
    let kb = -cb / det;
    let kc = ca / det;
    out[CON] = ka;
    out[CON + 1] = kb;
    out[CON + 2] = kc;
    if status == 0u32 && !(finite(ka) && finite(kb) && finite(kc)) {
        status = 3u32;
    }
    status
}

/// One thread per Gaussian: projects it, writes its aux row (radius, depth, tiles, status),
/// its projected record, its tile count and its depth sort key (`u32::MAX` when culled; the
/// value is the Gaussian's index).
#[cube(launch)]
pub fn project_forward(
    means: &[f32],
    quats: &[f32],
    scales: &[f32],
    opacities: &[f32],
    features: &[f32],
    offsets: &[f32],
    cam: &[f32],
    proj: &mut [f32],
    aux: &mut [f32],
    tiles: &mut [u32],
    keys: &mut [u32],
    vals: &mut [u32],
    n: u32,
    width: u32,
    height: u32,
    #[comptime] channels: usize,
) {
    let i = ABSOLUTE_POS as u32;
    if i >= n {
        terminate!();
    }
    let iu = i as usize;
    vals[iu] = i;
    keys[iu] = 0xffff_ffffu32;
    tiles[iu] = 0u32;
    aux[4 * iu] = 0.0;
    aux[4 * iu + 1] = 0.0;
    aux[4 * iu + 2] = 0.0;
    let mut core = Array::<f32>::new(CORE);
    let mut status = project_core(means, quats, scales, opacities, offsets, cam, i, &mut core);
    let mut feat_ok = true;
    #[unroll]
    for c in 0..channels {
        feat_ok = feat_ok && finite(features[iu * channels + c]);
    }
    if !feat_ok {
        status = 2u32;
    }
    let z = core[P + 2];
    let x = cam[12] * core[P] / z + cam[14] + offsets[2 * iu];
    let y = cam[13] * core[P + 1] / z + cam[15] + offsets[2 * iu + 1];
    let o = opacities[iu] * core[COMP];
    let level = 2.0 * (o / ALPHA_MIN).ln();
    if status == 0u32 && (!finite(level) || level <= 0.0) {
        status = 4u32;
    }
    let ex = (level * core[COV]).sqrt();
    let ey = (level * core[COV + 2]).sqrt();
    let lo_x = (x - ex - 0.5).ceil();
    let hi_x = (x + ex - 0.5).floor();
    let lo_y = (y - ey - 0.5).ceil();
    let hi_y = (y + ey - 0.5).floor();
    if status == 0u32 && !(finite(lo_x) && finite(hi_x) && finite(lo_y) && finite(hi_y)) {
        status = 3u32;
    }
    let wf = f32::cast_from(width);
    let hf = f32::cast_from(height);
    let x0 = clampf(lo_x, 0.0, wf);
    let y0 = clampf(lo_y, 0.0, hf);
    let x1 = clampf(hi_x + 1.0, 0.0, wf);
    let y1 = clampf(hi_y + 1.0, 0.0, hf);
    if status == 0u32 && !(x0 < x1 && y0 < y1) {
        status = 4u32;
    }
    aux[4 * iu + 3] = f32::cast_from(status);
    if status == 0u32 {
        let rx0 = u32::cast_from(x0);
        let ry0 = u32::cast_from(y0);
        let rx1 = u32::cast_from(x1);
        let ry1 = u32::cast_from(y1);
        let tx0 = rx0 / TILE_SIZE;
        let ty0 = ry0 / TILE_SIZE;
        let tx1 = (rx1 + TILE_SIZE - 1) / TILE_SIZE;
        let ty1 = (ry1 + TILE_SIZE - 1) / TILE_SIZE;
        let count = (tx1 - tx0) * (ty1 - ty0);
        let b = iu * PROJ as usize;
        proj[b] = x;
        proj[b + 1] = y;
        proj[b + 2] = core[CON];
        proj[b + 3] = core[CON + 1];
        proj[b + 4] = core[CON + 2];
        proj[b + 5] = o;
        proj[b + 6] = z;
        proj[b + 7] = -(0.5 * level) - 1e-3;
        proj[b + 8] = f32::cast_from(rx0);
        proj[b + 9] = f32::cast_from(ry0);
        proj[b + 10] = f32::cast_from(rx1);
        proj[b + 11] = f32::cast_from(ry1);
        tiles[iu] = count;
        // Visible depths are >= near > 0: their bit patterns sort like the values.
        keys[iu] = u32::reinterpret(z);
        aux[4 * iu] = select(ex > ey, ex, ey);
        aux[4 * iu + 1] = z;
        aux[4 * iu + 2] = f32::cast_from(count);
    }
}

/// Gradient of a unit quaternion from the gradient of its rotation matrix (row-major `g`).
#[cube]
fn quat_to_rot_vjp(w: f32, x: f32, y: f32, z: f32, g: &Array<f32>, out: &mut Array<f32>) {
    out[0] = 2.0 * (-z * g[1] + y * g[2] + z * g[3] - x * g[5] - y * g[6] + x * g[7]);
    out[1] = 2.0 * (y * g[1] + z * g[2] + y * g[3] - w * g[5] + z * g[6] + w * g[7])
        - 4.0 * x * (g[4] + g[8]);
    out[2] = 2.0 * (x * g[1] + w * g[2] + x * g[3] + z * g[5] - w * g[6] + z * g[7])
        - 4.0 * y * (g[0] + g[8]);
    out[3] = 2.0 * (-w * g[1] + x * g[2] + w * g[3] + y * g[5] + x * g[6] + y * g[7])
        - 4.0 * z * (g[0] + g[4]);
}

/// One thread per Gaussian in depth order: applies the projection VJP to its summed gradient
/// row (`sums`, in Gaussian order). Gaussians without intersections keep their zeroed
/// gradients.
#[cube(launch)]
pub fn project_backward(
    order: &[u32],
    starts: &[u32],
    sums: &[f32],
    means: &[f32],
    quats: &[f32],
    scales: &[f32],
    opacities: &[f32],
    offsets: &[f32],
    cam: &[f32],
    g_means: &mut [f32],
    g_quats: &mut [f32],
    g_scales: &mut [f32],
    g_opacities: &mut [f32],
    g_features: &mut [f32],
    g_offsets: &mut [f32],
    n: u32,
    #[comptime] channels: usize,
) {
    let values = channels + 6;
    let at = ranked(starts, n);
    if at.start >= at.end {
        terminate!();
    }
    let g = order[at.r as usize];
    let gu = g as usize;
    let mut acc = Array::<f32>::new(values);
    #[unroll]
    for v in 0..values {
        acc[v] = sums[gu * values + v];
    }
    #[unroll]
    for c in 0..channels {
        g_features[gu * channels + c] = acc[6 + c];
    }
    let mut f = Array::<f32>::new(CORE);
    project_core(means, quats, scales, opacities, offsets, cam, g, &mut f);
    let fx = cam[12];
    let fy = cam[13];
    let z = f[P + 2];
    let iz = 1.0 / z;
    let iz2 = iz * iz;
    let iz3 = iz2 * iz;
    let dxy0 = acc[0];
    let dxy1 = acc[1];
    let mut dp0 = dxy0 * fx * iz;
    let mut dp1 = dxy1 * fy * iz;
    let mut dp2 = -(dxy0 * fx * f[P] + dxy1 * fy * f[P + 1]) * iz2;
    // Conic -> covariance: dL/dcov = -Q G Q, G = [[ga, gb/2], [gb/2, gc]].
    let qa = f[CON];
    let qb = f[CON + 1];
    let qc = f[CON + 2];
    let ga = acc[2];
    let gb = 0.5 * acc[3];
    let gc = acc[4];
    let qg00 = qa * ga + qb * gb;
    let qg01 = qa * gb + qb * gc;
    let qg10 = qb * ga + qc * gb;
    let qg11 = qb * gb + qc * gc;
    let mut gc00 = -(qg00 * qa + qg01 * qb);
    let mut gc01 = -(qg00 * qb + qg01 * qc);
    let mut gc10 = -(qg10 * qa + qg11 * qb);
    let mut gc11 = -(qg10 * qb + qg11 * qc);
    let mut g_opacity = acc[5];
    if cam[23] > 0.5 {
        // comp = sqrt(r), r = det(cov - blur) / det(cov), clamped: no gradient where clamped.
        let ratio = f[RATIO];
        let comp = f[COMP];
        let inside = ratio == clampf(ratio, MIN_RATIO, 1.0);
        let d_r = select(inside, acc[5] * opacities[gu] * 0.5 / comp, 0.0f32);
        let b = f[COV + 1];
        let det = f[COV] * f[COV + 2] - b * b;
        let det0 = f[RAW] * f[RAW + 1] - b * b;
        let idet2 = 1.0 / (det * det);
        gc00 += d_r * (f[RAW + 1] * det - det0 * f[COV + 2]) * idet2;
        gc11 += d_r * (f[RAW] * det - det0 * f[COV]) * idet2;
        let off = -(d_r * b * (det - det0) * idet2);
        gc01 += off;
        gc10 += off;
        g_opacity = acc[5] * comp;
    }
    // J = [[j00, 0, j02], [0, j11, j12]].
    let mut jm = Array::<f32>::new(6usize);
    jm[0] = f[J00];
    jm[1] = 0.0;
    jm[2] = f[J02];
    jm[3] = 0.0;
    jm[4] = f[J11];
    jm[5] = f[J12];
    let mut gcv = Array::<f32>::new(4usize);
    gcv[0] = gc00;
    gcv[1] = gc01;
    gcv[2] = gc10;
    gcv[3] = gc11;
    // dSigma_c = J^T Gc J.
    let mut dsc = Array::<f32>::new(9usize);
    #[unroll]
    for a in 0..3usize {
        #[unroll]
        for b in 0..3usize {
            let mut s = 0.0f32;
            #[unroll]
            for i in 0..2usize {
                #[unroll]
                for k in 0..2usize {
                    s += jm[i * 3 + a] * gcv[i * 2 + k] * jm[k * 3 + b];
                }
            }
            dsc[a * 3 + b] = s;
        }
    }
    // dJ = 2 Gc J Sigma_c.
    let mut gj = Array::<f32>::new(6usize);
    #[unroll]
    for i in 0..2usize {
        #[unroll]
        for b in 0..3usize {
            gj[i * 3 + b] = gcv[i * 2] * jm[b] + gcv[i * 2 + 1] * jm[3 + b];
        }
    }
    let mut dj = Array::<f32>::new(6usize);
    #[unroll]
    for i in 0..2usize {
        #[unroll]
        for b in 0..3usize {
            dj[i * 3 + b] = 2.0
                * (gj[i * 3] * f[SC + b]
                    + gj[i * 3 + 1] * f[SC + 3 + b]
                    + gj[i * 3 + 2] * f[SC + 6 + b]);
        }
    }
    let tx = f[TX];
    let ty = f[TY];
    dp2 = dp2 - dj[0] * fx * iz2 - dj[4] * fy * iz2;
    let d_tx = -dj[2] * fx * iz2;
    let d_ty = -dj[5] * fy * iz2;
    dp2 += 2.0 * (dj[2] * fx * tx + dj[5] * fy * ty) * iz3;
    if f[CLX] > 0.5 {
        dp2 += d_tx * tx / z;
    } else {
        dp0 += d_tx;
    }
    if f[CLY] > 0.5 {
        dp2 += d_ty * ty / z;
    } else {
        dp1 += d_ty;
    }
    // p = W m + t.
    #[unroll]
    for k in 0..3usize {
        g_means[gu * 3 + k] = cam[k] * dp0 + cam[3 + k] * dp1 + cam[6 + k] * dp2;
    }
    // dSigma = W^T dSigma_c W.
    let mut tmp = Array::<f32>::new(9usize);
    #[unroll]
    for a in 0..3usize {
        #[unroll]
        for b in 0..3usize {
            tmp[a * 3 + b] = cam[a] * dsc[b] + cam[3 + a] * dsc[3 + b] + cam[6 + a] * dsc[6 + b];
        }
    }
    let mut ds = Array::<f32>::new(9usize);
    #[unroll]
    for a in 0..3usize {
        #[unroll]
        for b in 0..3usize {
            ds[a * 3 + b] =
                tmp[a * 3] * cam[b] + tmp[a * 3 + 1] * cam[3 + b] + tmp[a * 3 + 2] * cam[6 + b];
        }
    }
    // M = R_q diag(s); dM = (dSigma + dSigma^T) M; d_scale, d_rot.
    let mut sv = Array::<f32>::new(3usize);
    sv[0] = scales[gu * 3];
    sv[1] = scales[gu * 3 + 1];
    sv[2] = scales[gu * 3 + 2];
    let mut d_rot = Array::<f32>::new(9usize);
    let mut d_scale = Array::<f32>::new(3usize);
    #[unroll]
    for b in 0..3usize {
        d_scale[b] = 0.0;
    }
    #[unroll]
    for a in 0..3usize {
        #[unroll]
        for b in 0..3usize {
            let mut s = 0.0f32;
            #[unroll]
            for k in 0..3usize {
                s += (ds[a * 3 + k] + ds[k * 3 + a]) * f[RQ + k * 3 + b] * sv[b];
            }
            d_scale[b] += s * f[RQ + a * 3 + b];
            d_rot[a * 3 + b] = s * sv[b];
        }
    }
    #[unroll]
    for b in 0..3usize {
        g_scales[gu * 3 + b] = d_scale[b];
    }
    let mut dqn = Array::<f32>::new(4usize);
    quat_to_rot_vjp(f[QN], f[QN + 1], f[QN + 2], f[QN + 3], &d_rot, &mut dqn);
    let dot = f[QN] * dqn[0] + f[QN + 1] * dqn[1] + f[QN + 2] * dqn[2] + f[QN + 3] * dqn[3];
    #[unroll]
    for k in 0..4usize {
        g_quats[gu * 4 + k] = (dqn[k] - f[QN + k] * dot) / f[QNORM];
    }
    g_opacities[gu] = g_opacity;
    g_offsets[gu * 2] = dxy0;
    g_offsets[gu * 2 + 1] = dxy1;
}
