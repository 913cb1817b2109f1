//! Normal-guided refinement of a mesh that bounds the object from outside (the masks' mesh):
//! each vertex moves along its normal so that the faces' normals agree with target normals
//! (observed in normal maps, [`observed_normals`], or solved from the images' shading,
//! [`crate::shading`]), optionally pulled towards offsets observed in depth maps
//! ([`observed_offsets`]).
//!
//! Displacing the vertices of a face by `d_k` along its normal `N` turns the normal to
//! `N' ~ N - grad d`, with `grad d` the in-plane gradient of the linear interpolant of `d`
//! (exact for one flat face). So the displacements that make the normals `n*` are those whose
//! gradient is `-t`, with `t = (n* - (n* . N) N) / (n* . N)` the slope of `n*` over the face
//! (the tangent of its tilt, not the sine, which falls short on steep walls): a Poisson
//! problem on the mesh,
//!
//! `min_d  sum_f w_f A_f |grad_f d + t_f|^2 + mu sum_i m_i d_i^2,   d_i <= c`,
//!
//! with `A_f` the face areas, `m_i` the vertex areas (a third of the faces around), `w_f` the
//! weight of the face's target normal, `mu = 1 / anchor^2` pulling every vertex back to
//! where it was over the length `anchor`, and `c` the most a vertex may move outward. It is
//! solved by conjugate gradients; the vertices the solution would push beyond `c` are held
//! there and the rest solved again (an active set). Faces without a target keep their own
//! normal (`t = 0`).

use glam::Vec3;
use gtsr_data::Camera;
use gtsr_data::ply::TriMesh;
use rayon::prelude::*;

use crate::error::{MeshError, Result};

/// The default of [`RefineSettings::max_tilt`]: 30 degrees.
pub const MAX_TILT_SINE: f32 = 0.5;

/// Settings of [`refine_with_normals`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefineSettings {
    /// The length over which the displacements return to zero where the normals say nothing
    /// (scene units): `mu = 1 / anchor^2`.
    pub anchor: f32,
    /// The farthest a vertex may move inward (scene units).
    pub max_depth: f32,
    /// The farthest a vertex may move outward (scene units; 0: inward only).
    pub max_outward: f32,
    /// The sine of the largest tilt of a target normal from its face that is trusted: a
    /// steeper target is taken at this tilt.
    pub max_tilt: f32,
    /// Conjugate-gradient iterations per solve.
    pub iterations: usize,
    /// Active-set rounds (solves).
    pub rounds: usize,
}

impl Default for RefineSettings {
    fn default() -> Self {
        RefineSettings {
            anchor: 0.1,
            max_depth: 0.2,
            max_outward: 0.0,
            max_tilt: MAX_TILT_SINE,
            iterations: 400,
            rounds: 8,
        }
    }
}

/// Per face, the observed normal and its weight in `[0, 1]` (0: not observed).
#[derive(Clone, Debug, Default)]
pub struct FaceNormals {
    /// Unit world-space normal per face (zero where not observed).
    pub normal: Vec<Vec3>,
    /// Weight per face.
    pub weight: Vec<f32>,
}

/// One view's normal map for [`observed_normals`].
pub struct NormalView<'a> {
    /// The camera (pixel centres at `i + 0.5`).
    pub camera: &'a Camera,
    /// Camera-space normals, 3 per pixel, row-major (zero where nothing was rendered).
    pub normal: &'a [f32],
    /// The mesh's own depth through each pixel centre (`0` on a miss): a face is observed at
    /// a pixel only where it is the first surface the pixel's ray meets.
    pub mesh_depth: &'a [f32],
}

