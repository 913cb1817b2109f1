//! The shapes' meshes: icospheres, tubes along curves, the cube (and its slot), the bear by
//! marching tetrahedra over its ellipsoids.
use crate::ply::TriMesh;
use glam::Vec3;
use std::collections::HashMap;
use std::f32::consts::TAU;

use super::*;

/// The cube of half-side [`CUBE_HALF`], `n` squares (two triangles each) along each edge of
/// each face, vertices shared along the edges, turned by [`cube_rotation`]. With `slot`, the
/// squares of the face `z = CUBE_HALF` inside [`SLOT_CELLS`] sink to the slot's floor, and
/// walls join the floor to the face along the slot's outline (`n` must be [`SLOT_GRID`]).
pub(super) fn cube_mesh(n: u32, slot: bool) -> TriMesh {
    let turn = cube_rotation();
    // A vertex is a grid point; the slot's floor has its own (the fourth key is 1).
    let mut index: HashMap<[u32; 4], u32> = HashMap::new();
    let mut positions = Vec::new();
    let mut vertex = |g: [u32; 3], floor: bool| -> u32 {
        *index
            .entry([g[0], g[1], g[2], floor as u32])
            .or_insert_with(|| {
                let c = |k: usize| (2.0 * g[k] as f32 / n as f32 - 1.0) * CUBE_HALF;
                let lower = if floor { SLOT_DEPTH } else { 0.0 };
                positions.push(turn * Vec3::new(c(0), c(1), c(2) - lower));
                positions.len() as u32 - 1
            })
    };
    let ([su0, su1], [sv0, sv1]) = SLOT_CELLS;
    let mut triangles = Vec::with_capacity(12 * (n * n) as usize);
    for axis in 0..3 {
        // (u, v, axis) is right-handed, so u x v points along +axis.
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        for side in [0, n] {
            // The slotted face is z = +CUBE_HALF, where (u, v) is (x, y).
            let slotted = slot && axis == 2 && side == n;
            for i in 0..n {
                for j in 0..n {
                    let floor = slotted && (su0..su1).contains(&i) && (sv0..sv1).contains(&j);
                    let mut corner = |di: u32, dj: u32| {
                        let mut g = [0; 3];
                        g[axis] = side;
                        g[u] = i + di;
                        g[v] = j + dj;
                        vertex(g, floor)
                    };
                    let (a, b, c, d) = (corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1));
                    if side == n {
                        triangles.extend([[a, b, c], [a, c, d]]);
                    } else {
                        triangles.extend([[a, c, b], [a, d, c]]);
                    }
                }
            }
        }
    }
    if slot {
        // The walls: a quad from the face down to the floor along each edge `p -> q` of the
        // outline, walked counter-clockwise seen from above, so that the slot lies to the
        // left; (top p, floor q, floor p) then faces left, into the slot.
        let mut wall = |p: [u32; 2], q: [u32; 2]| {
            let (tp, tq) = (
                vertex([p[0], p[1], n], false),
                vertex([q[0], q[1], n], false),
            );
            let (fp, fq) = (vertex([p[0], p[1], n], true), vertex([q[0], q[1], n], true));
            triangles.extend([[tp, fq, fp], [tp, tq, fq]]);
        };
        for i in su0..su1 {
            wall([i, sv0], [i + 1, sv0]);
            wall([i + 1, sv1], [i, sv1]);
        }
        for j in sv0..sv1 {
            wall([su1, j], [su1, j + 1]);
            wall([su0, j + 1], [su0, j]);
        }
    }
    TriMesh {
        positions,
        triangles,
    }
}

