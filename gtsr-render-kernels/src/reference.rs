//! An independent brute-force renderer: every pixel against every Gaussian, in `f64`, with no
//! tiles, no bounding rectangles and no shared code with [`crate::cpu`] beyond the constants
//! that define the conventions. The kernels are tested against it.

use rayon::prelude::*;

use crate::config::{
    ALPHA_MAX, ALPHA_MIN, AlphaCutoff, FRUSTUM_MARGIN, QUAT_MIN_NORM2, SplatConfig,
    TRANSMITTANCE_MIN,
};
use crate::cpu::HostGaussians;

struct Projected {
    depth: f64,
    index: usize,
    mean: [f64; 2],
    inv: [[f64; 2]; 2],
    opacity: f64,
}

fn mat3_mul(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
}

fn mat3_t(a: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| std::array::from_fn(|j| a[j][i]))
}

fn project(g: &HostGaussians<'_, f64>, i: usize, cfg: &SplatConfig) -> Option<Projected> {
    let cam = &cfg.camera;
    let m = &g.means[3 * i..3 * i + 3];
    let q = &g.quats[4 * i..4 * i + 4];
    let s = &g.scales[3 * i..3 * i + 3];
    let o = g.opacities[i];
    let off = &g.xy_offsets[2 * i..2 * i + 2];
    let c = cfg.background.len();
    let f = &g.features[c * i..c * (i + 1)];
    if m.iter()
        .chain(f)
        .chain(q)
        .chain(s)
        .chain(off)
        .chain(std::iter::once(&o))
        .any(|v| !v.is_finite())
    {
        return None;
    }
    let w = cam.rotation;
    let p: [f64; 3] =
        std::array::from_fn(|r| (0..3).map(|k| w[r][k] * m[k]).sum::<f64>() + cam.translation[r]);
    if !(p[2] >= cam.near && p[2] <= cam.far) {
        return None;
    }
    let n2: f64 = q.iter().map(|v| v * v).sum();
    if n2 < QUAT_MIN_NORM2 {
        return None;
    }
    let n = n2.sqrt();
    let (qw, qx, qy, qz) = (q[0] / n, q[1] / n, q[2] / n, q[3] / n);
    // Rotation as the product of the quaternion's left and right multiplication matrices.
    let l = [
        [qw, -qx, -qy, -qz],
        [qx, qw, -qz, qy],
        [qy, qz, qw, -qx],
        [qz, -qy, qx, qw],
    ];
    let r = [
        [qw, -qx, -qy, -qz],
        [qx, qw, qz, -qy],
        [qy, -qz, qw, qx],
        [qz, qy, -qx, qw],
    ];
    // q v q* = L(q) R(q)^T v for pure quaternions v; take the 3x3 lower-right block.
    let rot: [[f64; 3]; 3] = std::array::from_fn(|a| {
        std::array::from_fn(|b| (0..4).map(|k| l[a + 1][k] * r[b + 1][k]).sum())
    });
    let s2 = [
        [s[0] * s[0], 0.0, 0.0],
        [0.0, s[1] * s[1], 0.0],
        [0.0, 0.0, s[2] * s[2]],
    ];
    let sigma = mat3_mul(&mat3_mul(&rot, &s2), &mat3_t(&rot));
    let sigma_c = mat3_mul(&mat3_mul(&w, &sigma), &mat3_t(&w));
    let (wf, hf) = (f64::from(cam.width), f64::from(cam.height));
    let x_lim = (
        (-FRUSTUM_MARGIN * wf - cam.cx) / cam.fx,
        ((1.0 + FRUSTUM_MARGIN) * wf - cam.cx) / cam.fx,
    );
    let y_lim = (
        (-FRUSTUM_MARGIN * hf - cam.cy) / cam.fy,
        ((1.0 + FRUSTUM_MARGIN) * hf - cam.cy) / cam.fy,
    );
    let z = p[2];
    let tx = (p[0] / z).clamp(x_lim.0, x_lim.1) * z;
    let ty = (p[1] / z).clamp(y_lim.0, y_lim.1) * z;
    let j = [
        [cam.fx / z, 0.0, -cam.fx * tx / (z * z)],
        [0.0, cam.fy / z, -cam.fy * ty / (z * z)],
    ];
    let cov: [[f64; 2]; 2] = std::array::from_fn(|a| {
        std::array::from_fn(|b| {
            let mut acc = 0.0;
            for k in 0..3 {
                for l in 0..3 {
                    acc += j[a][k] * sigma_c[k][l] * j[b][l];
                }
            }
            acc + if a == b { cfg.blur_px2 } else { 0.0 }
        })
    });
    let det = cov[0][0] * cov[1][1] - cov[0][1] * cov[1][0];
    if !det.is_finite() || det <= 0.0 {
        return None;
    }
    let inv = [
        [cov[1][1] / det, -cov[0][1] / det],
        [-cov[1][0] / det, cov[0][0] / det],
    ];
    Some(Projected {
        depth: z,
        index: i,
        mean: [
            cam.fx * p[0] / z + cam.cx + off[0],
            cam.fy * p[1] / z + cam.cy + off[1],
        ],
        inv,
        opacity: o,
    })
}

