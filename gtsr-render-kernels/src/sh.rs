//! Colours from real spherical harmonics (degree 0 to 3, the 3DGS basis and signs) in each
//! Gaussian's view direction, differentiable in the coefficients and the means.
//!
//! [`sh_colours`] gives, per Gaussian `i` and channel `c`,
//! `max(0, C0 dc[i, c] + 0.5 + sum_{k = 1}^{K - 1} Y_k(d_i) rest[i, 3 (k - 1) + c])`, with
//! `d_i = (mean_i - centre) / |mean_i - centre|` the direction from the camera centre to the
//! Gaussian and `K = (degree + 1)^2`. Coefficients of `rest` past the degree are ignored (their
//! gradient is zero).
//!
//! On NdArray it runs as a backend extension ([`ShBackend`]): one pass over the Gaussians
//! forward and one backward, parallel over chunks of Gaussians, where the same expression in
//! Burn ops takes about forty tensor ops and their autodiff nodes. Other devices take
//! [`sh_colours_by_tensor_ops`].

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
use crate::scalar::Real;

/// The degree-0 basis value `Y_0^0`.
pub const C0: f64 = 0.282_094_791_773_878_14;
/// The degree-1 factor.
pub const C1: f64 = 0.488_602_511_902_919_9;
/// The degree-2 factors.
pub const C2: [f64; 5] = [
    1.092_548_430_592_079_2,
    -1.092_548_430_592_079_2,
    0.315_391_565_252_520_05,
    -1.092_548_430_592_079_2,
    0.546_274_215_296_039_6,
];
/// The degree-3 factors.
pub const C3: [f64; 7] = [
    -0.590_043_589_926_643_5,
    2.890_611_442_640_554,
    -0.457_045_799_464_465_8,
    0.373_176_332_590_115_4,
    -0.457_045_799_464_465_8,
    1.445_305_721_320_277,
    -0.590_043_589_926_643_5,
];

/// The highest degree supported.
pub const MAX_DEGREE: u32 = 3;

/// Basis functions per channel for `degree` (`(degree + 1)^2`).
pub fn coeffs(degree: u32) -> usize {
    ((degree + 1) * (degree + 1)) as usize
}

/// The camera centre and the degree of one evaluation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShView {
    /// The camera centre (world).
    pub centre: [f64; 3],
    /// The degree in use, at most [`MAX_DEGREE`].
    pub degree: u32,
}

/// The SH colours as a backend op (NdArray, and autodiff over it). Use [`sh_colours`], which
/// picks this op or the tensor ops by device.
#[backend_extension(Autodiff, NdArray)]
pub trait ShBackend: Backend {
    /// Colours `[N, 3]` from `dc` `[N, 3]`, `rest` `[N, 3 M]` (`M >= coeffs(degree) - 1`) and
    /// `means` `[N, 3]`; see the module docs.
    fn sh_colours(
        dc: FloatTensor<Self>,
        rest: FloatTensor<Self>,
        means: FloatTensor<Self>,
        view: ShView,
    ) -> FloatTensor<Self>;
}

/// The kernels behind [`ShBackend`] on a backend: forward, and backward into `dc`, `rest` and
/// `means` given the colours' gradient.
pub trait ShKernels: Backend {
    /// The forward pass.
    fn sh_forward(
        dc: &FloatTensor<Self>,
        rest: &FloatTensor<Self>,
        means: &FloatTensor<Self>,
        view: ShView,
    ) -> FloatTensor<Self>;

    /// The gradients of `dc`, `rest` and `means`.
    fn sh_backward(
        dc: &FloatTensor<Self>,
        rest: &FloatTensor<Self>,
        means: &FloatTensor<Self>,
        view: ShView,
        grad: FloatTensor<Self>,
    ) -> [FloatTensor<Self>; 3];
}

