//! Projection of 3D Gaussians to screen-space conics (EWA splatting) and its vector-Jacobian
//! product.

use super::arith::{self, F32x16};
use super::host::HostGaussians;
use crate::antialias::MIN_COMPENSATION;
use crate::config::{ALPHA_MIN, QUAT_MIN_NORM2, SplatConfig, TILE_SIZE, status};
use crate::scalar::Real;

type M3<F> = [[F; 3]; 3];

/// The camera, converted once to the working precision.
#[derive(Clone, Copy, Debug)]
pub(crate) struct CamF<F> {
    pub rot: M3<F>,
    pub trans: [F; 3],
    pub fx: F,
    pub fy: F,
    pub cx: F,
    pub cy: F,
    pub width: u32,
    pub height: u32,
    pub near: F,
    pub far: F,
    /// x/z limits for the Jacobian clamp.
    pub lim_x: [F; 2],
    pub lim_y: [F; 2],
    /// Screen-space blur (pixels^2).
    pub blur: F,
    /// Whether each opacity is scaled by the blur's compensation
    /// ([`SplatConfig::compensate_blur`]).
    pub compensate: bool,
}

impl CamF<f32> {
    /// The camera broadcast to 16 lanes.
    pub fn lanes(&self) -> CamF<F32x16> {
        let b = |v: f32| F32x16([v; arith::WIDTH]);
        CamF {
            rot: self.rot.map(|r| r.map(b)),
            trans: self.trans.map(b),
            fx: b(self.fx),
            fy: b(self.fy),
            cx: b(self.cx),
            cy: b(self.cy),
            width: self.width,
            height: self.height,
            near: b(self.near),
            far: b(self.far),
            lim_x: self.lim_x.map(b),
            lim_y: self.lim_y.map(b),
            blur: b(self.blur),
            compensate: self.compensate,
        }
    }
}

impl<F: Real> CamF<F> {
    pub fn new(cfg: &SplatConfig) -> Self {
        let c = &cfg.camera;
        let (lim_x, lim_y) = c.jacobian_limits();
        Self {
            rot: c.rotation.map(|r| r.map(F::c)),
            trans: c.translation.map(F::c),
            fx: F::c(c.fx),
            fy: F::c(c.fy),
            cx: F::c(c.cx),
            cy: F::c(c.cy),
            width: c.width,
            height: c.height,
            near: F::c(c.near),
            far: F::c(c.far),
            lim_x: lim_x.map(F::c),
            lim_y: lim_y.map(F::c),
            blur: F::c(cfg.blur_px2),
            compensate: cfg.compensate_blur,
        }
    }
}

/// One Gaussian's raw parameters.
#[derive(Clone, Copy, Debug)]
pub(crate) struct GaussIn<F> {
    pub mean: [F; 3],
    pub quat: [F; 4],
    pub scale: [F; 3],
    pub opacity: F,
    pub xy_offset: [F; 2],
}

impl<F: Real> HostGaussians<'_, F> {
    pub(super) fn get(&self, i: usize) -> GaussIn<F> {
        let m = &self.means[3 * i..3 * i + 3];
        let q = &self.quats[4 * i..4 * i + 4];
        let s = &self.scales[3 * i..3 * i + 3];
        let o = &self.xy_offsets[2 * i..2 * i + 2];
        GaussIn {
            mean: [m[0], m[1], m[2]],
            quat: [q[0], q[1], q[2], q[3]],
            scale: [s[0], s[1], s[2]],
            opacity: self.opacities[i],
            xy_offset: [o[0], o[1]],
        }
    }
}

/// One Gaussian on screen.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Splat<F> {
    /// Mean in pixels.
    pub xy: [F; 2],
    /// Inverse 2D covariance (a, b, c): `[[a, b], [b, c]]`.
    pub conic: [F; 3],
    pub opacity: F,
    /// Camera-space z of the mean (the sort key).
    pub depth: F,
    /// Pixel rectangle `[x0, y0, x1, y1)` where alpha can reach `ALPHA_MIN`.
    pub rect: [u32; 4],
    /// Half extents of that region in pixels.
    pub extent: [F; 2],
    /// `ln(ALPHA_MIN / opacity) - 1e-3`: below this exponent alpha is certainly under the
    /// cut-off, so the exponential need not be evaluated (the margin keeps the decision at the
    /// boundary to the exact test).
    pub skip_power: F,
}