/// The Gaussians of `g` that project, in blending order (depth, then index).
fn depth_sorted(g: &HostGaussians<'_, f64>, cfg: &SplatConfig) -> Vec<Projected> {
    let mut list: Vec<Projected> = (0..g.len()).filter_map(|i| project(g, i, cfg)).collect();
    list.sort_by(|a, b| a.depth.total_cmp(&b.depth).then(a.index.cmp(&b.index)));
    list
}

/// Walks `list` front to back at the pixel centre `(x, y)`, calling `blend(splat, alpha, t)`
/// (`t`: the transmittance before it) for every splat blended, until `blend` returns false or
/// the pixel would saturate. Returns the transmittance left.
fn walk(
    list: &[Projected],
    cutoff: AlphaCutoff,
    x: f64,
    y: f64,
    mut blend: impl FnMut(&Projected, f64, f64) -> bool,
) -> f64 {
    let mut t = 1.0;
    for s in list {
        let d = [x - s.mean[0], y - s.mean[1]];
        let q = d[0] * (s.inv[0][0] * d[0] + s.inv[0][1] * d[1])
            + d[1] * (s.inv[1][0] * d[0] + s.inv[1][1] * d[1]);
        let mut alpha = (s.opacity * (-0.5 * q).exp()).min(ALPHA_MAX);
        if alpha < ALPHA_MIN {
            continue;
        }
        if cutoff == AlphaCutoff::Smooth {
            let u = ((alpha - ALPHA_MIN) / ALPHA_MIN).min(1.0);
            alpha *= u * u * (3.0 - 2.0 * u);
        }
        let next = t * (1.0 - alpha);
        if next < TRANSMITTANCE_MIN {
            break;
        }
        let go_on = blend(s, alpha, t);
        t = next;
        if !go_on {
            break;
        }
    }
    t
}

/// Renders `g` pixel by pixel. Returns row-major `[H, W, C + 1]` (features, then alpha).
pub fn render_reference(g: &HostGaussians<'_, f64>, cfg: &SplatConfig) -> Vec<f64> {
    let c = cfg.background.len();
    let list = depth_sorted(g, cfg);
    let w = cfg.camera.width as usize;
    let mut out = vec![0.0; w * cfg.camera.height as usize * (c + 1)];
    out.par_chunks_mut(c + 1).enumerate().for_each(|(pix, px)| {
        let (x, y) = ((pix % w) as f64 + 0.5, (pix / w) as f64 + 0.5);
        let t = walk(&list, cfg.cutoff, x, y, |s, alpha, t| {
            let f = &g.features[s.index * c..(s.index + 1) * c];
            for (acc, fk) in px.iter_mut().zip(f) {
                *acc += fk * alpha * t;
            }
            true
        });
        for (acc, b) in px.iter_mut().zip(&cfg.background) {
            *acc += t * b;
        }
        px[c] = 1.0 - t;
    });
    out
}

/// Brute-force counterpart of [`crate::cpu::crossing_features`]: per pixel, the features of the
/// Gaussian whose blend takes the transmittance to or below `threshold` (row-major `[H, W, C]`,
/// 0 where it stays above), the `[H, W]` 0/1 map of where it does, and per Gaussian whether it
/// was blended at some pixel while the transmittance in front of it was above `threshold`.
pub fn crossing_reference(
    g: &HostGaussians<'_, f64>,
    cfg: &SplatConfig,
    threshold: f64,
) -> (Vec<f64>, Vec<f64>, Vec<bool>) {
    let c = cfg.background.len();
    let list = depth_sorted(g, cfg);
    let (w, h) = (cfg.camera.width as usize, cfg.camera.height as usize);
    let mut feats = vec![0.0; w * h * c];
    let mut found = vec![0.0; w * h];
    let observed = feats
        .par_chunks_mut(c)
        .zip(found.par_iter_mut())
        .enumerate()
        .map(|(pix, (px, hit))| {
            let (x, y) = ((pix % w) as f64 + 0.5, (pix / w) as f64 + 0.5);
            let mut seen = Vec::new();
            walk(&list, cfg.cutoff, x, y, |s, alpha, t| {
                seen.push(s.index);
                if t * (1.0 - alpha) > threshold {
                    return true;
                }
                px.copy_from_slice(&g.features[s.index * c..(s.index + 1) * c]);
                *hit = 1.0;
                false
            });
            seen
        })
        .fold(
            || vec![false; g.len()],
            |mut acc, seen| {
                for i in seen {
                    acc[i] = true;
                }
                acc
            },
        )
        .reduce(
            || vec![false; g.len()],
            |a, b| a.iter().zip(&b).map(|(x, y)| *x || *y).collect(),
        );
    (feats, found, observed)
}