impl ShKernels for NdArray {
    fn sh_forward(
        dc: &NdArrayTensor,
        rest: &NdArrayTensor,
        means: &NdArrayTensor,
        view: ShView,
    ) -> NdArrayTensor {
        if is_f64(dc) {
            nd_forward::<f64>(dc, rest, means, view)
        } else {
            nd_forward::<f32>(dc, rest, means, view)
        }
    }

    fn sh_backward(
        dc: &NdArrayTensor,
        rest: &NdArrayTensor,
        means: &NdArrayTensor,
        view: ShView,
        grad: NdArrayTensor,
    ) -> [NdArrayTensor; 3] {
        if is_f64(dc) {
            nd_backward::<f64>(dc, rest, means, view, &grad)
        } else {
            nd_backward::<f32>(dc, rest, means, view, &grad)
        }
    }
}

impl ShBackend for NdArray {
    fn sh_colours(
        dc: NdArrayTensor,
        rest: NdArrayTensor,
        means: NdArrayTensor,
        view: ShView,
    ) -> NdArrayTensor {
        Self::sh_forward(&dc, &rest, &means, view)
    }
}

/// The number of rest coefficients per channel that `rest` holds (its columns over 3).
fn rest_per_channel(rest: &NdArrayTensor) -> usize {
    burn::backend::TensorMetadata::shape(rest).to_vec()[1] / 3
}

fn nd_forward<F: Real + burn::tensor::Element>(
    dc: &NdArrayTensor,
    rest: &NdArrayTensor,
    means: &NdArrayTensor,
    view: ShView,
) -> NdArrayTensor {
    let (dc, m) = (host_slice::<F>(dc), rest_per_channel(rest));
    let (rest, means) = (host_slice::<F>(rest), host_slice::<F>(means));
    let n = dc.len() / 3;
    to_nd(forward_host(&dc, &rest, m, &means, view), &[n, 3])
}

fn nd_backward<F: Real + burn::tensor::Element>(
    dc: &NdArrayTensor,
    rest: &NdArrayTensor,
    means: &NdArrayTensor,
    view: ShView,
    grad: &NdArrayTensor,
) -> [NdArrayTensor; 3] {
    let (dc, m) = (host_slice::<F>(dc), rest_per_channel(rest));
    let (rest, means) = (host_slice::<F>(rest), host_slice::<F>(means));
    let n = dc.len() / 3;
    let g = backward_host(&dc, &rest, m, &means, view, &host_slice::<F>(grad));
    [
        to_nd(g.dc, &[n, 3]),
        to_nd(g.rest, &[n, 3 * m]),
        to_nd(g.means, &[n, 3]),
    ]
}

#[derive(Debug)]
struct ShBackwardStep;

impl<B: ShKernels> Backward<B, 3> for ShBackwardStep {
    type State = (FloatTensor<B>, FloatTensor<B>, FloatTensor<B>, ShView);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        backward_step::<B, _, 3>(ops, grads, |(dc, rest, means, view), grad| {
            B::sh_backward(&dc, &rest, &means, view, grad)
        });
    }
}

impl<B: ShKernels, C: CheckpointStrategy> ShBackend for Autodiff<B, C> {
    fn sh_colours(
        dc: FloatTensor<Self>,
        rest: FloatTensor<Self>,
        means: FloatTensor<Self>,
        view: ShView,
    ) -> FloatTensor<Self> {
        let guards = [dc.node(), rest.node(), means.node()];
        let (dc, rest, means) = (
            dc.into_primitive(),
            rest.into_primitive(),
            means.into_primitive(),
        );
        let out = B::sh_forward(&dc, &rest, &means, view);
        match ShBackwardStep
            .prepare::<C>(guards)
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish((dc, rest, means, view), out),
            OpsKind::UnTracked(prep) => prep.finish(out),
        }
    }
}

/// Gaussians per parallel chunk.
const CHUNK: usize = 1024;

