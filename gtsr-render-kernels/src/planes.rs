//! Each flat Gaussian's plane as a camera sees it: its normal (the rotation's axis of the
//! smallest scale) turned to face the camera, in world and camera space, the plane's distance
//! from the camera centre, and the cosine between the normal and the direction to the camera.
//!
//! [`gaussian_planes`] gives, per Gaussian `i`, the `[N, 8]` row
//! `(n_w (3), n_c (3), -(n_c . p_c), n_w . v)`, where
//! - `R(q)` is the rotation of the quaternion `q = (w, x, y, z)` divided by
//!   `sqrt(max(|q|^2, 1e-24))`, and `a` the column of the smallest of the Gaussian's
//!   `log_scales` (the first on a tie);
//! - `n_w = s R(q)[:, a]`, with `s = +1` where the column points to the camera centre
//!   (`R(q)[:, a] . (centre - mean) >= 0`) and `-1` elsewhere;
//! - `n_c = R_cam n_w` and `p_c = R_cam mean + t_cam` in the camera's frame;
//! - `v = (centre - mean) / sqrt(max(|centre - mean|^2, 1e-24))`.
//!
//! The axis choice and the sign are piecewise constant: they carry no gradient, and the sign is
//! decided on the means as they are (no gradient into them through it). The gradients flow into
//! the quaternions and the means; `log_scales` gets none.
//!
//! On NdArray it runs as a backend extension ([`PlanesBackend`]): one pass over the Gaussians
//! forward and one backward, parallel over chunks, where the same expression in Burn ops takes
//! some thirty tensor ops and their autodiff nodes. Other devices take
//! [`gaussian_planes_by_tensor_ops`].

use burn::backend::{Autodiff, Backend, Dispatch, NdArray, backend_extension, tensor::FloatTensor};
use burn::tensor::{DType, Tensor, TensorData};
use burn_autodiff::{
    checkpoint::{base::Checkpointer, strategy::CheckpointStrategy},
    grads::Gradients,
    ops::{Backward, Ops, OpsKind},
};
use burn_ndarray::NdArrayTensor;
use rayon::prelude::*;

use crate::autodiff::backward_step;
use crate::backend::{host_slice, is_f64, on_ndarray, to_nd};
use crate::camera::Camera;
use crate::scalar::Real;

/// Columns of [`gaussian_planes`]'s output.
pub const PLANE_COLUMNS: usize = 8;
/// The floor of a quaternion's squared norm, and of the squared distance to the camera centre.
const NORM2_MIN: f64 = 1e-24;

/// The camera of one evaluation: its world-to-camera rotation (rows) and translation, and its
/// centre in the world.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlaneView {
    /// World-to-camera rotation, row-major.
    pub rotation: [[f64; 3]; 3],
    /// World-to-camera translation.
    pub translation: [f64; 3],
    /// The camera centre (world).
    pub centre: [f64; 3],
}

impl PlaneView {
    /// The view of `camera`.
    pub fn of(camera: &Camera) -> Self {
        Self {
            rotation: camera.rotation,
            translation: camera.translation,
            centre: camera.centre(),
        }
    }
}

/// The planes as a backend op (NdArray, and autodiff over it). Use [`gaussian_planes`], which
/// picks this op or the tensor ops by device.
#[backend_extension(Autodiff, NdArray)]
pub trait PlanesBackend: Backend {
    /// The `[N, 8]` rows of [`gaussian_planes`] from `quats` `[N, 4]`, `log_scales` `[N, 3]`
    /// (read, not differentiated) and `means` `[N, 3]`.
    fn gaussian_planes(
        quats: FloatTensor<Self>,
        log_scales: FloatTensor<Self>,
        means: FloatTensor<Self>,
        view: PlaneView,
    ) -> FloatTensor<Self>;
}

/// The kernels behind [`PlanesBackend`]: forward, and backward into the quaternions and the
/// means given the rows' gradient.
pub trait PlanesKernels: Backend {
    /// The forward pass.
    fn planes_forward(
        quats: &FloatTensor<Self>,
        log_scales: &FloatTensor<Self>,
        means: &FloatTensor<Self>,
        view: PlaneView,
    ) -> FloatTensor<Self>;