impl<F> Splat<F> {
    /// Tile rectangle `[tx0, ty0, tx1, ty1)`.
    #[inline]
    pub fn tile_rect(&self) -> [u32; 4] {
        let [x0, y0, x1, y1] = self.rect;
        [
            x0 / TILE_SIZE,
            y0 / TILE_SIZE,
            x1.div_ceil(TILE_SIZE),
            y1.div_ceil(TILE_SIZE),
        ]
    }

    #[inline]
    pub fn tile_count(&self) -> usize {
        let [tx0, ty0, tx1, ty1] = self.tile_rect();
        ((tx1 - tx0) * (ty1 - ty0)) as usize
    }
}

#[inline(always)]
fn matmul<T: arith::Arith>(a: &M3<T>, b: &M3<T>) -> M3<T> {
    let mut r = [[T::c(0.0); 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            r[i][j] = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j];
        }
    }
    r
}

#[inline(always)]
fn transpose<T: arith::Arith>(a: &M3<T>) -> M3<T> {
    let mut r = [[T::c(0.0); 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            r[i][j] = a[j][i];
        }
    }
    r
}

/// Rotation matrix of a unit quaternion (w, x, y, z).
#[inline(always)]
pub(crate) fn quat_to_rot<T: arith::Arith>(q: [T; 4]) -> M3<T> {
    let [w, x, y, z] = q;
    let one = T::c(1.0);
    let two = T::c(2.0);
    [
        [
            one - two * (y * y + z * z),
            two * (x * y - w * z),
            two * (x * z + w * y),
        ],
        [
            two * (x * y + w * z),
            one - two * (x * x + z * z),
            two * (y * z - w * x),
        ],
        [
            two * (x * z - w * y),
            two * (y * z + w * x),
            one - two * (x * x + y * y),
        ],
    ]
}

/// Gradient of a loss with respect to a unit quaternion, given its gradient `g` with respect
/// to the rotation matrix.
#[inline(always)]
fn quat_to_rot_vjp<T: arith::Arith>(q: [T; 4], g: &M3<T>) -> [T; 4] {
    let [w, x, y, z] = q;
    let two = T::c(2.0);
    let four = T::c(4.0);
    [
        two * (-z * g[0][1] + y * g[0][2] + z * g[1][0] - x * g[1][2] - y * g[2][0] + x * g[2][1]),
        two * (y * g[0][1] + z * g[0][2] + y * g[1][0] - w * g[1][2] + z * g[2][0] + w * g[2][1])
            - four * x * (g[1][1] + g[2][2]),
        two * (x * g[0][1] + w * g[0][2] + x * g[1][0] + z * g[1][2] - w * g[2][0] + z * g[2][1])
            - four * y * (g[0][0] + g[2][2]),
        two * (-w * g[0][1] + x * g[0][2] + w * g[1][0] + y * g[1][2] + x * g[2][0] + y * g[2][1])
            - four * z * (g[0][0] + g[1][1]),
    ]
}

/// Intermediate values of the projection, kept for the VJP.
pub(crate) struct Fwd<T: arith::Arith> {
    /// Squared norm of the raw quaternion.
    n2: T,
    qn: [T; 4],
    qnorm: T,
    rot_q: M3<T>,
    sigma_c: M3<T>,
    p: [T; 3],
    /// Whether x/z, y/z were clamped, and the clamp values used.
    tx: T,
    ty: T,
    clamped: [T::Mask; 2],
    j: [[T; 3]; 2],
    /// 2D covariance (with blur) as (a, b, c).
    cov: [T; 3],
    /// Its diagonal without the blur.
    raw: [T; 2],
    det: T,
    conic: [T; 3],
    /// With [`CamF::compensate`]: `det(cov - blur) / det(cov)` before the clamp; else 1.
    ratio: T,
    /// The opacity's factor: `sqrt` of the clamped ratio (1 without compensation).
    comp: T,
}

#[inline]
fn is_finite_in<F: Real>(g: &GaussIn<F>) -> bool {
    g.mean.iter().all(|v| v.is_finite())
        && g.quat.iter().all(|v| v.is_finite())
        && g.scale.iter().all(|v| v.is_finite())
        && g.opacity.is_finite()
        && g.xy_offset.iter().all(|v| v.is_finite())
}

