//! A binned-SAH bounding volume hierarchy over a triangle mesh, with closest-hit,
//! any-hit and closest-point queries, and a "safe distance" grid: for every cell a lower
//! bound on the distance from any point of the cell to the mesh. The volumetric random walk
//! uses it to skip the ray query when the sampled free flight is shorter than the bound.

use glam::{Vec3, Vec3A};
use rayon::prelude::*;

use crate::ply::TriMesh;

#[derive(Clone, Copy, Debug)]
struct Node {
    lo: Vec3A,
    hi: Vec3A,
    /// Leaf: first triangle; inner: index of the left child (right = left + 1).
    start: u32,
    /// Leaf: triangle count (> 0); inner: 0.
    count: u32,
}

#[derive(Clone, Copy, Debug)]
struct Tri {
    v0: Vec3A,
    e1: Vec3A,
    e2: Vec3A,
}

/// A ray hit.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    /// Ray parameter.
    pub t: f32,
    /// Unit geometric normal, pointing outward for an outward-oriented mesh.
    pub normal: Vec3,
}

/// BVH over a triangle mesh.
pub struct Bvh {
    nodes: Vec<Node>,
    tris: Vec<Tri>,
    normals: Vec<Vec3>,
}

const BINS: usize = 16;
const LEAF: usize = 4;

fn centroid(t: &Tri) -> Vec3A {
    t.v0 + (t.e1 + t.e2) / 3.0
}

fn tri_bounds(t: &Tri) -> (Vec3A, Vec3A) {
    let (a, b, c) = (t.v0, t.v0 + t.e1, t.v0 + t.e2);
    (a.min(b).min(c), a.max(b).max(c))
}

fn area(lo: Vec3A, hi: Vec3A) -> f32 {
    let d = (hi - lo).max(Vec3A::ZERO);
    d.x * d.y + d.y * d.z + d.z * d.x
}

