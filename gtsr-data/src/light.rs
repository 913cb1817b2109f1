//! Whether the light moves with the camera, read from the images alone.
//!
//! Under a light at the camera (the paper's capture) a surface point is brightest in the views
//! that face it squarely and darkens towards grazing views: the light's incidence is the view
//! direction. Under lights fixed in the room its brightness does not follow the view (a
//! diffuse or scattering surface sends the same light every way; a highlight sits where the
//! mirror direction of a fixed light falls, unrelated to how squarely the view faces the
//! point). [`light_evidence`] samples points on the masks' visual hull, gathers each point's
//! brightness in the views that see it (inside the mask, not hidden by the hull), and measures
//! per point the rank correlation between that brightness and the cosine between the point's
//! normal and the direction to the camera. The median over the points is near 1 under a flash
//! and near 0 (or below, from Fresnel at grazing views) under fixed lights.
//!
//! The hull stands in for the surface: where the object lies inside it (a concavity) the point
//! and normal are wrong and its correlation is noise, which the median over many points
//! outvotes.

use glam::Vec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::Encoding;
use crate::image_io::{linear_to_srgb, srgb_to_linear};
use crate::scene::{View, normalisation_of_cameras};

/// Settings of [`light_evidence`].
#[derive(Clone, Debug, PartialEq)]
pub struct LightSettings {
    /// Cells per side of the hull's grid (over 1.5 times the cameras' common sphere).
    pub grid: usize,
    /// At most this many hull points are read (evenly thinned).
    pub max_points: usize,
    /// A point counts when at least this many views see it.
    pub min_views: usize,
    /// A view sees a point only where the cosine between the point's normal and the direction
    /// to the camera reaches this (grazing views sample the mask's edge).
    pub min_facing: f32,
    /// A point counts when the cosines of its views spread over at least this much.
    pub min_spread: f32,
    /// Pixels read must lie this far inside the mask (every pixel of the 3x3 block around).
    pub inside_mask: f32,
}

impl Default for LightSettings {
    fn default() -> Self {
        LightSettings {
            grid: 64,
            max_points: 4000,
            min_views: 6,
            min_facing: 0.15,
            min_spread: 0.3,
            inside_mask: 0.99,
        }
    }
}

/// What the images say about the light.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LightEvidence {
    /// Hull points that enough views see, with enough spread in how squarely they face them.
    pub points: usize,
    /// Median number of views per point.
    pub views_per_point: usize,
    /// Median over the points of the rank correlation between a point's brightness in a view
    /// and the cosine between its normal and the direction to that view's camera.
    pub facing_correlation: f32,
    /// Share of the points whose correlation exceeds [`LightEvidence::THRESHOLD`].
    pub share_following: f32,
    /// The power of that cosine the brightness follows, fitted over every point and view with
    /// the exposures (about 1 for a diffuse surface under a light at the camera, 0 under fixed
    /// lights).
    pub facing_exponent: f32,
}

impl LightEvidence {
    /// The median correlation above which the light is taken to be at the camera: midway
    /// between the flash's 1 and fixed lights' 0, set before any scene was measured.
    pub const THRESHOLD: f32 = 0.5;

    /// Whether the shading follows the camera, as a light at the camera makes it.
    pub fn follows_camera(&self) -> bool {
        self.facing_correlation > Self::THRESHOLD
    }

    /// One line for the run's log and `config.json`.
    pub fn describe(&self) -> String {
        format!(
            "on {} points of the masks' hull (median {} views each), brightness against how \
             squarely the view faces the point: median rank correlation {:.2}, above {} on {:.0} \
             % of the points, brightness as the cosine to the power {:.2} (a light at the camera \
             gives near 1, fixed lights near 0)",
            self.points,
            self.views_per_point,
            self.facing_correlation,
            Self::THRESHOLD,
            100.0 * self.share_following,
            self.facing_exponent
        )
    }
}

/// Bilinear mask value at continuous pixel coordinates; 0 outside the image.
fn mask_at(mask: &[f32], w: usize, h: usize, u: f32, v: f32) -> f32 {
    let (x, y) = (u - 0.5, v - 0.5);
    if !(x > -1.0 && y > -1.0 && x < w as f32 && y < h as f32) {
        return 0.0;
    }
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let at = |i: i64, j: i64| -> f32 {
        if i < 0 || j < 0 || i >= w as i64 || j >= h as i64 {
            0.0
        } else {
            mask[j as usize * w + i as usize]
        }
    };
    let (i, j) = (x0 as i64, y0 as i64);
    (1.0 - fy) * ((1.0 - fx) * at(i, j) + fx * at(i + 1, j))
        + fy * ((1.0 - fx) * at(i, j + 1) + fx * at(i + 1, j + 1))
}