/// The unit direction from `centre` to `mean` and the length it was divided by (the squared
/// length clamped at `1e-24`, as [`sh_colours_by_tensor_ops`] does).
#[inline(always)]
fn direction<F: Real>(mean: &[F], centre: [F; 3]) -> ([F; 3], F, bool) {
    let v = [
        mean[0] - centre[0],
        mean[1] - centre[1],
        mean[2] - centre[2],
    ];
    let s = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    let floor = F::c(1e-24);
    let clamped = s < floor;
    let len = if clamped { floor } else { s }.sqrt();
    ([v[0] / len, v[1] / len, v[2] / len], len, clamped)
}

/// The basis values `Y_1..Y_{K-1}` at the unit direction `d` (`K = coeffs(degree)`), into
/// `out[..K - 1]`.
#[inline(always)]
fn basis<F: Real>(d: [F; 3], degree: u32, out: &mut [F; 15]) {
    let c = |v: f64| F::c(v);
    let [x, y, z] = d;
    if degree >= 1 {
        out[0] = -c(C1) * y;
        out[1] = c(C1) * z;
        out[2] = -c(C1) * x;
    }
    if degree >= 2 {
        let (xx, yy, zz) = (x * x, y * y, z * z);
        out[3] = c(C2[0]) * x * y;
        out[4] = c(C2[1]) * y * z;
        out[5] = c(C2[2]) * (c(2.0) * zz - xx - yy);
        out[6] = c(C2[3]) * x * z;
        out[7] = c(C2[4]) * (xx - yy);
        if degree >= 3 {
            out[8] = c(C3[0]) * y * (c(3.0) * xx - yy);
            out[9] = c(C3[1]) * x * y * z;
            out[10] = c(C3[2]) * y * (c(4.0) * zz - xx - yy);
            out[11] = c(C3[3]) * z * (c(2.0) * zz - c(3.0) * xx - c(3.0) * yy);
            out[12] = c(C3[4]) * x * (c(4.0) * zz - xx - yy);
            out[13] = c(C3[5]) * z * (xx - yy);
            out[14] = c(C3[6]) * x * (xx - c(3.0) * yy);
        }
    }
}

/// The gradient of `sum_k w[k] Y_{k+1}(d)` with respect to `d`, the basis read as polynomials
/// in `d`'s components.
#[inline(always)]
fn basis_gradient<F: Real>(d: [F; 3], degree: u32, w: &[F; 15]) -> [F; 3] {
    let c = |v: f64| F::c(v);
    let [x, y, z] = d;
    let mut g = [F::zero(); 3];
    if degree >= 1 {
        g[1] = g[1] - c(C1) * w[0];
        g[2] = g[2] + c(C1) * w[1];
        g[0] = g[0] - c(C1) * w[2];
    }
    if degree >= 2 {
        let (xx, yy, zz) = (x * x, y * y, z * z);
        let add = |g: &mut [F; 3], k: F, dx: F, dy: F, dz: F| {
            g[0] = g[0] + k * dx;
            g[1] = g[1] + k * dy;
            g[2] = g[2] + k * dz;
        };
        let zero = F::zero();
        add(&mut g, c(C2[0]) * w[3], y, x, zero);
        add(&mut g, c(C2[1]) * w[4], zero, z, y);
        add(
            &mut g,
            c(C2[2]) * w[5],
            c(-2.0) * x,
            c(-2.0) * y,
            c(4.0) * z,
        );
        add(&mut g, c(C2[3]) * w[6], z, zero, x);
        add(&mut g, c(C2[4]) * w[7], c(2.0) * x, c(-2.0) * y, zero);
        if degree >= 3 {
            add(
                &mut g,
                c(C3[0]) * w[8],
                c(6.0) * x * y,
                c(3.0) * (xx - yy),
                zero,
            );
            add(&mut g, c(C3[1]) * w[9], y * z, x * z, x * y);
            add(
                &mut g,
                c(C3[2]) * w[10],
                c(-2.0) * x * y,
                c(4.0) * zz - xx - c(3.0) * yy,
                c(8.0) * y * z,
            );
            add(
                &mut g,
                c(C3[3]) * w[11],
                c(-6.0) * x * z,
                c(-6.0) * y * z,
                c(6.0) * zz - c(3.0) * xx - c(3.0) * yy,
            );
            add(
                &mut g,
                c(C3[4]) * w[12],
                c(4.0) * zz - c(3.0) * xx - yy,
                c(-2.0) * x * y,
                c(8.0) * x * z,
            );
            add(
                &mut g,
                c(C3[5]) * w[13],
                c(2.0) * x * z,
                c(-2.0) * y * z,
                xx - yy,
            );
            add(
                &mut g,
                c(C3[6]) * w[14],
                c(3.0) * (xx - yy),
                c(-6.0) * x * y,
                zero,
            );
        }
    }
    g
}

