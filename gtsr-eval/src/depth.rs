//! Rendered geometry against a ground-truth mesh, pixel by pixel: the error of a rendered
//! depth / normal map ([`DepthComparison`], [`DepthMetrics`]) against the mesh's own maps
//! ([`gtsr_mesh::raycast::MeshRaycaster`]).
//!
//! The chamfer distance of a fused mesh mixes the rendered depth with what the fusion adds
//! (silhouette carving, truncation, marching cubes); these numbers measure the rendered
//! surface itself, per test view, where the object is: how far the depth lies from the true
//! surface (and on which side: translucency tends to pull it inward), and how far the normals
//! turn from the true ones.
//!
//! Conventions: depth is z-depth along the camera axis (OpenCV camera space, as
//! [`gtsr_mesh::tsdf::TsdfVolume::integrate`] takes it); normals are camera-space unit vectors facing the
//! camera; a pixel's ray goes through its centre.

use glam::Vec3;
use gtsr_mesh::MeshError;
use gtsr_mesh::raycast::{EDGE_FOOTPRINTS, MeshDepth};
use serde::{Deserialize, Serialize};

use crate::error::Result;

/// A pixel looks into a concavity the masks cannot see where the truth lies more than this
/// many footprints (at the truth's depth) behind the masks' own mesh
/// ([`DepthComparison::add_with_bound`]).
pub const CONCAVE_GAP_FOOTPRINTS: f32 = 3.0;

