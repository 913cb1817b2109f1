//! What of a ground-truth mesh the cameras can see: the faces that the training pixels show
//! ([`pixel_visible_faces`]), and the outer surface of a mesh whose parts overlap or enclose
//! cavities ([`outer_surface`]). A reconstruction from images can place only the first; the
//! rest is the floor of any mesh's score against the whole ground truth.
//!
//! ## The outer surface
//!
//! The faces that bound the space reachable from outside, without those buried inside another
//! part or facing a sealed cavity. A ground truth modelled as overlapping parts (a lid set
//! over a pit in a block) keeps faces that no camera can see: faces inside another part, and
//! the walls of cavities the parts seal. Which faces those are follows from two things:
//! * the *winding number* `w(p)`, how many times the mesh winds around `p` (0 outside, 1
//!   inside one outward-wound part, 2 where two overlap), counted exactly along rays: a ray
//!   from `p` crosses the mesh and each crossing adds the sign of the face's normal along the
//!   ray (leaving a part: +1, entering: -1). The crossings are found through a 2-D grid of
//!   the faces' footprints perpendicular to the ray, and every point is counted along three
//!   directions a few degrees off the axes; the median of the three counts is the answer,
//!   so that a ray through an edge or a vertex shared by several faces (counted twice or not
//!   at all) cannot decide alone;
//! * the *exterior*: the empty voxels (`w = 0` at their centres) of a grid around the mesh
//!   that a ball of a given width reaches from the grid's border, and those within its
//!   radius of there. A sealed cavity is empty but not exterior, nor is one opening through
//!   a slit narrower than the ball.
//!
//! A face is on the outer surface when the first empty voxel met stepping off it along its
//! normal is exterior.

use glam::Vec3;
use gtsr_data::ply::TriMesh;
use rayon::prelude::*;

use crate::carve::DepthMap;
use crate::error::{MeshError, Result};
use crate::mesh::{face_centroid, face_normal_scaled};
use crate::raycast::MeshRaycaster;

/// Faces binned by their footprint on the plane perpendicular to one ray direction. The mesh
/// is turned by `turn` so that the rays run along `+z`; the three directions are near the
/// three axes but not on them, so that rays from symmetric points (a sphere's centre) do not
/// pass exactly through the vertices and edges that lie on the axes.
struct RayGrid {
    turn: glam::Mat3,
    /// The turned vertex positions.
    pos: Vec<Vec3>,
    lo: [f32; 2],
    cell: [f32; 2],
    dims: [usize; 2],
    /// Per cell, the range of `faces` that holds its faces.
    starts: Vec<u32>,
    faces: Vec<u32>,
}

