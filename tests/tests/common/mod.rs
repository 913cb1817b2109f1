//! Shared test helpers (also used by the `sphere_tsdf` example): cameras around a sphere and
//! analytic depth maps / masks.
#![allow(dead_code)]

use glam::Vec3;
use gtsr_data::Camera;
use gtsr_data::synthetic::writer::fibonacci_sphere;

/// `n` cameras on a Fibonacci sphere of radius `distance` around `target` (pole along +y),
/// looking at it: gtsr-data's `fibonacci_sphere` with y and z swapped.
pub fn cameras_around(target: Vec3, distance: f32, n: usize, fov_x: f32, size: u32) -> Vec<Camera> {
    fibonacci_sphere(n, 1.0, 0.0)
        .into_iter()
        .map(|p| {
            let dir = Vec3::new(p.x, p.z, p.y);
            let up = if dir.y.abs() > 0.9 { Vec3::X } else { Vec3::Y };
            Camera::look_at(target + dir * distance, target, up, fov_x, size, size)
        })
        .collect()
}

/// Z-depth (0 where the ray misses) and mask (1 on the sphere) of a sphere, per pixel centre.
pub fn render_sphere(cam: &Camera, centre: Vec3, radius: f32) -> (Vec<f32>, Vec<f32>) {
    let c = cam.world_to_camera.transform_point3(centre);
    let (w, h) = (cam.width as usize, cam.height as usize);
    let mut depth = vec![0.0; w * h];
    let mut mask = vec![0.0; w * h];
    for j in 0..h {
        for i in 0..w {
            // Camera-space ray s * d with d.z = 1, so s is the z-depth.
            let d = cam.camera_direction(i as f32 + 0.5, j as f32 + 0.5);
            let a = d.length_squared();
            let b = d.dot(c);
            let disc = b * b - a * (c.length_squared() - radius * radius);
            if disc >= 0.0 {
                let s = (b - disc.sqrt()) / a;
                if s > 0.0 {
                    depth[j * w + i] = s;
                    mask[j * w + i] = 1.0;
                }
            }
        }
    }
    (depth, mask)
}

/// Each camera with the mask of a sphere ([`render_sphere`]).
pub fn sphere_masks(cams: &[Camera], centre: Vec3, radius: f32) -> Vec<(Camera, Vec<f32>)> {
    cams.iter()
        .map(|c| (*c, render_sphere(c, centre, radius).1))
        .collect()
}

/// `(camera, mask)` pairs borrowed as the hull functions take them.
pub fn as_views(masks: &[(Camera, Vec<f32>)]) -> Vec<(Camera, &[f32])> {
    masks.iter().map(|(c, m)| (*c, m.as_slice())).collect()
}