/// The normals the views observe on each face of `mesh`: a face is observed in a view when it
/// faces the camera (cosine at least `min_cos`) and its centroid lies within half a pixel footprint of
/// the mesh's own first hit at the pixel it projects to; the view's normal there (rotated to
/// the world) counts with that cosine as its weight. The weight of a face is the length of
/// the weighted mean of its unit normals (1 when every view agrees), 0 when fewer than
/// `min_views` views observe it.
pub fn observed_normals(
    mesh: &TriMesh,
    views: &[NormalView<'_>],
    min_views: usize,
    min_cos: f32,
) -> Result<FaceNormals> {
    let nf = mesh.triangles.len();
    for v in views {
        let n = v.camera.width as usize * v.camera.height as usize;
        if v.normal.len() != 3 * n || v.mesh_depth.len() != n {
            return Err(MeshError::InvalidArgument(format!(
                "normal view: expected 3 x {n} normals and {n} depths, got {} and {}",
                v.normal.len(),
                v.mesh_depth.len()
            )));
        }
    }
    let mut sum = vec![Vec3::ZERO; nf];
    let mut wsum = vec![0.0f32; nf];
    let mut count = vec![0usize; nf];
    for v in views {
        let to_world = v.camera.world_to_camera.inverse();
        for (f, p, cos) in visible_faces(mesh, v.camera, v.mesh_depth, min_cos) {
            let nc = Vec3::new(v.normal[3 * p], v.normal[3 * p + 1], v.normal[3 * p + 2]);
            let l = nc.length();
            if !(l.is_finite() && l > 0.0) {
                continue;
            }
            let nw = to_world.transform_vector3(nc / l).normalize_or_zero();
            sum[f] += cos * nw;
            wsum[f] += cos;
            count[f] += 1;
        }
    }
    let mut out = FaceNormals {
        normal: vec![Vec3::ZERO; nf],
        weight: vec![0.0; nf],
    };
    for f in 0..nf {
        if count[f] >= min_views.max(1) && wsum[f] > 0.0 {
            let m = sum[f] / wsum[f];
            out.normal[f] = m.normalize_or_zero();
            out.weight[f] = m.length().min(1.0);
        }
    }
    Ok(out)
}

/// The faces of `mesh` one view observes: those facing the camera (cosine at least `min_cos`)
/// whose centroid lies within half a pixel footprint of the mesh's own first hit (`mesh_depth`)
/// at the pixel it projects to; as (face, pixel, cosine).
pub(crate) fn visible_faces(
    mesh: &TriMesh,
    cam: &Camera,
    mesh_depth: &[f32],
    min_cos: f32,
) -> Vec<(usize, usize, f32)> {
    let eye = cam.world_to_camera.inverse().transform_point3(Vec3::ZERO);
    let (w, h) = (cam.width as usize, cam.height as usize);
    let mut out = Vec::new();
    for (f, t) in mesh.triangles.iter().enumerate() {
        let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
        let cross = (b - a).cross(c - a);
        let len = cross.length();
        if len <= 0.0 || !len.is_finite() {
            continue;
        }
        let centroid = (a + b + c) / 3.0;
        let cos = (cross / len).dot((eye - centroid).normalize_or_zero());
        if cos < min_cos {
            continue;
        }
        let q = cam.world_to_camera.transform_point3(centroid);
        if q.z <= 0.0 {
            continue;
        }
        let u = cam.fx * q.x / q.z + cam.cx;
        let v = cam.fy * q.y / q.z + cam.cy;
        if !(u >= 0.0 && v >= 0.0 && (u as usize) < w && (v as usize) < h) {
            continue;
        }
        let p = v as usize * w + u as usize;
        let z = mesh_depth[p];
        if z > 0.0 && (q.z - z).abs() <= 0.5 * q.z / cam.fx {
            out.push((f, p, cos));
        }
    }
    out
}

/// One view's depth map for [`observed_offsets`].
pub struct DepthView<'a> {
    /// The camera (pixel centres at `i + 0.5`).
    pub camera: &'a Camera,
    /// The observed z-depth through each pixel centre (`0` or non-finite: nothing).
    pub depth: &'a [f32],
    /// The mesh's own z-depth through each pixel centre (`0` on a miss).
    pub mesh_depth: &'a [f32],
}

/// Per face, how far the observed surface lies from the face along its normal (scene units,
/// negative: inside), and in how many views it was observed.
#[derive(Clone, Debug, Default)]
pub struct FaceOffsets {
    /// The median over the views observing the face (0 where none does).
    pub offset: Vec<f32>,
    /// Views observing the face.
    pub views: Vec<u32>,
}