impl RayGrid {
    fn new(mesh: &TriMesh, turn: glam::Mat3) -> RayGrid {
        let pos: Vec<Vec3> = mesh.positions.iter().map(|&p| turn * p).collect();
        let (lo, hi) = pos.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(a, b), p| (a.min(*p), b.max(*p)),
        );
        let side = ((mesh.triangles.len() as f64).sqrt() as usize).clamp(1, 1024);
        let lo2 = [lo.x, lo.y];
        let span = [(hi.x - lo.x).max(1e-12), (hi.y - lo.y).max(1e-12)];
        let dims = [side, side];
        let cell = [span[0] / side as f32, span[1] / side as f32];
        let cell_of = |x: f32, k: usize| -> usize {
            (((x - lo2[k]) / cell[k]).floor().max(0.0) as usize).min(dims[k] - 1)
        };
        let footprint = |t: &[u32; 3]| {
            let ps = t.map(|i| pos[i as usize]);
            let (mut a, mut b) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
            for p in ps {
                a = [a[0].min(p.x), a[1].min(p.y)];
                b = [b[0].max(p.x), b[1].max(p.y)];
            }
            (
                cell_of(a[0], 0),
                cell_of(b[0], 0),
                cell_of(a[1], 1),
                cell_of(b[1], 1),
            )
        };
        // Two passes: count per cell, then fill.
        let mut starts = vec![0u32; dims[0] * dims[1] + 1];
        for t in &mesh.triangles {
            let (i0, i1, j0, j1) = footprint(t);
            for j in j0..=j1 {
                for i in i0..=i1 {
                    starts[j * dims[0] + i + 1] += 1;
                }
            }
        }
        for k in 1..starts.len() {
            starts[k] += starts[k - 1];
        }
        let mut fill = starts.clone();
        let mut faces = vec![0u32; *starts.last().unwrap_or(&0) as usize];
        for (f, t) in mesh.triangles.iter().enumerate() {
            let (i0, i1, j0, j1) = footprint(t);
            for j in j0..=j1 {
                for i in i0..=i1 {
                    let c = j * dims[0] + i;
                    faces[fill[c] as usize] = f as u32;
                    fill[c] += 1;
                }
            }
        }
        RayGrid {
            turn,
            pos,
            lo: lo2,
            cell,
            dims,
            starts,
            faces,
        }
    }

    /// The signed crossings of the ray from `p` (untturned) along the grid's direction.
    fn crossings(&self, mesh: &TriMesh, p: Vec3) -> i32 {
        let p = self.turn * p;
        let gi = (p.x - self.lo[0]) / self.cell[0];
        let gj = (p.y - self.lo[1]) / self.cell[1];
        if !(gi >= 0.0 && gj >= 0.0) || gi >= self.dims[0] as f32 || gj >= self.dims[1] as f32 {
            return 0; // outside the mesh's footprint: no face on this ray
        }
        let c = gj as usize * self.dims[0] + gi as usize;
        let (px, py) = (f64::from(p.x), f64::from(p.y));
        let mut w = 0;
        for &f in &self.faces[self.starts[c] as usize..self.starts[c + 1] as usize] {
            let [q0, q1, q2] = mesh.triangles[f as usize].map(|i| self.pos[i as usize]);
            // Edge functions of the projected triangle at p, in f64.
            let e = |s: Vec3, t: Vec3| {
                (f64::from(t.x) - f64::from(s.x)) * (py - f64::from(s.y))
                    - (f64::from(t.y) - f64::from(s.y)) * (px - f64::from(s.x))
            };
            let (e0, e1, e2) = (e(q0, q1), e(q1, q2), e(q2, q0));
            let area = e0 + e1 + e2;
            if area == 0.0 {
                continue; // edge-on to the ray
            }
            let inside = if area > 0.0 {
                e0 >= 0.0 && e1 >= 0.0 && e2 >= 0.0
            } else {
                e0 <= 0.0 && e1 <= 0.0 && e2 <= 0.0
            };
            if !inside {
                continue;
            }
            // The hit's height along the ray, from the barycentric weights.
            let hit = (e1 * f64::from(q0.z) + e2 * f64::from(q1.z) + e0 * f64::from(q2.z)) / area;
            if hit > f64::from(p.z) {
                // The face normal's component along the ray has the sign of the projected area.
                w += if area > 0.0 { 1 } else { -1 };
            }
        }
        w
    }
}

/// The three turns of [`RayGrid`]: each takes a direction a few degrees off one axis to `+z`.
fn ray_turns() -> [glam::Mat3; 3] {
    let off = |to_z: glam::Mat3, a: f32, b: f32| {
        glam::Mat3::from_rotation_x(a) * glam::Mat3::from_rotation_y(b) * to_z
    };
    [
        off(glam::Mat3::IDENTITY, 0.0713, 0.0529),
        off(
            glam::Mat3::from_rotation_y(-std::f32::consts::FRAC_PI_2),
            0.0617,
            0.0881,
        ),
        off(
            glam::Mat3::from_rotation_x(std::f32::consts::FRAC_PI_2),
            0.0937,
            0.0433,
        ),
    ]
}

/// The three [`RayGrid`]s of a mesh: the winding number at any point.
struct Winding<'a> {
    mesh: &'a TriMesh,
    grids: Vec<RayGrid>,
}

