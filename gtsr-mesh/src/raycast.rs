//! Ray casting and exact closest-point queries against a triangle mesh (parry3d BVHs): a
//! mesh's depth and normal maps seen from a camera ([`MeshRaycaster`], [`MeshDepth`]) and its
//! signed distance ([`SignedDistance`]). The extraction casts the masks' mesh and its own
//! meshes with them; the evaluation casts the ground truth.
//!
//! Conventions: depth is z-depth along the camera axis (OpenCV camera space, as
//! [`crate::tsdf::TsdfVolume::integrate`] takes it); normals are camera-space unit vectors facing the
//! camera; a pixel's ray goes through its centre.

use glam::Vec3;
use gtsr_data::Camera;
use gtsr_data::ply::TriMesh;
use parry3d::query::{PointQueryWithLocation, RayCast};
use rayon::prelude::*;

use crate::error::{MeshError, Result};
use crate::mesh::{face_normal_scaled, validate};

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
    /// The camera's focal length in pixels (`fx`): a pixel's footprint at depth `z` is
    /// `z / focal`.
    pub focal: f32,
}

/// A pixel lies on an occluding edge of the truth ([`MeshDepth::occluding_edges`]) where the
/// depth jumps by more than this many footprints to a 4-neighbour.
pub const EDGE_FOOTPRINTS: f32 = 10.0;

impl MeshDepth {
    /// Per pixel, whether it lies on an occluding edge of the mesh: it hits the mesh and a
    /// 4-neighbour misses it or hits it more than `footprints` pixel footprints nearer or
    /// farther (a surface behind another, or the object's outline). Where a pixel straddles
    /// such an edge, a rendering that blends what the pixel covers cannot match the one
    /// surface its centre's ray meets.
    pub fn occluding_edges(&self, footprints: f32) -> Vec<bool> {
        let (w, h) = (self.width, self.height);
        (0..w * h)
            .map(|p| {
                let z = self.depth[p];
                if !(z.is_finite() && z > 0.0) {
                    return false;
                }
                let limit = footprints * z / self.focal;
                self.neighbour_depths(p)
                    .any(|zn| !(zn.is_finite() && zn > 0.0) || (zn - z).abs() > limit)
            })
            .collect()
    }

    /// The depths of pixel `p`'s 4-neighbours inside the image.
    fn neighbour_depths(&self, p: usize) -> impl Iterator<Item = f32> + '_ {
        let (w, h) = (self.width, self.height);
        let (x, y) = (p % w, p / w);
        [
            (x.wrapping_sub(1), y),
            (x + 1, y),
            (x, y.wrapping_sub(1)),
            (x, y + 1),
        ]
        .into_iter()
        .filter(move |&(nx, ny)| nx < w && ny < h)
        .map(move |(nx, ny)| self.depth[ny * w + nx])
    }

    /// Per pixel, the depth of the nearest 4-neighbour that the mesh places more than
    /// `footprints` pixel footprints in front of this pixel's own hit (this pixel lies just
    /// behind an occluding edge, on its far side), `0` where none does or the pixel misses the
    /// mesh. A rendering whose nearer surface spills past the edge reads this depth there.
    pub fn occluders(&self, footprints: f32) -> Vec<f32> {
        let (w, h) = (self.width, self.height);
        (0..w * h)
            .map(|p| {
                let z = self.depth[p];
                if !(z.is_finite() && z > 0.0) {
                    return 0.0;
                }
                let limit = z - footprints * z / self.focal;
                self.neighbour_depths(p)
                    .filter(|zn| zn.is_finite() && *zn > 0.0 && *zn < limit)
                    .reduce(f32::min)
                    .unwrap_or(0.0)
            })
            .collect()
    }
}

/// A mesh prepared for ray casting (a BVH, built once for any number of cameras).
pub struct MeshRaycaster<'a> {
    target: MeshBvh<'a>,
}