/// The offsets the views' depth maps observe on each face of `mesh`, visibility as in
/// [`observed_normals`]: in each view the depth difference at the face's pixel is taken along
/// the pixel's ray and projected on the face normal (a plane moved by `d` along its normal
/// moves the ray's hit by `d / cos`); per face the median over the views.
pub fn observed_offsets(
    mesh: &TriMesh,
    views: &[DepthView<'_>],
    min_cos: f32,
) -> Result<FaceOffsets> {
    let nf = mesh.triangles.len();
    let mut per_face: Vec<Vec<f32>> = vec![Vec::new(); nf];
    for v in views {
        let cam = v.camera;
        let n = cam.width as usize * cam.height as usize;
        if v.depth.len() != n || v.mesh_depth.len() != n {
            return Err(MeshError::InvalidArgument(format!(
                "depth view: expected {n} depths and {n} mesh depths, got {} and {}",
                v.depth.len(),
                v.mesh_depth.len()
            )));
        }
        let w = cam.width as usize;
        for (f, p, cos) in visible_faces(mesh, cam, v.mesh_depth, min_cos) {
            let z = v.depth[p];
            if !(z.is_finite() && z > 0.0) {
                continue;
            }
            let x = ((p % w) as f32 + 0.5 - cam.cx) / cam.fx;
            let y = ((p / w) as f32 + 0.5 - cam.cy) / cam.fy;
            let along_ray = (z - v.mesh_depth[p]) * (1.0 + x * x + y * y).sqrt();
            per_face[f].push(-along_ray * cos);
        }
    }
    let mut out = FaceOffsets {
        offset: vec![0.0; nf],
        views: vec![0; nf],
    };
    for (f, o) in per_face.iter_mut().enumerate() {
        if o.is_empty() {
            continue;
        }
        o.sort_by(f32::total_cmp);
        let m = o.len();
        out.offset[f] = if m % 2 == 1 {
            o[m / 2]
        } else {
            0.5 * (o[m / 2 - 1] + o[m / 2])
        };
        out.views[f] = m as u32;
    }
    Ok(out)
}

/// Depth targets from observed offsets that share an unknown bias (a rendered depth that lies
/// behind or before the surface throughout): each face's offset less the median over the faces
/// that `min_views` views observe (the bias, assuming most of `mesh` lies on the surface), and
/// trusted only inward beyond `threshold` (scene units): an offset `o` asks for
/// `min(o + threshold, 0)`, so the faces within the threshold are asked to stay. Faces fewer
/// views observe carry no weight. Returns the targets (of the given `length`) and the bias.
pub fn debiased_depth_targets(
    offsets: &FaceOffsets,
    min_views: u32,
    threshold: f32,
    length: f32,
) -> (DepthTargets, f32) {
    let mut kept: Vec<f32> = (offsets.offset.iter().zip(&offsets.views))
        .filter(|(_, v)| **v >= min_views)
        .map(|(o, _)| *o)
        .collect();
    let bias = if kept.is_empty() {
        0.0
    } else {
        let m = kept.len() / 2;
        *kept.select_nth_unstable_by(m, f32::total_cmp).1
    };
    let targets = DepthTargets {
        offset: (offsets.offset.iter())
            .map(|o| (o - bias + threshold).min(0.0))
            .collect(),
        weight: (offsets.views.iter())
            .map(|v| if *v >= min_views { 1.0 } else { 0.0 })
            .collect(),
        length,
    };
    (targets, bias)
}

/// Per face: the gradients of the three hat functions and the area.
struct FaceGeometry {
    grads: Vec<[Vec3; 3]>,
    areas: Vec<f32>,
    normals: Vec<Vec3>,
}

fn face_geometry(mesh: &TriMesh) -> FaceGeometry {
    let nf = mesh.triangles.len();
    let mut g = FaceGeometry {
        grads: vec![[Vec3::ZERO; 3]; nf],
        areas: vec![0.0; nf],
        normals: vec![Vec3::ZERO; nf],
    };
    for (f, t) in mesh.triangles.iter().enumerate() {
        let [p0, p1, p2] = t.map(|i| mesh.positions[i as usize]);
        let cross = (p1 - p0).cross(p2 - p0);
        let len = cross.length();
        if len <= 1e-20 || !len.is_finite() {
            continue;
        }
        let n = cross / len;
        let two_a = len;
        g.grads[f] = [
            n.cross(p2 - p1) / two_a,
            n.cross(p0 - p2) / two_a,
            n.cross(p1 - p0) / two_a,
        ];
        g.areas[f] = 0.5 * len;
        g.normals[f] = n;
    }
    g
}

/// Moves each vertex of `mesh` inward along its normal so that the faces' normals follow
/// `targets` (see the module docs). Returns the refined mesh and the displacement per vertex
/// (scene units, negative: inward; at most [`RefineSettings::max_outward`]).
pub fn refine_with_normals(
    mesh: &TriMesh,
    targets: &FaceNormals,
    settings: &RefineSettings,
) -> Result<(TriMesh, Vec<f32>)> {
    refine(mesh, targets, None, settings)
}

/// Per face, an offset along the face normal the refinement should reach (scene units,
/// negative: inward) and the weight of that wish (0: none).
#[derive(Clone, Debug, Default)]
pub struct DepthTargets {
    /// The offset per face.
    pub offset: Vec<f32>,
    /// Its weight per face, in `[0, 1]`.
    pub weight: Vec<f32>,
    /// The length over which a face's mean displacement may miss its offset where the
    /// normals pull the other way: the term is `sum_f w_f A_f (mean_f d - o_f)^2 / length^2`.
    pub length: f32,
}

/// [`refine_with_normals`] with, optionally, a depth term: each face's mean displacement is
/// also pulled towards an observed offset ([`DepthTargets`]).
pub fn refine(
    mesh: &TriMesh,
    targets: &FaceNormals,
    depth: Option<&DepthTargets>,
    settings: &RefineSettings,
) -> Result<(TriMesh, Vec<f32>)> {
    refine_anchored(mesh, targets, depth, settings, None, None)
}

/// Rows per parallel task of [`VertexSystem::apply`] and [`dot`]: fixed, so that the sums,
/// and so the solution, do not depend on how the work is split.
const ROWS_PER_TASK: usize = 4096;

/// A symmetric matrix over a mesh's vertices assembled from one 3x3 block per face, stored by
/// rows (compressed sparse rows) so that a product runs row by row in parallel.
struct VertexSystem {
    /// Where each row's entries start in `cols` and `vals` (one more than the rows).
    start: Vec<usize>,
    /// The column of each entry, increasing within a row.
    cols: Vec<u32>,
    /// The value of each entry.
    vals: Vec<f64>,
}

impl VertexSystem {
    /// `diag` (one value per vertex) plus, for each face `f` with vertices `t`, `block(f)[a][b]`
    /// added at `(t[a], t[b])`.
    fn assemble(
        triangles: &[[u32; 3]],
        diag: Vec<f64>,
        block: impl Fn(usize) -> [[f64; 3]; 3] + Sync,
    ) -> Self {
        let nv = diag.len();
        // Each row's slots: its diagonal and three per face around the vertex.
        let mut start = vec![0usize; nv + 1];
        for t in triangles {
            for &i in t {
                start[i as usize + 1] += 3;
            }
        }
        for i in 0..nv {
            start[i + 1] += start[i] + 1;
        }
        let blocks: Vec<[[f64; 3]; 3]> = (0..triangles.len()).into_par_iter().map(&block).collect();
        let mut cols = vec![0u32; start[nv]];
        let mut vals = vec![0.0f64; start[nv]];
        let mut fill: Vec<usize> = start[..nv].to_vec();
        for (i, d) in diag.iter().enumerate() {
            cols[fill[i]] = i as u32;
            vals[fill[i]] = *d;
            fill[i] += 1;
        }
        for (t, b) in triangles.iter().zip(&blocks) {
            for a in 0..3 {
                let row = t[a] as usize;
                for c in 0..3 {
                    cols[fill[row]] = t[c];
                    vals[fill[row]] = b[a][c];
                    fill[row] += 1;
                }
            }
        }
        // Each row sorted by column, the repeated columns merged.
        let mut out = VertexSystem {
            start: Vec::with_capacity(nv + 1),
            cols: Vec::with_capacity(cols.len()),
            vals: Vec::with_capacity(cols.len()),
        };
        out.start.push(0);
        let mut row: Vec<(u32, f64)> = Vec::new();
        for i in 0..nv {
            row.clear();
            row.extend((start[i]..start[i + 1]).map(|k| (cols[k], vals[k])));
            row.sort_by_key(|e| e.0);
            for &(c, v) in &row {
                if out.cols.len() > out.start[i] && out.cols.last() == Some(&c) {
                    *out.vals.last_mut().expect("an entry") += v;
                } else {
                    out.cols.push(c);
                    out.vals.push(v);
                }
            }
            out.start.push(out.cols.len());
        }
        out
    }

    /// The diagonal entries.
    fn diagonal(&self) -> Vec<f64> {
        (0..self.start.len() - 1)
            .map(|i| {
                let row = self.start[i]..self.start[i + 1];
                (self.cols[row.clone()].iter().zip(&self.vals[row]))
                    .find(|(c, _)| **c as usize == i)
                    .map_or(0.0, |(_, v)| *v)
            })
            .collect()
    }

    /// `out = A x` on the rows `free` flags, 0 on the others; returns `x . out`, summed as
    /// [`dot`] sums.
    fn apply(&self, x: &[f64], out: &mut [f64], free: &[bool]) -> f64 {
        let parts: Vec<f64> = out
            .par_chunks_mut(ROWS_PER_TASK)
            .enumerate()
            .map(|(task, chunk)| {
                let mut sum = 0.0;
                for (k, o) in chunk.iter_mut().enumerate() {
                    let i = task * ROWS_PER_TASK + k;
                    *o = if free[i] {
                        let row = self.start[i]..self.start[i + 1];
                        (self.cols[row.clone()].iter().zip(&self.vals[row]))
                            .map(|(c, v)| v * x[*c as usize])
                            .sum()
                    } else {
                        0.0
                    };
                    sum += x[i] * *o;
                }
                sum
            })
            .collect();
        parts.iter().sum()
    }
}

/// One conjugate-gradient step over the vectors, in parallel chunks: `x += alpha p`,
/// `r -= alpha ap`, `z = r * inv_diag`; returns `r . z`, summed as [`dot`] sums.
fn cg_step(
    alpha: f64,
    (x, r, z): (&mut [f64], &mut [f64], &mut [f64]),
    (p, ap, inv_diag): (&[f64], &[f64], &[f64]),
) -> f64 {
    let n = ROWS_PER_TASK;
    let parts: Vec<f64> = (x
        .par_chunks_mut(n)
        .zip(r.par_chunks_mut(n))
        .zip(z.par_chunks_mut(n)))
    .zip(
        p.par_chunks(n)
            .zip(ap.par_chunks(n))
            .zip(inv_diag.par_chunks(n)),
    )
    .map(|(((x, r), z), ((p, ap), d))| {
        let mut sum = 0.0;
        for i in 0..x.len() {
            x[i] += alpha * p[i];
            r[i] -= alpha * ap[i];
            z[i] = r[i] * d[i];
            sum += r[i] * z[i];
        }
        sum
    })
    .collect();
    parts.iter().sum()
}

/// `a . b`, summed in fixed chunks ([`ROWS_PER_TASK`]) in parallel, then in order.
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let parts: Vec<f64> = (a.par_chunks(ROWS_PER_TASK).zip(b.par_chunks(ROWS_PER_TASK)))
        .map(|(a, b)| a.iter().zip(b).map(|(x, y)| x * y).sum())
        .collect();
    parts.iter().sum()
}