impl Bvh {
    /// Builds the hierarchy (binned SAH, at most 4 triangles per leaf).
    pub fn new(mesh: &TriMesh) -> Bvh {
        let mut tris: Vec<Tri> = mesh
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| Vec3A::from(mesh.positions[i as usize]));
                Tri {
                    v0: a,
                    e1: b - a,
                    e2: c - a,
                }
            })
            .collect();
        let mut nodes = Vec::with_capacity(2 * tris.len() / LEAF + 1);
        nodes.push(Node {
            lo: Vec3A::ZERO,
            hi: Vec3A::ZERO,
            start: 0,
            count: tris.len() as u32,
        });
        let mut stack = vec![0usize];
        while let Some(ni) = stack.pop() {
            let (start, count) = (nodes[ni].start as usize, nodes[ni].count as usize);
            let slice = &mut tris[start..start + count];
            let (mut lo, mut hi) = (Vec3A::splat(f32::INFINITY), Vec3A::splat(f32::NEG_INFINITY));
            let (mut clo, mut chi) = (lo, hi);
            for t in slice.iter() {
                let (a, b) = tri_bounds(t);
                lo = lo.min(a);
                hi = hi.max(b);
                let c = centroid(t);
                clo = clo.min(c);
                chi = chi.max(c);
            }
            nodes[ni].lo = lo;
            nodes[ni].hi = hi;
            if count <= LEAF {
                continue;
            }
            // Binned SAH over the three axes.
            let mut best = (f32::INFINITY, 0usize, 0.0f32);
            let extent = chi - clo;
            for axis in 0..3 {
                if extent[axis] <= 1e-12 {
                    continue;
                }
                let scale = BINS as f32 / extent[axis];
                let mut bl = [(Vec3A::splat(f32::INFINITY), Vec3A::splat(f32::NEG_INFINITY)); BINS];
                let mut bc = [0usize; BINS];
                for t in slice.iter() {
                    let b = (((centroid(t)[axis] - clo[axis]) * scale) as usize).min(BINS - 1);
                    let (a, c) = tri_bounds(t);
                    bl[b].0 = bl[b].0.min(a);
                    bl[b].1 = bl[b].1.max(c);
                    bc[b] += 1;
                }
                let mut right_area = [0.0f32; BINS];
                let mut right_count = [0usize; BINS];
                let (mut rlo, mut rhi, mut rc) = (
                    Vec3A::splat(f32::INFINITY),
                    Vec3A::splat(f32::NEG_INFINITY),
                    0usize,
                );
                for b in (1..BINS).rev() {
                    rlo = rlo.min(bl[b].0);
                    rhi = rhi.max(bl[b].1);
                    rc += bc[b];
                    right_area[b] = area(rlo, rhi);
                    right_count[b] = rc;
                }
                let (mut llo, mut lhi, mut lc) = (
                    Vec3A::splat(f32::INFINITY),
                    Vec3A::splat(f32::NEG_INFINITY),
                    0usize,
                );
                for b in 0..BINS - 1 {
                    llo = llo.min(bl[b].0);
                    lhi = lhi.max(bl[b].1);
                    lc += bc[b];
                    if lc == 0 || right_count[b + 1] == 0 {
                        continue;
                    }
                    let cost =
                        lc as f32 * area(llo, lhi) + right_count[b + 1] as f32 * right_area[b + 1];
                    if cost < best.0 {
                        best = (cost, axis, clo[axis] + (b + 1) as f32 / scale);
                    }
                }
            }
            let leaf_cost = count as f32 * area(lo, hi);
            let can_split = best.0.is_finite();
            if (!can_split && count <= 64) || (can_split && best.0 >= leaf_cost && count <= 16) {
                continue;
            }
            let (axis, split) = (best.1, best.2);
            let mid = if best.0.is_finite() {
                let mut i = 0;
                for j in 0..slice.len() {
                    if centroid(&slice[j])[axis] < split {
                        slice.swap(i, j);
                        i += 1;
                    }
                }
                i
            } else {
                0
            };
            let mid = if mid == 0 || mid == count {
                // Degenerate (identical centroids): split in the middle.
                count / 2
            } else {
                mid
            };
            let left = nodes.len();
            nodes.push(Node {
                lo: Vec3A::ZERO,
                hi: Vec3A::ZERO,
                start: start as u32,
                count: mid as u32,
            });
            nodes.push(Node {
                lo: Vec3A::ZERO,
                hi: Vec3A::ZERO,
                start: (start + mid) as u32,
                count: (count - mid) as u32,
            });
            nodes[ni].start = left as u32;
            nodes[ni].count = 0;
            stack.push(left);
            stack.push(left + 1);
        }
        let normals = tris
            .iter()
            .map(|t| Vec3::from(t.e1.cross(t.e2).normalize_or_zero()))
            .collect();
        Bvh {
            nodes,
            tris,
            normals,
        }
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.tris.len()
    }

    /// Whether the mesh is empty.
    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }

    /// Bounds of the whole mesh.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        (self.nodes[0].lo.into(), self.nodes[0].hi.into())
    }

    #[inline]
    fn slab(lo: Vec3A, hi: Vec3A, o: Vec3A, inv: Vec3A, tmax: f32) -> f32 {
        let t0 = (lo - o) * inv;
        let t1 = (hi - o) * inv;
        let tn = t0.min(t1).max_element().max(0.0);
        let tf = t0.max(t1).min_element().min(tmax);
        if tn <= tf { tn } else { f32::INFINITY }
    }

    #[inline]
    fn tri_hit(t: &Tri, o: Vec3A, d: Vec3A, tmax: f32) -> Option<f32> {
        let p = d.cross(t.e2);
        let det = t.e1.dot(p);
        if det.abs() < 1e-12 {
            return None;
        }
        let inv = 1.0 / det;
        let s = o - t.v0;
        let u = s.dot(p) * inv;
        if !(0.0..=1.0).contains(&u) {
            return None;
        }
        let q = s.cross(t.e1);
        let v = d.dot(q) * inv;
        if v < 0.0 || u + v > 1.0 {
            return None;
        }
        let tt = t.e2.dot(q) * inv;
        (tt > 0.0 && tt < tmax).then_some(tt)
    }

    /// Closest hit with `0 < t < tmax`.
    pub fn intersect(&self, o: Vec3, d: Vec3, tmax: f32) -> Option<Hit> {
        let (o, d) = (Vec3A::from(o), Vec3A::from(d));
        let inv = d.recip();
        let mut best_t = tmax;
        let mut best = u32::MAX;
        let mut stack = [0u32; 64];
        let mut sp = 0usize;
        let root = &self.nodes[0];
        if Self::slab(root.lo, root.hi, o, inv, best_t).is_infinite() {
            return None;
        }
        let mut ni = 0u32;
        loop {
            let n = &self.nodes[ni as usize];
            if n.count > 0 {
                for k in n.start..n.start + n.count {
                    if let Some(t) = Self::tri_hit(&self.tris[k as usize], o, d, best_t) {
                        best_t = t;
                        best = k;
                    }
                }
            } else {
                let (a, b) = (n.start, n.start + 1);
                let na = &self.nodes[a as usize];
                let nb = &self.nodes[b as usize];
                let ta = Self::slab(na.lo, na.hi, o, inv, best_t);
                let tb = Self::slab(nb.lo, nb.hi, o, inv, best_t);
                let (near, far, tn, tf) = if ta <= tb {
                    (a, b, ta, tb)
                } else {
                    (b, a, tb, ta)
                };
                if tn.is_finite() {
                    if tf.is_finite() && sp < 64 {
                        stack[sp] = far;
                        sp += 1;
                    }
                    ni = near;
                    continue;
                }
            }
            if sp == 0 {
                break;
            }
            sp -= 1;
            ni = stack[sp];
        }
        (best != u32::MAX).then(|| Hit {
            t: best_t,
            normal: self.normals[best as usize],
        })
    }

    /// Whether anything is hit with `0 < t < tmax`.
    pub fn occluded(&self, o: Vec3, d: Vec3, tmax: f32) -> bool {
        let (o, d) = (Vec3A::from(o), Vec3A::from(d));
        let inv = d.recip();
        let mut stack = [0u32; 64];
        let mut sp = 0usize;
        stack[sp] = 0;
        sp += 1;
        while sp > 0 {
            sp -= 1;
            let n = &self.nodes[stack[sp] as usize];
            if Self::slab(n.lo, n.hi, o, inv, tmax).is_infinite() {
                continue;
            }
            if n.count > 0 {
                for k in n.start..n.start + n.count {
                    if Self::tri_hit(&self.tris[k as usize], o, d, tmax).is_some() {
                        return true;
                    }
                }
            } else if sp + 2 <= 64 {
                stack[sp] = n.start;
                stack[sp + 1] = n.start + 1;
                sp += 2;
            }
        }
        false
    }

    /// Distance from `p` to the mesh.
    pub fn distance(&self, p: Vec3) -> f32 {
        self.distance_below(p, f32::INFINITY)
    }

    /// Distance from `p` to the mesh, given an upper bound on it (which prunes the search;
    /// the result is exact when the bound is valid).
    pub fn distance_below(&self, p: Vec3, upper: f32) -> f32 {
        let p = Vec3A::from(p);
        let box_d2 = |n: &Node| {
            let q = p.clamp(n.lo, n.hi);
            (q - p).length_squared()
        };
        // Slightly inflated so a bound that is exact up to rounding still finds the triangle.
        let mut best = if upper.is_finite() {
            (upper * 1.0001 + 1e-6).powi(2)
        } else {
            f32::INFINITY
        };
        let mut stack = [0u32; 64];
        let mut sp = 1usize;
        while sp > 0 {
            sp -= 1;
            let n = &self.nodes[stack[sp] as usize];
            if box_d2(n) >= best {
                continue;
            }
            if n.count > 0 {
                for k in n.start..n.start + n.count {
                    let t = &self.tris[k as usize];
                    let q = closest_point_triangle(p, t.v0, t.v0 + t.e1, t.v0 + t.e2);
                    best = best.min((q - p).length_squared());
                }
            } else if sp + 2 <= 64 {
                let (a, b) = (n.start, n.start + 1);
                let (da, db) = (
                    box_d2(&self.nodes[a as usize]),
                    box_d2(&self.nodes[b as usize]),
                );
                // Push the farther first so the nearer is visited first.
                if da < db {
                    stack[sp] = b;
                    stack[sp + 1] = a;
                } else {
                    stack[sp] = a;
                    stack[sp + 1] = b;
                }
                sp += 2;
            }
        }
        best.sqrt()
    }
}