    /// The gradients of `quats` and `means`.
    fn planes_backward(
        quats: &FloatTensor<Self>,
        log_scales: &FloatTensor<Self>,
        means: &FloatTensor<Self>,
        view: PlaneView,
        grad: FloatTensor<Self>,
    ) -> [FloatTensor<Self>; 2];
}

impl PlanesKernels for NdArray {
    fn planes_forward(
        quats: &NdArrayTensor,
        log_scales: &NdArrayTensor,
        means: &NdArrayTensor,
        view: PlaneView,
    ) -> NdArrayTensor {
        if is_f64(quats) {
            nd_forward::<f64>(quats, log_scales, means, view)
        } else {
            nd_forward::<f32>(quats, log_scales, means, view)
        }
    }

    fn planes_backward(
        quats: &NdArrayTensor,
        log_scales: &NdArrayTensor,
        means: &NdArrayTensor,
        view: PlaneView,
        grad: NdArrayTensor,
    ) -> [NdArrayTensor; 2] {
        if is_f64(quats) {
            nd_backward::<f64>(quats, log_scales, means, view, &grad)
        } else {
            nd_backward::<f32>(quats, log_scales, means, view, &grad)
        }
    }
}

impl PlanesBackend for NdArray {
    fn gaussian_planes(
        quats: NdArrayTensor,
        log_scales: NdArrayTensor,
        means: NdArrayTensor,
        view: PlaneView,
    ) -> NdArrayTensor {
        Self::planes_forward(&quats, &log_scales, &means, view)
    }
}

fn nd_forward<F: Real + burn::tensor::Element>(
    quats: &NdArrayTensor,
    log_scales: &NdArrayTensor,
    means: &NdArrayTensor,
    view: PlaneView,
) -> NdArrayTensor {
    let (q, s, m) = (
        host_slice::<F>(quats),
        host_slice::<F>(log_scales),
        host_slice::<F>(means),
    );
    let n = m.len() / 3;
    to_nd(forward_host(&q, &s, &m, view), &[n, PLANE_COLUMNS])
}

fn nd_backward<F: Real + burn::tensor::Element>(
    quats: &NdArrayTensor,
    log_scales: &NdArrayTensor,
    means: &NdArrayTensor,
    view: PlaneView,
    grad: &NdArrayTensor,
) -> [NdArrayTensor; 2] {
    let (q, s, m) = (
        host_slice::<F>(quats),
        host_slice::<F>(log_scales),
        host_slice::<F>(means),
    );
    let n = m.len() / 3;
    let (gq, gm) = backward_host(&q, &s, &m, view, &host_slice::<F>(grad));
    [to_nd(gq, &[n, 4]), to_nd(gm, &[n, 3])]
}

#[derive(Debug)]
struct PlanesBackwardStep;

impl<B: PlanesKernels> Backward<B, 2> for PlanesBackwardStep {
    type State = (FloatTensor<B>, FloatTensor<B>, FloatTensor<B>, PlaneView);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        backward_step::<B, _, 2>(ops, grads, |(quats, log_scales, means, view), grad| {
            B::planes_backward(&quats, &log_scales, &means, view, grad)
        });
    }
}

impl<B: PlanesKernels, C: CheckpointStrategy> PlanesBackend for Autodiff<B, C> {
    fn gaussian_planes(
        quats: FloatTensor<Self>,
        log_scales: FloatTensor<Self>,
        means: FloatTensor<Self>,
        view: PlaneView,
    ) -> FloatTensor<Self> {
        let guards = [quats.node(), means.node()];
        let (quats, log_scales, means) = (
            quats.into_primitive(),
            log_scales.into_primitive(),
            means.into_primitive(),
        );
        let out = B::planes_forward(&quats, &log_scales, &means, view);
        match PlanesBackwardStep
            .prepare::<C>(guards)
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish((quats, log_scales, means, view), out),
            OpsKind::UnTracked(prep) => prep.finish(out),
        }
    }
}