/// The probabilities of [`DepthMetrics::depth_signed_quantiles`].
pub const DEPTH_QUANTILES: [f64; 5] = [0.05, 0.25, 0.5, 0.75, 0.95];

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
    /// Quantiles of `depth - true depth` at [`DEPTH_QUANTILES`]: where the signed mean comes
    /// from (the body of the pixels or a tail, such as pixels that straddle an occluding edge).
    #[serde(default)]
    pub depth_signed_quantiles: [f64; 5],
    /// Mean `depth - true depth` over the pixels between the first and the last of
    /// [`DEPTH_QUANTILES`] (the signed mean without its tails).
    #[serde(default)]
    pub depth_mean_signed_inner: f64,
    /// The share of the pixels compared that lie on an occluding edge of the truth
    /// ([`MeshDepth::occluding_edges`] at [`EDGE_FOOTPRINTS`]).
    #[serde(default)]
    pub edge_share: f64,
    /// Mean `depth - true depth` over the other pixels (those off the truth's occluding
    /// edges); `None` when every pixel compared lies on one.
    #[serde(default)]
    pub depth_mean_signed_off_edges: Option<f64>,
    /// The share of the pixels compared that lie just behind an occluding edge of the truth,
    /// on its far side ([`MeshDepth::occluders`] at [`EDGE_FOOTPRINTS`]): a subset of the edge
    /// pixels, where a nearer surface that spills past its outline reads in front.
    #[serde(default)]
    pub far_side_share: f64,
    /// Mean `depth - true depth` over those pixels; `None` when there are none.
    #[serde(default)]
    pub depth_mean_signed_far_side: Option<f64>,
    /// The share of the pixels compared that look into a concavity the masks cannot see
    /// ([`CONCAVE_GAP_FOOTPRINTS`]; 0 without the masks' mesh).
    #[serde(default)]
    pub concave_share: f64,
    /// Mean `depth - true depth` over those pixels, in footprints at the truth's depth (the
    /// truth's depth over the focal length): how far in front of a concavity's inside
    /// (negative) the rendered surface lies. `None` when there are none.
    #[serde(default)]
    pub depth_mean_signed_concave_fp: Option<f64>,
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
    /// Per entry of `depth_err`, whether its pixel lies on an occluding edge of the truth.
    at_edge: Vec<bool>,
    /// Per entry of `depth_err`, whether its pixel lies just behind one (its far side).
    far_side: Vec<bool>,
    /// Per entry of `depth_err`, whether its pixel looks into a concavity the masks cannot see.
    concave: Vec<bool>,
    /// Per entry of `depth_err`, the error in footprints at the truth's depth.
    err_fp: Vec<f32>,
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
        self.add_with_bound(truth, depth, normal, select, None)
    }

    /// [`DepthComparison::add`], with the masks' own mesh seen from the same camera (`bound`,
    /// the size of `truth`): the pixels where the truth lies more than
    /// [`CONCAVE_GAP_FOOTPRINTS`] behind it (or where it misses) also count apart
    /// ([`DepthMetrics::depth_mean_signed_concave_fp`]).
    pub fn add_with_bound(
        &mut self,
        truth: &MeshDepth,
        depth: &[f32],
        normal: &[f32],
        select: &[bool],
        bound: Option<&MeshDepth>,
    ) -> Result<()> {
        let n = truth.width * truth.height;
        let size = format!("{}x{} = {n}", truth.width, truth.height);
        if depth.len() != n {
            return Err(MeshError::size("rendered depth", size, depth.len()).into());
        }
        if normal.len() != 3 * n {
            return Err(
                MeshError::size("rendered normals", format!("3 x {size}"), normal.len()).into(),
            );
        }
        if select.len() != n {
            return Err(MeshError::size("pixel selection", size, select.len()).into());
        }
        if let Some(b) = bound
            && b.depth.len() != n
        {
            return Err(MeshError::size("masks' mesh depth", size, b.depth.len()).into());
        }
        let edges = truth.occluding_edges(EDGE_FOOTPRINTS);
        let occluders = truth.occluders(EDGE_FOOTPRINTS);
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
            self.at_edge.push(edges[p]);
            self.far_side.push(occluders[p] > 0.0);
            let footprint = t / truth.focal;
            self.concave.push(bound.is_some_and(|b| {
                let m = b.depth[p];
                m <= 0.0 || !m.is_finite() || t - m > CONCAVE_GAP_FOOTPRINTS * footprint
            }));
            self.err_fp.push((d - t) / footprint);
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
        let mut signed = self.depth_err.clone();
        signed.sort_by(f32::total_cmp);
        // Nearest rank: the smallest error with at least a share `q` of the pixels at or below it.
        let rank = |q: f64| ((q * k as f64).ceil() as usize).clamp(1, k) - 1;
        let quantiles = DEPTH_QUANTILES.map(|q| signed[rank(q)] as f64);
        let inner = &signed[rank(DEPTH_QUANTILES[0])..=rank(DEPTH_QUANTILES[4])];
        // The signed errors' sum and count over the pixels whose flag equals `keep`.
        let sum_where = |flags: &[bool], keep: bool| {
            self.depth_err
                .iter()
                .zip(flags)
                .filter(|(_, f)| **f == keep)
                .fold((0.0f64, 0usize), |(s, n), (e, _)| (s + *e as f64, n + 1))
        };
        let (off_sum, off_n) = sum_where(&self.at_edge, false);
        let (far_sum, far_n) = sum_where(&self.far_side, true);
        let (concave_sum, concave_n) = (self.err_fp.iter().zip(&self.concave))
            .filter(|(_, c)| **c)
            .fold((0.0f64, 0usize), |(s, n), (e, _)| (s + *e as f64, n + 1));
        Some(DepthMetrics {
            depth_mean_abs: mean(&abs),
            depth_median_abs: median(abs),
            depth_mean_signed: mean(&self.depth_err),
            depth_signed_quantiles: quantiles,
            depth_mean_signed_inner: inner.iter().map(|&e| e as f64).sum::<f64>()
                / inner.len() as f64,
            edge_share: (k - off_n) as f64 / k as f64,
            depth_mean_signed_off_edges: (off_n > 0).then(|| off_sum / off_n as f64),
            far_side_share: far_n as f64 / k as f64,
            depth_mean_signed_far_side: (far_n > 0).then(|| far_sum / far_n as f64),
            concave_share: concave_n as f64 / k as f64,
            depth_mean_signed_concave_fp: (concave_n > 0).then(|| concave_sum / concave_n as f64),
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
    use gtsr_data::Camera;
    use gtsr_data::ply::TriMesh;
    use gtsr_mesh::raycast::MeshRaycaster;

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
        let mesh = gtsr_mesh::mesh::icosphere(Vec3::new(0.0, 0.0, dist), r, 5);
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
    fn a_tail_moves_the_signed_mean_but_not_the_quantiles_or_the_inner_mean() {
        let mesh = square(2.0);
        let cam = camera_on_axis(10);
        let truth = MeshRaycaster::new(&mesh, "square").unwrap().render(&cam);
        // Errors -0.050, -0.049, ..., +0.049 in a shuffled pixel order; then the largest
        // replaced by a far tail (+1, a pixel that straddles an occluding edge).
        let err = |i: usize| ((i * 37) % 100) as f32 * 1e-3 - 0.05;
        let normal: Vec<f32> = (0..100).flat_map(|_| [0.0, 0.0, -1.0]).collect();
        let select = vec![true; 100];
        let metrics = |tail: bool| {
            let depth: Vec<f32> = (0..100)
                .map(|i| {
                    let e = if tail && err(i) > 0.0485 { 1.0 } else { err(i) };
                    truth.depth[i] + e
                })
                .collect();
            let mut c = DepthComparison::new();
            c.add(&truth, &depth, &normal, &select).unwrap();
            c.finish().unwrap()
        };
        let (plain, tailed) = (metrics(false), metrics(true));
        for m in [&plain, &tailed] {
            let want = [-0.046, -0.026, -0.001, 0.024, 0.044];
            for (q, w) in m.depth_signed_quantiles.iter().zip(want) {
                assert!((q - w).abs() < 1e-5, "{:?}", m.depth_signed_quantiles);
            }
            assert!((m.depth_mean_signed_inner + 0.001).abs() < 1e-5);
        }
        assert!((plain.depth_mean_signed + 0.0005).abs() < 1e-5);
        assert!((tailed.depth_mean_signed - plain.depth_mean_signed - 0.00951).abs() < 1e-5);
    }

    #[test]
    fn the_outline_is_an_occluding_edge_and_its_errors_are_kept_apart() {
        let mesh = gtsr_mesh::mesh::icosphere(Vec3::new(0.0, 0.0, 3.0), 0.5, 5);
        let cam = camera_on_axis(32);
        let truth = MeshRaycaster::new(&mesh, "sphere").unwrap().render(&cam);
        let edges = truth.occluding_edges(EDGE_FOOTPRINTS);
        let hit = |p: usize| truth.depth[p] > 0.0;
        let n = 32 * 32;
        assert!(!edges[16 * 32 + 16] && !edges[0]);
        // The edge pixels are the sphere's outline: hit, with a neighbour that misses.
        let outline: Vec<usize> = (0..n)
            .filter(|&p| {
                let (x, y) = (p % 32, p / 32);
                hit(p)
                    && [(x - 1, y), (x + 1, y), (x, y - 1), (x, y + 1)]
                        .iter()
                        .any(|&(i, j)| !hit(j * 32 + i))
            })
            .collect();
        assert!(outline.len() > 20);
        assert_eq!(outline, (0..n).filter(|&p| edges[p]).collect::<Vec<_>>());
        // A rendering exact inside and 0.3 in front on the outline.
        let depth: Vec<f32> = (0..n)
            .map(|p| truth.depth[p] - if edges[p] { 0.3 } else { 0.0 })
            .collect();
        let normal: Vec<f32> = truth.normal.iter().flat_map(|v| v.to_array()).collect();
        let mut c = DepthComparison::new();
        c.add(&truth, &depth, &normal, &vec![true; n]).unwrap();
        let m = c.finish().unwrap();
        let share = outline.len() as f64 / m.pixels as f64;
        assert!((m.edge_share - share).abs() < 1e-12);
        assert!(m.depth_mean_signed_off_edges.unwrap().abs() < 1e-6);
        assert!((m.depth_mean_signed + 0.3 * share).abs() < 1e-5);
    }

    #[test]
    fn a_surface_spilling_past_an_edge_shows_on_its_far_side() {
        // A far plane at z = 4 and, in front of its left half, a near one at z = 2 (x < 0.05,
        // between pixel centres, so that the edge's two sides are whole columns; the jump is
        // 13 footprints at z = 4).
        let mut mesh = square(4.0);
        let near = [(-2.0, -2.0), (0.05, -2.0), (0.05, 2.0), (-2.0, 2.0)];
        mesh.positions
            .extend(near.iter().map(|&(x, y)| Vec3::new(x, y, 2.0)));
        mesh.triangles.extend([[4, 5, 6], [4, 6, 7]]);
        let cam = camera_on_axis(16);
        let truth = MeshRaycaster::new(&mesh, "two planes")
            .unwrap()
            .render(&cam);
        let occ = truth.occluders(EDGE_FOOTPRINTS);
        let far: Vec<usize> = (0..256).filter(|&p| occ[p] > 0.0).collect();
        // One column of 16 pixels, each with the near plane's depth as its occluder.
        assert_eq!(far.len(), 16, "{far:?}");
        assert!(
            far.iter()
                .all(|&p| truth.depth[p] > 3.5 && (occ[p] - 2.0).abs() < 1e-5)
        );
        // A rendering that reads the near plane on that column, exact elsewhere.
        let depth: Vec<f32> = (0..256)
            .map(|p| if occ[p] > 0.0 { occ[p] } else { truth.depth[p] })
            .collect();
        let normal: Vec<f32> = truth.normal.iter().flat_map(|v| v.to_array()).collect();
        let mut c = DepthComparison::new();
        c.add(&truth, &depth, &normal, &[true; 256]).unwrap();
        let m = c.finish().unwrap();
        assert!((m.far_side_share - 16.0 / 256.0).abs() < 1e-12);
        assert!((m.depth_mean_signed_far_side.unwrap() + 2.0).abs() < 1e-5);
        assert!(m.depth_mean_signed_off_edges.unwrap().abs() < 1e-6);
        assert!((m.depth_mean_signed + 2.0 * 16.0 / 256.0).abs() < 1e-5);
    }

    #[test]
    fn pixels_behind_the_bound_count_as_concave_in_footprints() {
        // The truth: a far plane at z = 4 whose left half (x < 0.05) the masks' mesh covers
        // with a lid at z = 2, the right half flush (the bound is the truth there).
        let truth_mesh = square(4.0);
        let mut bound_mesh = square(4.0);
        let lid = [(-2.0, -2.0), (0.05, -2.0), (0.05, 2.0), (-2.0, 2.0)];
        bound_mesh
            .positions
            .extend(lid.iter().map(|&(x, y)| Vec3::new(x, y, 2.0)));
        bound_mesh.triangles.extend([[4, 5, 6], [4, 6, 7]]);
        let cam = camera_on_axis(16);
        let truth = MeshRaycaster::new(&truth_mesh, "plane")
            .unwrap()
            .render(&cam);
        let bound = MeshRaycaster::new(&bound_mesh, "lid").unwrap().render(&cam);
        // A rendering that reads the lid over the concavity, exact elsewhere.
        let depth = bound.depth.clone();
        let normal: Vec<f32> = truth.normal.iter().flat_map(|v| v.to_array()).collect();
        let mut c = DepthComparison::new();
        c.add_with_bound(&truth, &depth, &normal, &[true; 256], Some(&bound))
            .unwrap();
        let m = c.finish().unwrap();
        // The pixels that see the lid: about half the image (the lid's edge projects a little
        // right of the centre).
        let lid = bound.depth.iter().filter(|d| **d < 3.0).count();
        assert!((100..=160).contains(&lid), "{lid}");
        assert!(
            (m.concave_share - lid as f64 / 256.0).abs() < 1e-12,
            "{}",
            m.concave_share
        );
        // Two units in front at z = 4: 2 / (4 / focal) footprints.
        let expected = -2.0 / (4.0 / f64::from(truth.focal));
        let got = m.depth_mean_signed_concave_fp.unwrap();
        assert!((got - expected).abs() < 1e-3, "{got} against {expected}");
        // Without the bound no pixel is concave.
        let mut plain = DepthComparison::new();
        plain.add(&truth, &depth, &normal, &[true; 256]).unwrap();
        let m = plain.finish().unwrap();
        assert_eq!(m.concave_share, 0.0);
        assert!(m.depth_mean_signed_concave_fp.is_none());
        // A bound of the wrong size is an error.
        let small = MeshRaycaster::new(&bound_mesh, "lid")
            .unwrap()
            .render(&camera_on_axis(8));
        assert!(
            c.add_with_bound(&truth, &depth, &normal, &[true; 256], Some(&small))
                .is_err()
        );
    }

    #[test]
    fn occluders_mark_the_far_side_of_an_edge_with_the_nearer_depth() {
        // A 4x3 map: columns 0-1 at depth 2 (nearer), 2-3 at depth 4; row 2 column 3 misses.
        let depth: Vec<f32> = (0..12)
            .map(|p| match (p % 4, p / 4) {
                (3, 2) => 0.0,
                (x, _) if x < 2 => 2.0,
                _ => 4.0,
            })
            .collect();
        let md = MeshDepth {
            width: 4,
            height: 3,
            depth,
            normal: vec![Vec3::Z; 12],
            focal: 10.0,
        };
        // At depth 4 a footprint is 0.4: the jump of 2 is 5 footprints.
        let occ = md.occluders(3.0);
        for y in 0..3 {
            let row = &occ[4 * y..4 * y + 4];
            assert_eq!(row, [0.0, 0.0, 2.0, 0.0], "row {y}: {occ:?}");
        }
        // A larger threshold than the jump: no occluder; the nearer side and a miss never have one.
        assert!(md.occluders(6.0).iter().all(|o| *o == 0.0));
        // The nearest of two nearer neighbours.
        let mut two = md.clone();
        two.depth[1] = 1.5;
        two.depth[6] = 1.0;
        assert_eq!(two.occluders(3.0)[2], 1.0);
    }

    #[test]
    fn the_area_average_matches_the_centre_ray_on_a_plane_and_softens_an_outline() {
        let cam = camera_on_axis(16);
        let plane = square(2.0);
        let caster = MeshRaycaster::new(&plane, "square").unwrap();
        let (centre, area) = (caster.render(&cam), caster.render_area(&cam, 4).unwrap());
        for (a, c) in area.depth.iter().zip(&centre.depth) {
            assert!((a - c).abs() < 1e-4, "{a} vs {c}");
        }
        assert!(caster.render_area(&cam, 0).is_err());
        // A sphere: inside its outline the area depth is the mean over the pixel, nearer than
        // the centre ray where the surface turns away from the camera; the coverage rule
        // keeps pixels at least half covered.
        let sphere = gtsr_mesh::mesh::icosphere(Vec3::new(0.0, 0.0, 3.0), 0.5, 5);
        let cam = camera_on_axis(32);
        let caster = MeshRaycaster::new(&sphere, "sphere").unwrap();
        let (centre, area) = (caster.render(&cam), caster.render_area(&cam, 8).unwrap());
        let c = 16 * 32 + 16;
        assert!((area.depth[c] - centre.depth[c]).abs() < 2e-3);
        let hit = |d: &[f32]| d.iter().filter(|z| **z > 0.0).count() as i64;
        assert!((hit(&area.depth) - hit(&centre.depth)).abs() <= 8);
        let edges = centre.occluding_edges(EDGE_FOOTPRINTS);
        let nearer = (0..32 * 32)
            .filter(|&p| edges[p] && area.depth[p] > 0.0 && centre.depth[p] > 0.0)
            .map(|p| centre.depth[p] - area.depth[p])
            .sum::<f32>();
        assert!(nearer > 0.0, "{nearer}");
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