/// Ranks (ties averaged), 0-based.
fn ranks(x: &[f32]) -> Vec<f32> {
    let mut order: Vec<usize> = (0..x.len()).collect();
    order.sort_by(|&a, &b| x[a].total_cmp(&x[b]));
    let mut r = vec![0.0f32; x.len()];
    let mut k = 0;
    while k < order.len() {
        let mut e = k;
        while e + 1 < order.len() && x[order[e + 1]] == x[order[k]] {
            e += 1;
        }
        let mean = 0.5 * (k + e) as f32;
        for &o in &order[k..=e] {
            r[o] = mean;
        }
        k = e + 1;
    }
    r
}

/// Spearman's rank correlation; `None` when either side is constant.
pub fn rank_correlation(a: &[f32], b: &[f32]) -> Option<f32> {
    let (ra, rb) = (ranks(a), ranks(b));
    let n = ra.len() as f64;
    let ma = ra.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
    let mb = rb.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
    let (mut sab, mut saa, mut sbb) = (0.0f64, 0.0f64, 0.0f64);
    for (&x, &y) in ra.iter().zip(&rb) {
        let (dx, dy) = (f64::from(x) - ma, f64::from(y) - mb);
        sab += dx * dy;
        saa += dx * dx;
        sbb += dy * dy;
    }
    (saa > 0.0 && sbb > 0.0).then(|| (sab / (saa * sbb).sqrt()) as f32)
}

/// The hull's occupancy on a cubic grid: the least over the views of the bilinear mask at
/// each cell centre is at least 0.5.
struct Hull {
    n: usize,
    lo: Vec3,
    cell: f32,
    inside: Vec<bool>,
}

impl Hull {
    /// The hull of `views`' masks.
    fn carve(views: &[(&View, &[f32])], n: usize) -> Hull {
        let cameras: Vec<&crate::Camera> = views.iter().map(|(v, _)| &v.camera).collect();
        let sphere = normalisation_of_cameras(&cameras);
        let half = 1.5 * sphere.radius;
        let cell = 2.0 * half / n as f32;
        let lo = sphere.centre - Vec3::splat(half);
        let inside = (0..n * n * n)
            .into_par_iter()
            .map(|idx| {
                let (i, j, k) = (idx % n, (idx / n) % n, idx / (n * n));
                let p = lo + Vec3::new(i as f32 + 0.5, j as f32 + 0.5, k as f32 + 0.5) * cell;
                views.iter().all(|(v, m)| {
                    let c = &v.camera;
                    c.project(p).is_some_and(|(uv, _)| {
                        mask_at(m, c.width as usize, c.height as usize, uv.x, uv.y) >= 0.5
                    })
                })
            })
            .collect();
        Hull {
            n,
            lo,
            cell,
            inside,
        }
    }

    fn at(&self, i: i64, j: i64, k: i64) -> bool {
        let n = self.n as i64;
        if i < 0 || j < 0 || k < 0 || i >= n || j >= n || k >= n {
            return false;
        }
        self.inside[(k * n * n + j * n + i) as usize]
    }

    fn cell_of(&self, p: Vec3) -> (i64, i64, i64) {
        let q = (p - self.lo) / self.cell;
        (q.x.floor() as i64, q.y.floor() as i64, q.z.floor() as i64)
    }

    /// Whether the segment from `p` towards `to` leaves the hull and never re-enters it.
    fn clear(&self, p: Vec3, to: Vec3) -> bool {
        let d = to - p;
        let len = d.length();
        let dir = d / len;
        let step = 0.5 * self.cell;
        let mut t = 1.5 * self.cell;
        let box_len = self.cell * self.n as f32 * 1.8;
        while t < len.min(box_len) {
            let (i, j, k) = self.cell_of(p + dir * t);
            if self.at(i, j, k) {
                return false;
            }
            t += step;
        }
        true
    }
}

/// One view's reading of one hull point.
#[derive(Clone, Copy, Debug)]
struct Observation {
    view: usize,
    /// Log of the linear brightness (the mean of the 3x3 block's channels).
    log_bright: f32,
    /// Cosine between the point's normal and the direction to the camera.
    facing: f32,
    /// Its natural log, as the exposure fit reads it.
    log_facing: f64,
}