/// Gaussians per parallel chunk.
const CHUNK: usize = 1024;

/// What the backward pass reads of one Gaussian's forward pass.
struct Row<F> {
    /// The unit quaternion and the norm it was divided by (clamped: the floor was used).
    u: [F; 4],
    norm: F,
    norm_clamped: bool,
    axis: usize,
    sign: F,
    n_w: [F; 3],
    n_c: [F; 3],
    p_c: [F; 3],
    /// The unit direction to the camera centre, the length it was divided by, and whether its
    /// square was clamped.
    v: [F; 3],
    v_len: F,
    v_clamped: bool,
}

/// Column `a` of the rotation matrix of the unit quaternion `u = (w, x, y, z)`.
#[inline(always)]
fn column<F: Real>(u: [F; 4], a: usize) -> [F; 3] {
    let [w, x, y, z] = u;
    let two = F::c(2.0);
    match a {
        0 => [
            w * w + x * x - y * y - z * z,
            two * (x * y + w * z),
            two * (x * z - w * y),
        ],
        1 => [
            two * (x * y - w * z),
            w * w - x * x + y * y - z * z,
            two * (y * z + w * x),
        ],
        _ => [
            two * (x * z + w * y),
            two * (y * z - w * x),
            w * w - x * x - y * y + z * z,
        ],
    }
}

/// The gradient in `u` of `g . column(u, a)`.
#[inline(always)]
fn column_gradient<F: Real>(u: [F; 4], a: usize, g: [F; 3]) -> [F; 4] {
    let [w, x, y, z] = u;
    let two = F::c(2.0);
    // d column / d (w, x, y, z), one row per component of the column.
    let d: [[F; 4]; 3] = match a {
        0 => [[w, x, -y, -z], [z, y, x, w], [-y, z, -w, x]],
        1 => [[-z, y, x, -w], [w, -x, y, -z], [x, w, z, y]],
        _ => [[y, z, w, x], [-x, -w, z, y], [w, -x, -y, z]],
    };
    std::array::from_fn(|k| two * (g[0] * d[0][k] + g[1] * d[1][k] + g[2] * d[2][k]))
}

/// `rotation v` for a row-major rotation.
#[inline(always)]
fn rotate<F: Real>(r: &[[F; 3]; 3], v: [F; 3]) -> [F; 3] {
    std::array::from_fn(|j| r[j][0] * v[0] + r[j][1] * v[1] + r[j][2] * v[2])
}

/// `rotation^T v` for a row-major rotation.
#[inline(always)]
fn rotate_back<F: Real>(r: &[[F; 3]; 3], v: [F; 3]) -> [F; 3] {
    std::array::from_fn(|k| r[0][k] * v[0] + r[1][k] * v[1] + r[2][k] * v[2])
}

#[inline(always)]
fn dot<F: Real>(a: [F; 3], b: [F; 3]) -> F {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// One Gaussian's forward pass.
#[inline(always)]
fn row<F: Real>(q: &[F], s: &[F], m: &[F], r: &[[F; 3]; 3], t: [F; 3], centre: [F; 3]) -> Row<F> {
    let floor = F::c(NORM2_MIN);
    let q2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3];
    let norm_clamped = q2 < floor;
    let norm = if norm_clamped { floor } else { q2 }.sqrt();
    let u = [q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm];
    let mut axis = 0;
    for k in 1..3 {
        if s[k] < s[axis] {
            axis = k;
        }
    }
    let col = column(u, axis);
    let to_centre = [centre[0] - m[0], centre[1] - m[1], centre[2] - m[2]];
    let sign = if dot(col, to_centre) >= F::zero() {
        F::one()
    } else {
        -F::one()
    };
    let n_w = col.map(|v| v * sign);
    let n_c = rotate(r, n_w);
    let p = rotate(r, [m[0], m[1], m[2]]);
    let p_c = [p[0] + t[0], p[1] + t[1], p[2] + t[2]];
    let l2 = dot(to_centre, to_centre);
    let v_clamped = l2 < floor;
    let v_len = if v_clamped { floor } else { l2 }.sqrt();
    let v = to_centre.map(|x| x / v_len);
    Row {
        u,
        norm,
        norm_clamped,
        axis,
        sign,
        n_w,
        n_c,
        p_c,
        v,
        v_len,
        v_clamped,
    }
}