/// The projection's arithmetic up to the conic, without any test: [`project_core`] decides
/// from its results whether the Gaussian is culled.
#[inline(always)]
pub(crate) fn fwd_math<T: arith::Arith>(
    mean: [T; 3],
    quat: [T; 4],
    scale: [T; 3],
    cam: &CamF<T>,
) -> Fwd<T> {
    let r = &cam.rot;
    let m = mean;
    let p = [
        r[0][0] * m[0] + r[0][1] * m[1] + r[0][2] * m[2] + cam.trans[0],
        r[1][0] * m[0] + r[1][1] * m[1] + r[1][2] * m[2] + cam.trans[1],
        r[2][0] * m[0] + r[2][1] * m[1] + r[2][2] * m[2] + cam.trans[2],
    ];
    let z = p[2];
    let q = quat;
    let n2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3];
    let qnorm = n2.sqrt();
    let qn = q.map(|v| v / qnorm);
    let rot_q = quat_to_rot(qn);
    // M = R_q diag(s); Sigma = M M^T; Sigma_c = W Sigma W^T = (W M)(W M)^T.
    let mut wm = matmul(r, &rot_q);
    for row in wm.iter_mut() {
        for (k, v) in row.iter_mut().enumerate() {
            *v = *v * scale[k];
        }
    }
    let mut sigma_c = [[T::c(0.0); 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            sigma_c[i][j] = wm[i][0] * wm[j][0] + wm[i][1] * wm[j][1] + wm[i][2] * wm[j][2];
        }
    }
    let xz = p[0] / z;
    let yz = p[1] / z;
    let cxz = xz.max(cam.lim_x[0]).min(cam.lim_x[1]);
    let cyz = yz.max(cam.lim_y[0]).min(cam.lim_y[1]);
    let clamped = [cxz.ne(xz), cyz.ne(yz)];
    let tx = z * cxz;
    let ty = z * cyz;
    let iz = T::c(1.0) / z;
    let iz2 = iz * iz;
    let zero = T::c(0.0);
    let j = [
        [cam.fx * iz, zero, -cam.fx * tx * iz2],
        [zero, cam.fy * iz, -cam.fy * ty * iz2],
    ];
    // cov = J Sigma_c J^T (2x2) + blur.
    let mut js = [[zero; 3]; 2];
    for a in 0..2 {
        for b in 0..3 {
            js[a][b] = j[a][0] * sigma_c[0][b] + j[a][1] * sigma_c[1][b] + j[a][2] * sigma_c[2][b];
        }
    }
    let dot3 = |u: [T; 3], v: [T; 3]| u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
    let blur = cam.blur;
    let raw = [dot3(js[0], j[0]), dot3(js[1], j[1])];
    let cov = [raw[0] + blur, dot3(js[0], j[1]), raw[1] + blur];
    let det = cov[0] * cov[2] - cov[1] * cov[1];
    let conic = [cov[2] / det, -cov[1] / det, cov[0] / det];
    let (ratio, comp) = if cam.compensate {
        // Mip-Splatting's 2D filter: the blurred splat keeps the unblurred one's integral.
        let ratio = (raw[0] * raw[1] - cov[1] * cov[1]) / det;
        let floor = T::c(MIN_COMPENSATION * MIN_COMPENSATION);
        (ratio, ratio.max(floor).min(T::c(1.0)).sqrt())
    } else {
        (T::c(1.0), T::c(1.0))
    };
    Fwd {
        n2,
        qn,
        qnorm,
        rot_q,
        sigma_c,
        p,
        tx,
        ty,
        clamped,
        j,
        cov,
        raw,
        det,
        conic,
        ratio,
        comp,
    }
}

/// Forward projection up to the conic. `Err(status)` when culled before the rectangle test.
#[inline]
fn project_core<F: Real>(g: &GaussIn<F>, cam: &CamF<F>) -> Result<Fwd<F>, f32> {
    if !is_finite_in(g) {
        return Err(status::NON_FINITE);
    }
    let f = fwd_math(g.mean, g.quat, g.scale, cam);
    cull_tests(&f, cam)?;
    Ok(f)
}

/// The culling tests on the projection's arithmetic of a Gaussian with finite parameters.
#[inline(always)]
fn cull_tests<F: Real>(f: &Fwd<F>, cam: &CamF<F>) -> Result<(), f32> {
    let z = f.p[2];
    if !(z >= cam.near && z <= cam.far) {
        return Err(status::CLIPPED);
    }
    if f.n2.f64() < QUAT_MIN_NORM2 {
        return Err(status::DEGENERATE);
    }
    if !f.det.is_finite() || f.det <= F::zero() {
        return Err(status::DEGENERATE);
    }
    if !f.conic.iter().all(|v| v.is_finite()) {
        return Err(status::DEGENERATE);
    }
    Ok(())
}