impl<'a> Winding<'a> {
    fn new(mesh: &'a TriMesh) -> Result<Self> {
        if mesh.triangles.is_empty() {
            return Err(MeshError::InvalidArgument(
                "winding numbers need a mesh with faces".into(),
            ));
        }
        let grids = ray_turns()
            .into_iter()
            .map(|t| RayGrid::new(mesh, t))
            .collect();
        Ok(Winding { mesh, grids })
    }

    /// The median of the three directions' counts at `p`.
    fn at(&self, p: Vec3) -> i32 {
        let mut w = [0i32; 3];
        for (w, g) in w.iter_mut().zip(&self.grids) {
            *w = g.crossings(self.mesh, p);
        }
        w.sort_unstable();
        w[1]
    }
}

/// Winding numbers of a closed mesh at many points (module documentation): for a closed,
/// outward-wound mesh 0 outside, 1 inside one part, `k` where `k` parts overlap. Points on
/// the surface itself get either side's value. Errors on a mesh without faces or a
/// non-finite point. Parallel (rayon).
pub fn winding_numbers(mesh: &TriMesh, points: &[Vec3]) -> Result<Vec<i32>> {
    if let Some(i) = points.iter().position(|p| !p.is_finite()) {
        return Err(MeshError::InvalidArgument(format!(
            "point {i} of the winding-number query is not finite"
        )));
    }
    let winding = Winding::new(mesh)?;
    Ok(points.par_iter().map(|&p| winding.at(p)).collect())
}

/// The faces of `mesh` that `keep` flags (one flag a face), on its vertices; `none` is the
/// error when no face is kept.
pub(crate) fn faces_kept(mesh: &TriMesh, keep: &[bool], none: &str) -> Result<TriMesh> {
    let triangles: Vec<[u32; 3]> = mesh
        .triangles
        .iter()
        .zip(keep)
        .filter(|(_, k)| **k)
        .map(|(t, _)| *t)
        .collect();
    if triangles.is_empty() {
        return Err(MeshError::InvalidArgument(none.into()));
    }
    Ok(TriMesh {
        positions: mesh.positions.clone(),
        triangles,
    })
}

/// Voxels along the longest side of the box in [`outer_surface`]'s grid, for a ground truth
/// of the development scenes' detail.
pub const OUTER_GRID: usize = 512;

