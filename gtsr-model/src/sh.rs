//! Real spherical harmonics up to degree 3 (the 3DGS basis and sign conventions): colours in
//! each Gaussian's view direction, differentiable in the coefficients and the means. The
//! evaluation is [`gtsr_render_kernels::sh`]'s (a CPU kernel on NdArray, Burn ops elsewhere).

use burn::tensor::Tensor;
use gtsr_render_kernels::sh::{C0, C1, C2, C3, ShView};

pub use gtsr_render_kernels::sh::coeffs;

/// The DC basis value (`Y_0^0`): a DC coefficient `c` contributes `C0 * c`.
pub const SH_C0: f64 = C0;

/// RGB colours `[N, 3]` from the DC coefficients alone (degree 0, the same in every
/// direction): [`colours`] without higher coefficients.
pub fn dc_colours(dc: &Tensor<2>) -> Tensor<2> {
    gtsr_render_kernels::sh::dc_colours(dc.clone())
}

/// RGB colours `[N, 3]` from DC `[N, 3]` and higher coefficients `[N, (K - 1) * 3]`
/// (coefficient-major: index `(k - 1) * 3 + channel`), evaluated up to `degree` in the
/// directions from the camera centre `centre` to the `means` `[N, 3]`. As 3DGS:
/// `max(0, sum + 0.5)`.
pub fn colours(
    dc: &Tensor<2>,
    rest: Option<&Tensor<2>>,
    means: &Tensor<2>,
    centre: [f64; 3],
    degree: u32,
) -> Tensor<2> {
    gtsr_render_kernels::sh::sh_colours(
        dc.clone(),
        rest.cloned(),
        means.clone(),
        ShView { centre, degree },
    )
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