/// Projects one Gaussian. `Err(status)` when it is culled (see [`crate::config::status`]).
pub(crate) fn project_one<F: Real>(g: &GaussIn<F>, cam: &CamF<F>) -> Result<Splat<F>, f32> {
    let f = project_core(g, cam)?;
    on_screen(g, &f, cam)
}

/// The screen footprint of a Gaussian that passed [`cull_tests`].
#[inline(always)]
fn on_screen<F: Real>(g: &GaussIn<F>, f: &Fwd<F>, cam: &CamF<F>) -> Result<Splat<F>, f32> {
    let z = f.p[2];
    let xy = [
        cam.fx * f.p[0] / z + cam.cx + g.xy_offset[0],
        cam.fy * f.p[1] / z + cam.cy + g.xy_offset[1],
    ];
    // alpha = o * exp(-q/2) >= ALPHA_MIN  <=>  q <= 2 ln(o / ALPHA_MIN).
    let o = g.opacity * f.comp;
    let level = F::c(2.0) * (o / F::c(ALPHA_MIN)).ln();
    if level.is_nan() || level <= F::zero() {
        return Err(status::NOT_ON_SCREEN);
    }
    let extent = [(level * f.cov[0]).sqrt(), (level * f.cov[2]).sqrt()];
    // Pixel i is inside when its centre i + 0.5 lies in [x - e, x + e].
    let half = F::c(0.5);
    let lo_x = (xy[0] - extent[0] - half).ceil();
    let hi_x = (xy[0] + extent[0] - half).floor();
    let lo_y = (xy[1] - extent[1] - half).ceil();
    let hi_y = (xy[1] + extent[1] - half).floor();
    if !(lo_x.is_finite() && hi_x.is_finite() && lo_y.is_finite() && hi_y.is_finite()) {
        return Err(status::DEGENERATE);
    }
    let clampi = |v: F, max: u32| -> u32 {
        let v = v.f64();
        if v <= 0.0 {
            0
        } else if v >= f64::from(max) {
            max
        } else {
            v as u32
        }
    };
    let rect = [
        clampi(lo_x, cam.width),
        clampi(lo_y, cam.height),
        clampi(hi_x + F::one(), cam.width),
        clampi(hi_y + F::one(), cam.height),
    ];
    if rect[0] >= rect[2] || rect[1] >= rect[3] {
        return Err(status::NOT_ON_SCREEN);
    }
    Ok(Splat {
        xy,
        conic: f.conic,
        opacity: o,
        depth: z,
        rect,
        extent,
        skip_power: -(F::c(0.5) * level) - F::c(1e-3),
    })
}

/// Gradients of one Gaussian's mean, rotation, scales and opacity (that of the screen offset is
/// the screen gradient itself).
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct GaussGrad<F> {
    pub mean: [F; 3],
    pub quat: [F; 4],
    pub scale: [F; 3],
    pub opacity: F,
}

/// The summed screen gradients of one splat: its mean, its conic (a, b, c as stored) and its
/// opacity (the compensated one, as blended).
#[derive(Clone, Copy, Debug)]
pub(crate) struct ScreenGrad<T> {
    pub xy: [T; 2],
    pub conic: [T; 3],
    pub opacity: T,
}

/// Vector-Jacobian product of [`project_one`]: from the screen gradients to the mean,
/// rotation, scales and opacity.
pub(crate) fn project_vjp<F: Real>(
    g: &GaussIn<F>,
    cam: &CamF<F>,
    d: ScreenGrad<F>,
) -> GaussGrad<F> {
    let Ok(f) = project_core(g, cam) else {
        return GaussGrad::default();
    };
    vjp_math(&f, g.scale, g.opacity, cam, d)
}