/// The colour of one Gaussian before the clamp at zero.
#[inline(always)]
fn raw_colour<F: Real>(dc: &[F], rest: &[F], b: &[F; 15], used: usize) -> [F; 3] {
    let mut out = [F::zero(); 3];
    for (ch, o) in out.iter_mut().enumerate() {
        let mut s = F::c(C0) * dc[ch] + F::c(0.5);
        for (k, bk) in b.iter().take(used).enumerate() {
            s = s + *bk * rest[3 * k + ch];
        }
        *o = s;
    }
    out
}

/// The rest coefficients per channel that `view.degree` uses, for the kernel and the tensor
/// ops alike; panics when the degree exceeds [`MAX_DEGREE`] or `rest` holds fewer (`m` per
/// channel).
fn check_degree(view: ShView, m: usize) -> usize {
    assert!(
        view.degree <= MAX_DEGREE,
        "sh_colours: degree {} above {MAX_DEGREE}",
        view.degree
    );
    let used = coeffs(view.degree) - 1;
    assert!(
        m >= used,
        "sh_colours: degree {} needs {used} rest coefficients per channel, got {m}",
        view.degree
    );
    used
}

/// The forward pass on host buffers: `dc` `[N, 3]`, `rest` `[N, 3 m]`, `means` `[N, 3]`.
pub(crate) fn forward_host<F: Real>(
    dc: &[F],
    rest: &[F],
    m: usize,
    means: &[F],
    view: ShView,
) -> Vec<F> {
    let used = check_degree(view, m);
    let centre = view.centre.map(F::c);
    let mut out = vec![F::zero(); dc.len()];
    out.par_chunks_mut(3 * CHUNK)
        .enumerate()
        .for_each(|(chunk, o)| {
            let mut b = [F::zero(); 15];
            for (j, oc) in o.chunks_mut(3).enumerate() {
                let i = chunk * CHUNK + j;
                let (d, _, _) = direction(&means[3 * i..3 * i + 3], centre);
                basis(d, view.degree, &mut b);
                let raw = raw_colour(
                    &dc[3 * i..3 * i + 3],
                    &rest[3 * m * i..3 * m * (i + 1)],
                    &b,
                    used,
                );
                for (a, r) in oc.iter_mut().zip(raw) {
                    *a = r.max(F::zero());
                }
            }
        });
    out
}

/// The gradients of [`backward_host`].
pub(crate) struct ShGrads<F> {
    pub dc: Vec<F>,
    pub rest: Vec<F>,
    pub means: Vec<F>,
}