/// [`refine`] with the anchor's weight scaled per vertex by `anchor_scale` (e.g. large where
/// the mesh should stay, 1 where the normals may move it) and, with `face_max_tilt`, the
/// largest trusted tilt set per face (sines in (0, 1), instead of [`RefineSettings::max_tilt`]).
pub fn refine_anchored(
    mesh: &TriMesh,
    targets: &FaceNormals,
    depth: Option<&DepthTargets>,
    settings: &RefineSettings,
    anchor_scale: Option<&[f32]>,
    face_max_tilt: Option<&[f32]>,
) -> Result<(TriMesh, Vec<f32>)> {
    let nf = mesh.triangles.len();
    if face_max_tilt.is_some_and(|t| t.len() != nf || t.iter().any(|s| !(*s > 0.0 && *s < 1.0))) {
        return Err(MeshError::InvalidArgument(format!(
            "face tilt limits: one sine in (0, 1) per face expected ({nf} faces)"
        )));
    }
    if anchor_scale.is_some_and(|a| {
        a.len() != mesh.positions.len() || a.iter().any(|v| !(v.is_finite() && *v >= 0.0))
    }) {
        return Err(MeshError::InvalidArgument(
            "anchor scale: one finite, non-negative value per vertex expected".into(),
        ));
    }
    if let Some(dt) = depth {
        if dt.offset.len() != nf || dt.weight.len() != nf {
            return Err(MeshError::InvalidArgument(format!(
                "depth targets: expected {nf}, got {} offsets and {} weights",
                dt.offset.len(),
                dt.weight.len()
            )));
        }
        if !(dt.length > 0.0 && dt.length.is_finite()) {
            return Err(MeshError::InvalidArgument(
                "depth targets: the length must be positive".into(),
            ));
        }
    }
    let nv = mesh.positions.len();
    if targets.normal.len() != nf || targets.weight.len() != nf {
        return Err(MeshError::InvalidArgument(format!(
            "face normals: expected {nf}, got {} normals and {} weights",
            targets.normal.len(),
            targets.weight.len()
        )));
    }
    if !(settings.anchor > 0.0
        && settings.max_depth > 0.0
        && settings.max_tilt > 0.0
        && settings.max_tilt < 1.0)
    {
        return Err(MeshError::InvalidArgument(
            "refine settings: anchor and max_depth must be positive, max_tilt (a sine) in (0, 1)"
                .into(),
        ));
    }
    let geo = face_geometry(mesh);
    // Vertex normals (area-weighted) and areas.
    let mut vn = vec![Vec3::ZERO; nv];
    let mut varea = vec![0.0f32; nv];
    for (f, t) in mesh.triangles.iter().enumerate() {
        for &i in t {
            vn[i as usize] += geo.normals[f] * geo.areas[f];
            varea[i as usize] += geo.areas[f] / 3.0;
        }
    }
    for n in vn.iter_mut() {
        *n = n.normalize_or_zero();
    }
    // Face weights and target slopes.
    let mut wf = vec![1.0f32; nf];
    let mut tf = vec![Vec3::ZERO; nf];
    for f in 0..nf {
        let n = geo.normals[f];
        let w = targets.weight[f];
        if w > 0.0 {
            let s = targets.normal[f];
            let t = s - s.dot(n) * n;
            // The slope that tilts the face to `s`: tan of the tilt, at most the largest
            // trusted; none for a target facing away.
            let sine = t.length();
            tf[f] = if s.dot(n) > 0.0 && sine > 0.0 {
                let cap = face_max_tilt.map_or(settings.max_tilt, |limits| limits[f]);
                let trusted = sine.min(cap);
                t * (trusted / (1.0 - trusted * trusted).max(1e-6).sqrt() / sine)
            } else {
                Vec3::ZERO
            };
            wf[f] = w;
        }
    }
    let mu = 1.0 / (settings.anchor * settings.anchor);
    // The anchor's mass per vertex.
    let amass: Vec<f32> = match anchor_scale {
        Some(a) => varea.iter().zip(a).map(|(m, a)| m * a).collect(),
        None => varea.clone(),
    };
    // b = -sum_f w A grad_k . t
    let mut b = vec![0.0f64; nv];
    for (f, t) in mesh.triangles.iter().enumerate() {
        let c = (wf[f] * geo.areas[f]) as f64;
        for k in 0..3 {
            b[t[k] as usize] -= c * geo.grads[f][k].dot(tf[f]) as f64;
        }
    }
    // Solved for y = d - max_outward <= 0: the anchor term mu m (y + c)^2 moves into b.
    let c = settings.max_outward.max(0.0) as f64;
    for (bi, m) in b.iter_mut().zip(&amass) {
        *bi -= mu as f64 * *m as f64 * c;
    }
    // The depth term, per face lambda A w (mean y - (o - c))^2 with lambda = 1 / length^2.
    let depth_coef: Option<Vec<f64>> = depth.map(|dt| {
        let lambda = 1.0 / (dt.length as f64 * dt.length as f64);
        (0..nf)
            .map(|f| lambda * geo.areas[f] as f64 * dt.weight[f].clamp(0.0, 1.0) as f64)
            .collect()
    });
    if let (Some(dt), Some(coef)) = (depth, &depth_coef) {
        for (f, t) in mesh.triangles.iter().enumerate() {
            let rhs = coef[f] * (dt.offset[f] as f64 - c) / 3.0;
            for k in t {
                b[*k as usize] += rhs;
            }
        }
    }
    // The system matrix: the anchor's mass on the diagonal, each face's slope term and depth
    // term over its three vertices.
    let system = VertexSystem::assemble(
        &mesh.triangles,
        amass.iter().map(|m| mu as f64 * *m as f64).collect(),
        |f| {
            let c = (wf[f] * geo.areas[f]) as f64;
            let g = geo.grads[f].map(|g| g.as_dvec3());
            let k = depth_coef
                .as_ref()
                .map_or(0.0, |coef| coef[f].max(0.0) / 9.0);
            std::array::from_fn(|a| std::array::from_fn(|b| c * g[a].dot(g[b]) + k))
        },
    );
    // Jacobi preconditioner: the diagonal of the system.
    let inv_diag: Vec<f64> = system
        .diagonal()
        .iter()
        .map(|d| {
            if *d > 0.0 && d.is_finite() {
                1.0 / d
            } else {
                0.0
            }
        })
        .collect();
    let all = vec![true; nv];
    let mut free = vec![true; nv];
    // Start from the mesh as it is (d = 0, y = -c).
    let mut x = vec![-c; nv];
    for _ in 0..settings.rounds.max(1) {
        // Conjugate gradients on the free vertices (the held ones stay at 0).
        for (xi, f) in x.iter_mut().zip(&free) {
            if !f {
                *xi = 0.0;
            }
        }
        let mut ax = vec![0.0f64; nv];
        system.apply(&x, &mut ax, &free);
        let mut r: Vec<f64> = (0..nv)
            .map(|i| if free[i] { b[i] - ax[i] } else { 0.0 })
            .collect();
        let mut z: Vec<f64> = r.iter().zip(&inv_diag).map(|(r, d)| r * d).collect();
        let mut p = z.clone();
        let mut rz = dot(&r, &z);
        let rz0 = rz.max(1e-300);
        let mut ap = vec![0.0f64; nv];
        for _ in 0..settings.iterations {
            if rz <= 1e-14 * rz0 {
                break;
            }
            let pap = system.apply(&p, &mut ap, &free);
            if pap <= 0.0 || !pap.is_finite() {
                break;
            }
            let alpha = rz / pap;
            let rz_new = cg_step(alpha, (&mut x, &mut r, &mut z), (&p, &ap, &inv_diag));
            let beta = rz_new / rz;
            rz = rz_new;
            (p.par_chunks_mut(ROWS_PER_TASK)
                .zip(z.par_chunks(ROWS_PER_TASK)))
            .for_each(|(p, z)| p.iter_mut().zip(z).for_each(|(p, z)| *p = z + beta * *p));
        }
        // Hold the vertices pushed outward; release the held ones the energy pulls inward.
        system.apply(&x, &mut ax, &all);
        let mut changed = false;
        for i in 0..nv {
            if free[i] && x[i] > 0.0 {
                free[i] = false;
                changed = true;
            } else if !free[i] && b[i] - ax[i] < 0.0 {
                free[i] = true;
                changed = true;
            }
        }
        if !changed {
            break;
        }
    }
    let d: Vec<f32> = x
        .iter()
        .map(|v| ((*v + c) as f32).clamp(-settings.max_depth, c as f32))
        .collect();
    let positions = mesh
        .positions
        .iter()
        .zip(&vn)
        .zip(&d)
        .map(|((p, n), d)| *p + *n * *d)
        .collect();
    Ok((
        TriMesh {
            positions,
            triangles: mesh.triangles.clone(),
        },
        d,
    ))
}

#[cfg(test)]
mod tests;