/// The arithmetic of [`project_vjp`] on the forward's intermediates (of a Gaussian that was
/// not culled) and its raw `opacity`.
#[inline(always)]
pub(crate) fn vjp_math<T: arith::Arith>(
    f: &Fwd<T>,
    scale: [T; 3],
    opacity: T,
    cam: &CamF<T>,
    d: ScreenGrad<T>,
) -> GaussGrad<T> {
    let (d_xy, d_conic) = (d.xy, d.conic);
    let zero = T::c(0.0);
    let two = T::c(2.0);
    let half = T::c(0.5);
    let z = f.p[2];
    let iz = T::c(1.0) / z;
    let iz2 = iz * iz;
    let mut d_p = [zero; 3];
    // Screen mean.
    d_p[0] = d_p[0] + d_xy[0] * cam.fx * iz;
    d_p[1] = d_p[1] + d_xy[1] * cam.fy * iz;
    d_p[2] = d_p[2] - (d_xy[0] * cam.fx * f.p[0] + d_xy[1] * cam.fy * f.p[1]) * iz2;

    // Conic -> covariance: dL/dcov = -Q G Q with G = [[ga, gb/2], [gb/2, gc]].
    let q = f.conic;
    let gm = [
        [d_conic[0], half * d_conic[1]],
        [half * d_conic[1], d_conic[2]],
    ];
    let qm = [[q[0], q[1]], [q[1], q[2]]];
    let mut qg = [[zero; 2]; 2];
    for i in 0..2 {
        for k in 0..2 {
            qg[i][k] = qm[i][0] * gm[0][k] + qm[i][1] * gm[1][k];
        }
    }
    let mut g_cov = [[zero; 2]; 2];
    for i in 0..2 {
        for k in 0..2 {
            g_cov[i][k] = -(qg[i][0] * qm[0][k] + qg[i][1] * qm[1][k]);
        }
    }
    let d_opacity = if cam.compensate {
        // comp = sqrt(r), r = det(cov - blur) / det(cov), clamped: no gradient where clamped.
        let floor = T::c(MIN_COMPENSATION * MIN_COMPENSATION);
        let clamped = f.ratio.max(floor).min(T::c(1.0)).ne(f.ratio);
        let d_r = T::select(clamped, zero, d.opacity * opacity * half / f.comp);
        let b = f.cov[1];
        let det0 = f.raw[0] * f.raw[1] - b * b;
        let idet2 = T::c(1.0) / (f.det * f.det);
        // The blur adds to the diagonal only: d/d(raw) = d/d(cov) on every entry.
        g_cov[0][0] = g_cov[0][0] + d_r * (f.raw[1] * f.det - det0 * f.cov[2]) * idet2;
        g_cov[1][1] = g_cov[1][1] + d_r * (f.raw[0] * f.det - det0 * f.cov[0]) * idet2;
        // d r / d b = -2 b (det - det0) / det^2, shared by the two symmetric entries.
        let off = -(d_r * b * (f.det - det0) * idet2);
        g_cov[0][1] = g_cov[0][1] + off;
        g_cov[1][0] = g_cov[1][0] + off;
        d.opacity * f.comp
    } else {
        d.opacity
    };
    // cov = J S J^T: dS = J^T Gc J, dJ = 2 Gc J S.
    let j = f.j;
    let s = f.sigma_c;
    let mut d_sigma_c = [[zero; 3]; 3];
    for a in 0..3 {
        for b in 0..3 {
            let mut acc = zero;
            for i in 0..2 {
                for k in 0..2 {
                    acc = acc + j[i][a] * g_cov[i][k] * j[k][b];
                }
            }
            d_sigma_c[a][b] = acc;
        }
    }
    let mut gj = [[zero; 3]; 2];
    for i in 0..2 {
        for b in 0..3 {
            gj[i][b] = g_cov[i][0] * j[0][b] + g_cov[i][1] * j[1][b];
        }
    }
    let mut d_j = [[zero; 3]; 2];
    for i in 0..2 {
        for b in 0..3 {
            d_j[i][b] = two * (gj[i][0] * s[0][b] + gj[i][1] * s[1][b] + gj[i][2] * s[2][b]);
        }
    }
    // J entries -> p.
    // J00 = fx/z, J02 = -fx tx / z^2, J11 = fy/z, J12 = -fy ty / z^2.
    let iz3 = iz2 * iz;
    d_p[2] = d_p[2] - d_j[0][0] * cam.fx * iz2 - d_j[1][1] * cam.fy * iz2;
    let d_tx = -d_j[0][2] * cam.fx * iz2;
    let d_ty = -d_j[1][2] * cam.fy * iz2;
    d_p[2] = d_p[2] + two * (d_j[0][2] * cam.fx * f.tx + d_j[1][2] * cam.fy * f.ty) * iz3;
    // Where x/z was clamped, tx = z * lim depends on z only.
    d_p[2] = T::select(f.clamped[0], d_p[2] + d_tx * f.tx / z, d_p[2]);
    d_p[0] = T::select(f.clamped[0], d_p[0], d_p[0] + d_tx);
    d_p[2] = T::select(f.clamped[1], d_p[2] + d_ty * f.ty / z, d_p[2]);
    d_p[1] = T::select(f.clamped[1], d_p[1], d_p[1] + d_ty);
    // p = W m + t.
    let w = &cam.rot;
    let mut d_mean = [zero; 3];
    for (k, dm) in d_mean.iter_mut().enumerate() {
        *dm = w[0][k] * d_p[0] + w[1][k] * d_p[1] + w[2][k] * d_p[2];
    }
    // Sigma_c = W Sigma W^T: dSigma = W^T dSigma_c W.
    let wt = transpose(w);
    let d_sigma = matmul(&matmul(&wt, &d_sigma_c), w);
    // Sigma = M M^T with M = R_q diag(s): dM = (dSigma + dSigma^T) M.
    let mut m = f.rot_q;
    for row in m.iter_mut() {
        for (k, v) in row.iter_mut().enumerate() {
            *v = *v * scale[k];
        }
    }
    let mut d_m = [[zero; 3]; 3];
    for a in 0..3 {
        for b in 0..3 {
            let mut acc = zero;
            for k in 0..3 {
                acc = acc + (d_sigma[a][k] + d_sigma[k][a]) * m[k][b];
            }
            d_m[a][b] = acc;
        }
    }
    let mut d_scale = [zero; 3];
    let mut d_rot = [[zero; 3]; 3];
    for a in 0..3 {
        for b in 0..3 {
            d_scale[b] = d_scale[b] + d_m[a][b] * f.rot_q[a][b];
            d_rot[a][b] = d_m[a][b] * scale[b];
        }
    }
    let d_qn = quat_to_rot_vjp(f.qn, &d_rot);
    let dot = f.qn[0] * d_qn[0] + f.qn[1] * d_qn[1] + f.qn[2] * d_qn[2] + f.qn[3] * d_qn[3];
    let d_quat = [0, 1, 2, 3].map(|k| (d_qn[k] - f.qn[k] * dot) / f.qnorm);
    GaussGrad {
        mean: d_mean,
        quat: d_quat,
        scale: d_scale,
        opacity: d_opacity,
    }
}

