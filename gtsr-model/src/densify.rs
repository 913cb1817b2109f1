//! Adaptive density control (3DGS), per set: clone small Gaussians and split large ones whose
//! mean screen-space gradient exceeds the threshold, prune transparent (and, after the first
//! opacity reset, oversized) ones, and reset opacities. Works on host copies; the caller moves
//! the optimiser state with the returned row map.

use rand::RngExt;

use crate::config::DensifyConfig;
use crate::gaussians::{HostSet, ParamKind, logit};

/// Screen-space gradient statistics gathered between densifications.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DensifyStats {
    /// Sum over visible steps of `|dL/d mean2d|` in NDC units.
    pub grad_sum: Vec<f32>,
    /// Number of steps each Gaussian was visible.
    pub count: Vec<f32>,
    /// Largest screen radius seen (pixels).
    pub max_radius: Vec<f32>,
}

impl DensifyStats {
    /// Zeroed statistics for `n` Gaussians.
    pub fn new(n: usize) -> Self {
        DensifyStats {
            grad_sum: vec![0.0; n],
            count: vec![0.0; n],
            max_radius: vec![0.0; n],
        }
    }

    /// The rows `keep` (the statistics of the Gaussians that survive a pruning).
    pub fn select(&self, keep: &[usize]) -> DensifyStats {
        let pick = |v: &[f32]| keep.iter().map(|&i| v[i]).collect();
        DensifyStats {
            grad_sum: pick(&self.grad_sum),
            count: pick(&self.count),
            max_radius: pick(&self.max_radius),
        }
    }

    /// These statistics followed by zeroed ones for `added` new Gaussians.
    pub fn with_new_rows(&self, added: usize) -> DensifyStats {
        let grow = |v: &[f32]| {
            let mut v = v.to_vec();
            v.resize(v.len() + added, 0.0);
            v
        };
        DensifyStats {
            grad_sum: grow(&self.grad_sum),
            count: grow(&self.count),
            max_radius: grow(&self.max_radius),
        }
    }

    /// Adds one step: `grad_px` `[N, 2]` row-major (`dL/d mean2d` in pixels), the screen radii,
    /// and the image width (3DGS measures the gradient in NDC: `px * W / 2`).
    pub fn add(&mut self, grad_px: &[f32], radii: &[f32], width: usize, height: usize) {
        let (sx, sy) = (0.5 * width as f32, 0.5 * height as f32);
        for (i, r) in radii.iter().enumerate() {
            if *r > 0.0 {
                let (gx, gy) = (grad_px[2 * i] * sx, grad_px[2 * i + 1] * sy);
                let g = (gx * gx + gy * gy).sqrt();
                if g.is_finite() {
                    self.grad_sum[i] += g;
                    self.count[i] += 1.0;
                }
                self.max_radius[i] = self.max_radius[i].max(*r);
            }
        }
    }
}

/// What one densification did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DensifyReport {
    /// Gaussians cloned.
    pub cloned: usize,
    /// Gaussians split (each into two).
    pub split: usize,
    /// Gaussians pruned.
    pub pruned: usize,
}

/// The new set, the old rows kept (in order) and how many new rows follow them.
pub struct Densified {
    /// The new host set.
    pub set: HostSet,
    /// Old row indices kept, in the order they appear in `set`.
    pub keep: Vec<usize>,
    /// New rows appended after the kept ones (zero optimiser state).
    pub added: usize,
    /// Counts.
    pub report: DensifyReport,
}

/// Row-major rotation matrix of a quaternion `(w, x, y, z)` (normalised here).
pub fn quat_matrix(q: &[f32]) -> [[f32; 3]; 3] {
    let n = (q.iter().map(|v| v * v).sum::<f32>()).sqrt().max(1e-12);
    let (w, x, y, z) = (q[0] / n, q[1] / n, q[2] / n, q[3] / n);
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

fn normal_sample(rng: &mut impl RngExt) -> f32 {
    // Box-Muller.
    let u1: f32 = rng.random_range(f32::EPSILON..1.0);
    let u2: f32 = rng.random_range(0.0..1.0);
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f32::consts::PI * u2).cos()
}

