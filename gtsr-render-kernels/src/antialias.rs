//! Opacity compensation of the screen-space blur (Mip-Splatting's 2D filter).
//!
//! The blur `b` of [`SplatConfig::blur_px2`] widens every splat's 2D covariance
//! `Sigma -> Sigma + b I` at an unchanged peak opacity, so a splat that is thin on screen (a
//! flat Gaussian seen edge-on, or one smaller than a pixel) covers more of the image than the
//! Gaussian it stands for: a surface spills past its occluding edges and silhouettes. Scaling the
//! opacity by `sqrt(det Sigma / det(Sigma + b I))` keeps each splat's integral on screen that of
//! the unblurred Gaussian, while the blur still keeps it at least a pixel filter wide.
//! The kernels apply it in the projection, with its gradient, when
//! [`SplatConfig::compensate_blur`] is set. [`blur_compensation`] computes the same factor as a
//! Burn expression differentiated by Burn's autodiff: to inspect or weigh the Gaussians
//! outside a render, and as the kernels' reference in the tests.

use burn::tensor::Tensor;

use crate::config::{QUAT_MIN_NORM2, SplatConfig};

/// The smallest compensation factor: a ratio of determinants below its square is clamped, so
/// the factor's gradient stays bounded for splats that are (nearly) degenerate on screen.
/// Their compensated opacity then lies below the 1/255 cut-off of any opacity <= 1.
pub const MIN_COMPENSATION: f64 = 1e-3;

/// Entries of the Jacobian-projected covariance factor are clamped to this many pixels, so a
/// splat of absurd size cannot overflow the determinants (the kernels cull such splats).
const MAX_SCREEN_STD_PX: f64 = 1e6;

/// Per Gaussian, `sqrt(det Sigma / det(Sigma + b I))` with `Sigma` the 2D covariance the
/// kernels project (EWA with the Jacobian at the mean, `x/z` and `y/z` clamped to the frame's
/// margin) and `b` = `config.blur_px2`: `[N]` in `[MIN_COMPENSATION, 1]`, 1 for a splat much
/// wider than the blur and small for one that is thin on screen. All ones when the blur is 0.
/// `means` `[N, 3]`, `quats` `[N, 4]` `(w, x, y, z)`, `scales` `[N, 3]` (standard deviations),
/// as in [`crate::SplatInputs`]. Finite, with finite gradients, for any inputs: a mean nearer
/// than the near plane is evaluated at the near plane, a non-finite parameter as 0 (the
/// kernels cull both).
pub fn blur_compensation(
    means: &Tensor<2>,
    quats: &Tensor<2>,
    scales: &Tensor<2>,
    config: &SplatConfig,
) -> Tensor<1> {
    let n = means.dims()[0];
    let b = config.blur_px2;
    if b <= 0.0 {
        return Tensor::ones([n], (&means.device(), means.dtype()));
    }
    let cam = &config.camera;
    // Non-finite parameters (culled by the kernels) enter as 0, so that neither the factor nor
    // its gradient turns NaN.
    let col = |t: &Tensor<2>, k: usize| {
        let c = t.clone().slice([0..n, k..k + 1]);
        c.clone().mask_fill(c.is_finite().bool_not(), 0.0)
    };
    let (m, s) = (
        [0, 1, 2].map(|k| col(means, k)),
        [0, 1, 2].map(|k| col(scales, k)),
    );
    // Camera-space mean p = W m + t.
    let w = cam.rotation;
    let p: [Tensor<2>; 3] = std::array::from_fn(|i| {
        m[0].clone() * w[i][0]
            + m[1].clone() * w[i][1]
            + m[2].clone() * w[i][2]
            + cam.translation[i]
    });
    // Unit quaternion (a degenerate one is culled by the kernels; keep it finite here).
    let q = [0, 1, 2, 3].map(|k| col(quats, k));
    let norm = q
        .iter()
        .map(|v| v.clone().powi_scalar(2))
        .reduce(|a, v| a + v)
        .expect("four components")
        .clamp_min(QUAT_MIN_NORM2)
        .sqrt();
    let [qw, qx, qy, qz] = q.map(|v| v / norm.clone());
    let two = |a: &Tensor<2>, b: &Tensor<2>| a.clone() * b.clone() * 2.0;
    let one_minus = |a: &Tensor<2>, b: &Tensor<2>| -(two(a, a) + two(b, b)) + 1.0;
    let r = [
        [
            one_minus(&qy, &qz),
            two(&qx, &qy) - two(&qw, &qz),
            two(&qx, &qz) + two(&qw, &qy),
        ],
        [
            two(&qx, &qy) + two(&qw, &qz),
            one_minus(&qx, &qz),
            two(&qy, &qz) - two(&qw, &qx),
        ],
        [
            two(&qx, &qz) - two(&qw, &qy),
            two(&qy, &qz) + two(&qw, &qx),
            one_minus(&qx, &qy),
        ],
    ];
    // A = W R diag(s): the camera-space covariance is A A^T.
    let a: [[Tensor<2>; 3]; 3] = std::array::from_fn(|i| {
        std::array::from_fn(|k| {
            (r[0][k].clone() * w[i][0] + r[1][k].clone() * w[i][1] + r[2][k].clone() * w[i][2])
                * s[k].clone()
        })
    });
    // The EWA Jacobian at the mean, as the kernels evaluate it.
    let z = p[2].clone().clamp_min(cam.near);
    let (lx, ly) = cam.jacobian_limits();
    let tx = (p[0].clone() / z.clone()).clamp(lx[0], lx[1]) * z.clone();
    let ty = (p[1].clone() / z.clone()).clamp(ly[0], ly[1]) * z.clone();
    let iz = z.recip();
    let iz2 = iz.clone().powi_scalar(2);
    let (j00, j11) = (iz.clone() * cam.fx, iz * cam.fy);
    let j02 = -(tx * iz2.clone() * cam.fx);
    let j12 = -(ty * iz2 * cam.fy);
    // T = J A (2 x 3); the blur-free screen covariance is T T^T = [[ca, cb], [cb, cc]].
    let lim = MAX_SCREEN_STD_PX;
    let t0: [Tensor<2>; 3] = std::array::from_fn(|k| {
        (j00.clone() * a[0][k].clone() + j02.clone() * a[2][k].clone()).clamp(-lim, lim)
    });
    let t1: [Tensor<2>; 3] = std::array::from_fn(|k| {
        (j11.clone() * a[1][k].clone() + j12.clone() * a[2][k].clone()).clamp(-lim, lim)
    });
    let dot = |u: &[Tensor<2>; 3], v: &[Tensor<2>; 3]| {
        u[0].clone() * v[0].clone() + u[1].clone() * v[1].clone() + u[2].clone() * v[2].clone()
    };
    let (ca, cb, cc) = (dot(&t0, &t0), dot(&t0, &t1), dot(&t1, &t1));
    let cb2 = cb.powi_scalar(2);
    let det0 = ca.clone() * cc.clone() - cb2.clone();
    let det1 = (ca + b) * (cc + b) - cb2;
    let floor = MIN_COMPENSATION * MIN_COMPENSATION;
    (det0 / det1).clamp(floor, 1.0).sqrt().reshape([n])
}
