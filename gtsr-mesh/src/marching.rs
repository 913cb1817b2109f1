//! Marching cubes over a sampled scalar field, with unobserved samples.
//!
//! # Conventions
//!
//! * The field is sampled at grid points `origin + voxel * (i, j, k)`, `i < dims[0]` etc.,
//!   stored x-fastest: index `i + dims[0] * (j + dims[1] * k)`.
//! * **Negative is inside, positive is outside** (a signed distance function). The surface
//!   is the level set `value == iso`; triangles are counter-clockwise seen from the positive
//!   side, so face normals point toward increasing values (outward), and a closed surface
//!   around a negative region has positive signed volume.
//! * A cube with any unobserved or non-finite corner produces no triangles (no false walls
//!   between observed and unobserved space).
//! * Vertices are welded: each crossed grid edge gives exactly one vertex, shared by every
//!   triangle that uses it.
//!
//! # Triangulation table
//!
//! The 256-case table is generated at first use rather than typed in: on each cube face the
//! crossed edges are paired into segments (a face with four crossings separates its two
//! inside corners, a rule that depends only on the face, so the two cubes sharing a face
//! always agree and the output is watertight wherever all cubes are observed); segments are
//! oriented so the inside lies to one fixed side, chained into closed loops, and each loop is
//! fan-triangulated. The crossed-edge sets are those of the Lorensen–Cline / Bourke tables;
//! the triangulations differ from those tables only where a face is ambiguous.

use std::collections::HashMap;
use std::sync::LazyLock;

use glam::Vec3;
use gtsr_data::ply::TriMesh;
use rayon::prelude::*;

/// A scalar field sampled on a regular grid, with a per-sample observed flag.
#[derive(Clone, Debug, PartialEq)]
pub struct Grid {
    /// World position of grid point `(0, 0, 0)`.
    pub origin: Vec3,
    /// Spacing between grid points (world units).
    pub voxel: f32,
    /// Number of grid points along x, y, z.
    pub dims: [usize; 3],
    /// Field values, x-fastest (`dims[0] * dims[1] * dims[2]` of them).
    pub values: Vec<f32>,
    /// Whether each value was observed; unobserved values are ignored.
    pub observed: Vec<bool>,
}

impl Grid {
    /// A grid with every value `0.0` and unobserved.
    pub fn new(origin: Vec3, voxel: f32, dims: [usize; 3]) -> Self {
        let n = dims[0] * dims[1] * dims[2];
        Grid {
            origin,
            voxel,
            dims,
            values: vec![0.0; n],
            observed: vec![false; n],
        }
    }

    /// A fully observed grid with values `f(position)`, evaluated in parallel.
    pub fn from_fn(
        origin: Vec3,
        voxel: f32,
        dims: [usize; 3],
        f: impl Fn(Vec3) -> f32 + Sync,
    ) -> Self {
        let mut g = Grid::new(origin, voxel, dims);
        let plane = dims[0] * dims[1];
        if plane > 0 {
            g.values
                .par_chunks_mut(plane)
                .enumerate()
                .for_each(|(k, slice)| {
                    for j in 0..dims[1] {
                        for i in 0..dims[0] {
                            slice[i + dims[0] * j] =
                                f(origin + voxel * Vec3::new(i as f32, j as f32, k as f32));
                        }
                    }
                });
        }
        g.observed.fill(true);
        g
    }

    /// Linear index of grid point `(i, j, k)`.
    #[inline]
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.dims[0] * (j + self.dims[1] * k)
    }

    /// World position of grid point `(i, j, k)`.
    #[inline]
    pub fn point(&self, i: usize, j: usize, k: usize) -> Vec3 {
        self.origin + self.voxel * Vec3::new(i as f32, j as f32, k as f32)
    }
}

/// Corner offsets of a cube, Bourke numbering.
const CORNERS: [[usize; 3]; 8] = [
    [0, 0, 0],
    [1, 0, 0],
    [1, 1, 0],
    [0, 1, 0],
    [0, 0, 1],
    [1, 0, 1],
    [1, 1, 1],
    [0, 1, 1],
];

/// Cube edges as corner pairs, Bourke numbering (each pair differs along one axis).
const EDGES: [[usize; 2]; 12] = [
    [0, 1],
    [1, 2],
    [2, 3],
    [3, 0],
    [4, 5],
    [5, 6],
    [6, 7],
    [7, 4],
    [0, 4],
    [1, 5],
    [2, 6],
    [3, 7],
];

/// Cube faces: four corners in cyclic order and the outward face normal.
const FACES: [([usize; 4], [i32; 3]); 6] = [
    ([0, 1, 2, 3], [0, 0, -1]),
    ([4, 5, 6, 7], [0, 0, 1]),
    ([0, 1, 5, 4], [0, -1, 0]),
    ([3, 2, 6, 7], [0, 1, 0]),
    ([0, 3, 7, 4], [-1, 0, 0]),
    ([1, 2, 6, 5], [1, 0, 0]),
];

