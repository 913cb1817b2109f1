//! Surface and image metrics: chamfer distance, accuracy / completeness, precision / recall /
//! F-score, normal consistency, PSNR and SSIM.
//!
//! # Mesh metrics
//!
//! `samples` points are drawn area-uniformly on each mesh (seeded, see
//! [`gtsr_mesh::mesh::sample_surface`]); each sample's distance to the *other mesh* is the exact
//! Euclidean distance to its closest triangle (parry3d BVH, not a nearest-sample search).
//! `chamfer = (accuracy + completeness) / 2` with `accuracy` the mean predicted-to-ground-truth
//! distance and `completeness` the mean ground-truth-to-predicted distance.
//!
//! # Image metrics
//!
//! Images are [`ImageRef`]s of `f32` values in `[0, 1]`, interleaved channels. Masks hold
//! one value per pixel; a pixel is selected when `mask > 0.5`.
//! SSIM follows 3DGS (`utils/loss_utils.py`) and pytorch-msssim's defaults: an 11x11 Gaussian
//! window with sigma 1.5 (normalised to sum 1), applied per channel as a separable blur with
//! **zero padding** (same-size output, like `conv2d(padding=5)`), `C1 = 0.01^2`,
//! `C2 = 0.03^2`, and the mean of the SSIM map over all pixels and channels (over the
//! selected pixels when masked).

use glam::Vec3;
use gtsr_data::Camera;
use gtsr_data::ply::TriMesh;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::Result;
use gtsr_mesh::MeshError;
use gtsr_mesh::mesh::{SurfaceSamples, sample_surface};
use gtsr_mesh::raycast::MeshBvh;

/// Mesh-to-mesh metrics (distances in mesh units).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MeshMetrics {
    /// `(accuracy + completeness) / 2`.
    pub chamfer: f64,
    /// Mean distance from predicted samples to the ground-truth mesh.
    pub accuracy: f64,
    /// Mean distance from ground-truth samples to the predicted mesh.
    pub completeness: f64,
    /// Fraction of predicted samples within `threshold` of the ground truth.
    pub precision: f64,
    /// Fraction of ground-truth samples within `threshold` of the prediction.
    pub recall: f64,
    /// Harmonic mean of precision and recall (0 when both are 0).
    pub fscore: f64,
    /// Mean over both directions of `|n_sample . n_closest_triangle|` (1 = perfect).
    pub normal_consistency: f64,
    /// The F-score distance threshold used.
    pub threshold: f64,
    /// Samples drawn on each mesh.
    pub samples: usize,
    /// Fraction of the ground-truth samples kept: 1 for [`chamfer`]; for [`chamfer_seen`] the
    /// fraction some eye sees (the rest lie on surfaces no camera sees, such as faces inside a
    /// non-watertight ground truth).
    #[serde(default = "one")]
    pub gt_seen: f64,
    /// The completeness split by what the masks' hull can place ([`HullBlind`]); only from
    /// [`score_against_ground_truth`] given a hull.
    #[serde(default)]
    pub hull_blind: Option<HullBlind>,
}

/// Completeness split between the part of the (seen) ground truth that the masks' hull misses
/// by more than a distance threshold, which only shading can place (concavities no silhouette
/// shows), and the rest.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct HullBlind {
    /// The distance to the hull beyond which a ground-truth sample is hull-blind.
    pub threshold: f64,
    /// Fraction of the kept ground-truth samples that are hull-blind.
    pub fraction: f64,
    /// Mean distance from the hull-blind ground-truth samples to the predicted mesh (0 when
    /// there are none).
    pub blind: f64,
    /// Mean distance from the other ground-truth samples to the predicted mesh.
    pub rest: f64,
    /// Mean distance from the hull-blind ground-truth samples to the hull itself: what the
    /// masks alone score on that part.
    pub hull_on_blind: f64,
}

fn one() -> f64 {
    1.0
}

