//! Procedural shapes, each with an exact analytic description (for ground-truth tests) and a
//! fine watertight triangle mesh (what the tracer renders and `mesh.ply` stores).
//!
//! All shapes are normalised to a bounding radius of 1 around the origin; z is up.
//!
//! * [`ShapeKind::Sphere`]: unit sphere; icosphere mesh (5120 triangles, chord error
//!   below 5e-4).
//! * [`ShapeKind::Torus`]: major radius 0.7, minor radius 0.3, axis z; tube mesh.
//! * [`ShapeKind::Bear`]: union of ten axis-aligned ellipsoids (body, head, snout, ears,
//!   arms, legs); marching-tetrahedra mesh of the union with vertices projected onto the
//!   ellipsoids.
//! * [`ShapeKind::TorusKnot`]: tube of radius 0.1 around a (2,3) torus knot (thin
//!   features); tube mesh with rotation-minimising frames.
//! * [`ShapeKind::DentedSphere`]: unit sphere less a ball (radius [`DENT_RADIUS`], centre
//!   [`DENT_CENTRE`] from the origin along [`dent_axis`]): a smooth dent 0.25 deep and about
//!   0.85 across that no silhouette sees; icosphere mesh with its vertices moved radially onto
//!   the dent.
//! * [`ShapeKind::Cube`]: a cube of half-side [`CUBE_HALF`] turned obliquely
//!   ([`cube_rotation`]): flat faces and sharp edges; each face a grid of squares.
//! * [`ShapeKind::SlottedCube`]: that cube with a narrow closed slot ([`slot_box`]) sunk into
//!   one face: a trench [`SLOT_WIDTH`] across and [`SLOT_DEPTH`] deep that no silhouette
//!   sees, only the views that look down into it.
//! * [`ShapeKind::CappedWell`]: a round block with a hemispherical well in its top, and a
//!   domed cap in the well, free of it: a ring gap [`WELL_GAP`] wide opens onto the hollow
//!   between the cap's flat bottom and the well, which no silhouette sees; a solid of
//!   revolution, its axis turned obliquely ([`well_rotation`]).
//! * [`ShapeKind::NarrowCappedWell`]: the same with a gap of [`NARROW_WELL_GAP`].
//! * [`ShapeKind::ShallowCappedWell`]: the capped well with its cap's bottom
//!   [`SHALLOW_CAP_DIP`] below the block's top: the gap opens almost at once onto the hollow.

use std::collections::HashMap;
use std::f32::consts::TAU;

use glam::Vec3;

use crate::ply::TriMesh;

/// The procedural shapes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ShapeKind {
    /// Unit sphere.
    Sphere,
    /// Torus, radii 0.7 and 0.3.
    Torus,
    /// Union of ellipsoids shaped like a teddy bear.
    Bear,
    /// Thin tube around a (2,3) torus knot.
    TorusKnot,
    /// Unit sphere with a wide spherical dent, a concavity hidden from every silhouette.
    DentedSphere,
    /// A cube turned obliquely: flat faces and sharp edges.
    Cube,
    /// The oblique cube with a narrow slot sunk into one face, hidden from every silhouette.
    SlottedCube,
    /// A block with a well, and a cap resting free in it over a hollow no silhouette sees.
    CappedWell,
    /// The capped well with a gap half as wide.
    NarrowCappedWell,
    /// The capped well with a cap that hardly dips into the well.
    ShallowCappedWell,
}

/// Torus major radius.
pub const TORUS_R: f32 = 0.7;
/// Torus minor radius.
pub const TORUS_TUBE: f32 = 0.3;
/// Torus-knot tube radius.
pub const KNOT_TUBE: f32 = 0.1;
/// Distance from the origin to the centre of the ball the dented sphere's dent is cut with.
pub const DENT_CENTRE: f32 = 1.4;
/// Radius of that ball: the dent is `1 - (DENT_CENTRE - DENT_RADIUS)` = 0.25 deep.
pub const DENT_RADIUS: f32 = 0.65;

