//! The internal camera convention shared by every loader and by the rendering kernels.
//!
//! # Convention (OpenCV)
//!
//! * Camera space: the camera looks down **+z**, **x** points right in the image and
//!   **y** points down in the image. Right-handed.
//! * Extrinsics: [`Camera::world_to_camera`] is a *rigid* transform (orthonormal
//!   rotation with determinant +1, plus a translation): `p_c = R p_w + t`.
//!   Loaders check rigidity (tolerance [`RIGID_TOLERANCE`]) and return
//!   [`crate::DataError::NonRigid`] naming the file and frame otherwise.
//! * Intrinsics: `fx, fy, cx, cy` in pixels; `width, height` in pixels.
//!   Pixel `(i, j)` (column `i`, row `j`) covers `[i, i+1) x [j, j+1)` in continuous pixel
//!   coordinates, so its centre is at `(i + 0.5, j + 0.5)`. A camera-space point
//!   `(x, y, z)` with `z > 0` projects to `(fx * x / z + cx, fy * y / z + cy)`.
//! * Blender / NeRF files store camera-to-world in the OpenGL convention (looks down -z,
//!   y up): it becomes OpenCV by right-multiplying with `diag(1, -1, -1, 1)`
//!   ([`GL_TO_CV`]); their focal length is `0.5 * W / tan(0.5 * camera_angle_x)` and the
//!   principal point `(W/2, H/2)` unless `cx, cy` are given.
//! * COLMAP stores world-to-camera in the OpenCV convention already.
//! * World units are those of the file; [`crate::Scene`] carries a normalisation
//!   (centre, radius) that [`crate::Scene::normalise`] can apply.

use glam::{Affine3A, Mat3, Mat4, Vec2, Vec3, Vec4};

/// Tolerance of the rigidity check: `|R^T R - I|` (max abs entry) and `|det R - 1|`.
pub const RIGID_TOLERANCE: f32 = 2e-3;

/// `diag(1, -1, -1, 1)`: right-multiplying an OpenGL camera-to-world by it gives the
/// OpenCV camera-to-world (and it is its own inverse).
pub const GL_TO_CV: Mat4 = Mat4::from_cols(
    Vec4::new(1.0, 0.0, 0.0, 0.0),
    Vec4::new(0.0, -1.0, 0.0, 0.0),
    Vec4::new(0.0, 0.0, -1.0, 0.0),
    Vec4::new(0.0, 0.0, 0.0, 1.0),
);

/// A pinhole camera in the crate's OpenCV convention (see the module documentation).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Rigid world-to-camera transform (OpenCV camera space).
    pub world_to_camera: Affine3A,
    /// Focal length along x, pixels.
    pub fx: f32,
    /// Focal length along y, pixels.
    pub fy: f32,
    /// Principal point x, pixels (continuous coordinates; pixel centres at `i + 0.5`).
    pub cx: f32,
    /// Principal point y, pixels.
    pub cy: f32,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
}

impl Camera {
    /// A camera from an OpenCV camera-to-world matrix (assumed rigid; not checked).
    pub fn from_opencv_camera_to_world(
        c2w: Mat4,
        fx: f32,
        fy: f32,
        cx: f32,
        cy: f32,
        width: u32,
        height: u32,
    ) -> Self {
        let c2w = Affine3A::from_mat4(c2w);
        Camera {
            world_to_camera: c2w.inverse(),
            fx,
            fy,
            cx,
            cy,
            width,
            height,
        }
    }

    /// A camera from an OpenGL (Blender/NeRF) camera-to-world matrix (assumed rigid).
    pub fn from_opengl_camera_to_world(
        c2w_gl: Mat4,
        fx: f32,
        fy: f32,
        cx: f32,
        cy: f32,
        width: u32,
        height: u32,
    ) -> Self {
        Self::from_opencv_camera_to_world(c2w_gl * GL_TO_CV, fx, fy, cx, cy, width, height)
    }

    /// A camera at `eye` looking at `target`, with `up` giving the image's upward
    /// direction (image y points along `-up` projected), square pixels, principal point at
    /// the image centre and horizontal field of view `fov_x` (radians).
    pub fn look_at(eye: Vec3, target: Vec3, up: Vec3, fov_x: f32, width: u32, height: u32) -> Self {
        let forward = (target - eye).normalize();
        let mut right = forward.cross(up);
        if right.length_squared() < 1e-10 {
            // `up` parallel to the view direction: pick any perpendicular.
            right = forward.any_orthonormal_vector();
        }
        let right = right.normalize();
        let down = forward.cross(right).normalize();
        let c2w = Mat4::from_cols(
            right.extend(0.0),
            down.extend(0.0),
            forward.extend(0.0),
            eye.extend(1.0),
        );
        let f = focal_from_fov(fov_x, width);
        Self::from_opencv_camera_to_world(
            c2w,
            f,
            f,
            width as f32 * 0.5,
            height as f32 * 0.5,
            width,
            height,
        )
    }

    /// Camera-to-world transform (OpenCV camera space).
    pub fn camera_to_world(&self) -> Affine3A {
        self.world_to_camera.inverse()
    }

    /// Camera-to-world in the OpenGL convention, as Blender/NeRF `transform_matrix` stores it.
    pub fn opengl_camera_to_world(&self) -> Mat4 {
        Mat4::from(self.camera_to_world()) * GL_TO_CV
    }