/// Parameters of 16 f32 Gaussians as lanes: the mean, quaternion and scales of Gaussian
/// `index(l)` of `g` in lane `l`.
type Lanes16 = ([F32x16; 3], [F32x16; 4], [F32x16; 3]);

#[inline(always)]
fn load_lanes(g: &HostGaussians<'_, f32>, index: impl Fn(usize) -> usize) -> Lanes16 {
    let load = |base: &[f32], dim: usize, d: usize| {
        F32x16(std::array::from_fn(|l| base[index(l) * dim + d]))
    };
    (
        [0, 1, 2].map(|d| load(g.means, 3, d)),
        [0, 1, 2, 3].map(|d| load(g.quats, 4, d)),
        [0, 1, 2].map(|d| load(g.scales, 3, d)),
    )
}

/// [`vjp_math`] for a run of f32 Gaussians, 16 at a time: Gaussian `first + k` of `g` takes
/// its summed screen gradients from `sums[k * stride..]` (`d_xy` at 0..2, `d_conic` at 2..5)
/// and writes the gradients of its mean, quaternion and scales to `means[3 k..]`, `quats[4 k..]`
/// and `scales[3 k..]`, leaving them where `visible[k]` is `u32::MAX` (culled: its arithmetic
/// is not used). Bit-identical to [`project_vjp`] on the others.
pub(crate) struct VjpLanes<'a> {
    pub g: &'a HostGaussians<'a, f32>,
    pub cam: &'a CamF<F32x16>,
    pub first: usize,
    pub visible: &'a [u32],
    pub sums: &'a [f32],
    pub stride: usize,
    pub means: &'a mut [f32],
    pub quats: &'a mut [f32],
    pub scales: &'a mut [f32],
    pub opacities: &'a mut [f32],
}

/// `pulp::WithSimd` for a run struct whose work is the plain `#[inline(always)]` function `$run`
/// (portable `F32x16` arithmetic, compiled inside the instruction set pulp dispatches to).
macro_rules! with_simd_by {
    ($ty:ident, $run:ident) => {
        impl pulp::WithSimd for $ty<'_> {
            type Output = ();

            #[inline(always)]
            fn with_simd<S: pulp::Simd>(self, _simd: S) {
                $run(self);
            }
        }
    };
}

with_simd_by!(VjpLanes, vjp_lanes);

