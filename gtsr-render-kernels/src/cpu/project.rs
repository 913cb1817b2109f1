//! Projection of 3D Gaussians to screen-space conics (EWA splatting) and its vector-Jacobian
//! product.

use crate::config::{ALPHA_MIN, FRUSTUM_MARGIN, QUAT_MIN_NORM2, SplatConfig, TILE_SIZE, status};
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
}

impl<F: Real> CamF<F> {
    pub fn new(cfg: &SplatConfig) -> Self {
        let c = &cfg.camera;
        let w = f64::from(c.width);
        let h = f64::from(c.height);
        let m = FRUSTUM_MARGIN;
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
            lim_x: [
                F::c((-m * w - c.cx) / c.fx),
                F::c(((1.0 + m) * w - c.cx) / c.fx),
            ],
            lim_y: [
                F::c((-m * h - c.cy) / c.fy),
                F::c(((1.0 + m) * h - c.cy) / c.fy),
            ],
            blur: F::c(cfg.blur_px2),
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

#[inline]
fn matmul<F: Real>(a: &M3<F>, b: &M3<F>) -> M3<F> {
    let mut r = [[F::zero(); 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            r[i][j] = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j];
        }
    }
    r
}

#[inline]
fn transpose<F: Real>(a: &M3<F>) -> M3<F> {
    let mut r = [[F::zero(); 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            r[i][j] = a[j][i];
        }
    }
    r
}

/// Rotation matrix of a unit quaternion (w, x, y, z).
#[inline]
pub(crate) fn quat_to_rot<F: Real>(q: [F; 4]) -> M3<F> {
    let [w, x, y, z] = q;
    let one = F::one();
    let two = F::c(2.0);
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
#[inline]
fn quat_to_rot_vjp<F: Real>(q: [F; 4], g: &M3<F>) -> [F; 4] {
    let [w, x, y, z] = q;
    let two = F::c(2.0);
    let four = F::c(4.0);
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
struct Fwd<F> {
    qn: [F; 4],
    qnorm: F,
    rot_q: M3<F>,
    sigma_c: M3<F>,
    p: [F; 3],
    /// Whether x/z, y/z were clamped, and the clamp values used.
    tx: F,
    ty: F,
    clamped: [bool; 2],
    j: [[F; 3]; 2],
    /// 2D covariance (with blur) as (a, b, c).
    cov: [F; 3],
    conic: [F; 3],
}

#[inline]
fn is_finite_in<F: Real>(g: &GaussIn<F>) -> bool {
    g.mean.iter().all(|v| v.is_finite())
        && g.quat.iter().all(|v| v.is_finite())
        && g.scale.iter().all(|v| v.is_finite())
        && g.opacity.is_finite()
        && g.xy_offset.iter().all(|v| v.is_finite())
}

/// Forward projection up to the conic. `Err(status)` when culled before the rectangle test.
#[inline]
fn project_core<F: Real>(g: &GaussIn<F>, cam: &CamF<F>) -> Result<Fwd<F>, f32> {
    if !is_finite_in(g) {
        return Err(status::NON_FINITE);
    }
    let r = &cam.rot;
    let m = g.mean;
    let p = [
        r[0][0] * m[0] + r[0][1] * m[1] + r[0][2] * m[2] + cam.trans[0],
        r[1][0] * m[0] + r[1][1] * m[1] + r[1][2] * m[2] + cam.trans[1],
        r[2][0] * m[0] + r[2][1] * m[1] + r[2][2] * m[2] + cam.trans[2],
    ];
    let z = p[2];
    if !(z >= cam.near && z <= cam.far) {
        return Err(status::CLIPPED);
    }
    let q = g.quat;
    let n2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3];
    if n2.f64() < QUAT_MIN_NORM2 {
        return Err(status::DEGENERATE);
    }
    let qnorm = n2.sqrt();
    let qn = q.map(|v| v / qnorm);
    let rot_q = quat_to_rot(qn);
    // M = R_q diag(s); Sigma = M M^T; Sigma_c = W Sigma W^T = (W M)(W M)^T.
    let mut wm = matmul(r, &rot_q);
    for row in wm.iter_mut() {
        for (k, v) in row.iter_mut().enumerate() {
            *v = *v * g.scale[k];
        }
    }
    let mut sigma_c = [[F::zero(); 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            sigma_c[i][j] = wm[i][0] * wm[j][0] + wm[i][1] * wm[j][1] + wm[i][2] * wm[j][2];
        }
    }
    let xz = p[0] / z;
    let yz = p[1] / z;
    let cxz = xz.max(cam.lim_x[0]).min(cam.lim_x[1]);
    let cyz = yz.max(cam.lim_y[0]).min(cam.lim_y[1]);
    let clamped = [cxz != xz, cyz != yz];
    let tx = z * cxz;
    let ty = z * cyz;
    let iz = F::one() / z;
    let iz2 = iz * iz;
    let j = [
        [cam.fx * iz, F::zero(), -cam.fx * tx * iz2],
        [F::zero(), cam.fy * iz, -cam.fy * ty * iz2],
    ];
    // cov = J Sigma_c J^T (2x2) + blur.
    let mut js = [[F::zero(); 3]; 2];
    for a in 0..2 {
        for b in 0..3 {
            js[a][b] = j[a][0] * sigma_c[0][b] + j[a][1] * sigma_c[1][b] + j[a][2] * sigma_c[2][b];
        }
    }
    let dot3 = |u: [F; 3], v: [F; 3]| u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
    let blur = cam.blur;
    let cov = [
        dot3(js[0], j[0]) + blur,
        dot3(js[0], j[1]),
        dot3(js[1], j[1]) + blur,
    ];
    let det = cov[0] * cov[2] - cov[1] * cov[1];
    if !det.is_finite() || det <= F::zero() {
        return Err(status::DEGENERATE);
    }
    let conic = [cov[2] / det, -cov[1] / det, cov[0] / det];
    if !conic.iter().all(|v| v.is_finite()) {
        return Err(status::DEGENERATE);
    }
    Ok(Fwd {
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
        conic,
    })
}

/// Projects one Gaussian. `Err(status)` when it is culled (see [`crate::config::status`]).
pub(crate) fn project_one<F: Real>(g: &GaussIn<F>, cam: &CamF<F>) -> Result<Splat<F>, f32> {
    let f = project_core(g, cam)?;
    let z = f.p[2];
    let xy = [
        cam.fx * f.p[0] / z + cam.cx + g.xy_offset[0],
        cam.fy * f.p[1] / z + cam.cy + g.xy_offset[1],
    ];
    // alpha = o * exp(-q/2) >= ALPHA_MIN  <=>  q <= 2 ln(o / ALPHA_MIN).
    let o = g.opacity;
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

/// Gradients of one Gaussian's raw parameters.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct GaussGrad<F> {
    pub mean: [F; 3],
    pub quat: [F; 4],
    pub scale: [F; 3],
    pub opacity: F,
    pub xy_offset: [F; 2],
}

/// Vector-Jacobian product of [`project_one`]: from the gradients of the screen mean, the conic
/// (a, b, c as stored) and the opacity to the raw parameters.
pub(crate) fn project_vjp<F: Real>(
    g: &GaussIn<F>,
    cam: &CamF<F>,
    d_xy: [F; 2],
    d_conic: [F; 3],
    d_opacity: F,
) -> GaussGrad<F> {
    let Ok(f) = project_core(g, cam) else {
        return GaussGrad::default();
    };
    let zero = F::zero();
    let two = F::c(2.0);
    let half = F::c(0.5);
    let z = f.p[2];
    let iz = F::one() / z;
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
    if f.clamped[0] {
        // tx = z * lim.
        d_p[2] = d_p[2] + d_tx * f.tx / z;
    } else {
        d_p[0] = d_p[0] + d_tx;
    }
    if f.clamped[1] {
        d_p[2] = d_p[2] + d_ty * f.ty / z;
    } else {
        d_p[1] = d_p[1] + d_ty;
    }
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
            *v = *v * g.scale[k];
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
            d_rot[a][b] = d_m[a][b] * g.scale[b];
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
        xy_offset: d_xy,
    }
}