/// The backward pass on host buffers, given the colours' gradient `grad` `[N, 3]`.
pub(crate) fn backward_host<F: Real>(
    dc: &[F],
    rest: &[F],
    m: usize,
    means: &[F],
    view: ShView,
    grad: &[F],
) -> ShGrads<F> {
    let used = check_degree(view, m);
    let centre = view.centre.map(F::c);
    let n = dc.len() / 3;
    let mut g_dc = vec![F::zero(); 3 * n];
    let mut g_rest = vec![F::zero(); 3 * m * n];
    let mut g_means = vec![F::zero(); 3 * n];
    g_dc.par_chunks_mut(3 * CHUNK)
        .zip(g_rest.par_chunks_mut(3 * m * CHUNK))
        .zip(g_means.par_chunks_mut(3 * CHUNK))
        .enumerate()
        .for_each(|(chunk, ((gd, gr), gm))| {
            let mut b = [F::zero(); 15];
            for j in 0..gd.len() / 3 {
                let i = chunk * CHUNK + j;
                let (d, len, clamped) = direction(&means[3 * i..3 * i + 3], centre);
                basis(d, view.degree, &mut b);
                let r = &rest[3 * m * i..3 * m * (i + 1)];
                let raw = raw_colour(&dc[3 * i..3 * i + 3], r, &b, used);
                // The clamp passes the gradient where the colour is positive.
                let g: [F; 3] = std::array::from_fn(|ch| {
                    if raw[ch] > F::zero() {
                        grad[3 * i + ch]
                    } else {
                        F::zero()
                    }
                });
                for ch in 0..3 {
                    gd[3 * j + ch] = F::c(C0) * g[ch];
                }
                // Per basis function, the weight of its value in the loss.
                let mut w = [F::zero(); 15];
                for (k, wk) in w.iter_mut().enumerate().take(used) {
                    let mut s = F::zero();
                    for ch in 0..3 {
                        gr[3 * m * j + 3 * k + ch] = b[k] * g[ch];
                        s = s + r[3 * k + ch] * g[ch];
                    }
                    *wk = s;
                }
                if used == 0 {
                    continue;
                }
                // Through the normalisation: (g - d (d . g)) / len, or g / len where the
                // squared length was clamped.
                let gdir = basis_gradient(d, view.degree, &w);
                let dot = if clamped {
                    F::zero()
                } else {
                    d[0] * gdir[0] + d[1] * gdir[1] + d[2] * gdir[2]
                };
                for a in 0..3 {
                    gm[3 * j + a] = (gdir[a] - d[a] * dot) / len;
                }
            }
        });
    ShGrads {
        dc: g_dc,
        rest: g_rest,
        means: g_means,
    }
}

/// SH colours `[N, 3]` from `dc` `[N, 3]`, `rest` `[N, 3 M]` (coefficient-major: column
/// `3 (k - 1) + channel`; `None` or `M = 0` for degree 0) and `means` `[N, 3]`, seen from
/// `view`; differentiable on an autodiff device (see the module docs).
///
/// # Panics
/// When `view.degree` exceeds [`MAX_DEGREE`] or `rest` holds fewer than
/// `coeffs(view.degree) - 1` coefficients per channel.
///
/// ```
/// use burn::tensor::{Device, Tensor};
/// use gtsr_render_kernels::sh::{ShView, sh_colours};
///
/// let device = Device::ndarray();
/// let dc = Tensor::<2>::zeros([4, 3], &device);
/// let rest = Tensor::<2>::zeros([4, 45], &device);
/// let means = Tensor::<2>::ones([4, 3], &device);
/// let view = ShView { centre: [0.0, 0.0, -4.0], degree: 3 };
/// let colours = sh_colours(dc, Some(rest), means, view);
/// // Zero coefficients: mid grey in every direction.
/// assert_eq!(colours.into_data().to_vec::<f32>()?, vec![0.5; 12]);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn sh_colours(
    dc: Tensor<2>,
    rest: Option<Tensor<2>>,
    means: Tensor<2>,
    view: ShView,
) -> Tensor<2> {
    let device = dc.device();
    let float = matches!(dc.dtype(), DType::F32 | DType::F64);
    let rest = match rest {
        Some(r) if view.degree > 0 => r,
        _ => return dc_colours(dc),
    };
    if float && on_ndarray(&device) && [rest.dtype(), means.dtype()] == [dc.dtype(); 2] {
        return Tensor::from_dispatch(<Dispatch as ShBackend>::sh_colours(
            dc.into_dispatch(),
            rest.into_dispatch(),
            means.into_dispatch(),
            view,
        ));
    }
    sh_colours_by_tensor_ops(dc, Some(rest), means, view)
}