/// What [`read_views`] reads from the images: the light, and each view's exposure.
#[derive(Clone, Debug, PartialEq)]
pub struct Reading {
    /// Whether the shading follows the camera.
    pub light: LightEvidence,
    /// Each view's exposure in stops (log2 of its brightness gain) against the mean of the
    /// views; 0 for a view that sees no hull point well.
    pub exposure_stops: Vec<f32>,
}

impl Reading {
    /// The largest departure of a view's exposure from the mean, in stops.
    pub fn exposure_spread(&self) -> f32 {
        self.exposure_stops
            .iter()
            .fold(0.0f32, |m, s| m.max(s.abs()))
    }
}

/// [`read_views`]' light alone.
pub fn light_evidence(views: &[View], s: &LightSettings) -> Option<LightEvidence> {
    read_views(&views.iter().collect::<Vec<_>>(), s).map(|r| r.light)
}

/// Reads from the training views' images and masks whether the light moves with the camera,
/// and each view's exposure ([module docs](self)). Each hull point's log brightness is modelled
/// as its own level, plus its view's exposure, plus an exponent times the log of the cosine
/// towards the camera (a light at the camera makes the exponent about 1); the three are fitted
/// by alternating least squares over every point and view. The light's evidence is then read
/// on the brightness with the exposures taken out. `None` when a view has no mask, or when too
/// few hull points are seen well enough to tell (fewer than 50). Saturated pixels (a channel
/// at 0.995 or more of the encoding's range) and black ones are not read.
pub fn read_views(views: &[&View], s: &LightSettings) -> Option<Reading> {
    let with_masks: Vec<(&View, &[f32])> = views
        .iter()
        .map(|v| v.mask.as_deref().map(|m| (*v, m)))
        .collect::<Option<_>>()?;
    if with_masks.is_empty() {
        return None;
    }
    let hull = Hull::carve(&with_masks, s.grid.max(8));
    let n = hull.n as i64;
    // Boundary cells: inside, with an outside face neighbour.
    let mut boundary = Vec::new();
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                if hull.at(i, j, k)
                    && [
                        (1, 0, 0),
                        (-1, 0, 0),
                        (0, 1, 0),
                        (0, -1, 0),
                        (0, 0, 1),
                        (0, 0, -1),
                    ]
                    .iter()
                    .any(|(a, b, c)| !hull.at(i + a, j + b, k + c))
                {
                    boundary.push((i, j, k));
                }
            }
        }
    }
    let stride = boundary.len().div_ceil(s.max_points.max(1)).max(1);
    let cameras: Vec<Vec3> = views.iter().map(|v| v.camera.centre()).collect();
    let points: Vec<Vec<Observation>> = boundary
        .par_iter()
        .step_by(stride)
        .filter_map(|&(i, j, k)| {
            // The normal: away from the hull's occupied cells within two cells.
            let mut moment = Vec3::ZERO;
            for c in -2i64..=2 {
                for b in -2i64..=2 {
                    for a in -2i64..=2 {
                        if hull.at(i + a, j + b, k + c) {
                            moment += Vec3::new(a as f32, b as f32, c as f32);
                        }
                    }
                }
            }
            let normal = (-moment).try_normalize()?;
            let p = hull.lo + Vec3::new(i as f32 + 0.5, j as f32 + 0.5, k as f32 + 0.5) * hull.cell;
            let mut seen = Vec::new();
            for (view, ((v, mask), eye)) in with_masks.iter().zip(&cameras).enumerate() {
                let cos = normal.dot((*eye - p).normalize());
                if cos < s.min_facing || !hull.clear(p, *eye) {
                    continue;
                }
                let c = &v.camera;
                let Some((uv, _)) = c.project(p) else {
                    continue;
                };
                let (w, h) = (c.width as i64, c.height as i64);
                let (x, y) = (uv.x.floor() as i64, uv.y.floor() as i64);
                if x < 1 || y < 1 || x + 1 >= w || y + 1 >= h {
                    continue;
                }
                let srgb = v.encoding == Encoding::Srgb;
                let mut sum = 0.0f32;
                let mut usable = true;
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let q = ((y + dy) * w + x + dx) as usize;
                        usable &= mask[q] >= s.inside_mask;
                        for ch in 0..3 {
                            let e = v.rgb[3 * q + ch];
                            usable &= !srgb || e < 0.995;
                            sum += if srgb { srgb_to_linear(e) } else { e };
                        }
                    }
                }
                if usable && sum > 1e-3 {
                    seen.push(Observation {
                        view,
                        log_bright: (sum / 27.0).ln(),
                        facing: cos,
                        log_facing: f64::from(cos).ln(),
                    });
                }
            }
            let spread = seen
                .iter()
                .map(|o| o.facing)
                .fold(f32::NEG_INFINITY, f32::max)
                - seen.iter().map(|o| o.facing).fold(f32::INFINITY, f32::min);
            (seen.len() >= s.min_views && spread >= s.min_spread).then_some(seen)
        })
        .collect();
    if points.len() < 50 {
        return None;
    }
    let (gain, exponent) = fit_exposure(&points, views.len());
    let mut seen: Vec<(f32, usize)> = points
        .iter()
        .filter_map(|obs| {
            let bright: Vec<f32> = obs.iter().map(|o| o.log_bright - gain[o.view]).collect();
            let facing: Vec<f32> = obs.iter().map(|o| o.facing).collect();
            rank_correlation(&bright, &facing).map(|r| (r, obs.len()))
        })
        .collect();
    if seen.len() < 50 {
        return None;
    }
    let count = seen.len();
    let share_following = seen
        .iter()
        .filter(|(r, _)| *r > LightEvidence::THRESHOLD)
        .count() as f32
        / count as f32;
    seen.sort_by(|a, b| a.0.total_cmp(&b.0));
    let facing_correlation = seen[count / 2].0;
    let mut counts: Vec<usize> = seen.iter().map(|(_, c)| *c).collect();
    counts.sort_unstable();
    Some(Reading {
        light: LightEvidence {
            points: count,
            views_per_point: counts[count / 2],
            facing_correlation,
            share_following,
            facing_exponent: exponent,
        },
        exposure_stops: gain.iter().map(|g| g / std::f32::consts::LN_2).collect(),
    })
}

