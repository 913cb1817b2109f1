//! PGSR geometry with Burn ops: Gaussian normals (shortest axis, facing the camera), plane
//! distances, the unbiased depth `D = D_plane / -(N . r)`, and normals from depth.
//!
//! Conventions: OpenCV camera space (x right, y down, z forward); a pixel `(u, v)` (centre at
//! `i + 0.5`) has the ray `r = ((u - cx) / fx, (v - cy) / fy, 1)` so a point at z-depth `Z`
//! along it is `Z r`. Normals face the camera (`n . r < 0`), plane distances are positive.

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

/// `[N, 3]` one-hot rows marking each Gaussian's normal axis, that of its smallest scale
/// (decided on the detached `log_scales`; in their dtype).
pub fn normal_axis(log_scales: &Tensor<2>) -> Tensor<2> {
    let n = log_scales.dims()[0];
    let axis = log_scales.clone().detach().argmin(1).reshape([n]);
    let onehot: Tensor<2> = axis.one_hot::<2>(3).float();
    onehot.cast(log_scales.dtype())
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

/// Unit directions `[N, 3]` from the camera centre to each mean, as the SH colours take them
/// ([`gtsr_render_kernels::sh::view_directions`]).
pub fn view_dirs(means: &Tensor<2>, centre: [f64; 3]) -> Tensor<2> {
    gtsr_render_kernels::sh::view_directions(means.clone(), centre)
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