/// The view-independent colours `max(0, C0 dc + 0.5)` (degree 0).
pub fn dc_colours(dc: Tensor<2>) -> Tensor<2> {
    (dc * C0 + 0.5).clamp_min(0.0)
}

/// The unit directions `[N, 3]` from `centre` to each of `means` `[N, 3]` in Burn tensor ops,
/// the squared lengths clamped at `1e-24` (a mean on the centre gives a zero direction), as
/// [`sh_colours`] takes them.
pub fn view_directions(means: Tensor<2>, centre: [f64; 3]) -> Tensor<2> {
    let centre = Tensor::<2>::from_data(
        TensorData::new(centre.to_vec(), [1, 3]),
        (&means.device(), means.dtype()),
    );
    let v = means - centre;
    let len = v
        .clone()
        .powf_scalar(2.0)
        .sum_dim(1)
        .clamp_min(1e-24)
        .sqrt();
    v / len
}

/// [`sh_colours`] in Burn tensor ops (any backend).
pub fn sh_colours_by_tensor_ops(
    dc: Tensor<2>,
    rest: Option<Tensor<2>>,
    means: Tensor<2>,
    view: ShView,
) -> Tensor<2> {
    let rest = match rest {
        Some(r) if view.degree > 0 => r,
        _ => return dc_colours(dc),
    };
    let m = rest.dims()[1] / 3;
    let used = check_degree(view, m);
    let n = dc.dims()[0];
    let (device, dtype) = (dc.device(), dc.dtype());
    let d = view_directions(means, view.centre);
    // Columns as products with unit vectors (contiguous on every backend), each basis function
    // a contiguous row of a [used, N] stack.
    let col = |j: usize| {
        let mut e = vec![0f32; 3];
        e[j] = 1.0;
        let e = Tensor::<2>::from_data(TensorData::new(e, [3, 1]), &device).cast(dtype);
        d.clone().matmul(e).reshape([1, n])
    };
    let (x, y, z) = (col(0), col(1), col(2));
    let mut b = vec![y.clone() * (-C1), z.clone() * C1, x.clone() * (-C1)];
    if view.degree >= 2 {
        let (xx, yy, zz) = (
            x.clone() * x.clone(),
            y.clone() * y.clone(),
            z.clone() * z.clone(),
        );
        b.push(x.clone() * y.clone() * C2[0]);
        b.push(y.clone() * z.clone() * C2[1]);
        b.push((zz.clone() * 2.0 - xx.clone() - yy.clone()) * C2[2]);
        b.push(x.clone() * z.clone() * C2[3]);
        b.push((xx.clone() - yy.clone()) * C2[4]);
        if view.degree >= 3 {
            b.push(y.clone() * (xx.clone() * 3.0 - yy.clone()) * C3[0]);
            b.push(x.clone() * y.clone() * z.clone() * C3[1]);
            b.push(y.clone() * (zz.clone() * 4.0 - xx.clone() - yy.clone()) * C3[2]);
            b.push(z.clone() * (zz.clone() * 2.0 - xx.clone() * 3.0 - yy.clone() * 3.0) * C3[3]);
            b.push(x.clone() * (zz.clone() * 4.0 - xx.clone() - yy.clone()) * C3[4]);
            b.push(z.clone() * (xx.clone() - yy.clone()) * C3[5]);
            b.push(x * (xx - yy * 3.0) * C3[6]);
        }
    }
    let rows = Tensor::cat(b, 0);
    // Each basis value repeated over its three coefficients ([used, 3 M], zero past the degree),
    // times the coefficients, then summed per channel ([3 M, 3]): two small products and one
    // contiguous multiplication.
    let total = 3 * m;
    let mut spread = vec![0f32; used * total];
    let mut per_channel = vec![0f32; total * 3];
    for j in 0..used {
        for ch in 0..3 {
            spread[j * total + 3 * j + ch] = 1.0;
            per_channel[(3 * j + ch) * 3 + ch] = 1.0;
        }
    }
    let constant = |v: Vec<f32>, shape: [usize; 2]| {
        Tensor::<2>::from_data(TensorData::new(v, shape), &device).cast(dtype)
    };
    let b3 = rows.transpose().matmul(constant(spread, [used, total]));
    let sum = (b3 * rest).matmul(constant(per_channel, [total, 3]));
    (dc * C0 + 0.5 + sum).clamp_min(0.0)
}