/// The view's rotation, translation and centre in `F`.
fn view_in<F: Real>(view: PlaneView) -> ([[F; 3]; 3], [F; 3], [F; 3]) {
    (
        view.rotation.map(|r| r.map(F::c)),
        view.translation.map(F::c),
        view.centre.map(F::c),
    )
}

/// The forward pass on host buffers: `quats` `[N, 4]`, `log_scales` `[N, 3]`, `means`
/// `[N, 3]`; the `[N, 8]` rows.
pub fn forward_host<F: Real>(
    quats: &[F],
    log_scales: &[F],
    means: &[F],
    view: PlaneView,
) -> Vec<F> {
    let (r, t, centre) = view_in::<F>(view);
    let n = means.len() / 3;
    let mut out = vec![F::zero(); PLANE_COLUMNS * n];
    out.par_chunks_mut(PLANE_COLUMNS * CHUNK)
        .enumerate()
        .for_each(|(chunk, o)| {
            for (j, oc) in o.chunks_mut(PLANE_COLUMNS).enumerate() {
                let i = chunk * CHUNK + j;
                let g = row(
                    &quats[4 * i..4 * i + 4],
                    &log_scales[3 * i..3 * i + 3],
                    &means[3 * i..3 * i + 3],
                    &r,
                    t,
                    centre,
                );
                oc[..3].copy_from_slice(&g.n_w);
                oc[3..6].copy_from_slice(&g.n_c);
                oc[6] = -dot(g.n_c, g.p_c);
                oc[7] = dot(g.n_w, g.v);
            }
        });
    out
}

/// The backward pass on host buffers given the rows' gradient `grad` `[N, 8]`: the gradients
/// of the quaternions `[N, 4]` and of the means `[N, 3]`.
pub fn backward_host<F: Real>(
    quats: &[F],
    log_scales: &[F],
    means: &[F],
    view: PlaneView,
    grad: &[F],
) -> (Vec<F>, Vec<F>) {
    let (r, t, centre) = view_in::<F>(view);
    let n = means.len() / 3;
    let mut g_q = vec![F::zero(); 4 * n];
    let mut g_m = vec![F::zero(); 3 * n];
    g_q.par_chunks_mut(4 * CHUNK)
        .zip(g_m.par_chunks_mut(3 * CHUNK))
        .enumerate()
        .for_each(|(chunk, (gq, gm))| {
            for j in 0..gm.len() / 3 {
                let i = chunk * CHUNK + j;
                let m = &means[3 * i..3 * i + 3];
                let g = row(
                    &quats[4 * i..4 * i + 4],
                    &log_scales[3 * i..3 * i + 3],
                    m,
                    &r,
                    t,
                    centre,
                );
                let go = &grad[PLANE_COLUMNS * i..PLANE_COLUMNS * (i + 1)];
                let (g_plane, g_cos) = (go[6], go[7]);
                // plane = -(n_c . p_c), p_c = R m + t.
                let g_nc: [F; 3] = std::array::from_fn(|k| go[3 + k] - g_plane * g.p_c[k]);
                let g_pc = g.n_c.map(|v| -g_plane * v);
                let mut g_mean = rotate_back(&r, g_pc);
                // n_c = R n_w; cos = n_w . v.
                let back = rotate_back(&r, g_nc);
                let g_nw: [F; 3] = std::array::from_fn(|k| go[k] + back[k] + g_cos * g.v[k]);
                // v = (centre - m) / |centre - m|: d v / d m = -(I - v v^T) / |.|.
                let g_v = g.n_w.map(|x| g_cos * x);
                let along = if g.v_clamped {
                    F::zero()
                } else {
                    dot(g.v, g_v)
                };
                for k in 0..3 {
                    g_mean[k] = g_mean[k] - (g_v[k] - g.v[k] * along) / g.v_len;
                }
                // n_w = sign R(u)[:, a], u = q / |q|.
                let g_col = g_nw.map(|x| x * g.sign);
                let g_u = column_gradient(g.u, g.axis, g_col);
                let along_u = if g.norm_clamped {
                    F::zero()
                } else {
                    g.u[0] * g_u[0] + g.u[1] * g_u[1] + g.u[2] * g_u[2] + g.u[3] * g_u[3]
                };
                for k in 0..4 {
                    gq[4 * j + k] = (g_u[k] - g.u[k] * along_u) / g.norm;
                }
                gm[3 * j..3 * j + 3].copy_from_slice(&g_mean);
            }
        });
    (g_q, g_m)
}