fn corner_pos(c: usize) -> Vec3 {
    let [x, y, z] = CORNERS[c];
    Vec3::new(x as f32, y as f32, z as f32)
}

fn edge_between(a: usize, b: usize) -> usize {
    EDGES
        .iter()
        .position(|e| (e[0] == a && e[1] == b) || (e[0] == b && e[1] == a))
        .expect("face corners are adjacent")
}

/// Triangles (as cube-edge triples) for each of the 256 inside/outside corner patterns
/// (bit `c` set when corner `c` is inside, i.e. below the iso level).
static TRIANGLES: LazyLock<Vec<Vec<[u8; 3]>>> =
    LazyLock::new(|| (0..256).map(case_triangles).collect());

fn case_triangles(case: usize) -> Vec<[u8; 3]> {
    let inside = |c: usize| case & (1 << c) != 0;
    let edge_mid = |e: usize| 0.5 * (corner_pos(EDGES[e][0]) + corner_pos(EDGES[e][1]));
    // next[e] = the crossed edge that follows e along the oriented loop.
    let mut next = [usize::MAX; 12];
    for (corners, normal) in FACES {
        let n = Vec3::new(normal[0] as f32, normal[1] as f32, normal[2] as f32);
        let crossed: Vec<usize> = (0..4)
            .filter(|&k| inside(corners[k]) != inside(corners[(k + 1) % 4]))
            .collect();
        // Segments as (edge, edge, direction from the inside part toward the outside part).
        let mut segments: Vec<(usize, usize, Vec3)> = Vec::new();
        match crossed.len() {
            0 => {}
            2 => {
                let ea = edge_between(corners[crossed[0]], corners[(crossed[0] + 1) % 4]);
                let eb = edge_between(corners[crossed[1]], corners[(crossed[1] + 1) % 4]);
                let (mut sin, mut nin, mut sout, mut nout) = (Vec3::ZERO, 0.0, Vec3::ZERO, 0.0);
                for &c in &corners {
                    if inside(c) {
                        sin += corner_pos(c);
                        nin += 1.0;
                    } else {
                        sout += corner_pos(c);
                        nout += 1.0;
                    }
                }
                segments.push((ea, eb, sout / nout - sin / nin));
            }
            4 => {
                // Ambiguous face: cut off each inside corner on its own.
                for k in 0..4 {
                    let c = corners[k];
                    if inside(c) {
                        let prev = corners[(k + 3) % 4];
                        let nxt = corners[(k + 1) % 4];
                        let ea = edge_between(prev, c);
                        let eb = edge_between(c, nxt);
                        let mid = 0.5 * (edge_mid(ea) + edge_mid(eb));
                        segments.push((ea, eb, mid - corner_pos(c)));
                    }
                }
            }
            _ => unreachable!("a face has an even number of sign changes"),
        }
        for (ea, eb, m) in segments {
            // Walk so that the outward (positive) side m and the face normal n give
            // direction m x n: the loop is then counter-clockwise seen from outside.
            let d = m.cross(n);
            let (from, to) = if (edge_mid(eb) - edge_mid(ea)).dot(d) > 0.0 {
                (ea, eb)
            } else {
                (eb, ea)
            };
            debug_assert_eq!(next[from], usize::MAX);
            next[from] = to;
        }
    }
    let mut tris = Vec::new();
    let mut visited = [false; 12];
    for start in 0..12 {
        if next[start] == usize::MAX || visited[start] {
            continue;
        }
        let mut lp = vec![start];
        visited[start] = true;
        let mut e = next[start];
        while e != start {
            visited[e] = true;
            lp.push(e);
            e = next[e];
        }
        triangulate_loop(&lp, &mut tris);
    }
    tris
}

/// Whether cube edges `a` and `b` lie on a common cube face.
fn share_face(a: usize, b: usize) -> bool {
    FACES.iter().any(|(corners, _)| {
        let on = |e: usize| corners.contains(&EDGES[e][0]) && corners.contains(&EDGES[e][1]);
        on(a) && on(b)
    })
}

/// Triangulates a closed loop of crossed edges (orientation kept) without any diagonal
/// between two vertices on a common cube face: such a diagonal would also be an edge of the
/// neighbouring cube's triangulation (a pinched, non-manifold edge). Ear clipping that only
/// cuts allowed diagonals; a fan from the first vertex when no such triangulation exists.
fn triangulate_loop(lp: &[usize], tris: &mut Vec<[u8; 3]>) {
    fn clip(poly: &[usize], out: &mut Vec<[u8; 3]>) -> bool {
        if poly.len() == 3 {
            out.push([poly[0] as u8, poly[1] as u8, poly[2] as u8]);
            return true;
        }
        let n = poly.len();
        for k in 0..n {
            let (prev, cur, next) = (poly[(k + n - 1) % n], poly[k], poly[(k + 1) % n]);
            if share_face(prev, next) {
                continue;
            }
            let mut rest = poly.to_vec();
            rest.remove(k);
            let mark = out.len();
            out.push([prev as u8, cur as u8, next as u8]);
            if clip(&rest, out) {
                return true;
            }
            out.truncate(mark);
        }
        false
    }
    if !clip(lp, tris) {
        FAN_FALLBACKS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        for w in 1..lp.len() - 1 {
            tris.push([lp[0] as u8, lp[w] as u8, lp[w + 1] as u8]);
        }
    }
}