impl<'a> MeshRaycaster<'a> {
    /// Builds the BVH; errors on an empty or invalid mesh (`what` names it in errors).
    pub fn new(mesh: &'a TriMesh, what: &str) -> Result<Self> {
        Ok(MeshRaycaster {
            target: MeshBvh::new(mesh, what)?,
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
        self.render_grid(camera, 1)
    }

    /// The mesh's depth and normal maps averaged over each pixel's area: `n x n` rays per
    /// pixel on a regular grid of sub-pixel centres; a pixel where at least half of them hit
    /// the mesh gets the mean z-depth of those hits and the normalised mean of their normals,
    /// the others none (`0`, zero normal). What a rendering that blends a pixel's whole
    /// footprint can be held to where the depth changes within a pixel (an occluding edge, a
    /// surface seen at a grazing angle); `n = 1` is [`MeshRaycaster::render`]. Errors when
    /// `n` is 0.
    pub fn render_area(&self, camera: &Camera, n: u32) -> Result<MeshDepth> {
        if n == 0 {
            return Err(MeshError::InvalidArgument(
                "render_area needs at least one ray per pixel".into(),
            ));
        }
        Ok(self.render_grid(camera, n))
    }

    /// [`MeshRaycaster::render_area`] for `n >= 1` (`n = 1`: one ray through each pixel
    /// centre).
    fn render_grid(&self, camera: &Camera, n: u32) -> MeshDepth {
        let (w, h) = (camera.width as usize, camera.height as usize);
        let m = camera.world_to_camera;
        let mut depth = vec![0.0; w * h];
        let mut normal = vec![Vec3::ZERO; w * h];
        let need = (n * n).div_ceil(2) as usize;
        depth
            .par_chunks_mut(w.max(1))
            .zip(normal.par_chunks_mut(w.max(1)))
            .enumerate()
            .for_each(|(j, (depth, normal))| {
                for i in 0..w {
                    let (mut zs, mut ns, mut hits) = (0.0f32, Vec3::ZERO, 0usize);
                    for a in 0..n {
                        for b in 0..n {
                            let u = i as f32 + (a as f32 + 0.5) / n as f32;
                            let v = j as f32 + (b as f32 + 0.5) / n as f32;
                            let (o, d) = camera.ray(u, v);
                            if let Some((t, nn)) = self.target.first_hit(o, d) {
                                let z = m.transform_point3(o + d * t).z;
                                if z > 0.0 && z.is_finite() {
                                    zs += z;
                                    ns += m.transform_vector3(nn);
                                    hits += 1;
                                }
                            }
                        }
                    }
                    if hits >= need {
                        depth[i] = zs / hits as f32;
                        normal[i] = ns.normalize_or_zero();
                    }
                }
            });
        MeshDepth {
            width: w,
            height: h,
            depth,
            normal,
            focal: camera.fx,
        }
    }
}

/// The parry3d ray from `o` along `d`.
fn parry_ray(o: Vec3, d: Vec3) -> parry3d::query::Ray {
    parry3d::query::Ray::new(
        parry3d::math::Vector::new(o.x, o.y, o.z),
        parry3d::math::Vector::new(d.x, d.y, d.z),
    )
}

/// A mesh prepared for exact closest-point queries and ray casts.
pub struct MeshBvh<'a> {
    mesh: &'a TriMesh,
    bvh: parry3d::shape::TriMesh,
    /// Original triangle index of each triangle kept in `bvh`.
    original: Vec<u32>,
}

impl<'a> MeshBvh<'a> {
    /// Builds the BVH over `mesh`'s triangles of positive area; errors on an empty or invalid
    /// mesh (`what` names it in errors).
    pub fn new(mesh: &'a TriMesh, what: &str) -> Result<Self> {
        validate(mesh, what)?;
        let mut original = Vec::with_capacity(mesh.triangles.len());
        let mut tris = Vec::with_capacity(mesh.triangles.len());
        for (k, &t) in mesh.triangles.iter().enumerate() {
            let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
            let scale = (b - a)
                .length_squared()
                .max((c - b).length_squared())
                .max((a - c).length_squared());
            let n2 = (b - a).cross(c - a).length_squared();
            // Drop degenerate (zero-area) triangles: they add no surface.
            if n2.is_finite() && n2 > 1e-14 * scale * scale {
                original.push(k as u32);
                tris.push(t);
            }
        }
        if tris.is_empty() {
            return Err(MeshError::EmptyMesh {
                what: what.to_string(),
            });
        }
        let verts = mesh
            .positions
            .iter()
            .map(|p| parry3d::math::Vector::new(p.x, p.y, p.z))
            .collect();
        let bvh =
            parry3d::shape::TriMesh::new(verts, tris).map_err(|e| MeshError::InvalidMesh {
                what: what.to_string(),
                message: e.to_string(),
            })?;
        Ok(MeshBvh {
            mesh,
            bvh,
            original,
        })
    }

