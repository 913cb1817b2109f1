//! Rendered geometry against a ground-truth mesh, pixel by pixel: the mesh's depth and normal
//! maps by ray casting ([`MeshRaycaster`]) and the error of a rendered depth / normal map
//! against them ([`DepthComparison`], [`DepthMetrics`]).
//!
//! The chamfer distance of a fused mesh mixes the rendered depth with what the fusion adds
//! (silhouette carving, truncation, marching cubes); these numbers measure the rendered
//! surface itself, per test view, where the object is: how far the depth lies from the true
//! surface (and on which side: translucency tends to pull it inward), and how far the normals
//! turn from the true ones.
//!
//! Conventions: depth is z-depth along the camera axis (OpenCV camera space, as
//! [`crate::TsdfVolume::integrate`] takes it); normals are camera-space unit vectors facing the
//! camera; a pixel's ray goes through its centre.

use glam::Vec3;
use gtsr_data::Camera;
use gtsr_data::ply::TriMesh;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{EvalError, Result};
use crate::metrics::Target;

/// The ground-truth geometry one camera sees.
#[derive(Clone, Debug)]
pub struct MeshDepth {
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// Z-depth of the first hit per pixel (row-major), `0` where the ray misses the mesh.
    pub depth: Vec<f32>,
    /// Camera-space unit normal of the triangle hit, facing the camera; zero on a miss.
    pub normal: Vec<Vec3>,
}

/// A mesh prepared for ray casting (a BVH, built once for any number of cameras).
pub struct MeshRaycaster<'a> {
    target: Target<'a>,
}

impl<'a> MeshRaycaster<'a> {
    /// Builds the BVH; errors on an empty or invalid mesh (`what` names it in errors).
    pub fn new(mesh: &'a TriMesh, what: &str) -> Result<Self> {
        Ok(MeshRaycaster {
            target: Target::new(mesh, what)?,
        })
    }

    /// The first hit of the ray from `origin` along the unit direction `dir`: the distance
    /// along the ray and the unit normal of the triangle hit, turned to face the origin.
    pub fn first_hit(&self, origin: Vec3, dir: Vec3) -> Option<(f32, Vec3)> {
        self.target.first_hit(origin, dir)
    }

    /// The mesh's depth and normal maps seen from `camera` (one ray through each pixel
    /// centre, first hit). Parallel over rows.
    pub fn render(&self, camera: &Camera) -> MeshDepth {
        let (w, h) = (camera.width as usize, camera.height as usize);
        let m = camera.world_to_camera;
        let mut depth = vec![0.0; w * h];
        let mut normal = vec![Vec3::ZERO; w * h];
        depth
            .par_chunks_mut(w.max(1))
            .zip(normal.par_chunks_mut(w.max(1)))
            .enumerate()
            .for_each(|(j, (depth, normal))| {
                for i in 0..w {
                    let (o, d) = camera.pixel_ray(i as u32, j as u32);
                    if let Some((t, n)) = self.target.first_hit(o, d) {
                        let z = m.transform_point3(o + d * t).z;
                        if z > 0.0 && z.is_finite() {
                            depth[i] = z;
                            normal[i] = m.transform_vector3(n).normalize_or_zero();
                        }
                    }
                }
            });
        MeshDepth {
            width: w,
            height: h,
            depth,
            normal,
        }
    }
}

/// Rendered depth and normals against the ground truth, over the pixels where both exist.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DepthMetrics {
    /// Mean `|depth - true depth|` (mesh units).
    pub depth_mean_abs: f64,
    /// Median `|depth - true depth|`.
    pub depth_median_abs: f64,
    /// Mean `depth - true depth`: positive when the rendered surface lies behind the true one
    /// (inside the object, seen from the camera).
    pub depth_mean_signed: f64,
    /// Mean angle between the rendered and the true normal, degrees.
    pub normal_mean_deg: f64,
    /// Median of that angle, degrees.
    pub normal_median_deg: f64,
    /// Pixels compared.
    pub pixels: usize,
    /// Of the pixels where the ground truth is hit (and the caller's mask holds), the
    /// fraction the rendering covered.
    pub coverage: f64,
}