/// The direction the dented sphere's dent faces (unit), oblique to the cameras' up axis.
pub fn dent_axis() -> Vec3 {
    Vec3::new(1.0, -1.0, 1.0).normalize()
}
const KNOT_SCALE: f32 = (1.0 - KNOT_TUBE) / 3.0;
/// The cube's half-side: its corners lie on the unit sphere.
pub const CUBE_HALF: f32 = 0.577_350_26;
/// Squares along each edge of a cube face in the mesh.
const CUBE_GRID: u32 = 48;
/// Squares along each edge of a face of the slotted cube's mesh; the slot's walls lie on
/// its grid lines.
const SLOT_GRID: u32 = 64;
/// The slot's extent in grid squares of the slotted face, along its length and across.
const SLOT_CELLS: ([u32; 2], [u32; 2]) = ([12, 52], [30, 35]);
/// The slot's depth below the face.
pub const SLOT_DEPTH: f32 = 0.25;
/// The slot's width across (two pixels of a 64 px view of the scene at distance 4, four at
/// 128 px).
pub const SLOT_WIDTH: f32 =
    (SLOT_CELLS.1[1] - SLOT_CELLS.1[0]) as f32 * 2.0 * CUBE_HALF / SLOT_GRID as f32;

/// The capped well's block: radius, bottom and top (its farthest corner on the unit sphere).
pub const WELL_BLOCK: (f32, f32, f32) = (0.8, -0.6, 0.1);
/// Radius of the hemispherical well, centred on the block's top face.
pub const WELL_RADIUS: f32 = 0.35;
/// The ring gap between the cap and the well of [`ShapeKind::CappedWell`] (the cap's sphere
/// is the well's, this much smaller): two pixels of a 128 px view of the scene at distance 4.
pub const WELL_GAP: f32 = 0.05;
/// The gap of [`ShapeKind::NarrowCappedWell`]: two pixels at 256 px (amber_ingot's gap round its
/// dome is about as wide).
pub const NARROW_WELL_GAP: f32 = 0.0225;
/// How far the cap's flat bottom lies below the block's top face.
pub const CAP_DIP: f32 = 0.12;
/// How far the cap of [`ShapeKind::ShallowCappedWell`] dips below the block's top.
pub const SHALLOW_CAP_DIP: f32 = 0.02;
/// Azimuthal segments of the capped well's mesh.
const WELL_AROUND: u32 = 256;

/// The capped well's orientation: its axis (z in its own frame) turned away from the
/// cameras' axes.
pub fn well_rotation() -> glam::Quat {
    glam::Quat::from_euler(glam::EulerRot::ZXY, 0.3, 0.25, -0.15)
}

/// The slot of [`ShapeKind::SlottedCube`] as a box in the cube's own frame (before
/// [`cube_rotation`]): its opening lies in the face `z = CUBE_HALF`. Returns its lower and
/// upper corners.
pub fn slot_box() -> (Vec3, Vec3) {
    let at = |c: u32| (2.0 * c as f32 / SLOT_GRID as f32 - 1.0) * CUBE_HALF;
    let ([u0, u1], [v0, v1]) = SLOT_CELLS;
    (
        Vec3::new(at(u0), at(v0), CUBE_HALF - SLOT_DEPTH),
        Vec3::new(at(u1), at(v1), CUBE_HALF),
    )
}

/// The cube's orientation: its own axes turned so that no face looks straight along the
/// cameras' up axis or a horizontal axis.
pub fn cube_rotation() -> glam::Quat {
    glam::Quat::from_euler(glam::EulerRot::ZXY, 0.5, 0.35, 0.2)
}

impl ShapeKind {
    /// Every shape.
    pub const ALL: [ShapeKind; 10] = [
        ShapeKind::Sphere,
        ShapeKind::Torus,
        ShapeKind::Bear,
        ShapeKind::TorusKnot,
        ShapeKind::DentedSphere,
        ShapeKind::Cube,
        ShapeKind::SlottedCube,
        ShapeKind::CappedWell,
        ShapeKind::NarrowCappedWell,
        ShapeKind::ShallowCappedWell,
    ];

