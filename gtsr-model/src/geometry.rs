//! PGSR geometry: the unbiased depth `D = D_plane / -(N . r)` and normals from depth, in Burn
//! ops. Each Gaussian's normal (shortest axis, facing the camera) and plane distance are
//! [`gtsr_render_kernels::planes::gaussian_planes`] (one op on the CPU), whose Burn-ops pieces
//! are re-exported here.
//!
//! Conventions: OpenCV camera space (x right, y down, z forward); a pixel `(u, v)` (centre at
//! `i + 0.5`) has the ray `r = ((u - cx) / fx, (v - cy) / fy, 1)` so a point at z-depth `Z`
//! along it is `Z r`. Normals face the camera (`n . r < 0`), plane distances are positive.

use burn::tensor::{Bool, Device, Int, Tensor, TensorData};

use gtsr_render_kernels::Camera;

/// Smallest allowed `-(N . r)` in the unbiased depth (grazing or empty pixels).
pub const DEPTH_DENOM_MIN: f64 = 1e-3;

pub use gtsr_render_kernels::planes::{facing_normals, normal_axis, quat_to_matrix};

/// A camera's rotation (world to camera, rows) and translation as tensors: `([3, 3], [1, 3])`.
pub fn camera_tensors(camera: &Camera, device: &Device) -> (Tensor<2>, Tensor<2>) {
    let r: Vec<f32> = camera
        .rotation
        .iter()
        .flatten()
        .map(|v| *v as f32)
        .collect();
    let t: Vec<f32> = camera.translation.iter().map(|v| *v as f32).collect();
    (
        Tensor::from_data(TensorData::new(r, [3, 3]), device),
        Tensor::from_data(TensorData::new(t, [1, 3]), device),
    )
}

/// World points `[N, 3]` to camera space.
pub fn to_camera(points: &Tensor<2>, camera: &Camera) -> Tensor<2> {
    let (r, t) = camera_tensors(camera, &points.device());
    points.clone().matmul(r.transpose()) + t
}

/// The `[H, W, 3]` camera-space rays `((u - cx) / fx, (v - cy) / fy, 1)` through pixel centres.
pub fn pixel_rays(camera: &Camera, device: &Device) -> Tensor<3> {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let mut v = Vec::with_capacity(w * h * 3);
    for j in 0..h {
        for i in 0..w {
            v.push(((i as f64 + 0.5 - camera.cx) / camera.fx) as f32);
            v.push(((j as f64 + 0.5 - camera.cy) / camera.fy) as f32);
            v.push(1.0);
        }
    }
    Tensor::from_data(TensorData::new(v, [h, w, 3]), device)
}

/// Unbiased depth `[H, W]` from the blended camera-space normal `[H, W, 3]` and plane
/// distance `[H, W]`: `D_plane / max(-(N . r), DEPTH_DENOM_MIN)`. Both maps are blended with the
/// same weights, so coverage cancels.
pub fn unbiased_depth(normal: &Tensor<3>, plane: &Tensor<2>, rays: &Tensor<3>) -> Tensor<2> {
    let [h, w, _] = normal.dims();
    let ndr = (normal.clone() * rays.clone()).sum_dim(2).reshape([h, w]);
    plane.clone() / ndr.neg().clamp_min(DEPTH_DENOM_MIN)
}

/// Normals `[H, W, 3]` from a depth map by central differences of the back-projected points,
/// facing the camera; the one-pixel border is zero. Also returns the `[H, W]` validity mask of
/// pixels whose four neighbours and own depth are all valid (per `valid` `[H, W]`).
pub fn normals_from_depth(
    depth: &Tensor<2>,
    rays: &Tensor<3>,
    valid: &Tensor<2, Bool>,
) -> (Tensor<3>, Tensor<2>) {
    let [h, w] = depth.dims();
    let m = h * w;
    let dtype = depth.dtype();
    let device = depth.device();
    // Pixels in row-major order: the x neighbours of pixel j are j -+ 1, the y neighbours
    // j -+ w. Differences over whole rows of that list are contiguous; pixels j in [w, m - w)
    // (every row but the first and last) get them, and the first and last columns, whose x
    // neighbours wrap to the next row, are zeroed by `border`.
    let p = (rays.clone() * depth.clone().reshape([h, w, 1])).reshape([m, 3]);
    let mid = m - 2 * w;
    let dx = crate::layout::rows(&p, w + 1..m - w + 1) - crate::layout::rows(&p, w - 1..m - w - 1);
    let dy = crate::layout::rows(&p, 2 * w..m) - crate::layout::rows(&p, 0..mid);
    let n = cross_rows(&dx, &dy).neg();
    let len = (n.clone() * n.clone()).sum_dim(1).clamp_min(1e-20).sqrt();
    let mut border = vec![1f32; mid];
    for (j, b) in border.iter_mut().enumerate() {
        let x = j % w;
        if x == 0 || x == w - 1 {
            *b = 0.0;
        }
    }
    let border = Tensor::<1>::from_data(TensorData::new(border, [mid]), &device).cast(dtype);
    let n = n / len * border.clone().reshape([mid, 1]);
    let pad_rows = |t: Tensor<2>| {
        let c = t.dims()[1];
        let zeros = Tensor::<2>::zeros([w, c], (&device, dtype));
        Tensor::cat(vec![zeros.clone(), t, zeros], 0)
    };
    let n = pad_rows(n).reshape([h, w, 3]);
    let vf = valid.clone().float().cast(dtype).reshape([m]);
    let inner = crate::layout::rows(&vf, w..m - w)
        * crate::layout::rows(&vf, w + 1..m - w + 1)
        * crate::layout::rows(&vf, w - 1..m - w - 1)
        * crate::layout::rows(&vf, 2 * w..m)
        * crate::layout::rows(&vf, 0..mid)
        * border;
    (n, pad_rows(inner.reshape([mid, 1])).reshape([h, w]))
}

/// Row-wise cross product of `[M, 3]` tensors.
pub fn cross_rows(a: &Tensor<2>, b: &Tensor<2>) -> Tensor<2> {
    // a x b = a_yzx * b_zxy - a_zxy * b_yzx, with the rotated copies as products with
    // permutation matrices (contiguous; see `crate::layout`).
    let yzx = |t: &Tensor<2>| crate::layout::pick_cols(t, &[1, 2, 0]);
    let zxy = |t: &Tensor<2>| crate::layout::pick_cols(t, &[2, 0, 1]);
    yzx(a) * zxy(b) - zxy(a) * yzx(b)
}

/// Row-wise cross product of `[.., .., 3]` tensors.
pub fn cross(a: &Tensor<3>, b: &Tensor<3>) -> Tensor<3> {
    let [h, w, _] = a.dims();
    let flat = |t: &Tensor<3>| t.clone().reshape([h * w, 3]);
    cross_rows(&flat(a), &flat(b)).reshape([h, w, 3])
}

/// Integer pixel indices `[M]` (row-major) of continuous positions, clamped to the image.
pub fn nearest_index(u: Tensor<1>, v: Tensor<1>, width: usize, height: usize) -> Tensor<1, Int> {
    let i = u.floor().clamp(0.0, width as f64 - 1.0).int();
    let j = v.floor().clamp(0.0, height as f64 - 1.0).int();
    j * (width as i64) + i
}