/// The `[N, 8]` planes of the Gaussians with `quats` `[N, 4]`, `log_scales` `[N, 3]` and
/// `means` `[N, 3]` as `camera` sees them (see the module docs); differentiable on an autodiff
/// device in the quaternions and the means.
///
/// ```
/// use burn::tensor::{Device, Tensor};
/// use gtsr_render_kernels::{Camera, planes::gaussian_planes};
///
/// let device = Device::ndarray();
/// let camera = Camera::look_at([0.0, 0.0, -4.0], [0.0; 3], [0.0, -1.0, 0.0], 0.8, 64, 64)?;
/// // The identity rotation, flattest along z, at the origin: its normal is the z axis, turned
/// // to face the camera at z = -4; the plane lies 4 from the camera and faces it squarely.
/// let quats = Tensor::<2>::from_floats([[1.0, 0.0, 0.0, 0.0]], &device);
/// let log_scales = Tensor::<2>::from_floats([[0.0, 0.0, -3.0]], &device);
/// let means = Tensor::<2>::zeros([1, 3], &device);
/// let planes = gaussian_planes(quats, log_scales, means, &camera);
/// let row = planes.into_data().to_vec::<f32>()?;
/// assert_eq!(&row[..3], &[0.0, 0.0, -1.0]);
/// assert!((row[6] - 4.0).abs() < 1e-5 && (row[7] - 1.0).abs() < 1e-6);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn gaussian_planes(
    quats: Tensor<2>,
    log_scales: Tensor<2>,
    means: Tensor<2>,
    camera: &Camera,
) -> Tensor<2> {
    let device = means.device();
    let dtype = means.dtype();
    let fused = matches!(dtype, DType::F32 | DType::F64)
        && [quats.dtype(), log_scales.dtype()] == [dtype; 2]
        && on_ndarray(&device);
    if !fused {
        return gaussian_planes_by_tensor_ops(quats, log_scales, means, camera);
    }
    Tensor::from_dispatch(<Dispatch as PlanesBackend>::gaussian_planes(
        quats.into_dispatch(),
        log_scales.detach().into_dispatch(),
        means.into_dispatch(),
        PlaneView::of(camera),
    ))
}

/// [`gaussian_planes`] in Burn tensor ops (any backend).
pub fn gaussian_planes_by_tensor_ops(
    quats: Tensor<2>,
    log_scales: Tensor<2>,
    means: Tensor<2>,
    camera: &Camera,
) -> Tensor<2> {
    let centre = camera.centre();
    let n_w = facing_normals(&quat_to_matrix(&quats), &log_scales, &means, centre);
    let (r, t) = camera_tensors(camera, &means);
    let n_c = n_w.clone().matmul(r.clone().transpose());
    let p_c = means.clone().matmul(r.transpose()) + t;
    let plane = (n_c.clone() * p_c).sum_dim(1).neg();
    let cos = (n_w.clone() * crate::sh::view_directions(means, centre).neg()).sum_dim(1);
    Tensor::cat(vec![n_w, n_c, plane, cos], 1)
}

