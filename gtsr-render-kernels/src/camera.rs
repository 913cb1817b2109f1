//! Pinhole cameras in the convention the kernels use.
//!
//! **Convention (OpenCV):** camera space looks down `+z`, `x` to the right, `y` down. A point
//! `p_w` in world space maps to camera space as `p_c = R p_w + t` (`R`, `t` = the
//! world-to-camera rigid transform) and to pixel coordinates as
//! `(fx * x / z + cx, fy * y / z + cy)`. Pixel `(i, j)` (column `i`, row `j`) covers
//! `[i, i + 1) x [j, j + 1)`; its centre, where the splats are evaluated, is `(i + 0.5, j + 0.5)`.
//! Points with `z` outside `[near, far]` are culled.

use thiserror::Error;

/// A validated pinhole camera (see the module docs for the convention).
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    /// Focal length along x, in pixels.
    pub fx: f64,
    /// Focal length along y, in pixels.
    pub fy: f64,
    /// Principal point x, in pixels (the image centre is `width / 2`).
    pub cx: f64,
    /// Principal point y, in pixels.
    pub cy: f64,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// World-to-camera rotation, row-major.
    pub rotation: [[f64; 3]; 3],
    /// World-to-camera translation.
    pub translation: [f64; 3],
    /// Near clipping distance along `z` (> 0).
    pub near: f64,
    /// Far clipping distance along `z` (> near).
    pub far: f64,
}

/// Why a camera was rejected.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum CameraError {
    /// A parameter is NaN or infinite.
    #[error("camera parameter `{0}` is not finite")]
    NonFinite(&'static str),
    /// Focal lengths must be strictly positive.
    #[error("camera focal lengths must be > 0 (got fx = {fx}, fy = {fy})")]
    BadFocal {
        /// fx as given.
        fx: f64,
        /// fy as given.
        fy: f64,
    },
    /// Zero-sized image.
    #[error("camera image size must be at least 1x1 (got {width}x{height})")]
    EmptyImage {
        /// width as given.
        width: u32,
        /// height as given.
        height: u32,
    },
    /// Rotation is not orthonormal with determinant +1.
    #[error(
        "camera rotation is not a rotation matrix (max |R R^T - I| = {orthogonality_error:.3e}, det = {det:.6})"
    )]
    NotRigid {
        /// Largest entry of `|R R^T - I|`.
        orthogonality_error: f64,
        /// Determinant of `R`.
        det: f64,
    },
    /// Clipping range is not `0 < near < far`.
    #[error("camera clipping range must satisfy 0 < near < far (got near = {near}, far = {far})")]
    BadClip {
        /// near as given.
        near: f64,
        /// far as given.
        far: f64,
    },
}

/// Tolerance on `|R R^T - I|` accepted by [`Camera::new`].
pub const ROTATION_TOLERANCE: f64 = 1e-4;

/// The EWA Jacobian is evaluated at a mean clamped to this fraction of the image outside the
/// frame (x/z and y/z limited to `[-0.15 W, 1.15 W]` in pixels), which keeps splats far outside
/// the frustum from blowing up.
pub const FRUSTUM_MARGIN: f64 = 0.15;