/// Per sample: the distance to `target` and `|cos|` between the sample's normal and the
/// closest triangle's.
fn closest_all(samples: &SurfaceSamples, target: &MeshBvh, what: &str) -> Result<Vec<(f32, f32)>> {
    let out: Vec<(f32, f32)> = samples
        .points
        .par_iter()
        .zip(&samples.normals)
        .map(|(&p, &n)| {
            let (d, tn) = target.closest(p);
            (d, n.dot(tn).abs())
        })
        .collect();
    let bad = out.iter().filter(|(d, _)| !d.is_finite()).count();
    if bad > 0 {
        return Err(MeshError::NonFinite {
            what: format!("{bad} closest-point distances from {what} samples"),
        }
        .into());
    }
    Ok(out)
}

/// One direction over the samples `keep` flags (all when `None`): (mean distance, fraction
/// within threshold, mean |cos|).
fn one_way(rows: &[(f32, f32)], keep: Option<&[bool]>, threshold: f32) -> (f64, f64, f64) {
    let (mut sum_d, mut hits, mut sum_n, mut n) = (0.0f64, 0usize, 0.0f64, 0usize);
    for (k, &(d, c)) in rows.iter().enumerate() {
        if keep.is_some_and(|f| !f[k]) {
            continue;
        }
        sum_d += d as f64;
        hits += (d <= threshold) as usize;
        sum_n += c as f64;
        n += 1;
    }
    let n = n.max(1) as f64;
    (sum_d / n, hits as f64 / n, sum_n / n)
}

/// The metrics from both directions' aggregates.
fn metrics(
    (accuracy, precision, nc_pred): (f64, f64, f64),
    (completeness, recall, nc_gt): (f64, f64, f64),
    threshold: f32,
    samples: usize,
    gt_seen: f64,
) -> MeshMetrics {
    let fscore = if precision + recall > 0.0 {
        2.0 * precision * recall / (precision + recall)
    } else {
        0.0
    };
    MeshMetrics {
        chamfer: 0.5 * (accuracy + completeness),
        accuracy,
        completeness,
        precision,
        recall,
        fscore,
        normal_consistency: 0.5 * (nc_pred + nc_gt),
        threshold: threshold as f64,
        samples,
        gt_seen,
        hull_blind: None,
    }
}

/// Chamfer distance, F-score at `threshold` and normal consistency between a predicted and a
/// ground-truth mesh, from `samples` area-uniform samples per mesh drawn with `seed` (see the
/// module documentation). Errors on empty or invalid meshes and on `samples == 0` or a
/// non-positive threshold. Parallel (rayon).
pub fn chamfer(
    pred: &TriMesh,
    gt: &TriMesh,
    samples: usize,
    threshold: f32,
    seed: u64,
) -> Result<MeshMetrics> {
    Ok(chamfer_impl(pred, gt, None, None, samples, threshold, seed)?.0)
}