/// A camera's rotation (world to camera, rows) `[3, 3]` and translation `[1, 3]` as tensors on
/// the device and in the dtype of `like`.
fn camera_tensors(camera: &Camera, like: &Tensor<2>) -> (Tensor<2>, Tensor<2>) {
    let opts = (&like.device(), like.dtype());
    let r: Vec<f64> = camera.rotation.iter().flatten().copied().collect();
    (
        Tensor::from_data(TensorData::new(r, [3, 3]), opts),
        Tensor::from_data(TensorData::new(camera.translation.to_vec(), [1, 3]), opts),
    )
}

/// `[N, 3, 3]` rotation matrices from quaternions `(w, x, y, z)` `[N, 4]` (normalised here), in
/// Burn tensor ops.
pub fn quat_to_matrix(q: &Tensor<2>) -> Tensor<3> {
    let n = q.dims()[0];
    let norm = q
        .clone()
        .powf_scalar(2.0)
        .sum_dim(1)
        .clamp_min(NORM2_MIN)
        .sqrt();
    let q = q.clone() / norm;
    // Every entry is a quadratic form of the unit quaternion, so the nine entries are the
    // sixteen products q_a q_b times a constant [16, 9] matrix (one pass, contiguous).
    let outer = (q.clone().reshape([n, 4, 1]) * q.reshape([n, 1, 4])).reshape([n, 16]);
    let coeffs = rotation_from_products(&outer);
    outer.matmul(coeffs).reshape([n, 3, 3])
}

/// `[16, 9]`: row `4a + b` holds the coefficient of `q_a q_b` (`q = (w, x, y, z)`, unit) in
/// each entry of the row-major rotation matrix, split evenly between `q_a q_b` and `q_b q_a`.
fn rotation_from_products(like: &Tensor<2>) -> Tensor<2> {
    const W: usize = 0;
    const X: usize = 1;
    const Y: usize = 2;
    const Z: usize = 3;
    let mut m = [[0f32; 9]; 16];
    let mut add = |entry: usize, a: usize, b: usize, coeff: f32| {
        if a == b {
            m[4 * a + b][entry] += coeff;
        } else {
            m[4 * a + b][entry] += coeff / 2.0;
            m[4 * b + a][entry] += coeff / 2.0;
        }
    };
    // 1 - 2 (y^2 + z^2) = w^2 + x^2 - y^2 - z^2 on the unit sphere, and so on.
    for (entry, signs) in [
        (0, [1.0, 1.0, -1.0, -1.0]),
        (4, [1.0, -1.0, 1.0, -1.0]),
        (8, [1.0, -1.0, -1.0, 1.0]),
    ] {
        for (k, s) in signs.into_iter().enumerate() {
            add(entry, k, k, s);
        }
    }
    add(1, X, Y, 2.0);
    add(1, W, Z, -2.0);
    add(2, X, Z, 2.0);
    add(2, W, Y, 2.0);
    add(3, X, Y, 2.0);
    add(3, W, Z, 2.0);
    add(5, Y, Z, 2.0);
    add(5, W, X, -2.0);
    add(6, X, Z, 2.0);
    add(6, W, Y, -2.0);
    add(7, Y, Z, 2.0);
    add(7, W, X, 2.0);
    let v: Vec<f32> = m.iter().flatten().copied().collect();
    Tensor::<2>::from_data(TensorData::new(v, [16, 9]), &like.device()).cast(like.dtype())
}

/// `[N, 3]` one-hot rows marking each Gaussian's normal axis, that of its smallest scale
/// (decided on the detached `log_scales`; in their dtype).
pub fn normal_axis(log_scales: &Tensor<2>) -> Tensor<2> {
    let n = log_scales.dims()[0];
    let axis = log_scales.clone().detach().argmin(1).reshape([n]);
    let onehot: Tensor<2> = axis.one_hot::<2>(3).float();
    onehot.cast(log_scales.dtype())
}

