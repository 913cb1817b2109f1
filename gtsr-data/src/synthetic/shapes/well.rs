//! The capped wells: a round block with a hemispherical well and a domed cap free in it, as
//! two surfaces of revolution.
use crate::ply::TriMesh;
use glam::Vec3;
use std::f32::consts::TAU;

use super::*;

/// The closed surface of revolution about z of a profile `(r, z)` that starts and ends on the
/// axis (`r = 0`), `around` segments in azimuth. Wound as a sphere's meridians run from its
/// north pole to its south pole: outward when the solid lies on the profile's right in the
/// `(r, z)` half-plane (the z axis up, r to the right).
pub(super) fn revolve(profile: &[(f32, f32)], around: u32) -> TriMesh {
    let n = profile.len();
    assert!(n >= 3 && profile[0].0 == 0.0 && profile[n - 1].0 == 0.0);
    let mut positions = vec![Vec3::new(0.0, 0.0, profile[0].1)];
    for &(r, z) in &profile[1..n - 1] {
        for j in 0..around {
            let a = TAU * j as f32 / around as f32;
            positions.push(Vec3::new(r * a.cos(), r * a.sin(), z));
        }
    }
    positions.push(Vec3::new(0.0, 0.0, profile[n - 1].1));
    let last = positions.len() as u32 - 1;
    // Ring i (1..n-1) holds the profile's point i.
    let v = |i: usize, j: u32| 1 + (i as u32 - 1) * around + j % around;
    let mut triangles = Vec::new();
    for j in 0..around {
        triangles.push([0, v(1, j), v(1, j + 1)]);
        for i in 1..n - 2 {
            let (a, b, c, d) = (v(i, j), v(i + 1, j), v(i + 1, j + 1), v(i, j + 1));
            triangles.extend([[a, b, c], [a, c, d]]);
        }
        triangles.push([v(n - 2, j), last, v(n - 2, j + 1)]);
    }
    TriMesh {
        positions,
        triangles,
    }
}

/// `(r, z)` points along the circle of radius `rho` about `(0, zc)` from polar angle `from`
/// to `to` (from +z), about every `step`, both ends included.
pub(super) fn arc(rho: f32, zc: f32, from: f32, to: f32, step: f32) -> Vec<(f32, f32)> {
    let k = ((rho * (to - from).abs() / step).ceil() as usize).max(1);
    (0..=k)
        .map(|i| {
            let t = from + (to - from) * i as f32 / k as f32;
            (rho * t.sin().abs(), zc + rho * t.cos())
        })
        .collect()
}

/// `(r, z)` points along the segment from `a` to `b`, about every `step`, both ends included.
pub(super) fn segment(a: (f32, f32), b: (f32, f32), step: f32) -> Vec<(f32, f32)> {
    let len = (b.0 - a.0).hypot(b.1 - a.1);
    let k = ((len / step).ceil() as usize).max(1);
    (0..=k)
        .map(|i| {
            let t = i as f32 / k as f32;
            (a.0 + (b.0 - a.0) * t, a.1 + (b.1 - a.1) * t)
        })
        .collect()
}

/// Joins profile pieces that each start where the previous one ended.
pub(super) fn join(pieces: &[Vec<(f32, f32)>]) -> Vec<(f32, f32)> {
    let mut out: Vec<(f32, f32)> = Vec::new();
    for p in pieces {
        out.extend(if out.is_empty() { &p[..] } else { &p[1..] });
    }
    // The axis points are exact.
    let n = out.len();
    out[0].0 = 0.0;
    out[n - 1].0 = 0.0;
    out
}

/// A capped well's proportions: the ring gap and how far the cap dips below the block's top.
#[derive(Clone, Copy, Debug)]
pub(super) struct Well {
    pub(super) gap: f32,
    pub(super) dip: f32,
}

impl Well {
    fn cap_radius(self) -> f32 {
        WELL_RADIUS - self.gap
    }