/// Clones, splits and prunes `set` from `stats`.
///
/// `extent` is the scene extent (split versus clone by `percent_dense * extent`); `prune_big`
/// also prunes Gaussians larger than `0.1 * extent` in the world (3DGS, after the first
/// opacity reset); `cap` bounds the size of the result (new Gaussians go to the largest
/// gradients first).
pub fn densify_and_prune(
    set: &HostSet,
    stats: &DensifyStats,
    cfg: &DensifyConfig,
    extent: f64,
    prune_big: bool,
    cap: usize,
    rng: &mut impl RngExt,
) -> Densified {
    let n = set.n;
    let (op, _) = set.column(ParamKind::Opacity).expect("opacity");
    let (ls, _) = set.column(ParamKind::LogScales).expect("scales");
    let max_scale = |i: usize| {
        ls[3 * i..3 * i + 3]
            .iter()
            .fold(f32::NEG_INFINITY, |a, b| a.max(*b))
            .exp()
    };
    let min_logit = logit(cfg.min_opacity) as f32;
    let prune: Vec<bool> = (0..n)
        .map(|i| {
            op[i] < min_logit
                || !op[i].is_finite()
                || (prune_big && f64::from(max_scale(i)) > 0.1 * extent)
                || set.row(i).iter().flatten().any(|v| !v.is_finite())
        })
        .collect();
    let mut candidates: Vec<(f32, usize)> = (0..n)
        .filter(|&i| !prune[i] && stats.count[i] > 0.0)
        .map(|i| (stats.grad_sum[i] / stats.count[i], i))
        .filter(|(g, _)| f64::from(*g) >= cfg.grad_threshold)
        .collect();
    candidates.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    let kept_base = prune.iter().filter(|p| !**p).count();
    let mut room = cap.saturating_sub(kept_base);
    let mut clone = vec![false; n];
    let mut split = vec![false; n];
    for &(_, i) in &candidates {
        if room == 0 {
            break;
        }
        if f64::from(max_scale(i)) > cfg.percent_dense * extent {
            split[i] = true; // replaces one by two
        } else {
            clone[i] = true;
        }
        room -= 1;
    }
    let keep: Vec<usize> = (0..n).filter(|&i| !prune[i] && !split[i]).collect();
    let mut extra = set.empty_like();
    let shrink = (1.6f32).ln();
    for (i, _) in clone.iter().enumerate().filter(|(_, c)| **c) {
        extra.push_row(&set.row(i));
    }
    for (i, _) in split.iter().enumerate().filter(|(_, s)| **s) {
        let row = set.row(i);
        let idx = |k: ParamKind| {
            set.columns
                .iter()
                .position(|(c, _, _)| *c == k)
                .expect("column")
        };
        let (im, ir, is) = (
            idx(ParamKind::Means),
            idx(ParamKind::Rotations),
            idx(ParamKind::LogScales),
        );
        let r = quat_matrix(&row[ir]);
        let s: Vec<f32> = row[is].iter().map(|v| v.exp()).collect();
        for _ in 0..2 {
            let z: [f32; 3] = std::array::from_fn(|k| normal_sample(rng) * s[k]);
            let mut child = row.clone();
            for a in 0..3 {
                child[im][a] += (0..3).map(|b| r[a][b] * z[b]).sum::<f32>();
            }
            for v in child[is].iter_mut() {
                *v -= shrink;
            }
            extra.push_row(&child);
        }
    }
    let report = DensifyReport {
        cloned: clone.iter().filter(|c| **c).count(),
        split: split.iter().filter(|c| **c).count(),
        pruned: prune.iter().filter(|c| **c).count(),
    };
    let added = extra.n;
    Densified {
        set: set.reindex(&keep, Some(&extra)),
        keep,
        added,
        report,
    }
}

/// 3DGS opacity reset: every opacity above `ceiling` is set to `ceiling`.
pub fn reset_opacity(set: &mut HostSet, ceiling: f64) {
    let cap = logit(ceiling) as f32;
    if let Some(v) = set.column_mut(ParamKind::Opacity) {
        for x in v.iter_mut() {
            *x = x.min(cap);
        }
    }
}