/// `[N, 3]` world-space normals in Burn tensor ops: the rotation column of the smallest scale,
/// flipped to face the camera centre. The axis choice and the flip are piecewise constant (no
/// gradient), the rotation is differentiated.
pub fn facing_normals(
    rot: &Tensor<3>,
    log_scales: &Tensor<2>,
    means: &Tensor<2>,
    centre: [f64; 3],
) -> Tensor<2> {
    let n = means.dims()[0];
    let device = means.device();
    let onehot = normal_axis(log_scales);
    // The column as a masked row sum in contiguous [N, 9] rows (row-major entries): the
    // one-hot spread over the entries of its column, and the rows summed, as products with
    // 0/1 matrices. A batched [3, 3] x [3, 1] product would run one tiny matrix product per
    // Gaussian, forward and backward, and a broadcast product takes ndarray's slow path.
    let entries = |rows: usize, cols: usize, one: &dyn Fn(usize, usize) -> bool| {
        let v: Vec<f32> = (0..rows * cols)
            .map(|k| f32::from(u8::from(one(k / cols, k % cols))))
            .collect();
        Tensor::<2>::from_data(TensorData::new(v, [rows, cols]), &device).cast(means.dtype())
    };
    // [3, 9]: axis c marks entries 3 r + c; [9, 3]: entry 3 r + c adds to row r.
    let spread = entries(3, 9, &|c, e| e % 3 == c);
    let rows = entries(9, 3, &|e, r| e / 3 == r);
    let normal = (rot.clone().reshape([n, 9]) * onehot.matmul(spread)).matmul(rows);
    let c = Tensor::<2>::from_data(
        TensorData::new(centre.map(|v| v as f32).to_vec(), [1, 3]),
        &device,
    )
    .cast(means.dtype());
    let to_cam = c - means.clone().detach();
    let side = (normal.clone().detach() * to_cam).sum_dim(1);
    let sign = side.greater_equal_elem(0.0).float().cast(means.dtype()) * 2.0 - 1.0;
    normal * sign
}

#[cfg(test)]
mod tests {
    use burn::tensor::DType::{F32, F64};
    use burn::tensor::Device;
    use rand::{RngExt, SeedableRng, rngs::StdRng};

    use super::*;

    fn camera() -> Camera {
        Camera::look_at(
            [0.5, -0.4, -4.0],
            [0.1, 0.0, 0.2],
            [0.0, -1.0, 0.0],
            0.8,
            64,
            48,
        )
        .expect("a camera")
    }

    /// Random quaternions, log-scales (distinct per row) and means of `n` Gaussians.
    fn inputs(n: usize, seed: u64) -> [Vec<f64>; 3] {
        let mut rng = StdRng::seed_from_u64(seed);
        let mut r = |k: usize, lo: f64, hi: f64| -> Vec<f64> {
            (0..k).map(|_| rng.random_range(lo..hi)).collect()
        };
        [
            r(4 * n, -1.0, 1.0),
            r(3 * n, -5.0, 0.0),
            r(3 * n, -1.5, 1.5),
        ]
    }

    fn tensor(v: &[f64], cols: usize, device: &Device, dtype: DType) -> Tensor<2> {
        Tensor::<2>::from_data(
            TensorData::new(v.to_vec(), [v.len() / cols, cols]),
            (device, dtype),
        )
    }

    fn host(t: Tensor<2>) -> Vec<f64> {
        t.cast(F64).into_data().to_vec::<f64>().unwrap()
    }

    type Planes = fn(Tensor<2>, Tensor<2>, Tensor<2>, &Camera) -> Tensor<2>;