    pub(super) fn contains(self, p: Vec3) -> bool {
        let q = well_rotation().inverse() * p;
        let (radius, bottom, top) = WELL_BLOCK;
        let from_centre = (q - Vec3::Z * top).length_squared();
        let block = q.truncate().length_squared() <= radius * radius
            && (bottom..=top).contains(&q.z)
            && from_centre > WELL_RADIUS * WELL_RADIUS;
        let cap_radius = self.cap_radius();
        let cap = from_centre <= cap_radius * cap_radius && q.z >= top - self.dip;
        block || cap
    }

    /// A ray into the well can leave it only through the bowl: the well's opening lies in one
    /// plane. So the block hits as its solid cylinder does; the cap as its ball cut by the
    /// plane of its bottom.
    pub(super) fn ray_hits(self, o: Vec3, d: Vec3) -> bool {
        let r = well_rotation().inverse();
        let (o, d) = (r * o, r * d);
        let (radius, bottom, top) = WELL_BLOCK;
        let ahead = |c: Option<(f32, f32)>| c.is_some_and(|(t0, t1)| t0 <= t1 && t1 > 0.0);
        let slab = |lo: f32, hi: f32| -> Option<(f32, f32)> {
            if d.z == 0.0 {
                return (lo..=hi)
                    .contains(&o.z)
                    .then_some((f32::NEG_INFINITY, f32::INFINITY));
            }
            let (a, b) = ((lo - o.z) / d.z, (hi - o.z) / d.z);
            Some((a.min(b), a.max(b)))
        };
        let meet = |a: Option<(f32, f32)>, b: Option<(f32, f32)>| {
            a.zip(b).map(|(a, b)| (a.0.max(b.0), a.1.min(b.1)))
        };
        let block = meet(slab(bottom, top), disc_chord(o, d, radius));
        let cap_ball = ball_chord(o, d, Vec3::Z * top, self.cap_radius());
        let cap = meet(slab(top - self.dip, f32::INFINITY), cap_ball);
        ahead(block) || ahead(cap)
    }

    /// Whether a face with this centroid is hidden: below the block's top, within the well's
    /// rim and no deeper than the well (the well, the cap's dipped side and its bottom).
    pub(super) fn hides(centroid: Vec3) -> bool {
        let c = well_rotation().inverse() * centroid;
        let top = WELL_BLOCK.2;
        c.z < top - 1e-4
            && c.z > top - WELL_RADIUS - 1e-3
            && c.truncate().length() < WELL_RADIUS + 1e-4
    }

    /// The two closed surfaces (block and cap), turned by [`well_rotation`].
    pub(super) fn mesh(self) -> TriMesh {
        use std::f32::consts::{FRAC_PI_2, PI};
        let (radius, bottom, top) = WELL_BLOCK;
        let step = 0.01;
        // The block, from the well's lowest point up the bowl, out over the top, down the side
        // and in along the bottom.
        let block = join(&[
            arc(WELL_RADIUS, top, PI, FRAC_PI_2, step),
            segment((WELL_RADIUS, top), (radius, top), step),
            segment((radius, top), (radius, bottom), step),
            segment((radius, bottom), (0.0, bottom), step),
        ]);
        // The cap, from its top down its sphere (a profile point on the block's top) and in along
        // its flat bottom.
        let rho = self.cap_radius();
        let floor = top - self.dip;
        let lowest = ((floor - top) / rho).acos();
        let cap = join(&[
            arc(rho, top, 0.0, FRAC_PI_2, step),
            arc(rho, top, FRAC_PI_2, lowest, step),
            segment(
                ((rho * rho - self.dip * self.dip).sqrt(), floor),
                (0.0, floor),
                step,
            ),
        ]);
        let mut mesh = revolve(&block, WELL_AROUND);
        let cap = revolve(&cap, WELL_AROUND);
        let offset = mesh.positions.len() as u32;
        mesh.positions.extend(cap.positions);
        (mesh.triangles).extend(cap.triangles.iter().map(|t| t.map(|i| i + offset)));
        let turn = well_rotation();
        for p in mesh.positions.iter_mut() {
            *p = turn * *p;
        }
        mesh
    }
}