#[inline(always)]
fn vjp_lanes(v: VjpLanes<'_>) {
    const W: usize = arith::WIDTH;
    let n = v.visible.len();
    let mut start = 0;
    while start < n {
        let len = W.min(n - start);
        // Short runs repeat their last Gaussian in the spare lanes, whose results are dropped.
        let lane = |l: usize| start + l.min(len - 1);
        let sum = |d: usize| F32x16(std::array::from_fn(|l| v.sums[lane(l) * v.stride + d]));
        let (mean, quat, scale) = load_lanes(v.g, |l| v.first + lane(l));
        let opacity = F32x16(std::array::from_fn(|l| v.g.opacities[v.first + lane(l)]));
        let f = fwd_math(mean, quat, scale, v.cam);
        let d = ScreenGrad {
            xy: [sum(0), sum(1)],
            conic: [sum(2), sum(3), sum(4)],
            opacity: sum(5),
        };
        let gg = vjp_math(&f, scale, opacity, v.cam, d);
        for l in 0..len {
            let k = start + l;
            if v.visible[k] == u32::MAX {
                continue;
            }
            for d in 0..3 {
                v.means[3 * k + d] = gg.mean[d].0[l];
                v.scales[3 * k + d] = gg.scale[d].0[l];
            }
            for d in 0..4 {
                v.quats[4 * k + d] = gg.quat[d].0[l];
            }
            v.opacities[k] = gg.opacity.0[l];
        }
        start += len;
    }
}

impl Fwd<F32x16> {
    /// Lane `l` as a scalar.
    #[inline(always)]
    fn lane(&self, l: usize) -> Fwd<f32> {
        let a = |v: &F32x16| v.0[l];
        let m3 = |m: &M3<F32x16>| m.map(|r| r.map(|v| v.0[l]));
        Fwd {
            n2: a(&self.n2),
            qn: self.qn.map(|v| v.0[l]),
            qnorm: a(&self.qnorm),
            rot_q: m3(&self.rot_q),
            sigma_c: m3(&self.sigma_c),
            p: self.p.map(|v| v.0[l]),
            tx: a(&self.tx),
            ty: a(&self.ty),
            clamped: self.clamped.map(|m| m[l]),
            j: self.j.map(|r| r.map(|v| v.0[l])),
            cov: self.cov.map(|v| v.0[l]),
            raw: self.raw.map(|v| v.0[l]),
            det: a(&self.det),
            conic: self.conic.map(|v| v.0[l]),
            ratio: a(&self.ratio),
            comp: a(&self.comp),
        }
    }
}

/// [`project_one`] for a run of f32 Gaussians, the arithmetic 16 at a time: Gaussian
/// `first + k` of `g` goes to `out[k]`, culled (`NON_FINITE`) also where one of its `channels`
/// features is not finite. Bit-identical to [`project_one`].
pub(crate) struct ProjectLanes<'a> {
    pub g: &'a HostGaussians<'a, f32>,
    pub channels: usize,
    pub cam: &'a CamF<f32>,
    pub cam16: &'a CamF<F32x16>,
    pub first: usize,
    pub out: &'a mut [Result<Splat<f32>, f32>],
}

with_simd_by!(ProjectLanes, project_lanes);

#[inline(always)]
fn project_lanes(v: ProjectLanes<'_>) {
    const W: usize = arith::WIDTH;
    let n = v.out.len();
    let c = v.channels;
    let mut start = 0;
    while start < n {
        let len = W.min(n - start);
        // Short runs repeat their last Gaussian in the spare lanes, whose results are dropped.
        let (mean, quat, scale) = load_lanes(v.g, |l| v.first + start + l.min(len - 1));
        let f = fwd_math(mean, quat, scale, v.cam16);
        for l in 0..len {
            let i = v.first + start + l;
            let gi = v.g.get(i);
            v.out[start + l] = if v.g.feature_not_finite(i, c) || !is_finite_in(&gi) {
                Err(status::NON_FINITE)
            } else {
                let fl = f.lane(l);
                cull_tests(&fl, v.cam).and_then(|()| on_screen(&gi, &fl, v.cam))
            };
        }
        start += len;
    }
}

#[cfg(test)]
mod tests {
    use rand::{RngExt, SeedableRng, rngs::StdRng};

    use super::super::{BlendPath, HostGaussians};
    use super::*;
    use crate::AlphaCutoff;
    use crate::scenes::{HostScene, RandomSceneSpec, random_scene, stiff_cases};

    /// Random scenes with Gaussians beside the frustum (the Jacobian's clamp), and every stiff
    /// case.
    fn scenes() -> Vec<HostScene> {
        let spec = |count, radius, distance, max_scale| RandomSceneSpec {
            count,
            channels: 3,
            size: (96, 80),
            radius,
            scale_range: (0.001, max_scale),
            opacity_range: (0.004, 0.999),
            distance,
            fov_x: 0.8,
        };
        let mut out = vec![
            random_scene(11, &spec(997, 1.0, 4.0, 0.5)),
            random_scene(12, &spec(500, 6.0, 8.0, 3.0)),
        ];
        out.extend(stiff_cases().into_iter().map(|c| c.scene));
        out
    }