/// The outer surface of a closed, outward-wound mesh (module documentation), on a grid of
/// `grid` voxels along the longest side of its box (at least 8), where openings narrower
/// than `min_gap` (world units; a voxel at least) count as sealed: the exterior is the
/// empty space a ball of diameter `min_gap` reaches from outside, and the empty space within
/// its radius of there. A camera whose pixel footprint is wider than a slit does not see
/// through it. The faces kept are those from whose centroid the first empty voxel along the
/// face's normal (probed at 0.5 to 3 voxels) belongs to the exterior. With parts that
/// neither overlap nor enclose a cavity this is the whole mesh. Degenerate faces are
/// dropped. Errors on an empty or non-finite mesh, a bad grid or gap, or when no face faces
/// the exterior (a mesh wound inward).
pub fn outer_surface(mesh: &TriMesh, grid: usize, min_gap: f32) -> Result<TriMesh> {
    crate::mesh::validate(mesh, "the mesh of the outer surface")?;
    if !(8..=4096).contains(&grid) {
        return Err(MeshError::InvalidArgument(format!(
            "the outer surface's grid needs 8 to 4096 voxels a side, not {grid}"
        )));
    }
    if !(min_gap.is_finite() && min_gap >= 0.0) {
        return Err(MeshError::InvalidArgument(format!(
            "the outer surface's narrowest opening must be finite and >= 0, not {min_gap}"
        )));
    }
    let (lo, hi) = mesh.bounds();
    let voxel = (hi - lo).max_element().max(1e-12) / grid as f32;
    // The ball's radius in voxels, and a margin of empty voxels beyond it on every side, so
    // that the border is exterior.
    let radius = 0.5 * min_gap / voxel;
    let reach = radius.ceil() as i64;
    let pad = 2.0 + reach as f32;
    let origin = lo - Vec3::splat(pad * voxel);
    let dims = ((hi - lo) / voxel).ceil().as_uvec3() + glam::UVec3::splat(2 * pad as u32 + 1);
    let (nx, ny, nz) = (dims.x as usize, dims.y as usize, dims.z as usize);
    let centre = |i: usize, j: usize, k: usize| {
        origin + (Vec3::new(i as f32, j as f32, k as f32) + 0.5) * voxel
    };
    let winding = Winding::new(mesh)?;
    let solid: Vec<bool> = (0..nx * ny * nz)
        .into_par_iter()
        .map(|v| winding.at(centre(v % nx, (v / nx) % ny, v / (nx * ny))) != 0)
        .collect();
    let coords = |v: usize| (v % nx, (v / nx) % ny, v / (nx * ny));
    // Offsets within the ball (none beyond the voxel itself when the radius is below one).
    let ball: Vec<(i64, i64, i64)> = (-reach..=reach)
        .flat_map(|i| (-reach..=reach).flat_map(move |j| (-reach..=reach).map(move |k| (i, j, k))))
        .filter(|&(i, j, k)| ((i * i + j * j + k * k) as f32) <= radius * radius)
        .collect();
    let neighbours = |v: usize, offsets: &[(i64, i64, i64)], out: &mut Vec<usize>| {
        out.clear();
        let (i, j, k) = coords(v);
        for &(di, dj, dk) in offsets {
            let (a, b, c) = (i as i64 + di, j as i64 + dj, k as i64 + dk);
            if a >= 0
                && b >= 0
                && c >= 0
                && (a as usize) < nx
                && (b as usize) < ny
                && (c as usize) < nz
            {
                out.push(a as usize + nx * (b as usize + ny * c as usize));
            }
        }
    };
    // Where the ball's centre cannot go: the solid grown by the radius (from its boundary).
    let mut blocked = solid.clone();
    let mut near = Vec::new();
    if ball.len() > 1 {
        for (v, _) in solid.iter().enumerate().filter(|(_, s)| **s) {
            neighbours(v, &ball, &mut near);
            if near.iter().any(|&u| !solid[u]) {
                for &u in &near {
                    blocked[u] = true;
                }
            }
        }
    }
    // Flood the ball's centres from the border (6-connected).
    let steps = [
        (1, 0, 0),
        (-1, 0, 0),
        (0, 1, 0),
        (0, -1, 0),
        (0, 0, 1),
        (0, 0, -1),
    ];
    let mut reached = vec![false; solid.len()];
    let mut stack: Vec<usize> = (0..solid.len())
        .filter(|&v| {
            let (i, j, k) = coords(v);
            i == 0 || j == 0 || k == 0 || i == nx - 1 || j == ny - 1 || k == nz - 1
        })
        .collect();
    for &v in &stack {
        reached[v] = true;
    }
    while let Some(v) = stack.pop() {
        neighbours(v, &steps, &mut near);
        for &u in &near {
            if !blocked[u] && !reached[u] {
                reached[u] = true;
                stack.push(u);
            }
        }
    }
    // The exterior: the empty voxels the ball covers from the centres it reached.
    let mut exterior = reached.clone();
    if ball.len() > 1 {
        for (v, _) in reached.iter().enumerate().filter(|(_, r)| **r) {
            neighbours(v, &ball, &mut near);
            if near.iter().any(|&u| blocked[u]) {
                for &u in &near {
                    exterior[u] |= !solid[u];
                }
            }
        }
    }
    let voxel_of = |p: Vec3| -> Option<usize> {
        let g = ((p - origin) / voxel).floor();
        if g.min_element() < 0.0 || g.x >= nx as f32 || g.y >= ny as f32 || g.z >= nz as f32 {
            return None;
        }
        Some(g.x as usize + nx * (g.y as usize + ny * g.z as usize))
    };
    let outer: Vec<bool> = mesh
        .triangles
        .par_iter()
        .map(|t| {
            let n = face_normal_scaled(mesh, *t).normalize_or_zero();
            if n == Vec3::ZERO {
                return false;
            }
            let c = face_centroid(mesh, *t);
            for step in [0.5f32, 1.0, 1.5, 2.0, 2.5, 3.0] {
                match voxel_of(c + step * voxel * n) {
                    None => return true,
                    Some(v) if !solid[v] => return exterior[v],
                    Some(_) => {}
                }
            }
            false
        })
        .collect();
    faces_kept(
        mesh,
        &outer,
        "no face of the mesh faces the space outside it (is it wound inward?)",
    )
}