    /// The name used on the command line and in `meta.json`.
    pub fn name(&self) -> &'static str {
        match self {
            ShapeKind::Sphere => "sphere",
            ShapeKind::Torus => "torus",
            ShapeKind::Bear => "bear",
            ShapeKind::TorusKnot => "torus_knot",
            ShapeKind::DentedSphere => "dented_sphere",
            ShapeKind::Cube => "cube",
            ShapeKind::SlottedCube => "slotted_cube",
            ShapeKind::CappedWell => "capped_well",
            ShapeKind::NarrowCappedWell => "narrow_capped_well",
            ShapeKind::ShallowCappedWell => "shallow_capped_well",
        }
    }

    /// The ground-truth mesh (watertight, outward counter-clockwise triangles).
    pub fn mesh(&self) -> TriMesh {
        match self {
            ShapeKind::Sphere => icosphere(4),
            ShapeKind::Torus => tube_mesh(torus_curve, TORUS_TUBE, 256, 96),
            ShapeKind::Bear => bear_mesh(112),
            ShapeKind::TorusKnot => tube_mesh(knot_curve, KNOT_TUBE, 1024, 40),
            ShapeKind::DentedSphere => dented_sphere_mesh(6),
            ShapeKind::Cube => cube_mesh(CUBE_GRID, false),
            ShapeKind::SlottedCube => cube_mesh(SLOT_GRID, true),
            ShapeKind::CappedWell | ShapeKind::NarrowCappedWell | ShapeKind::ShallowCappedWell => {
                self.well().map(Well::mesh).unwrap_or_default()
            }
        }
    }

    /// The faces of [`ShapeKind::mesh`] that no silhouette sees: the dent of
    /// [`ShapeKind::DentedSphere`], the slot's floor and walls of [`ShapeKind::SlottedCube`],
    /// the well and the cap's part below the block's top of the capped wells;
    /// `None` for the other shapes, whose masks' hull touches all of them. Scoring a mesh
    /// against this part alone (its completeness) says whether a method placed what only the
    /// shading shows.
    pub fn hidden_part(&self) -> Option<TriMesh> {
        self.hidden_part_of(&self.mesh())
    }

    /// [`ShapeKind::hidden_part`] of `mesh`, this shape's own [`ShapeKind::mesh`] already built.
    pub(crate) fn hidden_part_of(&self, mesh: &TriMesh) -> Option<TriMesh> {
        if !matches!(self, ShapeKind::DentedSphere | ShapeKind::SlottedCube)
            && self.well().is_none()
        {
            return None;
        }
        let (turn, (lo, hi)) = (cube_rotation().inverse(), slot_box());
        let eps = Vec3::splat(1e-4);
        let hidden = |v: [Vec3; 3]| match self {
            // The dent's vertices lie inside the unit sphere, the others on it; the faces
            // across the dent's rim (they span its steep edge) count.
            ShapeKind::DentedSphere => v.iter().any(|p| p.length() < 1.0 - 1e-4),
            ShapeKind::CappedWell | ShapeKind::NarrowCappedWell | ShapeKind::ShallowCappedWell => {
                Well::hides((v[0] + v[1] + v[2]) / 3.0)
            }
            // A floor or wall face has its centroid below the slotted face, over the slot.
            _ => {
                let c = turn * ((v[0] + v[1] + v[2]) / 3.0);
                c.z < CUBE_HALF - 1e-4 && c.cmpge(lo - eps).all() && c.cmple(hi + eps).all()
            }
        };
        let mut part = TriMesh::default();
        let mut index: HashMap<u32, u32> = HashMap::new();
        for t in &mesh.triangles {
            if hidden(t.map(|i| mesh.positions[i as usize])) {
                part.triangles.push(t.map(|i| {
                    *index.entry(i).or_insert_with(|| {
                        part.positions.push(mesh.positions[i as usize]);
                        part.positions.len() as u32 - 1
                    })
                }));
            }
        }
        Some(part)
    }

    /// A capped well's proportions; `None` for the other shapes.
    fn well(&self) -> Option<Well> {
        let (gap, dip) = match self {
            ShapeKind::CappedWell => (WELL_GAP, CAP_DIP),
            ShapeKind::NarrowCappedWell => (NARROW_WELL_GAP, CAP_DIP),
            ShapeKind::ShallowCappedWell => (WELL_GAP, SHALLOW_CAP_DIP),
            _ => return None,
        };
        Some(Well { gap, dip })
    }

    /// The ring gap of a capped well ([`WELL_GAP`], [`NARROW_WELL_GAP`]); `None` for the other
    /// shapes.
    pub fn well_gap(&self) -> Option<f32> {
        self.well().map(|w| w.gap)
    }

    /// How far a capped well's cap dips below the block's top ([`CAP_DIP`],
    /// [`SHALLOW_CAP_DIP`]); `None` for the other shapes.
    pub fn cap_dip(&self) -> Option<f32> {
        self.well().map(|w| w.dip)
    }

    /// Exact point-membership test of the analytic shape.
    pub fn contains(&self, p: Vec3) -> bool {
        match self {
            ShapeKind::Sphere => p.length_squared() <= 1.0,
            ShapeKind::Torus => {
                let q = (p.truncate().length() - TORUS_R, p.z);
                q.0 * q.0 + q.1 * q.1 <= TORUS_TUBE * TORUS_TUBE
            }
            ShapeKind::Bear => bear_ellipsoids().iter().any(|e| e.implicit(p) <= 0.0),
            ShapeKind::TorusKnot => {
                curve_min(knot_curve, |c| (c - p).length_squared()) <= KNOT_TUBE * KNOT_TUBE
            }
            ShapeKind::DentedSphere => {
                p.length_squared() <= 1.0
                    && (p - dent_axis() * DENT_CENTRE).length_squared() > DENT_RADIUS * DENT_RADIUS
            }
            ShapeKind::Cube => {
                let q = cube_rotation().inverse() * p;
                q.abs().max_element() <= CUBE_HALF
            }
            ShapeKind::SlottedCube => {
                let q = cube_rotation().inverse() * p;
                let (lo, hi) = slot_box();
                q.abs().max_element() <= CUBE_HALF && !(q.cmpgt(lo).all() && q.cmplt(hi).all())
            }
            ShapeKind::CappedWell | ShapeKind::NarrowCappedWell | ShapeKind::ShallowCappedWell => {
                self.well().is_some_and(|w| w.contains(p))
            }
        }
    }

    /// Exact test of whether the ray `o + t d`, `t > 0`, hits the analytic shape, for
    /// origins outside the bounding sphere (silhouette ground truth). `d` must be unit.
    pub fn ray_hits(&self, o: Vec3, d: Vec3) -> bool {
        // Distance from the line to a point; the shapes lie in front of outside origins.
        let line_d2 = |c: Vec3| {
            let v = c - o;
            let t = v.dot(d);
            if t < 0.0 {
                v.length_squared()
            } else {
                (v - d * t).length_squared()
            }
        };
        match self {
            ShapeKind::Sphere => line_d2(Vec3::ZERO) <= 1.0,
            // A torus / tube is the union of balls centred on its core curve.
            ShapeKind::Torus => curve_min(torus_curve, line_d2) <= TORUS_TUBE * TORUS_TUBE,
            ShapeKind::TorusKnot => curve_min(knot_curve, line_d2) <= KNOT_TUBE * KNOT_TUBE,
            ShapeKind::Bear => bear_ellipsoids().iter().any(|e| e.ray_hits(o, d)),
            // Hit unless the ray's chord through the sphere lies wholly inside the cut ball.
            ShapeKind::DentedSphere => match ball_chord(o, d, Vec3::ZERO, 1.0) {
                None => false,
                Some((t0, t1)) => {
                    t1 > 0.0
                        && match ball_chord(o, d, dent_axis() * DENT_CENTRE, DENT_RADIUS) {
                            None => true,
                            Some((s0, s1)) => !(s0 <= t0 && s1 >= t1),
                        }
                }
            },
            // A ray into the slot can leave it only through the floor or the walls: the slot
            // is closed on every side but its opening, which lies in one plane.
            ShapeKind::Cube | ShapeKind::SlottedCube => {
                let r = cube_rotation().inverse();
                box_chord(r * o, r * d, CUBE_HALF).is_some_and(|(_, t1)| t1 > 0.0)
            }
            ShapeKind::CappedWell | ShapeKind::NarrowCappedWell | ShapeKind::ShallowCappedWell => {
                self.well().is_some_and(|w| w.ray_hits(o, d))
            }
        }
    }
}