/// The whole-ground-truth metrics and, with `eyes`, the seen ones, from one set of samples.
fn chamfer_impl(
    pred: &TriMesh,
    gt: &TriMesh,
    eyes: Option<(&[Vec3], usize)>,
    hull: Option<(&TriMesh, f32)>,
    samples: usize,
    threshold: f32,
    seed: u64,
) -> Result<(MeshMetrics, Option<MeshMetrics>)> {
    if samples == 0 {
        return Err(MeshError::InvalidArgument("chamfer needs at least one sample".into()).into());
    }
    if !(threshold > 0.0 && threshold.is_finite()) {
        return Err(MeshError::InvalidArgument(format!(
            "F-score threshold {threshold} must be positive and finite"
        ))
        .into());
    }
    let (pred_target, gt_target) = rayon::join(
        || MeshBvh::new(pred, "predicted"),
        || MeshBvh::new(gt, "ground-truth"),
    );
    let (pred_target, gt_target) = (pred_target?, gt_target?);
    let pred_samples = sample_surface(pred, samples, seed, "predicted")?;
    let gt_samples = sample_surface(gt, samples, seed ^ 0x5eed_0f67, "ground-truth")?;
    let keep = match eyes {
        Some((eyes, min_eyes)) => Some(seen_flags(&gt_samples, &gt_target, gt, eyes, min_eyes)?),
        None => None,
    };
    let to_gt = one_way(
        &closest_all(&pred_samples, &gt_target, "predicted")?,
        None,
        threshold,
    );
    let to_pred = closest_all(&gt_samples, &pred_target, "ground-truth")?;
    let to_hull = match hull {
        Some((hull, blind_at)) => {
            if !(blind_at > 0.0 && blind_at.is_finite()) {
                return Err(MeshError::InvalidArgument(format!(
                    "hull-blind threshold {blind_at} must be positive and finite"
                ))
                .into());
            }
            let target = MeshBvh::new(hull, "masks' hull")?;
            Some((closest_all(&gt_samples, &target, "ground-truth")?, blind_at))
        }
        None => None,
    };
    let split = |keep: Option<&[bool]>| {
        to_hull
            .as_ref()
            .map(|(to_hull, blind_at)| hull_blind_split(&to_pred, to_hull, keep, *blind_at))
    };
    let mut whole = metrics(
        to_gt,
        one_way(&to_pred, None, threshold),
        threshold,
        samples,
        1.0,
    );
    whole.hull_blind = split(None);
    let seen = keep.map(|keep| {
        let kept = keep.iter().filter(|k| **k).count();
        let mut m = metrics(
            to_gt,
            one_way(&to_pred, Some(&keep), threshold),
            threshold,
            samples,
            kept as f64 / keep.len() as f64,
        );
        m.hull_blind = split(Some(&keep));
        m
    });
    Ok((whole, seen))
}

/// [`HullBlind`] over the ground-truth samples `keep` flags (all when `None`): `to_pred` and
/// `to_hull` hold each sample's distance to the prediction and to the hull.
fn hull_blind_split(
    to_pred: &[(f32, f32)],
    to_hull: &[(f32, f32)],
    keep: Option<&[bool]>,
    blind_at: f32,
) -> HullBlind {
    let (mut n, mut nb, mut sb, mut sr, mut sh) = (0usize, 0usize, 0.0f64, 0.0f64, 0.0f64);
    for (k, (&(dp, _), &(dh, _))) in to_pred.iter().zip(to_hull).enumerate() {
        if keep.is_some_and(|f| !f[k]) {
            continue;
        }
        n += 1;
        if dh > blind_at {
            nb += 1;
            sb += dp as f64;
            sh += dh as f64;
        } else {
            sr += dp as f64;
        }
    }
    let mean = |s: f64, k: usize| if k > 0 { s / k as f64 } else { 0.0 };
    HullBlind {
        threshold: blind_at as f64,
        fraction: nb as f64 / n.max(1) as f64,
        blind: mean(sb, nb),
        rest: mean(sr, n - nb),
        hull_on_blind: mean(sh, nb),
    }
}

/// Which ground-truth samples at least `min_eyes` of `eyes` see; errors as [`chamfer_seen`].
fn seen_flags(
    gt_samples: &SurfaceSamples,
    gt_target: &MeshBvh,
    gt: &TriMesh,
    eyes: &[Vec3],
    min_eyes: usize,
) -> Result<Vec<bool>> {
    if eyes.is_empty() || eyes.iter().any(|e| !e.is_finite()) {
        return Err(MeshError::InvalidArgument(
            "chamfer_seen needs at least one eye, all finite".into(),
        )
        .into());
    }
    if min_eyes == 0 || min_eyes > eyes.len() {
        return Err(MeshError::InvalidArgument(format!(
            "chamfer_seen: a sample must be seen by 1 to {} eyes, not {min_eyes}",
            eyes.len()
        ))
        .into());
    }
    let (lo, hi) = gt.bounds();
    let eps = 1e-5 * (hi - lo).length().max(f32::MIN_POSITIVE);
    let keep: Vec<bool> = gt_samples
        .points
        .par_iter()
        .zip(&gt_samples.normals)
        .map(|(&p, &n)| {
            eyes.iter()
                .filter(|&&e| gt_target.sees(p, n, e, eps))
                .take(min_eyes)
                .count()
                == min_eyes
        })
        .collect();
    if !keep.contains(&true) {
        return Err(MeshError::InvalidArgument(format!(
            "no ground-truth sample is seen by {min_eyes} of the {} eyes",
            eyes.len()
        ))
        .into());
    }
    Ok(keep)
}