/// The faces of `mesh` that the pixels of `cameras` show: those whose centroid, projected
/// into some camera that it faces, lies within `tolerance` pixel footprints (at its depth)
/// of the first hit of the ray through that pixel's centre. The images record nothing of the
/// other faces, so no reconstruction from them can place those. Errors on an invalid mesh,
/// no camera, a bad tolerance, or when no face is shown.
pub fn pixel_visible_faces(
    mesh: &TriMesh,
    cameras: &[gtsr_data::Camera],
    tolerance: f32,
) -> Result<TriMesh> {
    if cameras.is_empty() {
        return Err(MeshError::InvalidArgument(
            "pixel visibility needs at least one camera".into(),
        ));
    }
    check_tolerance(tolerance)?;
    let caster = MeshRaycaster::new(mesh, "the mesh of the pixel visibility")?;
    let maps: Vec<_> = cameras.iter().map(|c| caster.render(c)).collect();
    let depths: Vec<DepthMap> = cameras
        .iter()
        .zip(&maps)
        .map(|(camera, map)| DepthMap {
            camera,
            depth: &map.depth,
            hull_depth: None,
        })
        .collect();
    observed_faces(mesh, &depths, tolerance)
}

/// The faces of `mesh` that some depth map observes ([`faces_observed`]): a closed mesh
/// carved through an opening narrower than the views can look through has walls inside the
/// cavity behind it that no view sees as a surface, and this leaves them out (the mesh is then
/// open). Errors as [`faces_observed`] does, and when no face is observed.
pub fn observed_faces(mesh: &TriMesh, depths: &[DepthMap], tolerance: f32) -> Result<TriMesh> {
    let shown = faces_observed(mesh, depths, tolerance)?;
    faces_kept(
        mesh,
        &shown,
        "no face of the mesh is observed by any depth map",
    )
}

/// Per face of `mesh`, whether some depth map observes it: its centroid, projected into a
/// view that it faces, lies within `tolerance` pixel footprints (at its depth) of that view's
/// depth at the nearest pixel. Errors on an invalid mesh, no depth map, a bad tolerance or a
/// depth map of the wrong size.
pub fn faces_observed(mesh: &TriMesh, depths: &[DepthMap], tolerance: f32) -> Result<Vec<bool>> {
    faces_observed_among(mesh, depths, tolerance, &vec![true; mesh.triangles.len()])
}

/// The observation tolerance must be a finite, positive number of footprints.
fn check_tolerance(tolerance: f32) -> Result<()> {
    if tolerance.is_finite() && tolerance > 0.0 {
        Ok(())
    } else {
        Err(MeshError::InvalidArgument(format!(
            "the observation tolerance must be finite and > 0 footprints, not {tolerance}"
        )))
    }
}