/// Number of table loops that had to fall back to a fan (tests check it stays 0).
static FAN_FALLBACKS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

/// How many of the 256 table cases contain a loop that could not be triangulated without a
/// face-chord diagonal (0 for the generated table; exposed for tests).
pub fn table_fallbacks() -> usize {
    LazyLock::force(&TRIANGLES);
    FAN_FALLBACKS.load(std::sync::atomic::Ordering::Relaxed)
}

/// Number of triangles the table holds for corner pattern `case` (bit `c` set when corner
/// `c` is inside); exposed for tests.
pub fn case_triangle_count(case: u8) -> usize {
    TRIANGLES[case as usize].len()
}

/// One z-slab's output: edge key of each local vertex, the vertices, local triangles.
type Slab = (Vec<u64>, Vec<Vec3>, Vec<[u32; 3]>);

/// Extracts the `iso` level set of `grid` as a welded, outward-oriented triangle mesh
/// (see the module documentation). Work is split into z-slabs processed in parallel; the
/// output is the same for any thread count.
pub fn marching_cubes(grid: &Grid, iso: f32) -> TriMesh {
    let [nx, ny, nz] = grid.dims;
    if nx < 2
        || ny < 2
        || nz < 2
        || grid.values.len() != nx * ny * nz
        || grid.observed.len() != grid.values.len()
    {
        return TriMesh::default();
    }
    let cube_layers = nz - 1;
    let slab = cube_layers
        .div_ceil(rayon::current_num_threads() * 4)
        .clamp(1, 16);
    let slabs: Vec<Slab> = (0..cube_layers.div_ceil(slab))
        .into_par_iter()
        .map(|s| {
            let mut keys = Vec::new();
            let mut verts = Vec::new();
            let mut tris = Vec::new();
            let mut local: HashMap<u64, u32> = HashMap::new();
            for k in s * slab..((s + 1) * slab).min(cube_layers) {
                for j in 0..ny - 1 {
                    for i in 0..nx - 1 {
                        let mut idx = [0usize; 8];
                        let mut val = [0f32; 8];
                        let mut case = 0usize;
                        let mut ok = true;
                        for c in 0..8 {
                            let [dx, dy, dz] = CORNERS[c];
                            let id = grid.index(i + dx, j + dy, k + dz);
                            let v = grid.values[id];
                            if !grid.observed[id] || !v.is_finite() {
                                ok = false;
                                break;
                            }
                            idx[c] = id;
                            val[c] = v;
                            if v < iso {
                                case |= 1 << c;
                            }
                        }
                        if !ok || case == 0 || case == 255 {
                            continue;
                        }
                        for t in &TRIANGLES[case] {
                            let tri = t.map(|e| {
                                // Interpolate from the lower grid point so a shared edge
                                // gives the same position from every cube.
                                let [a, b] = EDGES[e as usize];
                                let (a, b) = if idx[a] < idx[b] { (a, b) } else { (b, a) };
                                let axis = (0..3)
                                    .find(|&d| CORNERS[a][d] != CORNERS[b][d])
                                    .unwrap_or(0);
                                let key = idx[a] as u64 * 3 + axis as u64;
                                *local.entry(key).or_insert_with(|| {
                                    let (va, vb) = (val[a], val[b]);
                                    let t = ((iso - va) / (vb - va)).clamp(0.0, 1.0);
                                    let pa = grid.point(
                                        i + CORNERS[a][0],
                                        j + CORNERS[a][1],
                                        k + CORNERS[a][2],
                                    );
                                    let pb = grid.point(
                                        i + CORNERS[b][0],
                                        j + CORNERS[b][1],
                                        k + CORNERS[b][2],
                                    );
                                    keys.push(key);
                                    verts.push(pa + (pb - pa) * t);
                                    (verts.len() - 1) as u32
                                })
                            });
                            tris.push(tri);
                        }
                    }
                }
            }
            (keys, verts, tris)
        })
        .collect();
    // Merge slabs in order; vertices on the planes between slabs are shared through their
    // edge key.
    let mut global: HashMap<u64, u32> = HashMap::new();
    let mut mesh = TriMesh::default();
    for (keys, verts, tris) in slabs {
        let remap: Vec<u32> = keys
            .iter()
            .zip(&verts)
            .map(|(&key, &p)| {
                *global.entry(key).or_insert_with(|| {
                    mesh.positions.push(p);
                    (mesh.positions.len() - 1) as u32
                })
            })
            .collect();
        mesh.triangles
            .extend(tris.iter().map(|t| t.map(|v| remap[v as usize])));
    }
    mesh
}