/// Closest point on triangle `abc` to `p` (Ericson, Real-Time Collision Detection 5.1.5).
fn closest_point_triangle(p: Vec3A, a: Vec3A, b: Vec3A, c: Vec3A) -> Vec3A {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

/// Lower bounds on the distance to the mesh, on a regular grid over the mesh bounds: for
/// every cell, the exact distance at its centre minus half its diagonal (the distance is
/// 1-Lipschitz), so one memory read gives a bound for any point of the cell.
pub struct SafeGrid {
    lo: Vec3,
    inv_h: f32,
    dims: [usize; 3],
    cells: Vec<f32>,
}

impl SafeGrid {
    /// Builds a grid with `res` cells along the longest side of the mesh bounds.
    pub fn new(bvh: &Bvh, res: usize) -> SafeGrid {
        let (lo, hi) = bvh.bounds();
        let ext = hi - lo;
        let h = ext.max_element() / res as f32;
        let dims = [0, 1, 2].map(|a| ((ext[a] / h).ceil() as usize).max(1));
        let half_diag = 0.5 * 3f32.sqrt() * h;
        // Rows along x in parallel; within a row each distance seeds the next query with the
        // upper bound d(previous) + h (1-Lipschitz), which prunes the BVH search.
        let cells: Vec<f32> = (0..dims[1] * dims[2])
            .into_par_iter()
            .flat_map_iter(|row| {
                let (j, k) = (row % dims[1], row / dims[1]);
                let mut prev = f32::INFINITY;
                (0..dims[0])
                    .map(|i| {
                        let c = lo + Vec3::new(i as f32 + 0.5, j as f32 + 0.5, k as f32 + 0.5) * h;
                        prev = bvh.distance_below(c, prev + h);
                        // 1e-4 absorbs float error in the distance and the point lookup.
                        (prev - half_diag - 1e-4).max(0.0)
                    })
                    .collect::<Vec<_>>()
            })
            .collect();
        SafeGrid {
            lo,
            inv_h: 1.0 / h,
            dims,
            cells,
        }
    }

    /// A lower bound on the distance from `p` to the mesh (0 outside the grid).
    #[inline]
    pub fn safe(&self, p: Vec3) -> f32 {
        let q = (p - self.lo) * self.inv_h;
        if q.x < 0.0 || q.y < 0.0 || q.z < 0.0 {
            return 0.0;
        }
        let (i, j, k) = (q.x as usize, q.y as usize, q.z as usize);
        if i >= self.dims[0] || j >= self.dims[1] || k >= self.dims[2] {
            return 0.0;
        }
        self.cells[i + self.dims[0] * (j + self.dims[1] * k)]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::shapes::icosphere;
    use crate::transport::rng::Rng;

    /// Ray hits, distances and safe bounds agree with the analytic unit sphere.
    #[test]
    fn sphere_queries_match_analytic() {
        let mesh = icosphere(5);
        let bvh = Bvh::new(&mesh);
        let grid = SafeGrid::new(&bvh, 48);
        let mut rng = Rng::new(9, 9, 9, 9);
        let tol = 2e-3; // chord sag of the icosphere
        for _ in 0..20_000 {
            let p = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - 1.0;
            if p.length() > 0.99 {
                continue;
            }
            let d = (Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5).normalize();
            let b = p.dot(d);
            let t_exact = -b + (b * b - p.length_squared() + 1.0).sqrt();
            let h = bvh
                .intersect(p, d, f32::INFINITY)
                .expect("inside ray must hit");
            assert!((h.t - t_exact).abs() < tol, "t {} vs {}", h.t, t_exact);
            assert!(
                h.normal.dot(d) > 0.0,
                "exit hit must see the outward normal"
            );
            let dist = 1.0 - p.length();
            assert!((bvh.distance(p) - dist).abs() < tol);
            assert!(
                grid.safe(p) <= dist + tol,
                "safe {} > distance {}",
                grid.safe(p),
                dist
            );
            assert!(!bvh.occluded(p, d, t_exact - tol));
            assert!(bvh.occluded(p, d, t_exact + tol));
        }
    }
}