    fn host(h: &super::super::HostBuffers<f32>) -> HostGaussians<'_, f32> {
        h.host()
    }

    #[test]
    fn lane_projection_and_vjp_are_bit_identical_to_the_scalar_code() {
        let paths: Vec<BlendPath> = [
            BlendPath::LanesScalar,
            BlendPath::LanesAvx2,
            BlendPath::LanesAvx512,
        ]
        .into_iter()
        .filter(|p| p.available())
        .collect();
        let mut rng = StdRng::seed_from_u64(3);
        let mut clamped = 0;
        let mut faded = 0;
        let cases = scenes()
            .into_iter()
            .flat_map(|s| [(s.clone(), false), (s, true)]);
        for (scene, compensate) in cases {
            let cfg = SplatConfig {
                compensate_blur: compensate,
                ..scene.config(AlphaCutoff::Hard)
            };
            let buffers = scene.to_f32();
            let g = host(&buffers);
            let cam = CamF::<f32>::new(&cfg);
            let cam16 = cam.lanes();
            let c = scene.channels;
            let scalar: Vec<Result<Splat<f32>, f32>> = (0..g.len())
                .map(|i| {
                    if g.feature_not_finite(i, c) {
                        Err(status::NON_FINITE)
                    } else {
                        project_one(&g.get(i), &cam)
                    }
                })
                .collect();
            let visible: Vec<u32> = (0..g.len() as u32)
                .filter(|&i| scalar[i as usize].is_ok())
                .collect();
            clamped += visible
                .iter()
                .filter(|&&i| {
                    let f = project_core(&g.get(i as usize), &cam).unwrap();
                    f.clamped[0] || f.clamped[1]
                })
                .count();
            faded += visible
                .iter()
                .filter(|&&i| project_core(&g.get(i as usize), &cam).unwrap().comp < 0.5)
                .count();
            // Culled Gaussians are marked `u32::MAX` and get zeros, as in the backward pass.
            let marks: Vec<u32> = scalar
                .iter()
                .map(|r| if r.is_ok() { 0 } else { u32::MAX })
                .collect();
            let sums: Vec<f32> = (0..g.len() * 6)
                .map(|_| rng.random_range(-1.0f32..1.0))
                .collect();
            let scalar_vjp: Vec<f32> = (0..g.len())
                .flat_map(|i| {
                    let s = &sums[i * 6..i * 6 + 6];
                    if marks[i] == u32::MAX {
                        return vec![0.0; 11];
                    }
                    let d = ScreenGrad {
                        xy: [s[0], s[1]],
                        conic: [s[2], s[3], s[4]],
                        opacity: s[5],
                    };
                    let gg = project_vjp(&g.get(i), &cam, d);
                    [gg.mean.as_slice(), &gg.quat, &gg.scale, &[gg.opacity]].concat()
                })
                .collect();
            for &path in &paths {
                let mut lanes = vec![Err(status::NON_FINITE); g.len()];
                path.run(ProjectLanes {
                    g: &g,
                    channels: c,
                    cam: &cam,
                    cam16: &cam16,
                    first: 0,
                    out: &mut lanes,
                });
                assert_eq!(format!("{lanes:?}"), format!("{scalar:?}"), "{path:?}");
                let (mut dm, mut dq, mut ds, mut dop) = (
                    vec![0.0; 3 * g.len()],
                    vec![0.0; 4 * g.len()],
                    vec![0.0; 3 * g.len()],
                    vec![0.0; g.len()],
                );
                path.run(VjpLanes {
                    g: &g,
                    cam: &cam16,
                    first: 0,
                    visible: &marks,
                    sums: &sums,
                    stride: 6,
                    means: &mut dm,
                    quats: &mut dq,
                    scales: &mut ds,
                    opacities: &mut dop,
                });
                let vjp: Vec<f32> = (0..g.len())
                    .flat_map(|i| {
                        [
                            &dm[3 * i..3 * i + 3],
                            &dq[4 * i..4 * i + 4],
                            &ds[3 * i..3 * i + 3],
                            &dop[i..i + 1],
                        ]
                        .concat()
                    })
                    .collect();
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&vjp), bits(&scalar_vjp), "{path:?}");
            }
        }
        assert!(
            clamped > 10,
            "only {clamped} Gaussians met the Jacobian's clamp"
        );
        assert!(
            faded > 10,
            "only {faded} compensated Gaussians lost half their opacity"
        );
    }
}