    /// Whether the segment from `p` (on the mesh, with the unit normal `n` of its triangle) to
    /// `eye` is free of the mesh. The ray starts `eps` off the surface on the eye's side, so the
    /// sample's own triangle does not block it.
    pub fn sees(&self, p: Vec3, n: Vec3, eye: Vec3, eps: f32) -> bool {
        let to_eye = eye - p;
        let dist = to_eye.length();
        if dist <= 2.0 * eps {
            return true;
        }
        let d = to_eye / dist;
        let side = if n.dot(d) >= 0.0 { n } else { -n };
        let o = p + side * eps + d * eps;
        self.bvh
            .cast_local_ray(&parry_ray(o, d), dist - 2.0 * eps, false)
            .is_none()
    }

    /// The first hit of the ray from `o` along the unit direction `d`: the distance along the
    /// ray and the unit normal of the triangle hit, turned to face the ray's origin.
    pub fn first_hit(&self, o: Vec3, d: Vec3) -> Option<(f32, Vec3)> {
        let hit = self
            .bvh
            .cast_local_ray_and_get_normal(&parry_ray(o, d), f32::MAX, false)?;
        let n = Vec3::new(hit.normal.x, hit.normal.y, hit.normal.z).normalize_or_zero();
        let n = if n.dot(d) > 0.0 { -n } else { n };
        (hit.time_of_impact.is_finite() && n != Vec3::ZERO).then_some((hit.time_of_impact, n))
    }

    /// Exact distance from `p` to the mesh and the unit normal of the closest triangle.
    pub fn closest(&self, p: Vec3) -> (f32, Vec3) {
        let q = parry3d::math::Vector::new(p.x, p.y, p.z);
        let (proj, (tri, _)) = self.bvh.project_local_point_and_get_location(q, false);
        let d = Vec3::new(proj.point.x - p.x, proj.point.y - p.y, proj.point.z - p.z).length();
        let t = self.mesh.triangles[self.original[tri as usize] as usize];
        (d, face_normal_scaled(self.mesh, t).normalize_or_zero())
    }
}

/// Exact closest-point queries against a mesh, signed by the side of the closest triangle: for
/// diagnosing where reconstructed points lie relative to a ground truth.
pub struct SignedDistance<'a> {
    target: MeshBvh<'a>,
}

impl<'a> SignedDistance<'a> {
    /// Prepares `mesh` (`what` names it in errors; invalid or empty meshes are errors).
    pub fn new(mesh: &'a TriMesh, what: &str) -> Result<Self> {
        Ok(SignedDistance {
            target: MeshBvh::new(mesh, what)?,
        })
    }

    /// The distance from `p` to the mesh, positive on the side the closest triangle's winding
    /// normal points to (outside, for a closed outward-wound mesh), and that unit normal.
    pub fn query(&self, p: Vec3) -> (f32, Vec3) {
        let q = parry3d::math::Vector::new(p.x, p.y, p.z);
        let (proj, (tri, _)) = self
            .target
            .bvh
            .project_local_point_and_get_location(q, false);
        let c = Vec3::new(proj.point.x, proj.point.y, proj.point.z);
        let t = self.target.mesh.triangles[self.target.original[tri as usize] as usize];
        let n = face_normal_scaled(self.target.mesh, t).normalize_or_zero();
        let d = (p - c).length();
        (if (p - c).dot(n) < 0.0 { -d } else { d }, n)
    }
}