impl std::fmt::Display for ShapeKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for ShapeKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        ShapeKind::ALL
            .into_iter()
            .find(|k| k.name() == s || (s == "knot" && *k == ShapeKind::TorusKnot))
            .ok_or_else(|| {
                format!(
                    "unknown shape '{s}' (sphere, torus, bear, torus_knot, dented_sphere, cube, \
                     slotted_cube, capped_well, narrow_capped_well, shallow_capped_well)"
                )
            })
    }
}

/// The interval `[t0, t1]` of the line `o + t d` (`d` unit) inside the ball `|p - c| <= r`.
fn ball_chord(o: Vec3, d: Vec3, c: Vec3, r: f32) -> Option<(f32, f32)> {
    let oc = o - c;
    let b = oc.dot(d);
    let disc = b * b - (oc.length_squared() - r * r);
    (disc >= 0.0).then(|| (-b - disc.sqrt(), -b + disc.sqrt()))
}

/// The interval `[t0, t1]` of the line `o + t d` inside the infinite cylinder
/// `x^2 + y^2 <= r^2` (all of it when the line runs along the axis inside it).
fn disc_chord(o: Vec3, d: Vec3, r: f32) -> Option<(f32, f32)> {
    let (o2, d2) = (o.truncate(), d.truncate());
    let a = d2.length_squared();
    if a < 1e-12 {
        return (o2.length_squared() <= r * r).then_some((f32::NEG_INFINITY, f32::INFINITY));
    }
    let b = o2.dot(d2) / a;
    let disc = b * b - (o2.length_squared() - r * r) / a;
    (disc >= 0.0).then(|| (-b - disc.sqrt(), -b + disc.sqrt()))
}