impl Camera {
    /// Builds a camera, checking that every parameter is finite, the focal lengths are positive,
    /// the image is not empty, the rotation is proper (`R R^T = I`, `det R = 1`, within
    /// [`ROTATION_TOLERANCE`]) and `0 < near < far`.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        width: u32,
        height: u32,
        rotation: [[f64; 3]; 3],
        translation: [f64; 3],
        near: f64,
        far: f64,
    ) -> Result<Self, CameraError> {
        for (name, v) in [
            ("fx", fx),
            ("fy", fy),
            ("cx", cx),
            ("cy", cy),
            ("near", near),
        ] {
            if !v.is_finite() {
                return Err(CameraError::NonFinite(name));
            }
        }
        if far.is_nan() {
            return Err(CameraError::NonFinite("far"));
        }
        if rotation.iter().flatten().any(|v| !v.is_finite()) {
            return Err(CameraError::NonFinite("rotation"));
        }
        if translation.iter().any(|v| !v.is_finite()) {
            return Err(CameraError::NonFinite("translation"));
        }
        if fx <= 0.0 || fy <= 0.0 {
            return Err(CameraError::BadFocal { fx, fy });
        }
        if width == 0 || height == 0 {
            return Err(CameraError::EmptyImage { width, height });
        }
        if !(near > 0.0 && far > near) {
            return Err(CameraError::BadClip { near, far });
        }
        let r = rotation;
        let mut err: f64 = 0.0;
        for i in 0..3 {
            for j in 0..3 {
                let dot: f64 = (0..3).map(|k| r[i][k] * r[j][k]).sum();
                let target = if i == j { 1.0 } else { 0.0 };
                err = err.max((dot - target).abs());
            }
        }
        let det = r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1])
            - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0])
            + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]);
        if err > ROTATION_TOLERANCE || (det - 1.0).abs() > ROTATION_TOLERANCE {
            return Err(CameraError::NotRigid {
                orthogonality_error: err,
                det,
            });
        }
        Ok(Self {
            fx,
            fy,
            cx,
            cy,
            width,
            height,
            rotation,
            translation,
            near,
            far,
        })
    }

    /// A camera at `eye` looking at `target`, with `up` roughly the world's up direction
    /// (the image's `-y`), horizontal field of view `fov_x` (radians) and the principal point at
    /// the image centre. `near = 0.01`, `far = 1e4`.
    pub fn look_at(
        eye: [f64; 3],
        target: [f64; 3],
        up: [f64; 3],
        fov_x: f64,
        width: u32,
        height: u32,
    ) -> Result<Self, CameraError> {
        let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
        let cross = |a: [f64; 3], b: [f64; 3]| {
            [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ]
        };
        let norm = |a: [f64; 3]| {
            let n = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
            [a[0] / n, a[1] / n, a[2] / n]
        };
        let z = norm(sub(target, eye));
        // Image x points right: x = z cross up (for y down).
        let x = norm(cross(z, up));
        let y = cross(z, x);
        let rotation = [x, y, z];
        let translation = [
            -(x[0] * eye[0] + x[1] * eye[1] + x[2] * eye[2]),
            -(y[0] * eye[0] + y[1] * eye[1] + y[2] * eye[2]),
            -(z[0] * eye[0] + z[1] * eye[1] + z[2] * eye[2]),
        ];
        let f = 0.5 * f64::from(width) / (0.5 * fov_x).tan();
        Self::new(
            f,
            f,
            0.5 * f64::from(width),
            0.5 * f64::from(height),
            width,
            height,
            rotation,
            translation,
            0.01,
            1e4,
        )
    }

    /// World-space position of the camera centre, `-R^T t`.
    pub fn centre(&self) -> [f64; 3] {
        let r = &self.rotation;
        let t = &self.translation;
        [
            -(r[0][0] * t[0] + r[1][0] * t[1] + r[2][0] * t[2]),
            -(r[0][1] * t[0] + r[1][1] * t[1] + r[2][1] * t[2]),
            -(r[0][2] * t[0] + r[1][2] * t[1] + r[2][2] * t[2]),
        ]
    }

    /// The ranges `[lo, hi]` of `x/z` and of `y/z` at which the EWA Jacobian is evaluated:
    /// the frame widened by [`FRUSTUM_MARGIN`] on every side.
    pub fn jacobian_limits(&self) -> ([f64; 2], [f64; 2]) {
        let m = FRUSTUM_MARGIN;
        let (w, h) = (f64::from(self.width), f64::from(self.height));
        (
            [
                (-m * w - self.cx) / self.fx,
                ((1.0 + m) * w - self.cx) / self.fx,
            ],
            [
                (-m * h - self.cy) / self.fy,
                ((1.0 + m) * h - self.cy) / self.fy,
            ],
        )
    }
}