/// Icosphere with `levels` subdivisions (20 * 4^levels triangles), unit radius.
pub fn icosphere(levels: u32) -> TriMesh {
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    let mut pos: Vec<Vec3> = [
        (-1.0, t, 0.0),
        (1.0, t, 0.0),
        (-1.0, -t, 0.0),
        (1.0, -t, 0.0),
        (0.0, -1.0, t),
        (0.0, 1.0, t),
        (0.0, -1.0, -t),
        (0.0, 1.0, -t),
        (t, 0.0, -1.0),
        (t, 0.0, 1.0),
        (-t, 0.0, -1.0),
        (-t, 0.0, 1.0),
    ]
    .iter()
    .map(|&(x, y, z)| Vec3::new(x, y, z).normalize())
    .collect();
    let mut tris: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..levels {
        let mut cache: HashMap<(u32, u32), u32> = HashMap::new();
        let mut mid = |a: u32, b: u32, pos: &mut Vec<Vec3>| -> u32 {
            let key = (a.min(b), a.max(b));
            *cache.entry(key).or_insert_with(|| {
                pos.push((pos[a as usize] + pos[b as usize]).normalize());
                pos.len() as u32 - 1
            })
        };
        let mut next = Vec::with_capacity(tris.len() * 4);
        for [a, b, c] in tris {
            let ab = mid(a, b, &mut pos);
            let bc = mid(b, c, &mut pos);
            let ca = mid(c, a, &mut pos);
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        tris = next;
    }
    orient_outward(TriMesh {
        positions: pos,
        triangles: tris,
    })
}

pub(super) fn orient_outward(mut m: TriMesh) -> TriMesh {
    if m.volume() < 0.0 {
        for t in m.triangles.iter_mut() {
            t.swap(1, 2);
        }
    }
    m
}

/// A tube of radius `radius` around a closed curve (`t` in `[0, 2 pi)`), with `n_along`
/// rings of `n_around` vertices, framed by parallel transport with the closing twist
/// spread evenly.
pub fn tube_mesh(curve: fn(f32) -> Vec3, radius: f32, n_along: usize, n_around: usize) -> TriMesh {
    let c: Vec<Vec3> = (0..n_along)
        .map(|i| curve(TAU * i as f32 / n_along as f32))
        .collect();
    let tang: Vec<Vec3> = (0..n_along)
        .map(|i| (c[(i + 1) % n_along] - c[(i + n_along - 1) % n_along]).normalize())
        .collect();
    let mut normals = Vec::with_capacity(n_along);
    let mut n = tang[0].any_orthonormal_vector();
    normals.push(n);
    for t in tang.iter().skip(1) {
        n = (n - *t * n.dot(*t)).normalize();
        normals.push(n);
    }
    // Transport once more to the start and measure the twist.
    let n_end = (n - tang[0] * n.dot(tang[0])).normalize();
    let twist = (n_end.cross(normals[0]).dot(tang[0])).atan2(n_end.dot(normals[0]));
    let mut pos = Vec::with_capacity(n_along * n_around);
    for i in 0..n_along {
        let ang = twist * i as f32 / n_along as f32;
        let t = tang[i];
        let n0 = normals[i];
        let b0 = t.cross(n0);
        let (n1, b1) = (
            n0 * ang.cos() + b0 * ang.sin(),
            b0 * ang.cos() - n0 * ang.sin(),
        );
        for j in 0..n_around {
            let a = TAU * j as f32 / n_around as f32;
            pos.push(c[i] + radius * (n1 * a.cos() + b1 * a.sin()));
        }
    }
    let mut tris = Vec::with_capacity(2 * n_along * n_around);
    for i in 0..n_along {
        let i1 = (i + 1) % n_along;
        for j in 0..n_around {
            let j1 = (j + 1) % n_around;
            let v = |a: usize, b: usize| (a * n_around + b) as u32;
            tris.push([v(i, j), v(i1, j), v(i1, j1)]);
            tris.push([v(i, j), v(i1, j1), v(i, j1)]);
        }
    }
    orient_outward(TriMesh {
        positions: pos,
        triangles: tris,
    })
}

/// Marching tetrahedra of the bear's union of ellipsoids on an `n^3` grid.
pub(super) fn bear_mesh(n: usize) -> TriMesh {
    let ell = bear_ellipsoids();
    let f = |p: Vec3| ell.iter().map(|e| e.sdf(p)).fold(f32::INFINITY, f32::min);
    let mut m = marching_tetrahedra(&f, Vec3::splat(-1.02), Vec3::splat(1.02), n);
    // Project every vertex onto the ellipsoid it belongs to, unless that would move it
    // inside another ellipsoid (crease vertices keep their interpolated position).
    for p in m.positions.iter_mut() {
        let (k, _) = ell
            .iter()
            .enumerate()
            .map(|(k, e)| (k, e.sdf(*p)))
            .fold((0, f32::INFINITY), |a, b| if b.1 < a.1 { b } else { a });
        let q = ell[k].project(*p);
        let ok = ell
            .iter()
            .enumerate()
            .all(|(j, e)| j == k || e.implicit(q) > -1e-4);
        if ok && (q - *p).length() < 0.05 {
            *p = q;
        }
    }
    m
}

/// Marching tetrahedra (Kuhn decomposition, 6 tetrahedra per cube along the 0-7 diagonal,
/// consistent across cubes, so the result is watertight) of `f < 0` over the box
/// `[lo, hi]` with `n` cells per side. Triangles face the positive side.
pub fn marching_tetrahedra(
    f: &(dyn Fn(Vec3) -> f32 + Sync),
    lo: Vec3,
    hi: Vec3,
    n: usize,
) -> TriMesh {
    use rayon::prelude::*;
    let np = n + 1;
    let h = (hi - lo) / n as f32;
    let grid_pos = |i: usize, j: usize, k: usize| lo + Vec3::new(i as f32, j as f32, k as f32) * h;
    let vals: Vec<f32> = (0..np * np * np)
        .into_par_iter()
        .map(|idx| {
            let v = f(grid_pos(idx % np, (idx / np) % np, idx / (np * np)));
            if v == 0.0 { 1e-9 } else { v }
        })
        .collect();
    let gid = |i: usize, j: usize, k: usize| i + np * (j + np * k);
    const TETS: [[usize; 4]; 6] = [
        [0, 1, 3, 7],
        [0, 1, 5, 7],
        [0, 2, 3, 7],
        [0, 2, 6, 7],
        [0, 4, 5, 7],
        [0, 4, 6, 7],
    ];
    let mut positions: Vec<Vec3> = Vec::new();
    let mut triangles: Vec<[u32; 3]> = Vec::new();
    let mut edge_vertex: HashMap<(usize, usize), u32> = HashMap::new();
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let corner = |b: usize| gid(i + (b & 1), j + ((b >> 1) & 1), k + ((b >> 2) & 1));
                let cs: [usize; 8] = std::array::from_fn(corner);
                let inside_count = cs.iter().filter(|&&g| vals[g] < 0.0).count();
                if inside_count == 0 || inside_count == 8 {
                    continue;
                }
                for tet in TETS {
                    let g: [usize; 4] = tet.map(|b| cs[b]);
                    let ins: Vec<usize> = (0..4).filter(|&a| vals[g[a]] < 0.0).collect();
                    let outs: Vec<usize> = (0..4).filter(|&a| vals[g[a]] >= 0.0).collect();
                    if ins.is_empty() || outs.is_empty() {
                        continue;
                    }
                    let pos_of = |gi: usize| grid_pos(gi % np, (gi / np) % np, gi / (np * np));
                    let mut vert = |a: usize, b: usize| -> u32 {
                        let (ga, gb) = (g[a], g[b]);
                        let key = (ga.min(gb), ga.max(gb));
                        *edge_vertex.entry(key).or_insert_with(|| {
                            let (va, vb) = (vals[ga], vals[gb]);
                            let t = va / (va - vb);
                            positions.push(pos_of(ga).lerp(pos_of(gb), t));
                            positions.len() as u32 - 1
                        })
                    };
                    let mut tri_list: Vec<[u32; 3]> = Vec::new();
                    match (ins.len(), outs.len()) {
                        (1, 3) => tri_list.push([
                            vert(ins[0], outs[0]),
                            vert(ins[0], outs[1]),
                            vert(ins[0], outs[2]),
                        ]),
                        (3, 1) => tri_list.push([
                            vert(outs[0], ins[0]),
                            vert(outs[0], ins[1]),
                            vert(outs[0], ins[2]),
                        ]),
                        _ => {
                            let a = vert(ins[0], outs[0]);
                            let b = vert(ins[0], outs[1]);
                            let c = vert(ins[1], outs[1]);
                            let d = vert(ins[1], outs[0]);
                            tri_list.push([a, b, c]);
                            tri_list.push([a, c, d]);
                        }
                    }
                    // Orient: the normal points from the inside corners to the outside ones.
                    let cin = ins.iter().map(|&a| pos_of(g[a])).sum::<Vec3>() / ins.len() as f32;
                    let cout = outs.iter().map(|&a| pos_of(g[a])).sum::<Vec3>() / outs.len() as f32;
                    for mut t in tri_list {
                        let [p0, p1, p2] = t.map(|v| positions[v as usize]);
                        let nrm = (p1 - p0).cross(p2 - p0);
                        if nrm.dot(cout - cin) < 0.0 {
                            t.swap(1, 2);
                        }
                        if t[0] != t[1] && t[1] != t[2] && t[0] != t[2] {
                            triangles.push(t);
                        }
                    }
                }
            }
        }
    }
    TriMesh {
        positions,
        triangles,
    }
}