/// The interval `[t0, t1]` of the line `o + t d` inside the axis-aligned box `|p_i| <= h`
/// (slabs; a direction component of zero keeps the slab when the origin lies in it).
fn box_chord(o: Vec3, d: Vec3, h: f32) -> Option<(f32, f32)> {
    let (mut t0, mut t1) = (f32::NEG_INFINITY, f32::INFINITY);
    for k in 0..3 {
        if d[k] == 0.0 {
            if o[k].abs() > h {
                return None;
            }
            continue;
        }
        let (a, b) = ((-h - o[k]) / d[k], (h - o[k]) / d[k]);
        t0 = t0.max(a.min(b));
        t1 = t1.min(a.max(b));
    }
    (t0 <= t1).then_some((t0, t1))
}

/// The dented sphere's radius along the unit direction `u`: 1, or where the ray from the
/// origin first enters the cut ball if that is nearer. The shape is star-shaped about the
/// origin (the ball's centre lies outside the unit sphere), so this describes it exactly.
pub fn dented_sphere_radius(u: Vec3) -> f32 {
    match ball_chord(Vec3::ZERO, u, dent_axis() * DENT_CENTRE, DENT_RADIUS) {
        Some((t_in, _)) if t_in > 0.0 && t_in < 1.0 => t_in,
        _ => 1.0,
    }
}

/// An icosphere with `levels` subdivisions, every vertex moved radially onto the dent.
fn dented_sphere_mesh(levels: u32) -> TriMesh {
    let mut m = icosphere(levels);
    for p in m.positions.iter_mut() {
        *p *= dented_sphere_radius(*p);
    }
    m
}

fn torus_curve(t: f32) -> Vec3 {
    Vec3::new(TORUS_R * t.cos(), TORUS_R * t.sin(), 0.0)
}

/// The (2,3) torus knot core curve, `t` in `[0, 2 pi)`, scaled so the tube fits radius 1.
pub fn knot_curve(t: f32) -> Vec3 {
    let r = 2.0 + (3.0 * t).cos();
    Vec3::new(r * (2.0 * t).cos(), r * (2.0 * t).sin(), (3.0 * t).sin()) * KNOT_SCALE
}

/// Minimum of `f(curve(t))` over `t in [0, 2 pi)`: dense sampling, then golden-section
/// refinement around the best few samples.
fn curve_min(curve: fn(f32) -> Vec3, f: impl Fn(Vec3) -> f32) -> f32 {
    const N: usize = 2048;
    let h = TAU / N as f32;
    let vals: Vec<f32> = (0..N).map(|i| f(curve(i as f32 * h))).collect();
    let mut best = f32::INFINITY;
    for i in 0..N {
        let (a, b, c) = (vals[(i + N - 1) % N], vals[i], vals[(i + 1) % N]);
        if b <= a && b <= c {
            // local minimum: refine on [t - h, t + h]
            let (mut lo, mut hi) = ((i as f32 - 1.0) * h, (i as f32 + 1.0) * h);
            let g = 0.618_034f32;
            for _ in 0..30 {
                let m1 = hi - g * (hi - lo);
                let m2 = lo + g * (hi - lo);
                if f(curve(m1)) < f(curve(m2)) {
                    hi = m2;
                } else {
                    lo = m1;
                }
            }
            best = best.min(f(curve(0.5 * (lo + hi)))).min(b);
        }
    }
    best
}