/// Accumulates per-pixel errors over views; [`DepthComparison::finish`] gives the metrics.
#[derive(Clone, Debug, Default)]
pub struct DepthComparison {
    depth_err: Vec<f32>,
    normal_deg: Vec<f32>,
    truth_pixels: usize,
}

impl DepthComparison {
    /// An empty comparison.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds one view. `depth` (z-depth per pixel) and `normal` (camera-space, 3 values per
    /// pixel, any length: normalised here) are the rendering, row-major at the size of `truth`;
    /// `select` marks the pixels to count (e.g. inside the ground-truth mask); among them those
    /// the truth hits count toward the coverage, and those where the rendered depth is also
    /// finite and positive and the normal non-zero are compared. Errors on mismatched sizes.
    pub fn add(
        &mut self,
        truth: &MeshDepth,
        depth: &[f32],
        normal: &[f32],
        select: &[bool],
    ) -> Result<()> {
        let n = truth.width * truth.height;
        let size = format!("{}x{} = {n}", truth.width, truth.height);
        if depth.len() != n {
            return Err(EvalError::size("rendered depth", size, depth.len()));
        }
        if normal.len() != 3 * n {
            return Err(EvalError::size(
                "rendered normals",
                format!("3 x {size}"),
                normal.len(),
            ));
        }
        if select.len() != n {
            return Err(EvalError::size("pixel selection", size, select.len()));
        }
        for p in 0..n {
            let t = truth.depth[p];
            if !(select[p] && t.is_finite() && t > 0.0) {
                continue;
            }
            self.truth_pixels += 1;
            let d = depth[p];
            let nv = Vec3::new(normal[3 * p], normal[3 * p + 1], normal[3 * p + 2]);
            let nl = nv.length();
            if !(d.is_finite() && d > 0.0 && nl.is_finite() && nl > 0.0) {
                continue;
            }
            self.depth_err.push(d - t);
            let cos = (nv / nl).dot(truth.normal[p]).clamp(-1.0, 1.0);
            self.normal_deg.push(cos.acos().to_degrees());
        }
        Ok(())
    }