/// [`faces_observed`] for the faces `among` flags (one flag a face); the others are false and
/// cost nothing.
pub(crate) fn faces_observed_among(
    mesh: &TriMesh,
    depths: &[DepthMap],
    tolerance: f32,
    among: &[bool],
) -> Result<Vec<bool>> {
    if depths.is_empty() {
        return Err(MeshError::InvalidArgument(
            "observing faces needs at least one depth map".into(),
        ));
    }
    check_tolerance(tolerance)?;
    debug_assert_eq!(among.len(), mesh.triangles.len());
    for (k, dm) in depths.iter().enumerate() {
        let n = dm.camera.width as usize * dm.camera.height as usize;
        if dm.depth.len() != n {
            return Err(MeshError::size(
                &format!("depth map {k}"),
                n,
                dm.depth.len(),
            ));
        }
    }
    crate::mesh::validate(mesh, "the mesh to observe")?;
    let eyes: Vec<Vec3> = depths.iter().map(|dm| dm.camera.centre()).collect();
    let shown: Vec<bool> = mesh
        .triangles
        .par_iter()
        .zip(among)
        .map(|(t, among)| {
            if !among {
                return false;
            }
            let n = face_normal_scaled(mesh, *t);
            let c = face_centroid(mesh, *t);
            depths.iter().zip(&eyes).any(|(dm, eye)| {
                if n.dot(*eye - c) <= 0.0 {
                    return false; // faces away
                }
                let cam = dm.camera;
                let Some((uv, z)) = cam.project(c) else {
                    return false;
                };
                let (i, j) = (uv.x.floor(), uv.y.floor());
                if i < 0.0 || j < 0.0 || i >= cam.width as f32 || j >= cam.height as f32 {
                    return false;
                }
                let d = dm.depth[j as usize * cam.width as usize + i as usize];
                d > 0.0 && (d - z).abs() <= tolerance * z / cam.fx
            })
        })
        .collect();
    Ok(shown)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::icosphere;

    fn merged(a: TriMesh, b: TriMesh) -> TriMesh {
        let base = a.positions.len() as u32;
        let mut out = a;
        out.positions.extend(b.positions);
        out.triangles
            .extend(b.triangles.iter().map(|t| t.map(|i| i + base)));
        out
    }

    #[test]
    fn winding_numbers_count_the_parts_around_a_point() {
        // Two overlapping spheres: radius 1 at the origin, radius 0.5 at x = 0.9.
        let mesh = merged(
            icosphere(Vec3::ZERO, 1.0, 4),
            icosphere(Vec3::new(0.9, 0.0, 0.0), 0.5, 4),
        );
        let pts = [
            Vec3::new(0.0, 0.0, 0.0),   // inside the big one only
            Vec3::new(0.8, 0.05, 0.03), // inside both
            Vec3::new(1.3, 0.01, 0.02), // inside the small one only
            Vec3::new(2.0, 0.3, 0.1),   // outside
            Vec3::new(-0.3, 0.95, 0.2), // outside, beside the big one
        ];
        let w = winding_numbers(&mesh, &pts).unwrap();
        assert_eq!(w, vec![1, 2, 1, 0, 0]);
    }

    #[test]
    fn the_outer_surface_leaves_out_buried_faces_and_sealed_cavities() {
        let big = icosphere(Vec3::ZERO, 1.0, 3);
        let small = icosphere(Vec3::new(0.9, 0.0, 0.0), 0.5, 3);
        let (n_big, n_small) = (big.triangles.len(), small.triangles.len());
        let mesh = merged(big.clone(), small);
        // Voxel 0.025: a probe 3 voxels off a face lies in a voxel whose centre is at most
        // 0.097 from the face.
        let outer = outer_surface(&mesh, 96, 0.0).unwrap();
        // Every kept face is outside the other sphere; every dropped face is inside it.
        // (Signed distances to the true spheres; the faceted ones lie within 0.01 of them, and
        // faces within 0.1 of the other sphere are left to the grid.)
        let to_big = |p: Vec3| p.length() - 1.0;
        let to_small = |p: Vec3| (p - Vec3::new(0.9, 0.0, 0.0)).length() - 0.5;
        let kept: std::collections::HashSet<[u32; 3]> = outer.triangles.iter().copied().collect();
        let (mut dropped, mut checked) = (0, 0);
        for (f, t) in mesh.triangles.iter().enumerate() {
            let c = face_centroid(&mesh, *t);
            let gap = if f < n_big { to_small(c) } else { to_big(c) };
            if gap.abs() < 0.1 {
                continue;
            }
            assert_eq!(kept.contains(t), gap > 0.0, "face {f} at {c}");
            dropped += (gap < 0.0) as usize;
            checked += 1;
        }
        assert!(
            dropped > 100 && checked > (n_big + n_small) / 2,
            "{dropped} {checked}"
        );
        // A cavity: a sphere wound inward inside the big one. Nothing outside sees its walls.
        let hollow = icosphere(Vec3::new(0.1, 0.0, 0.0), 0.4, 3);
        let inward = TriMesh {
            positions: hollow.positions.clone(),
            triangles: hollow
                .triangles
                .iter()
                .map(|t| [t[0], t[2], t[1]])
                .collect(),
        };
        let shell = merged(big.clone(), inward);
        let w = winding_numbers(
            &shell,
            &[Vec3::new(0.1, 0.0, 0.0), Vec3::new(0.0, 0.75, 0.0)],
        )
        .unwrap();
        assert_eq!(w, vec![0, 1], "the cavity is empty, the shell solid");
        let outer = outer_surface(&shell, 64, 0.0).unwrap();
        assert_eq!(
            outer.triangles, big.triangles,
            "the cavity's walls are left out"
        );
        // A single closed part is its own outer surface.
        assert_eq!(outer_surface(&big, 32, 0.0).unwrap().triangles.len(), n_big);
        // Bad input is an error, not a panic.
        assert!(outer_surface(&big, 4, 0.0).is_err());
        assert!(outer_surface(&big, 32, f32::NAN).is_err());
        assert!(winding_numbers(&big, &[Vec3::NAN]).is_err());
        let flipped = TriMesh {
            positions: big.positions.clone(),
            triangles: big.triangles.iter().map(|t| [t[0], t[2], t[1]]).collect(),
        };
        assert!(outer_surface(&flipped, 32, 0.0).is_err());
    }

    /// An axis-aligned box, 12 outward-wound triangles.
    fn cuboid(lo: Vec3, hi: Vec3) -> TriMesh {
        let positions = (0..8)
            .map(|k| {
                Vec3::new(
                    if k & 1 == 0 { lo.x } else { hi.x },
                    if k & 2 == 0 { lo.y } else { hi.y },
                    if k & 4 == 0 { lo.z } else { hi.z },
                )
            })
            .collect();
        let quads = [
            [0, 2, 6, 4], // -x (listed clockwise from outside)
            [1, 5, 7, 3], // +x
            [0, 4, 5, 1], // -y
            [2, 3, 7, 6], // +y
            [0, 1, 3, 2], // -z
            [4, 6, 7, 5], // +z
        ];
        let triangles = quads
            .iter()
            .flat_map(|q| [[q[0], q[2], q[1]], [q[0], q[3], q[2]]])
            .collect();
        TriMesh {
            positions,
            triangles,
        }
    }

    #[test]
    fn openings_narrower_than_the_gap_count_as_sealed() {
        // Two blocks facing each other across a slit 0.1 wide.
        let a = cuboid(Vec3::new(-1.0, -0.5, -0.5), Vec3::new(-0.05, 0.5, 0.5));
        let b = cuboid(Vec3::new(0.05, -0.5, -0.5), Vec3::new(1.0, 0.5, 0.5));
        assert!(crate::mesh::is_closed(&a), "the test block is closed");
        let mesh = merged(a, b);
        let facing = |t: &[u32; 3]| t.iter().all(|&i| mesh.positions[i as usize].x.abs() < 0.06);
        // Open at any gap below the slit's width: every face is outer.
        let open = outer_surface(&mesh, 64, 0.0).unwrap();
        assert_eq!(open.triangles.len(), 24);
        // A ball 0.25 wide does not fit in: the slit's walls are left out, the rest kept.
        let sealed = outer_surface(&mesh, 64, 0.25).unwrap();
        assert_eq!(sealed.triangles.len(), 20);
        assert!(sealed.triangles.iter().all(|t| !facing(t)));
    }

    #[test]
    fn pixels_show_no_buried_face() {
        let big = icosphere(Vec3::ZERO, 1.0, 3);
        let small = icosphere(Vec3::new(0.9, 0.0, 0.0), 0.5, 3);
        let n_big = big.triangles.len();
        let mesh = merged(big, small);
        let cameras: Vec<gtsr_data::Camera> =
            [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z]
                .iter()
                .map(|&d| {
                    let up = if d.y.abs() > 0.5 { Vec3::Z } else { Vec3::Y };
                    gtsr_data::Camera::look_at(
                        4.0 * d + Vec3::new(0.3, 0.0, 0.0),
                        Vec3::new(0.3, 0.0, 0.0),
                        up,
                        0.9,
                        96,
                        96,
                    )
                })
                .collect();
        let shown = pixel_visible_faces(&mesh, &cameras, 1.5).unwrap();
        let kept: std::collections::HashSet<[u32; 3]> = shown.triangles.iter().copied().collect();
        let to_big = |p: Vec3| p.length() - 1.0;
        let to_small = |p: Vec3| (p - Vec3::new(0.9, 0.0, 0.0)).length() - 0.5;
        let (mut outside, mut outside_kept) = (0, 0);
        for (f, t) in mesh.triangles.iter().enumerate() {
            let c = face_centroid(&mesh, *t);
            let gap = if f < n_big { to_small(c) } else { to_big(c) };
            if gap < -0.05 {
                assert!(!kept.contains(t), "buried face {f} at {c} is shown");
            } else if gap > 0.05 {
                outside += 1;
                outside_kept += kept.contains(t) as usize;
            }
        }
        // Six cameras see nearly all of the outer surface.
        assert!(
            outside_kept * 10 >= outside * 9,
            "{outside_kept} of {outside}"
        );
        assert!(pixel_visible_faces(&mesh, &[], 1.5).is_err());
        assert!(pixel_visible_faces(&mesh, &cameras, 0.0).is_err());
    }

    #[test]
    fn observed_faces_keep_what_the_depth_sees() {
        // A sphere hidden inside another: the depth maps of the pair see only the outer one.
        let outer = icosphere(Vec3::ZERO, 1.0, 3);
        let n_outer = outer.triangles.len();
        let both = merged(outer, icosphere(Vec3::new(0.1, 0.0, 0.0), 0.5, 3));
        let cams: Vec<gtsr_data::Camera> = (0..12)
            .map(|k| {
                let a = k as f32 * std::f32::consts::TAU / 12.0;
                let eye = Vec3::new(4.0 * a.cos(), 1.5 * (k % 3) as f32 - 1.5, 4.0 * a.sin());
                gtsr_data::Camera::look_at(eye, Vec3::ZERO, Vec3::Y, 0.7, 64, 64)
            })
            .collect();
        let caster = MeshRaycaster::new(&both, "both").unwrap();
        let maps: Vec<_> = cams.iter().map(|c| caster.render(c)).collect();
        let depths: Vec<DepthMap> = cams
            .iter()
            .zip(&maps)
            .map(|(camera, m)| DepthMap {
                camera,
                depth: &m.depth,
                hull_depth: None,
            })
            .collect();
        let kept = observed_faces(&both, &depths, 1.0).unwrap();
        let inner_kept = kept
            .triangles
            .iter()
            .filter(|t| kept.positions[t[0] as usize].length() < 0.9)
            .count();
        assert_eq!(inner_kept, 0, "inner faces kept");
        assert!(
            kept.triangles.len() * 10 > n_outer * 9,
            "{} of {n_outer} outer faces kept",
            kept.triangles.len()
        );
        assert!(observed_faces(&both, &[], 1.0).is_err());
        assert!(observed_faces(&both, &depths, 0.0).is_err());
        let short = [DepthMap {
            camera: &cams[0],
            depth: &maps[0].depth[1..],
            hull_depth: None,
        }];
        assert!(observed_faces(&both, &short, 1.0).is_err());
    }
}
