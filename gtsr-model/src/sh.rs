//! Real spherical harmonics up to degree 3 (the 3DGS basis and sign conventions), evaluated
//! with Burn ops so colours are differentiable in the coefficients and the view direction.

use burn::tensor::Tensor;

const C0: f64 = 0.282_094_791_773_878_14;
const C1: f64 = 0.488_602_511_902_919_9;
const C2: [f64; 5] = [
    1.092_548_430_592_079_2,
    -1.092_548_430_592_079_2,
    0.315_391_565_252_520_05,
    -1.092_548_430_592_079_2,
    0.546_274_215_296_039_6,
];
const C3: [f64; 7] = [
    -0.590_043_589_926_643_5,
    2.890_611_442_640_554,
    -0.457_045_799_464_465_8,
    0.373_176_332_590_115_4,
    -0.457_045_799_464_465_8,
    1.445_305_721_320_277,
    -0.590_043_589_926_643_5,
];

/// The DC basis value (`Y_0^0`): a DC coefficient `c` contributes `C0 * c`.
pub const SH_C0: f64 = C0;

/// Number of coefficients per channel for `degree`.
pub fn coeffs(degree: u32) -> usize {
    ((degree + 1) * (degree + 1)) as usize
}

/// The `[N, coeffs(degree) - 1]` basis values beyond DC for unit directions `dirs` `[N, 3]`
/// (`None` for degree 0).
pub fn basis_rest(dirs: &Tensor<2>, degree: u32) -> Option<Tensor<2>> {
    basis_rest_rows(dirs, degree).map(|rows| rows.transpose())
}

/// [`basis_rest`] as `[coeffs(degree) - 1, N]`: one contiguous row per basis function (rows
/// stack without strided writes on the NdArray backend).
fn basis_rest_rows(dirs: &Tensor<2>, degree: u32) -> Option<Tensor<2>> {
    if degree == 0 {
        return None;
    }
    let n = dirs.dims()[0];
    let col = |j: usize| crate::layout::col(dirs, j);
    let (x, y, z) = (col(0), col(1), col(2));
    let mut b = vec![y.clone() * (-C1), z.clone() * C1, x.clone() * (-C1)];
    if degree >= 2 {
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
        if degree >= 3 {
            b.push(y.clone() * (xx.clone() * 3.0 - yy.clone()) * C3[0]);
            b.push(x.clone() * y.clone() * z.clone() * C3[1]);
            b.push(y.clone() * (zz.clone() * 4.0 - xx.clone() - yy.clone()) * C3[2]);
            b.push(z.clone() * (zz.clone() * 2.0 - xx.clone() * 3.0 - yy.clone() * 3.0) * C3[3]);
            b.push(x.clone() * (zz.clone() * 4.0 - xx.clone() - yy.clone()) * C3[4]);
            b.push(z.clone() * (xx.clone() - yy.clone()) * C3[5]);
            b.push(x * (xx - yy * 3.0) * C3[6]);
        }
    }
    let rows = b.into_iter().map(|r| r.reshape([1, n])).collect();
    Some(Tensor::cat(rows, 0))
}

/// The view-independent part of the colour, before the clamp: `C0 dc + 0.5`.
fn dc_term(dc: &Tensor<2>) -> Tensor<2> {
    dc.clone() * C0 + 0.5
}

/// RGB colours `[N, 3]` from the DC coefficients alone (degree 0, the same in every
/// direction): [`colours`] without higher coefficients.
pub fn dc_colours(dc: &Tensor<2>) -> Tensor<2> {
    dc_term(dc).clamp_min(0.0)
}

/// RGB colours `[N, 3]` from DC `[N, 3]` and higher coefficients `[N, (K - 1) * 3]`
/// (coefficient-major: index `(k - 1) * 3 + channel`), evaluated up to `degree` in the unit
/// directions `dirs` (from the camera to the Gaussian). As 3DGS: `max(0, sum + 0.5)`.
pub fn colours(
    dc: &Tensor<2>,
    rest: Option<&Tensor<2>>,
    dirs: &Tensor<2>,
    degree: u32,
) -> Tensor<2> {
    let mut c = dc_term(dc);
    if let (Some(rest), Some(rows)) = (rest, basis_rest_rows(dirs, degree)) {
        let k = rows.dims()[0];
        let total = rest.dims()[1];
        // Each basis value repeated over its three coefficients ([k, total], zero past the
        // degree in use), multiplied by the coefficients, then summed per channel
        // ([total, 3]): two small products and one contiguous multiplication.
        let mut spread = vec![0f32; k * total];
        let mut per_channel = vec![0f32; total * 3];
        for j in 0..k {
            for ch in 0..3 {
                spread[j * total + 3 * j + ch] = 1.0;
                per_channel[(3 * j + ch) * 3 + ch] = 1.0;
            }
        }
        let (device, dtype) = (rest.device(), rest.dtype());
        let constant = |v: Vec<f32>, shape: [usize; 2]| {
            Tensor::<2>::from_data(burn::tensor::TensorData::new(v, shape), &device).cast(dtype)
        };
        let b3 = rows.transpose().matmul(constant(spread, [k, total]));
        c = c + (b3 * rest.clone()).matmul(constant(per_channel, [total, 3]));
    }
    c.clamp_min(0.0)
}

/// Host evaluation of the same basis (f64), for tests and exports.
pub fn basis_host(d: [f64; 3], degree: u32) -> Vec<f64> {
    let [x, y, z] = d;
    let mut b = vec![C0];
    if degree >= 1 {
        b.extend([-C1 * y, C1 * z, -C1 * x]);
    }
    if degree >= 2 {
        let (xx, yy, zz) = (x * x, y * y, z * z);
        b.extend([
            C2[0] * x * y,
            C2[1] * y * z,
            C2[2] * (2.0 * zz - xx - yy),
            C2[3] * x * z,
            C2[4] * (xx - yy),
        ]);
        if degree >= 3 {
            b.extend([
                C3[0] * y * (3.0 * xx - yy),
                C3[1] * x * y * z,
                C3[2] * y * (4.0 * zz - xx - yy),
                C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
                C3[4] * x * (4.0 * zz - xx - yy),
                C3[5] * z * (xx - yy),
                C3[6] * x * (xx - 3.0 * yy),
            ]);
        }
    }
    b
}