#[cfg(test)]
mod tests {
    use burn::tensor::Device;

    use super::*;
    use burn::tensor::DType::{F32, F64};
    use rand::{RngExt, SeedableRng};

    fn random(n: usize, seed: u64, scale: f64) -> Vec<f64> {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        (0..n)
            .map(|_| scale * (rng.random::<f64>() * 2.0 - 1.0))
            .collect()
    }

    fn tensor(v: Vec<f64>, shape: [usize; 2], device: &Device, dtype: DType) -> Tensor<2> {
        Tensor::<2>::from_data(TensorData::new(v, shape), (device, dtype))
    }

    fn host(t: Tensor<2>) -> Vec<f64> {
        t.cast(F64).into_data().to_vec::<f64>().unwrap()
    }

    /// Random inputs for `n` Gaussians with 15 rest coefficients per channel.
    fn inputs(n: usize, seed: u64) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        (
            random(3 * n, seed, 1.0),
            random(45 * n, seed + 1, 0.5),
            random(3 * n, seed + 2, 1.5),
        )
    }

    const CENTRE: [f64; 3] = [0.4, -0.3, -4.0];

    /// [`sh_colours`] or [`sh_colours_by_tensor_ops`].
    type Colours = fn(Tensor<2>, Option<Tensor<2>>, Tensor<2>, ShView) -> Tensor<2>;

    #[test]
    fn the_op_equals_the_tensor_ops_at_every_degree() {
        let device = Device::ndarray();
        let n = 2500; // more than two chunks
        let (dc, rest, means) = inputs(n, 3);
        for degree in 0..=MAX_DEGREE {
            let view = ShView {
                centre: CENTRE,
                degree,
            };
            // The colours by `colours` of the inputs as tensors of `dtype`.
            let run = |colours: Colours, dtype| {
                let t = |v: &Vec<f64>, c: usize| tensor(v.clone(), [n, c], &device, dtype);
                host(colours(t(&dc, 3), Some(t(&rest, 45)), t(&means, 3), view))
            };
            let op = run(sh_colours, F64);
            let ops = run(sh_colours_by_tensor_ops, F64);
            for (a, b) in op.iter().zip(&ops) {
                assert!((a - b).abs() < 1e-12, "degree {degree}: {a} against {b}");
            }
            // f32 against the f64 result.
            let op32 = run(sh_colours, F32);
            for (a, b) in op32.iter().zip(&op) {
                assert!((a - b).abs() < 1e-5, "degree {degree}: {a} against {b}");
            }
        }
    }

    #[test]
    fn the_basis_matches_the_closed_forms_on_the_axes() {
        // Y_1 = -C1 y, Y_2 = C1 z, Y_3 = -C1 x; on +z the degree-2 zonal term is 2 C2[2] and
        // the degree-3 zonal term 2 C3[3].
        let mut b = [0f64; 15];
        basis([0.0, 0.0, 1.0], 3, &mut b);
        let mut want = [0f64; 15];
        want[1] = C1;
        want[5] = 2.0 * C2[2];
        want[11] = 2.0 * C3[3];
        assert_eq!(b, want);
        basis([1.0, 0.0, 0.0], 3, &mut b);
        assert_eq!(b[2], -C1);
        assert_eq!(b[7], C2[4]);
        assert_eq!(b[14], C3[6]);
    }

    #[test]
    fn the_gradients_match_central_differences_in_f64() {
        let device = Device::ndarray().autodiff();
        let n = 7;
        let (dc0, rest0, means0) = inputs(n, 9);
        let u = random(3 * n, 12, 1.0);
        for degree in 0..=MAX_DEGREE {
            let view = ShView {
                centre: CENTRE,
                degree,
            };
            let plain = Device::ndarray();
            let loss = |dc: &Vec<f64>, rest: &Vec<f64>, means: &Vec<f64>| -> f64 {
                let c = host(sh_colours(
                    tensor(dc.clone(), [n, 3], &plain, F64),
                    Some(tensor(rest.clone(), [n, 45], &plain, F64)),
                    tensor(means.clone(), [n, 3], &plain, F64),
                    view,
                ));
                c.iter().zip(&u).map(|(a, b)| a * b).sum()
            };
            let dc = tensor(dc0.clone(), [n, 3], &device, F64).require_grad();
            let rest = tensor(rest0.clone(), [n, 45], &device, F64).require_grad();
            let means = tensor(means0.clone(), [n, 3], &device, F64).require_grad();
            let c = sh_colours(dc.clone(), Some(rest.clone()), means.clone(), view);
            let l = (c * tensor(u.clone(), [n, 3], &device, F64)).sum();
            let grads = l.backward();
            let eps = 1e-6;
            let check = |what: &str, g: Vec<f64>, x0: &Vec<f64>, which: usize| {
                for k in 0..x0.len() {
                    let (mut p, mut m) = (x0.clone(), x0.clone());
                    p[k] += eps;
                    m[k] -= eps;
                    let f = |x: &Vec<f64>| match which {
                        0 => loss(x, &rest0, &means0),
                        1 => loss(&dc0, x, &means0),
                        _ => loss(&dc0, &rest0, x),
                    };
                    let fd = (f(&p) - f(&m)) / (2.0 * eps);
                    assert!(
                        (g[k] - fd).abs() < 1e-7 * (1.0 + fd.abs()),
                        "degree {degree}, {what} {k}: {} against {fd}",
                        g[k]
                    );
                }
            };
            check("dc", host(dc.grad(&grads).unwrap()), &dc0, 0);
            if degree > 0 {
                check("rest", host(rest.grad(&grads).unwrap()), &rest0, 1);
                check("means", host(means.grad(&grads).unwrap()), &means0, 2);
            }
        }
    }

    #[test]
    fn stiff_inputs_give_finite_colours_and_gradients() {
        let device = Device::ndarray().autodiff();
        let n = 6;
        let (dc0, mut rest0, mut means0) = inputs(n, 21);
        // A mean on the camera centre (the squared length at its floor), one a few f32 steps
        // from it, one far away with huge coefficients.
        means0[..3].copy_from_slice(&CENTRE);
        means0[6..9].copy_from_slice(&[1e30, -1e30, 1e30]);
        rest0[95] = 1e30;
        rest0[100] = -1e30;
        let view = ShView {
            centre: CENTRE,
            degree: 3,
        };
        means0[3..6].copy_from_slice(&[CENTRE[0] + 1e-6, CENTRE[1], CENTRE[2]]);
        let dc = tensor(dc0, [n, 3], &device, F32).require_grad();
        let rest = tensor(rest0, [n, 45], &device, F32).require_grad();
        let means = tensor(means0, [n, 3], &device, F32).require_grad();
        let c = sh_colours(dc.clone(), Some(rest.clone()), means.clone(), view);
        assert!(host(c.clone()).iter().all(|v| v.is_finite()));
        let grads = (c * 1e-3).sum().backward();
        for g in [
            host(dc.grad(&grads).unwrap()),
            host(rest.grad(&grads).unwrap()),
            host(means.grad(&grads).unwrap()),
        ] {
            assert!(g.iter().all(|v| v.is_finite()), "{g:?}");
        }
    }
}