    /// The camera centre (optical centre) in world space.
    pub fn centre(&self) -> Vec3 {
        Vec3::from(self.camera_to_world().translation)
    }

    /// The viewing direction (camera +z) in world space, unit length.
    pub fn forward(&self) -> Vec3 {
        self.world_to_camera
            .matrix3
            .transpose()
            .mul_vec3(Vec3::Z)
            .normalize()
    }

    /// Horizontal field of view in radians.
    pub fn fov_x(&self) -> f32 {
        2.0 * (0.5 * self.width as f32 / self.fx).atan()
    }

    /// Projects a world point to continuous pixel coordinates; also returns the camera-space
    /// depth `z`. `None` when the point is not in front of the camera (`z <= 1e-8`).
    pub fn project(&self, p_world: Vec3) -> Option<(Vec2, f32)> {
        let p = self.world_to_camera.transform_point3(p_world);
        if p.z <= 1e-8 {
            return None;
        }
        Some((
            Vec2::new(self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy),
            p.z,
        ))
    }

    /// Camera-space direction (not normalised, z = 1) through continuous pixel coordinates
    /// `(u, v)`; the centre of pixel `(i, j)` is `(i + 0.5, j + 0.5)`.
    pub fn camera_direction(&self, u: f32, v: f32) -> Vec3 {
        Vec3::new((u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0)
    }

    /// World-space ray `(origin, unit direction)` through continuous pixel coordinates.
    pub fn ray(&self, u: f32, v: f32) -> (Vec3, Vec3) {
        let c2w = self.camera_to_world();
        let d = c2w
            .transform_vector3(self.camera_direction(u, v))
            .normalize();
        (Vec3::from(c2w.translation), d)
    }

    /// World-space ray through the centre of pixel `(i, j)` (column, row).
    pub fn pixel_ray(&self, i: u32, j: u32) -> (Vec3, Vec3) {
        self.ray(i as f32 + 0.5, j as f32 + 0.5)
    }

    /// The camera for an image downscaled by an integer `factor` with a box filter
    /// (output pixel `(i, j)` averages input pixels `[f*i, f*i+f) x [f*j, f*j+f)`;
    /// remainders at the right and bottom are cropped). Continuous pixel coordinates scale by
    /// `1/factor`, so `fx, fy, cx, cy` all divide by `factor`.
    pub fn downscaled(&self, factor: u32) -> Camera {
        let f = factor.max(1) as f32;
        Camera {
            fx: self.fx / f,
            fy: self.fy / f,
            cx: self.cx / f,
            cy: self.cy / f,
            width: self.width / factor.max(1),
            height: self.height / factor.max(1),
            ..*self
        }
    }

    /// This camera after the world transform `p_new = (p_old - centre) / radius`
    /// (the rotation is unchanged, the translation becomes `(R centre + t) / radius`, so the
    /// transform stays rigid and the images are unchanged).
    pub fn normalised(&self, centre: Vec3, radius: f32) -> Camera {
        let r = self.world_to_camera.matrix3;
        let t = Vec3::from(self.world_to_camera.translation);
        let t_new = (r.mul_vec3(centre) + t) / radius;
        Camera {
            world_to_camera: Affine3A::from_mat3_translation(Mat3::from(r), t_new),
            ..*self
        }
    }
}

/// Focal length in pixels for a horizontal field of view (radians) and image width.
pub fn focal_from_fov(fov: f32, size: u32) -> f32 {
    0.5 * size as f32 / (0.5 * fov).tan()
}

/// Checks that the upper 3x3 of `m` is a rotation (orthonormal within
/// [`RIGID_TOLERANCE`], determinant +1), the last row is `(0, 0, 0, 1)` and every entry is
/// finite. Returns a description of the first failed test.
pub fn check_rigid(m: &Mat4) -> std::result::Result<(), String> {
    let a = m.to_cols_array();
    if a.iter().any(|v| !v.is_finite()) {
        return Err("matrix has a non-finite entry".into());
    }
    let row3 = m.row(3);
    if (row3 - Vec4::W).abs().max_element() > 1e-5 {
        return Err(format!("last row is {row3:?}, expected (0, 0, 0, 1)"));
    }
    let r = Mat3::from_mat4(*m);
    let rtr = r.transpose() * r;
    let err = (0..3)
        .flat_map(|i| (0..3).map(move |j| (i, j)))
        .map(|(i, j)| {
            let want = if i == j { 1.0 } else { 0.0 };
            (rtr.col(i)[j] - want).abs()
        })
        .fold(0.0f32, f32::max);
    if err > RIGID_TOLERANCE {
        return Err(format!(
            "rotation part is not orthonormal (max |R^T R - I| = {err:.3e}; scaled or sheared?)"
        ));
    }
    let det = r.determinant();
    if (det - 1.0).abs() > RIGID_TOLERANCE {
        return Err(format!(
            "rotation determinant is {det:.4}, expected +1 (reflection?)"
        ));
    }
    Ok(())
}

/// Re-orthonormalises the rotation of an (almost) rigid matrix so the stored transform is
/// exactly rigid to float precision (through a quaternion).
pub fn orthonormalise(m: &Mat4) -> Mat4 {
    let r = Mat3::from_mat4(*m);
    let q = glam::Quat::from_mat3(&r).normalize();
    Mat4::from_rotation_translation(q, m.col(3).truncate())
}