/// [`chamfer`] against the part of the ground truth that can be observed: ground-truth samples
/// that fewer than `min_eyes` of `eyes` (camera centres) see, because the mesh itself blocks
/// the segments to them, are left out of completeness and recall. They lie on surfaces the
/// images do not show, such as the faces left inside a ground truth made of overlapping closed
/// parts; DTU's evaluation drops unobserved ground truth in the same way.
/// [`MeshMetrics::gt_seen`] is the fraction kept. Asking for more than one eye also keeps out
/// the inside faces that a ray or two reaches through the seams where such parts meet (see
/// [`SEEN_MIN_EYES`]). Errors as [`chamfer`] does, and when `eyes` is empty, holds a
/// non-finite point, has fewer than `min_eyes` (or `min_eyes` is 0) or no sample is seen.
pub fn chamfer_seen(
    pred: &TriMesh,
    gt: &TriMesh,
    eyes: &[Vec3],
    min_eyes: usize,
    samples: usize,
    threshold: f32,
    seed: u64,
) -> Result<MeshMetrics> {
    Ok(chamfer_seen_and_whole(pred, gt, (eyes, min_eyes), samples, threshold, seed)?.0)
}

/// [`chamfer_seen`] and [`chamfer`] together, `(seen, whole)`, from one set of samples: the
/// predicted side and the distances are computed once. `seen_from` is `(eyes, min_eyes)` of
/// [`chamfer_seen`].
pub fn chamfer_seen_and_whole(
    pred: &TriMesh,
    gt: &TriMesh,
    seen_from: (&[Vec3], usize),
    samples: usize,
    threshold: f32,
    seed: u64,
) -> Result<(MeshMetrics, MeshMetrics)> {
    let (whole, seen) = chamfer_impl(pred, gt, Some(seen_from), None, samples, threshold, seed)?;
    Ok((seen.expect("eyes were given"), whole))
}

/// The number of eyes that must see a ground-truth sample for [`chamfer_seen`] to keep it, as
/// [`score_against_ground_truth`] and `gtsr-eval mesh --seen-from` (`--min-eyes`) use it: one
/// training camera with an unblocked segment to the sample is enough.
pub const SEEN_MIN_EYES: usize = 1;

/// Area-uniform samples per mesh in [`score_against_ground_truth`].
pub const SCORE_SAMPLES: usize = 100_000;

/// Ground truth farther than this fraction of its radius from the masks' hull is hull-blind
/// ([`HullBlind`]; 0.01 for the unit-radius development scenes).
pub const HULL_BLIND_RADII: f32 = 0.01;

/// A reconstructed mesh against a scene's ground truth as gtsr-train, `cargo xtask
/// bench-recon` and `cargo lab fusion-ceiling` report it, `(seen, whole)`: the seen ground
/// truth is what [`SEEN_MIN_EYES`] of the training `cameras`' centres see (unblocked
/// segments), [`SCORE_SAMPLES`] samples per mesh with seed 0, and the F-score threshold 1 % of
/// the ground truth's radius (half the longest side of its box).
/// With `hull` (the masks alone, [`gtsr_mesh::hull::masks_mesh`]) both carry the [`HullBlind`]
/// split at [`HULL_BLIND_RADII`].
pub fn score_against_ground_truth(
    pred: &TriMesh,
    gt: &TriMesh,
    cameras: &[Camera],
    hull: Option<&TriMesh>,
) -> Result<(MeshMetrics, MeshMetrics)> {
    let (lo, hi) = gt.bounds();
    let radius = 0.5 * (hi - lo).max_element();
    let eyes: Vec<Vec3> = cameras.iter().map(|c| c.centre()).collect();
    let (whole, seen) = chamfer_impl(
        pred,
        gt,
        Some((&eyes, SEEN_MIN_EYES)),
        hull.map(|h| (h, HULL_BLIND_RADII * radius)),
        SCORE_SAMPLES,
        0.01 * radius,
        0,
    )?;
    Ok((seen.expect("eyes were given"), whole))
}