/// An axis-aligned ellipsoid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ellipsoid {
    /// Centre.
    pub centre: Vec3,
    /// Semi-axes.
    pub radii: Vec3,
}

impl Ellipsoid {
    /// `|(p - c) / r|^2 - 1`: negative inside.
    pub fn implicit(&self, p: Vec3) -> f32 {
        ((p - self.centre) / self.radii).length_squared() - 1.0
    }

    /// Approximate signed distance (exact on the surface, good near it).
    fn sdf(&self, p: Vec3) -> f32 {
        let q = (p - self.centre) / self.radii;
        let k0 = q.length();
        let k1 = (q / self.radii).length();
        if k1 == 0.0 {
            -self.radii.min_element()
        } else {
            k0 * (k0 - 1.0) / k1
        }
    }

    fn ray_hits(&self, o: Vec3, d: Vec3) -> bool {
        let oc = (o - self.centre) / self.radii;
        let dd = d / self.radii;
        let a = dd.length_squared();
        let b = oc.dot(dd);
        let c = oc.length_squared() - 1.0;
        let disc = b * b - a * c;
        disc >= 0.0 && (-b + disc.sqrt()) > 0.0
    }

    fn project(&self, p: Vec3) -> Vec3 {
        let mut x = p;
        for _ in 0..4 {
            let q = (x - self.centre) / self.radii;
            let g = q.length_squared() - 1.0;
            let grad = 2.0 * q / self.radii;
            let gl = grad.length_squared();
            if gl < 1e-12 {
                break;
            }
            x -= grad * (g / gl);
        }
        x
    }
}

/// The bear's ellipsoids, normalised to a bounding radius of 1.
pub fn bear_ellipsoids() -> &'static [Ellipsoid] {
    static CELL: std::sync::OnceLock<Vec<Ellipsoid>> = std::sync::OnceLock::new();
    CELL.get_or_init(make_bear_ellipsoids)
}

fn make_bear_ellipsoids() -> Vec<Ellipsoid> {
    let raw = [
        // body
        (Vec3::new(0.0, 0.0, -0.25), Vec3::new(0.55, 0.45, 0.62)),
        // head
        (Vec3::new(0.0, -0.05, 0.62), Vec3::new(0.36, 0.33, 0.31)),
        // snout
        (Vec3::new(0.0, -0.34, 0.55), Vec3::new(0.14, 0.12, 0.1)),
        // ears
        (Vec3::new(0.27, -0.02, 0.9), Vec3::new(0.12, 0.06, 0.12)),
        (Vec3::new(-0.27, -0.02, 0.9), Vec3::new(0.12, 0.06, 0.12)),
        // arms
        (Vec3::new(0.52, -0.12, 0.0), Vec3::new(0.14, 0.14, 0.34)),
        (Vec3::new(-0.52, -0.12, 0.0), Vec3::new(0.14, 0.14, 0.34)),
        // legs
        (Vec3::new(0.3, -0.18, -0.8), Vec3::new(0.18, 0.24, 0.17)),
        (Vec3::new(-0.3, -0.18, -0.8), Vec3::new(0.18, 0.24, 0.17)),
        // tail
        (Vec3::new(0.0, 0.46, -0.55), Vec3::new(0.08, 0.07, 0.08)),
    ];
    // Exact bounding radius of the union: the largest |p| over each ellipsoid's surface,
    // found by dense sampling plus a small safety margin of one sample spacing.
    let mut rmax = 0.0f32;
    for (c, r) in raw {
        for i in 0..=128 {
            let th = std::f32::consts::PI * i as f32 / 128.0;
            for j in 0..256 {
                let ph = TAU * j as f32 / 256.0;
                let u = Vec3::new(th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos());
                rmax = rmax.max((c + r * u).length());
            }
        }
    }
    let s = 1.0 / rmax;
    raw.iter()
        .map(|&(c, r)| Ellipsoid {
            centre: c * s,
            radii: r * s,
        })
        .collect()
}

mod mesh;
mod well;

use mesh::{bear_mesh, cube_mesh};
pub use mesh::{icosphere, marching_tetrahedra, tube_mesh};
use well::Well;