    #[test]
    fn the_op_equals_the_tensor_ops_forward_and_backward() {
        let n = 2500; // more than two chunks
        let [q, s, m] = inputs(n, 3);
        let cam = camera();
        let plain = Device::ndarray();
        let run = |planes: Planes, dtype| {
            host(planes(
                tensor(&q, 4, &plain, dtype),
                tensor(&s, 3, &plain, dtype),
                tensor(&m, 3, &plain, dtype),
                &cam,
            ))
        };
        let op = run(gaussian_planes, F64);
        for (a, b) in op.iter().zip(&run(gaussian_planes_by_tensor_ops, F64)) {
            assert!((a - b).abs() < 1e-12, "{a} against {b}");
        }
        for (a, b) in run(gaussian_planes, F32).iter().zip(&op) {
            assert!((a - b).abs() < 1e-5, "f32: {a} against {b}");
        }
        let device = Device::ndarray().autodiff();
        let mut rng = StdRng::seed_from_u64(4);
        let u: Vec<f64> = (0..PLANE_COLUMNS * n)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        let grads = |planes: Planes| {
            let qt = tensor(&q, 4, &device, F64).require_grad();
            let st = tensor(&s, 3, &device, F64).require_grad();
            let mt = tensor(&m, 3, &device, F64).require_grad();
            let out = planes(qt.clone(), st, mt.clone(), &cam);
            let g = (out * tensor(&u, PLANE_COLUMNS, &device, F64))
                .sum()
                .backward();
            [host(qt.grad(&g).unwrap()), host(mt.grad(&g).unwrap())]
        };
        for (a, b) in grads(gaussian_planes)
            .iter()
            .zip(grads(gaussian_planes_by_tensor_ops))
        {
            for (x, y) in a.iter().zip(&b) {
                assert!((x - y).abs() < 1e-12 * (1.0 + y.abs()), "{x} against {y}");
            }
        }
    }

    #[test]
    fn the_gradients_match_central_differences_in_f64() {
        let n = 12;
        let [q, s, m] = inputs(n, 7);
        let view = PlaneView::of(&camera());
        let mut rng = StdRng::seed_from_u64(8);
        let u: Vec<f64> = (0..PLANE_COLUMNS * n)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        let loss = |q: &[f64], m: &[f64]| -> f64 {
            forward_host(q, &s, m, view)
                .iter()
                .zip(&u)
                .map(|(a, b)| a * b)
                .sum()
        };
        let (gq, gm) = backward_host(&q, &s, &m, view, &u);
        let eps = 1e-6;
        let close = |what: &str, k: usize, got: f64, fd: f64| {
            assert!(
                (got - fd).abs() < 1e-7 * (1.0 + fd.abs()),
                "{what} {k}: {got} against {fd}"
            );
        };
        for k in 0..q.len() {
            let (mut p, mut mi) = (q.clone(), q.clone());
            p[k] += eps;
            mi[k] -= eps;
            close(
                "quats",
                k,
                gq[k],
                (loss(&p, &m) - loss(&mi, &m)) / (2.0 * eps),
            );
        }
        for k in 0..m.len() {
            let (mut p, mut mi) = (m.clone(), m.clone());
            p[k] += eps;
            mi[k] -= eps;
            close(
                "means",
                k,
                gm[k],
                (loss(&q, &p) - loss(&q, &mi)) / (2.0 * eps),
            );
        }
    }

    #[test]
    fn stiff_gaussians_give_finite_planes_and_gradients() {
        let n = 5;
        let [mut q, s, mut m] = inputs(n, 11);
        let cam = camera();
        // A zero quaternion; a tiny one; a huge one; a mean on the camera centre; a far mean.
        q[..4].copy_from_slice(&[0.0; 4]);
        q[4..8].copy_from_slice(&[1e-20, 0.0, 1e-21, 0.0]);
        q[8..12].copy_from_slice(&[1e18, -1e18, 1e18, 0.0]);
        m[9..12].copy_from_slice(&cam.centre());
        m[12..15].copy_from_slice(&[1e6, -1e6, 1e6]);
        let device = Device::ndarray().autodiff();
        let qt = tensor(&q, 4, &device, F32).require_grad();
        let mt = tensor(&m, 3, &device, F32).require_grad();
        let out = gaussian_planes(qt.clone(), tensor(&s, 3, &device, F32), mt.clone(), &cam);
        assert!(host(out.clone()).iter().all(|v| v.is_finite()));
        let g = (out * 1e-3).sum().backward();
        for t in [host(qt.grad(&g).unwrap()), host(mt.grad(&g).unwrap())] {
            assert!(t.iter().all(|v| v.is_finite()), "{t:?}");
        }
    }
}
