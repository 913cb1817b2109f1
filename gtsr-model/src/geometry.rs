//! PGSR geometry with Burn ops: Gaussian normals (shortest axis, facing the camera), plane
//! distances, the unbiased depth `D = D_plane / -(N . r)`, and normals from depth.
//!
//! Conventions: OpenCV camera space (x right, y down, z forward); a pixel `(u, v)` (centre at
//! `i + 0.5`) has the ray `r = ((u - cx) / fx, (v - cy) / fy, 1)` so a point at z-depth `Z`
//! along it is `Z r`. Normals face the camera (`n . r < 0`), plane distances are positive.

use burn::tensor::ops::PadMode;
use burn::tensor::{Bool, Device, Int, Tensor, TensorData};

use gtsr_render_kernels::Camera;

/// Smallest allowed `-(N . r)` in the unbiased depth (grazing or empty pixels).
pub const DEPTH_DENOM_MIN: f64 = 1e-3;

/// `[N, 3, 3]` rotation matrices from quaternions `(w, x, y, z)` `[N, 4]` (normalised here).
pub fn quat_to_matrix(q: &Tensor<2>) -> Tensor<3> {
    let n = q.dims()[0];
    let norm = q
        .clone()
        .powf_scalar(2.0)
        .sum_dim(1)
        .clamp_min(1e-24)
        .sqrt();
    let q = q.clone() / norm;
    let c = |j: usize| q.clone().slice([0..n, j..j + 1]);
    let (w, x, y, z) = (c(0), c(1), c(2), c(3));
    let two = 2.0;
    let m = [
        -(y.clone() * y.clone() + z.clone() * z.clone()) * two + 1.0,
        (x.clone() * y.clone() - w.clone() * z.clone()) * two,
        (x.clone() * z.clone() + w.clone() * y.clone()) * two,
        (x.clone() * y.clone() + w.clone() * z.clone()) * two,
        -(x.clone() * x.clone() + z.clone() * z.clone()) * two + 1.0,
        (y.clone() * z.clone() - w.clone() * x.clone()) * two,
        (x.clone() * z.clone() - w.clone() * y.clone()) * two,
        (y.clone() * z.clone() + w.clone() * x.clone()) * two,
        -(x.clone() * x + y.clone() * y) * two + 1.0,
    ];
    Tensor::cat(m.to_vec(), 1).reshape([n, 3, 3])
}

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

/// World directions `[N, 3]` to camera space (rotation only).
pub fn dir_to_camera(dirs: &Tensor<2>, camera: &Camera) -> Tensor<2> {
    let (r, _) = camera_tensors(camera, &dirs.device());
    dirs.clone().matmul(r.transpose())
}

/// Unit rows.
pub fn normalize_rows(v: Tensor<2>) -> Tensor<2> {
    let len = v
        .clone()
        .powf_scalar(2.0)
        .sum_dim(1)
        .clamp_min(1e-24)
        .sqrt();
    v / len
}

/// `[N, 3]` world-space normals: the rotation column of the smallest scale, flipped to face the
/// camera centre. The axis choice and the flip are piecewise constant (no gradient), the
/// rotation is differentiated.
pub fn facing_normals(
    rot: &Tensor<3>,
    log_scales: &Tensor<2>,
    means: &Tensor<2>,
    centre: [f64; 3],
) -> Tensor<2> {
    let n = means.dims()[0];
    let device = means.device();
    let axis = log_scales.clone().detach().argmin(1).reshape([n]);
    let onehot: Tensor<2> = axis.one_hot::<2>(3).float();
    let onehot = onehot.cast(means.dtype());
    let normal = rot
        .clone()
        .matmul(onehot.reshape([n, 3, 1]))
        .reshape([n, 3]);
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

/// Unit directions `[N, 3]` from the camera centre to each mean.
pub fn view_dirs(means: &Tensor<2>, centre: [f64; 3]) -> Tensor<2> {
    let c = Tensor::<2>::from_data(
        TensorData::new(centre.map(|v| v as f32).to_vec(), [1, 3]),
        &means.device(),
    )
    .cast(means.dtype());
    normalize_rows(means.clone() - c)
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
    let p = rays.clone() * depth.clone().reshape([h, w, 1]);
    let dx = p.clone().slice([1..h - 1, 2..w, 0..3]) - p.clone().slice([1..h - 1, 0..w - 2, 0..3]);
    let dy = p.clone().slice([2..h, 1..w - 1, 0..3]) - p.slice([0..h - 2, 1..w - 1, 0..3]);
    let n = cross(&dx, &dy).neg();
    let len = n
        .clone()
        .powf_scalar(2.0)
        .sum_dim(2)
        .clamp_min(1e-20)
        .sqrt();
    let n = n / len;
    let n = n.pad([(1, 1), (1, 1), (0, 0)], PadMode::Constant(0.0));
    let vf = valid.clone().float().cast(depth.dtype());
    let inner = vf.clone().slice([1..h - 1, 1..w - 1])
        * vf.clone().slice([1..h - 1, 2..w])
        * vf.clone().slice([1..h - 1, 0..w - 2])
        * vf.clone().slice([2..h, 1..w - 1])
        * vf.slice([0..h - 2, 1..w - 1]);
    (n, inner.pad([(1, 1), (1, 1)], PadMode::Constant(0.0)))
}

/// Row-wise cross product of `[.., .., 3]` tensors.
pub fn cross(a: &Tensor<3>, b: &Tensor<3>) -> Tensor<3> {
    let [h, w, _] = a.dims();
    let c = |t: &Tensor<3>, k: usize| t.clone().slice([0..h, 0..w, k..k + 1]);
    Tensor::cat(
        vec![
            c(a, 1) * c(b, 2) - c(a, 2) * c(b, 1),
            c(a, 2) * c(b, 0) - c(a, 0) * c(b, 2),
            c(a, 0) * c(b, 1) - c(a, 1) * c(b, 0),
        ],
        2,
    )
}

/// Integer pixel indices `[M]` (row-major) of continuous positions, clamped to the image.
pub fn nearest_index(u: Tensor<1>, v: Tensor<1>, width: usize, height: usize) -> Tensor<1, Int> {
    let i = u.floor().clamp(0.0, width as f64 - 1.0).int();
    let j = v.floor().clamp(0.0, height as f64 - 1.0).int();
    j * (width as i64) + i
}