    /// The metrics over every view added; `None` when no pixel was compared.
    pub fn finish(&self) -> Option<DepthMetrics> {
        let k = self.depth_err.len();
        if k == 0 {
            return None;
        }
        let mean = |v: &[f32]| v.iter().map(|&e| e as f64).sum::<f64>() / k as f64;
        let median = |mut v: Vec<f32>| {
            v.sort_by(f32::total_cmp);
            if k % 2 == 1 {
                v[k / 2] as f64
            } else {
                0.5 * (v[k / 2 - 1] as f64 + v[k / 2] as f64)
            }
        };
        let abs: Vec<f32> = self.depth_err.iter().map(|e| e.abs()).collect();
        Some(DepthMetrics {
            depth_mean_abs: mean(&abs),
            depth_median_abs: median(abs),
            depth_mean_signed: mean(&self.depth_err),
            normal_mean_deg: mean(&self.normal_deg),
            normal_median_deg: median(self.normal_deg.clone()),
            pixels: k,
            coverage: k as f64 / self.truth_pixels as f64,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A square in the plane z = `z` (world), side 4, facing -z.
    fn square(z: f32) -> TriMesh {
        TriMesh {
            positions: vec![
                Vec3::new(-2.0, -2.0, z),
                Vec3::new(2.0, -2.0, z),
                Vec3::new(2.0, 2.0, z),
                Vec3::new(-2.0, 2.0, z),
            ],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
        }
    }

    fn camera_on_axis(w: u32) -> Camera {
        // At the origin looking along +z (OpenCV camera = world axes).
        Camera::look_at(Vec3::ZERO, Vec3::Z, -Vec3::Y, 0.6, w, w)
    }

    #[test]
    fn a_plane_facing_the_camera_has_constant_z_depth_and_the_axis_normal() {
        let mesh = square(2.0);
        let cam = camera_on_axis(16);
        let truth = MeshRaycaster::new(&mesh, "square").unwrap().render(&cam);
        for (d, n) in truth.depth.iter().zip(&truth.normal) {
            assert!((d - 2.0).abs() < 1e-5, "z-depth {d}");
            assert!(
                (*n - Vec3::new(0.0, 0.0, -1.0)).length() < 1e-5,
                "normal {n}"
            );
        }
    }

    #[test]
    fn a_sphere_is_hit_at_its_distance_minus_its_radius() {
        let (dist, r) = (3.0, 0.5);
        let mesh = crate::mesh::icosphere(Vec3::new(0.0, 0.0, dist), r, 5);
        let cam = camera_on_axis(32);
        let truth = MeshRaycaster::new(&mesh, "sphere").unwrap().render(&cam);
        let centre = 16 * 32 + 16;
        // The icosphere is inscribed: its depth is within r (1 - cos(edge angle)) of the sphere's.
        let expect = {
            let (o, d) = cam.pixel_ray(16, 16);
            let oc = o - Vec3::new(0.0, 0.0, dist);
            let b = oc.dot(d);
            let t = -b - (b * b - (oc.length_squared() - r * r)).sqrt();
            (o + d * t).z
        };
        assert!(
            (truth.depth[centre] - expect).abs() < 2e-3 * r,
            "{} vs {expect}",
            truth.depth[centre]
        );
        assert!(truth.normal[centre].z < -0.99);
        // Corners miss.
        assert_eq!(truth.depth[0], 0.0);
        assert_eq!(truth.normal[0], Vec3::ZERO);
    }

    #[test]
    fn known_offsets_and_tilts_give_their_errors() {
        let mesh = square(2.0);
        let cam = camera_on_axis(8);
        let truth = MeshRaycaster::new(&mesh, "square").unwrap().render(&cam);
        let n = 64;
        // Half the pixels 0.01 behind, half 0.03 in front; normals tilted by 10 degrees.
        let depth: Vec<f32> = (0..n)
            .map(|p| if p % 2 == 0 { 2.01 } else { 1.97 })
            .collect();
        let a = 10f32.to_radians();
        let normal: Vec<f32> = (0..n)
            .flat_map(|_| [0.0, 2.0 * a.sin(), -2.0 * a.cos()])
            .collect();
        let mut select = vec![true; n];
        select[0] = false;
        select[1] = false;
        let mut c = DepthComparison::new();
        c.add(&truth, &depth, &normal, &select).unwrap();
        // A pixel without rendered depth counts against the coverage only.
        let mut holes = depth.clone();
        holes[2] = 0.0;
        holes[3] = f32::NAN;
        c.add(&truth, &holes, &normal, &select).unwrap();
        let m = c.finish().unwrap();
        assert_eq!(m.pixels, 62 + 60);
        assert!((m.coverage - 122.0 / 124.0).abs() < 1e-12);
        // 61 at +0.01 and 61 at -0.03.
        assert!(
            (m.depth_mean_abs - 0.02).abs() < 1e-6,
            "{}",
            m.depth_mean_abs
        );
        assert!((m.depth_mean_signed + 0.01).abs() < 1e-6);
        assert!((m.depth_median_abs - 0.02).abs() < 1e-6);
        assert!((m.normal_mean_deg - 10.0).abs() < 1e-3);
        assert!((m.normal_median_deg - 10.0).abs() < 1e-3);
    }

    #[test]
    fn mismatched_sizes_and_empty_comparisons_are_reported() {
        let mesh = square(2.0);
        let cam = camera_on_axis(4);
        let truth = MeshRaycaster::new(&mesh, "square").unwrap().render(&cam);
        let mut c = DepthComparison::new();
        assert!(c.add(&truth, &[1.0; 15], &[0.0; 48], &[true; 16]).is_err());
        assert!(c.add(&truth, &[1.0; 16], &[0.0; 47], &[true; 16]).is_err());
        assert!(c.add(&truth, &[1.0; 16], &[0.0; 48], &[true; 15]).is_err());
        assert!(c.finish().is_none());
        // Zero normals: nothing compared.
        c.add(&truth, &[1.0; 16], &[0.0; 48], &[true; 16]).unwrap();
        assert!(c.finish().is_none());
        assert!(MeshRaycaster::new(&TriMesh::default(), "empty").is_err());
    }
}