/// A borrowed image: `width * height * channels` values, row-major, channels interleaved.
#[derive(Clone, Copy, Debug)]
pub struct ImageRef<'a> {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Channels per pixel.
    pub channels: usize,
    /// The values.
    pub data: &'a [f32],
}

impl<'a> ImageRef<'a> {
    /// A view of `data` as a `width x height` image with `channels` channels.
    pub fn new(width: usize, height: usize, channels: usize, data: &'a [f32]) -> Self {
        ImageRef {
            width,
            height,
            channels,
            data,
        }
    }

    /// The RGB values of a decoded [`gtsr_data::Image`].
    pub fn rgb(image: &'a gtsr_data::Image) -> Self {
        ImageRef::new(image.width as usize, image.height as usize, 3, &image.rgb)
    }

    fn check(&self, what: &str) -> Result<()> {
        let n = self.width * self.height * self.channels;
        if n == 0 || self.data.len() != n {
            return Err(MeshError::size(
                what,
                format!(
                    "{}x{}x{} = {n} values (non-zero)",
                    self.width, self.height, self.channels
                ),
                self.data.len(),
            )
            .into());
        }
        if self.data.iter().any(|v| !v.is_finite()) {
            return Err(MeshError::NonFinite {
                what: what.to_string(),
            }
            .into());
        }
        Ok(())
    }
}

fn check_pair(pred: &ImageRef, gt: &ImageRef, mask: Option<&[f32]>) -> Result<()> {
    pred.check("predicted image")?;
    gt.check("ground-truth image")?;
    if (pred.width, pred.height, pred.channels) != (gt.width, gt.height, gt.channels) {
        return Err(MeshError::size(
            "predicted image",
            format!(
                "{}x{}x{} (as the ground truth)",
                gt.width, gt.height, gt.channels
            ),
            format!("{}x{}x{}", pred.width, pred.height, pred.channels),
        )
        .into());
    }
    if let Some(m) = mask {
        if m.len() != gt.width * gt.height {
            return Err(MeshError::size(
                "mask",
                format!("{}x{} = {}", gt.width, gt.height, gt.width * gt.height),
                m.len(),
            )
            .into());
        }
        if !m.iter().any(|&v| v > 0.5) {
            return Err(MeshError::EmptyMask.into());
        }
    }
    Ok(())
}

