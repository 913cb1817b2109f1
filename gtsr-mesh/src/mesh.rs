//! Triangle-mesh utilities: seeded area-uniform surface sampling, vertex welding,
//! connected components, closedness checks and an icosphere generator.
//!
//! Meshes are [`gtsr_data::ply::TriMesh`] (indexed, `u32` triangles). Face normals follow
//! the right-hand rule: `(b - a) x (c - a)`, so counter-clockwise triangles seen from
//! outside have outward normals.

use std::collections::HashMap;

use glam::Vec3;
use gtsr_data::ply::TriMesh;

use crate::error::{MeshError, Result};

/// A small deterministic random number generator (SplitMix64). Same seed, same stream, on
/// every platform.
#[derive(Clone, Debug)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    /// A generator seeded with `seed`.
    pub fn new(seed: u64) -> Self {
        SplitMix64(seed)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// A uniform `f64` in `[0, 1)` (53 random bits).
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

/// Points sampled on a mesh surface.
#[derive(Clone, Debug, Default)]
pub struct SurfaceSamples {
    /// Sample positions.
    pub points: Vec<Vec3>,
    /// Unit normal of the triangle each sample lies on.
    pub normals: Vec<Vec3>,
    /// Index (into the mesh's `triangles`) of the triangle each sample lies on.
    pub triangles: Vec<u32>,
}

/// The unnormalised normal `(b - a) x (c - a)` of triangle `t` (length = twice the area).
pub fn face_normal_scaled(mesh: &TriMesh, t: [u32; 3]) -> Vec3 {
    let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
    (b - a).cross(c - a)
}

/// The centroid of triangle `t`.
pub fn face_centroid(mesh: &TriMesh, t: [u32; 3]) -> Vec3 {
    t.iter().map(|&i| mesh.positions[i as usize]).sum::<Vec3>() / 3.0
}

/// Total surface area.
pub fn surface_area(mesh: &TriMesh) -> f64 {
    mesh.triangles
        .iter()
        .map(|&t| 0.5 * face_normal_scaled(mesh, t).length() as f64)
        .sum()
}

/// Checks that every index is in range and every vertex used is finite. `what` names the
/// mesh in the error.
pub fn validate(mesh: &TriMesh, what: &str) -> Result<()> {
    let n = mesh.positions.len();
    for (k, t) in mesh.triangles.iter().enumerate() {
        for &i in t {
            if i as usize >= n {
                return Err(MeshError::InvalidMesh {
                    what: what.to_string(),
                    message: format!("triangle {k} uses vertex {i} but there are {n} vertices"),
                });
            }
            if !mesh.positions[i as usize].is_finite() {
                return Err(MeshError::InvalidMesh {
                    what: what.to_string(),
                    message: format!("vertex {i} is not finite"),
                });
            }
        }
    }
    Ok(())
}

/// Samples `n` points uniformly by area on the surface of `mesh` (triangle chosen with
/// probability proportional to its area, then a uniform point in it), deterministically from
/// `seed`. Errors when the mesh is invalid or has no area; `what` names it in the error.
pub fn sample_surface(mesh: &TriMesh, n: usize, seed: u64, what: &str) -> Result<SurfaceSamples> {
    validate(mesh, what)?;
    let mut cumulative = Vec::with_capacity(mesh.triangles.len());
    let mut total = 0.0f64;
    for &t in &mesh.triangles {
        let a = face_normal_scaled(mesh, t).length() as f64;
        if a.is_finite() {
            total += a;
        }
        cumulative.push(total);
    }
    if total <= 0.0 {
        return Err(MeshError::EmptyMesh {
            what: what.to_string(),
        });
    }
    let mut rng = SplitMix64::new(seed);
    let mut out = SurfaceSamples {
        points: Vec::with_capacity(n),
        normals: Vec::with_capacity(n),
        triangles: Vec::with_capacity(n),
    };
    for _ in 0..n {
        let target = rng.next_f64() * total;
        // First triangle whose cumulative area exceeds the target: never a zero-area one.
        let k = cumulative
            .partition_point(|&c| c <= target)
            .min(cumulative.len() - 1);
        let t = mesh.triangles[k];
        let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
        let (r1, r2) = (rng.next_f64().sqrt(), rng.next_f64());
        let (wa, wb, wc) = (1.0 - r1, r1 * (1.0 - r2), r1 * r2);
        let p = a * wa as f32 + b * wb as f32 + c * wc as f32;
        out.points.push(p);
        out.normals.push((b - a).cross(c - a).normalize_or_zero());
        out.triangles.push(k as u32);
    }
    Ok(out)
}

/// Merges vertices closer than about `tolerance` (same cell of a grid of that size; with
/// `tolerance <= 0` only bit-identical positions merge), drops triangles that become
/// degenerate (repeated vertex) and vertices no triangle uses. Vertex order follows first
/// use, so the result is deterministic.
pub fn weld(mesh: &TriMesh, tolerance: f32) -> TriMesh {
    let mut key_to_new: HashMap<[i64; 3], u32> = HashMap::new();
    let mut remap = vec![u32::MAX; mesh.positions.len()];
    let mut positions = Vec::new();
    let mut triangles = Vec::with_capacity(mesh.triangles.len());
    let key = |p: Vec3| -> [i64; 3] {
        if tolerance > 0.0 {
            (p / tolerance).round().as_i64vec3().to_array()
        } else {
            p.to_array().map(|v| (v + 0.0).to_bits() as i64)
        }
    };
    for t in &mesh.triangles {
        if t.iter().any(|&i| i as usize >= mesh.positions.len()) {
            continue;
        }
        let nt = t.map(|i| {
            let i = i as usize;
            if remap[i] == u32::MAX {
                let p = mesh.positions[i];
                remap[i] = *key_to_new.entry(key(p)).or_insert_with(|| {
                    positions.push(p);
                    (positions.len() - 1) as u32
                });
            }
            remap[i]
        });
        if nt[0] != nt[1] && nt[1] != nt[2] && nt[0] != nt[2] {
            triangles.push(nt);
        }
    }
    TriMesh {
        positions,
        triangles,
    }
}

fn find(parent: &mut [u32], mut i: u32) -> u32 {
    while parent[i as usize] != i {
        let p = parent[parent[i as usize] as usize];
        parent[i as usize] = p;
        i = p;
    }
    i
}

/// Component label (a representative vertex) of every vertex, triangles connecting
/// vertices they share.
fn vertex_components(mesh: &TriMesh) -> Vec<u32> {
    let mut parent: Vec<u32> = (0..mesh.positions.len() as u32).collect();
    for t in &mesh.triangles {
        for &v in &t[1..] {
            let (ra, rb) = (find(&mut parent, t[0]), find(&mut parent, v));
            if ra != rb {
                parent[ra.max(rb) as usize] = ra.min(rb);
            }
        }
    }
    (0..mesh.positions.len() as u32)
        .map(|i| find(&mut parent, i))
        .collect()
}

/// Triangle count of every connected component (triangles connected through shared
/// vertices after welding bit-identical positions), largest first.
pub fn component_sizes(mesh: &TriMesh) -> Vec<usize> {
    let welded = weld(mesh, 0.0);
    let labels = vertex_components(&welded);
    let mut counts: HashMap<u32, usize> = HashMap::new();
    for t in &welded.triangles {
        *counts.entry(labels[t[0] as usize]).or_default() += 1;
    }
    let mut sizes: Vec<usize> = counts.into_values().collect();
    sizes.sort_unstable_by(|a, b| b.cmp(a));
    sizes
}

/// The connected component with the most triangles (ties: the one whose first triangle
/// comes first), after welding bit-identical positions. Unused vertices are dropped. An empty
/// mesh gives an empty mesh.
pub fn largest_component(mesh: &TriMesh) -> TriMesh {
    let welded = weld(mesh, 0.0);
    let labels = vertex_components(&welded);
    let mut counts: HashMap<u32, (usize, usize)> = HashMap::new();
    for (k, t) in welded.triangles.iter().enumerate() {
        counts.entry(labels[t[0] as usize]).or_insert((0, k)).0 += 1;
    }
    let Some((&best, _)) = counts
        .iter()
        .max_by(|a, b| a.1.0.cmp(&b.1.0).then(b.1.1.cmp(&a.1.1)))
    else {
        return TriMesh::default();
    };
    let kept = TriMesh {
        positions: welded.positions.clone(),
        triangles: welded
            .triangles
            .iter()
            .copied()
            .filter(|t| labels[t[0] as usize] == best)
            .collect(),
    };
    weld(&kept, 0.0)
}

/// Whether the mesh is closed and consistently oriented: every undirected edge is used by
/// exactly two triangles, once in each direction. (Non-manifold vertices are not detected.)
pub fn is_closed(mesh: &TriMesh) -> bool {
    let mut directed: HashMap<(u32, u32), u32> = HashMap::with_capacity(mesh.triangles.len() * 3);
    for t in &mesh.triangles {
        for k in 0..3 {
            *directed.entry((t[k], t[(k + 1) % 3])).or_default() += 1;
        }
    }
    !mesh.triangles.is_empty()
        && directed
            .iter()
            .all(|(&(a, b), &n)| n == 1 && directed.get(&(b, a)) == Some(&1))
}

/// A height field over the rectangle `[lo, hi]` of the xy plane: `n` cells a side, two
/// triangles per cell, vertex `(x, y, z(x, y))`, faces up (+z) where it is flat.
pub fn height_grid(
    n: usize,
    lo: glam::Vec2,
    hi: glam::Vec2,
    z: impl Fn(f32, f32) -> f32,
) -> TriMesh {
    let mut positions = Vec::with_capacity((n + 1) * (n + 1));
    for j in 0..=n {
        for i in 0..=n {
            let x = lo.x + (hi.x - lo.x) * i as f32 / n as f32;
            let y = lo.y + (hi.y - lo.y) * j as f32 / n as f32;
            positions.push(Vec3::new(x, y, z(x, y)));
        }
    }
    let at = |i: usize, j: usize| (j * (n + 1) + i) as u32;
    let mut triangles = Vec::with_capacity(2 * n * n);
    for j in 0..n {
        for i in 0..n {
            triangles.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            triangles.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    TriMesh {
        positions,
        triangles,
    }
}

/// An icosphere: a regular icosahedron subdivided `subdivisions` times with vertices pushed
/// onto the sphere (`20 * 4^subdivisions` triangles), outward oriented. Vertices lie on the
/// sphere, so the faces lie slightly inside it.
pub fn icosphere(centre: Vec3, radius: f32, subdivisions: u32) -> TriMesh {
    let unit = gtsr_data::synthetic::shapes::icosphere(subdivisions);
    TriMesh {
        positions: unit
            .positions
            .iter()
            .map(|&p| centre + p * radius)
            .collect(),
        triangles: unit.triangles,
    }
}