/// Fits `log_bright = level[point] + gain[view] + exponent * ln(facing)` by alternating least
/// squares; returns the gains (natural log, mean 0 over the views observed) and the exponent.
fn fit_exposure(points: &[Vec<Observation>], views: usize) -> (Vec<f32>, f32) {
    let mut gain = vec![0.0f64; views];
    let mut exponent = 0.0f64;
    let mut level = vec![0.0f64; points.len()];
    for _ in 0..40 {
        for (l, obs) in level.iter_mut().zip(points) {
            *l = obs
                .iter()
                .map(|o| f64::from(o.log_bright) - gain[o.view] - exponent * o.log_facing)
                .sum::<f64>()
                / obs.len() as f64;
        }
        let (mut sum, mut count) = (vec![0.0f64; views], vec![0usize; views]);
        for (l, obs) in level.iter().zip(points) {
            for o in obs {
                sum[o.view] += f64::from(o.log_bright) - l - exponent * o.log_facing;
                count[o.view] += 1;
            }
        }
        let observed = count.iter().filter(|&&c| c > 0).count().max(1);
        for v in 0..views {
            gain[v] = if count[v] > 0 {
                sum[v] / count[v] as f64
            } else {
                0.0
            };
        }
        let mean = gain.iter().sum::<f64>() / observed as f64;
        for v in 0..views {
            if count[v] > 0 {
                gain[v] -= mean;
            }
        }
        // The exponent: regression of what is left on ln(facing) about each point's mean.
        let (mut sxy, mut sxx) = (0.0f64, 0.0f64);
        for obs in points {
            let mx = obs.iter().map(|o| o.log_facing).sum::<f64>() / obs.len() as f64;
            let my = obs
                .iter()
                .map(|o| f64::from(o.log_bright) - gain[o.view])
                .sum::<f64>()
                / obs.len() as f64;
            for o in obs {
                let x = o.log_facing - mx;
                sxy += x * (f64::from(o.log_bright) - gain[o.view] - my);
                sxx += x * x;
            }
        }
        if sxx > 0.0 {
            exponent = sxy / sxx;
        }
    }
    (gain.iter().map(|&g| g as f32).collect(), exponent as f32)
}