/// Peak signal-to-noise ratio in dB for `[0, 1]` images: `-10 log10(MSE)`, the mean over all
/// channels of the pixels selected by `mask` (all pixels without one). Identical images give
/// `+inf`. Errors on size mismatches, non-finite values and empty masks.
pub fn psnr(pred: ImageRef, gt: ImageRef, mask: Option<&[f32]>) -> Result<f64> {
    check_pair(&pred, &gt, mask)?;
    let c = gt.channels;
    let (sum, count) = pred
        .data
        .par_chunks(c)
        .zip(gt.data.par_chunks(c))
        .enumerate()
        .filter(|(i, _)| mask.is_none_or(|m| m[*i] > 0.5))
        .map(|(_, (a, b))| {
            let s: f64 = a
                .iter()
                .zip(b)
                .map(|(&x, &y)| ((x - y) as f64).powi(2))
                .sum();
            (s, c)
        })
        .reduce(|| (0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    let mse = sum / count as f64;
    Ok(-10.0 * mse.log10())
}

/// The normalised 1-D Gaussian window: 11 taps, sigma 1.5.
fn gaussian_window() -> [f64; 11] {
    let mut w = [0.0; 11];
    for (k, v) in w.iter_mut().enumerate() {
        let x = k as f64 - 5.0;
        *v = (-x * x / (2.0 * 1.5 * 1.5)).exp();
    }
    let s: f64 = w.iter().sum();
    w.map(|v| v / s)
}

/// Separable Gaussian blur with zero padding (same size).
fn blur(img: &[f64], w: usize, h: usize, win: &[f64; 11]) -> Vec<f64> {
    let mut tmp = vec![0.0; w * h];
    tmp.par_chunks_mut(w).enumerate().for_each(|(j, row)| {
        for (i, out) in row.iter_mut().enumerate() {
            let mut s = 0.0;
            for (k, &wk) in win.iter().enumerate() {
                let x = i as isize + k as isize - 5;
                if x >= 0 && (x as usize) < w {
                    s += wk * img[j * w + x as usize];
                }
            }
            *out = s;
        }
    });
    let mut out = vec![0.0; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(j, row)| {
        for (k, &wk) in win.iter().enumerate() {
            let y = j as isize + k as isize - 5;
            if y >= 0 && (y as usize) < h {
                let src = &tmp[y as usize * w..(y as usize + 1) * w];
                for (o, &s) in row.iter_mut().zip(src) {
                    *o += wk * s;
                }
            }
        }
    });
    out
}

/// The SSIM map of one channel.
fn ssim_map(x: &[f64], y: &[f64], w: usize, h: usize) -> Vec<f64> {
    const C1: f64 = 0.01 * 0.01;
    const C2: f64 = 0.03 * 0.03;
    let win = gaussian_window();
    let mu_x = blur(x, w, h, &win);
    let mu_y = blur(y, w, h, &win);
    let xx: Vec<f64> = x.iter().map(|v| v * v).collect();
    let yy: Vec<f64> = y.iter().map(|v| v * v).collect();
    let xy: Vec<f64> = x.iter().zip(y).map(|(a, b)| a * b).collect();
    let (sxx, syy, sxy) = (
        blur(&xx, w, h, &win),
        blur(&yy, w, h, &win),
        blur(&xy, w, h, &win),
    );
    (0..w * h)
        .map(|i| {
            let (mx, my) = (mu_x[i], mu_y[i]);
            let vx = sxx[i] - mx * mx;
            let vy = syy[i] - my * my;
            let cov = sxy[i] - mx * my;
            ((2.0 * mx * my + C1) * (2.0 * cov + C2)) / ((mx * mx + my * my + C1) * (vx + vy + C2))
        })
        .collect()
}

/// Structural similarity (see the module documentation for the exact definition: 3DGS's
/// zero-padded 11x11 Gaussian window). With a mask, the mean of the SSIM map over the
/// selected pixels (the window still sees the whole image). Identical images give exactly 1.
/// Errors on size mismatches, non-finite values and empty masks.
pub fn ssim(pred: ImageRef, gt: ImageRef, mask: Option<&[f32]>) -> Result<f64> {
    check_pair(&pred, &gt, mask)?;
    let (w, h, c) = (gt.width, gt.height, gt.channels);
    let channel = |img: &ImageRef, ch: usize| -> Vec<f64> {
        img.data
            .iter()
            .skip(ch)
            .step_by(c)
            .map(|&v| v as f64)
            .collect()
    };
    let (sum, count) = (0..c)
        .map(|ch| {
            let map = ssim_map(&channel(&pred, ch), &channel(&gt, ch), w, h);
            map.iter()
                .enumerate()
                .filter(|(i, _)| mask.is_none_or(|m| m[*i] > 0.5))
                .fold((0.0, 0usize), |(s, n), (_, v)| (s + v, n + 1))
        })
        .fold((0.0, 0usize), |a, b| (a.0 + b.0, a.1 + b.1));
    Ok(sum / count as f64)
}