/// Takes each view's exposure out of its image: `stops[k]` (as [`Reading::exposure_stops`])
/// divides view `k`'s linear radiance by `2^stops[k]`, re-encoded as it was (sRGB values
/// clamped to 1).
pub fn normalise_exposure<'a>(views: impl IntoIterator<Item = &'a mut View>, stops: &[f32]) {
    for (v, &st) in views.into_iter().zip(stops) {
        let scale = (-st).exp2();
        let srgb = v.encoding == Encoding::Srgb;
        for e in v.rgb.iter_mut() {
            *e = if srgb {
                linear_to_srgb(srgb_to_linear(*e) * scale)
            } else {
                *e * scale
            };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rank_correlation_reads_order_not_scale() {
        let a = [1.0, 2.0, 3.0, 4.0, 5.0];
        let b = [10.0, 200.0, 3000.0, 40000.0, 500000.0];
        assert!((rank_correlation(&a, &b).unwrap() - 1.0).abs() < 1e-6);
        let c = [5.0, 4.0, 3.0, 2.0, 1.0];
        assert!((rank_correlation(&a, &c).unwrap() + 1.0).abs() < 1e-6);
        assert_eq!(rank_correlation(&a, &[1.0; 5]), None);
        // Ties share their mean rank.
        assert_eq!(ranks(&[3.0, 1.0, 3.0, 2.0]), vec![2.5, 0.0, 2.5, 1.0]);
    }

    /// Views of a translucent sphere path-traced under `lighting`.
    fn sphere_views(lighting: crate::transport::Lighting) -> Vec<View> {
        use crate::synthetic::{SceneConfig, ShapeKind, scene_cameras};
        use crate::transport::{MaterialPreset, Tracer};
        let mut cfg = SceneConfig::new(ShapeKind::Sphere, MaterialPreset::Marble);
        cfg.resolution = 40;
        cfg.n_train = 24;
        let tracer = Tracer::new(&cfg.shape.mesh(), cfg.material);
        let (train, _) = scene_cameras(&cfg);
        train
            .iter()
            .enumerate()
            .map(|(k, cam)| {
                let r = tracer.render(cam, lighting, 8, 7, k as u64);
                View {
                    name: format!("r_{k}"),
                    path: format!("r_{k}.png").into(),
                    camera: *cam,
                    rgb: r.rgb,
                    encoding: crate::Encoding::Linear,
                    mask: Some(r.alpha),
                }
            })
            .collect()
    }

    #[test]
    fn a_light_at_the_camera_is_told_from_a_fixed_surround() {
        use crate::transport::Lighting;
        let s = LightSettings {
            grid: 32,
            ..LightSettings::default()
        };
        let flash = light_evidence(
            &sphere_views(Lighting {
                point_intensity: 20.0,
                environment: 0.0,
            }),
            &s,
        )
        .expect("the sphere's hull is seen");
        assert!(flash.follows_camera(), "flash: {}", flash.describe());
        assert!(flash.facing_correlation > 0.8, "{}", flash.describe());
        let fixed = light_evidence(
            &sphere_views(Lighting {
                point_intensity: 0.0,
                environment: 1.0,
            }),
            &s,
        )
        .expect("the sphere's hull is seen");
        assert!(!fixed.follows_camera(), "fixed: {}", fixed.describe());
        // Without masks nothing can be read.
        let mut bare = sphere_views(Lighting {
            point_intensity: 20.0,
            environment: 0.0,
        });
        bare[3].mask = None;
        assert_eq!(light_evidence(&bare, &s), None);
    }

    #[test]
    fn each_views_exposure_is_read_and_taken_out() {
        use crate::transport::Lighting;
        let s = LightSettings {
            grid: 32,
            ..LightSettings::default()
        };
        let mut views = sphere_views(Lighting {
            point_intensity: 20.0,
            environment: 0.0,
        });
        let plain = read_views(&views.iter().collect::<Vec<_>>(), &s).unwrap();
        assert!(plain.exposure_spread() < 0.2, "{:?}", plain.exposure_stops);
        // Up to a stop either way, as a phone's auto exposure.
        let truth: Vec<f32> = (0..views.len())
            .map(|k| ((k * 7) % 9) as f32 / 4.0 - 1.0)
            .collect();
        for (v, t) in views.iter_mut().zip(&truth) {
            v.rgb.iter_mut().for_each(|e| *e *= t.exp2());
        }
        let read = read_views(&views.iter().collect::<Vec<_>>(), &s).unwrap();
        assert!(read.light.follows_camera(), "{}", read.light.describe());
        let mean = truth.iter().sum::<f32>() / truth.len() as f32;
        for (k, (r, t)) in read.exposure_stops.iter().zip(&truth).enumerate() {
            let set = t - mean;
            let unset = plain.exposure_stops[k];
            assert!(
                (r - set - unset).abs() < 0.05,
                "view {k}: read {r}, set {set}, {unset} unset"
            );
        }
        normalise_exposure(&mut views, &read.exposure_stops);
        let again = read_views(&views.iter().collect::<Vec<_>>(), &s).unwrap();
        assert!(
            again.exposure_spread() < plain.exposure_spread() + 0.05,
            "{:?}",
            again.exposure_stops
        );
    }
}
