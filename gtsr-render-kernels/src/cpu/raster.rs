//! Front-to-back blending per tile and its backward pass.
//!
//! Each tile keeps its 256 pixels' state (transmittance, accumulated features, done flags) in
//! local arrays and walks its depth-sorted splat list once; for every splat it visits only the
//! pixels of the tile that lie inside the splat's opacity-aware rectangle. Per pixel the order is
//! still front to back, so the result equals the per-pixel formulation of 3DGS exactly.

use rayon::prelude::*;

use super::bin::Bins;
use super::project::Splat;
use crate::config::{ALPHA_MAX, ALPHA_MIN, AlphaCutoff, TILE_PIXELS, TILE_SIZE, TRANSMITTANCE_MIN};
use crate::scalar::Real;

/// Image geometry and blending settings for one raster pass.
#[derive(Clone, Copy, Debug)]
pub(crate) struct RasterCtx<'a, F> {
    pub width: u32,
    pub height: u32,
    pub tiles_x: u32,
    pub channels: usize,
    pub background: &'a [F],
    pub cutoff: AlphaCutoff,
}

/// Forward results kept for the backward pass.
#[derive(Debug, Default)]
pub(crate) struct RasterState<F> {
    /// Final transmittance per pixel, tile-major (`tile * 256 + local`).
    pub t_final: Vec<F>,
    /// Per pixel, one past the index (in its tile's list) of the last splat blended.
    pub n_contrib: Vec<u32>,
}

/// Alpha of a splat at offset `(dx, dy)` from its mean: `(alpha, raw, gauss)` where `raw =
/// opacity * gauss` before the cap and `alpha` after cap and cut-off (0 when cut).
#[inline(always)]
fn eval_alpha<F: Real>(s: &Splat<F>, dx: F, dy: F, cutoff: AlphaCutoff) -> (F, F, F, F) {
    let [a, b, c] = s.conic;
    let power = F::c(-0.5) * (a * dx * dx + c * dy * dy) - b * dx * dy;
    let gauss = power.exp();
    let raw = s.opacity * gauss;
    let capped = raw.min(F::c(ALPHA_MAX));
    let amin = F::c(ALPHA_MIN);
    if capped < amin {
        return (F::zero(), raw, gauss, F::zero());
    }
    match cutoff {
        AlphaCutoff::Hard => (capped, raw, gauss, F::one()),
        AlphaCutoff::Smooth => {
            let t = (capped - amin) / amin;
            if t >= F::one() {
                (capped, raw, gauss, F::one())
            } else {
                // w = t^2 (3 - 2t); d(alpha w)/d alpha = w + alpha * 6 t (1 - t) / amin.
                let w = t * t * (F::c(3.0) - F::c(2.0) * t);
                let dw = F::c(6.0) * t * (F::one() - t) / amin;
                (capped * w, raw, gauss, w + capped * dw)
            }
        }
    }
}

#[inline(always)]
fn tile_bounds(t: usize, ctx: &RasterCtx<'_, impl Real>) -> (u32, u32, u32, u32) {
    let ox = (t as u32 % ctx.tiles_x) * TILE_SIZE;
    let oy = (t as u32 / ctx.tiles_x) * TILE_SIZE;
    let ex = (ox + TILE_SIZE).min(ctx.width);
    let ey = (oy + TILE_SIZE).min(ctx.height);
    (ox, oy, ex, ey)
}

/// Blends every tile. Returns the image (row-major `[H, W, C + 1]`, the last channel is alpha),
/// the state for the backward pass and the number of splat-pixel alpha evaluations.
pub(crate) fn rasterize<F: Real>(
    splats: &[Option<Splat<F>>],
    features: &[F],
    bins: &Bins,
    ctx: &RasterCtx<'_, F>,
) -> (Vec<F>, RasterState<F>, u64) {
    let c = ctx.channels;
    let stride = c + 1;
    let n_tiles = bins.tile_ranges.len();
    let mut tile_buf = vec![F::zero(); n_tiles * TILE_PIXELS * stride];
    let mut t_final = vec![F::one(); n_tiles * TILE_PIXELS];
    let mut n_contrib = vec![0u32; n_tiles * TILE_PIXELS];
    let t_min = F::c(TRANSMITTANCE_MIN);

    let evals: u64 = tile_buf
        .par_chunks_mut(TILE_PIXELS * stride)
        .zip(t_final.par_chunks_mut(TILE_PIXELS))
        .zip(n_contrib.par_chunks_mut(TILE_PIXELS))
        .enumerate()
        .map(|(t, ((img, trans), nc))| {
            let (ox, oy, ex, ey) = tile_bounds(t, ctx);
            let mut done = [true; TILE_PIXELS];
            let mut alive = 0usize;
            for y in oy..ey {
                for x in ox..ex {
                    done[((y - oy) * TILE_SIZE + (x - ox)) as usize] = false;
                    alive += 1;
                }
            }
            let [start, end] = bins.tile_ranges[t];
            let mut evals = 0u64;
            for (k, &g) in bins.ids[start as usize..end as usize].iter().enumerate() {
                if alive == 0 {
                    break;
                }
                let s = splats[g as usize].as_ref().expect("binned splats are visible");
                let feat = &features[g as usize * c..(g as usize + 1) * c];
                let x0 = s.rect[0].max(ox);
                let x1 = s.rect[2].min(ex);
                let y0 = s.rect[1].max(oy);
                let y1 = s.rect[3].min(ey);
                for y in y0..y1 {
                    let dy = F::c(f64::from(y) + 0.5) - s.xy[1];
                    for x in x0..x1 {
                        let p = ((y - oy) * TILE_SIZE + (x - ox)) as usize;
                        if done[p] {
                            continue;
                        }
                        evals += 1;
                        let dx = F::c(f64::from(x) + 0.5) - s.xy[0];
                        let (alpha, _, _, _) = eval_alpha(s, dx, dy, ctx.cutoff);
                        if alpha <= F::zero() {
                            continue;
                        }
                        let tp = trans[p];
                        let next_t = tp * (F::one() - alpha);
                        if next_t < t_min {
                            done[p] = true;
                            alive -= 1;
                            continue;
                        }
                        let w = alpha * tp;
                        let px = &mut img[p * stride..p * stride + c];
                        for (acc, &f) in px.iter_mut().zip(feat) {
                            *acc = *acc + f * w;
                        }
                        trans[p] = next_t;
                        nc[p] = k as u32 + 1;
                    }
                }
            }
            for p in 0..TILE_PIXELS {
                let tp = trans[p];
                for ch in 0..c {
                    img[p * stride + ch] = img[p * stride + ch] + tp * ctx.background[ch];
                }
                img[p * stride + c] = F::one() - tp;
            }
            evals
        })
        .sum();

    // Tile-major -> row-major.
    let w = ctx.width as usize;
    let mut image = vec![F::zero(); ctx.height as usize * w * stride];
    image
        .par_chunks_mut(w * stride)
        .enumerate()
        .for_each(|(y, row)| {
            let ty = y / TILE_SIZE as usize;
            let ly = y % TILE_SIZE as usize;
            for x in 0..w {
                let t = ty * ctx.tiles_x as usize + x / TILE_SIZE as usize;
                let p = t * TILE_PIXELS + ly * TILE_SIZE as usize + x % TILE_SIZE as usize;
                row[x * stride..(x + 1) * stride]
                    .copy_from_slice(&tile_buf[p * stride..(p + 1) * stride]);
            }
        });
    (
        image,
        RasterState {
            t_final,
            n_contrib,
        },
        evals,
    )
}

/// Number of gradient values stored per (tile, splat) intersection: screen mean (2), conic (3),
/// opacity (1), then the features.
pub(crate) const SLOT_FIXED: usize = 6;

/// Backward pass of [`rasterize`]: from the gradient of the image (row-major `[H, W, C + 1]`) to
/// one gradient row per intersection (layout: `d_xy[2], d_conic[3], d_opacity, d_features[C]`).
pub(crate) fn rasterize_backward<F: Real>(
    splats: &[Option<Splat<F>>],
    features: &[F],
    bins: &Bins,
    ctx: &RasterCtx<'_, F>,
    state: &RasterState<F>,
    grad_image: &[F],
) -> Vec<F> {
    let c = ctx.channels;
    let stride = c + 1;
    let slot = SLOT_FIXED + c;
    let mut slots = vec![F::zero(); bins.ids.len() * slot];
    // Disjoint per-tile views of the slot buffer.
    let mut views: Vec<&mut [F]> = Vec::with_capacity(bins.tile_ranges.len());
    let mut rest: &mut [F] = &mut slots;
    for r in &bins.tile_ranges {
        let (head, tail) = rest.split_at_mut((r[1] - r[0]) as usize * slot);
        views.push(head);
        rest = tail;
    }
    let w = ctx.width as usize;
    let one = F::one();
    let half = F::c(0.5);

    views.into_par_iter().enumerate().for_each(|(t, out)| {
        let [start, end] = bins.tile_ranges[t];
        if start == end {
            return;
        }
        let (ox, oy, ex, ey) = tile_bounds(t, ctx);
        let base = t * TILE_PIXELS;
        let t_fin = &state.t_final[base..base + TILE_PIXELS];
        let nc = &state.n_contrib[base..base + TILE_PIXELS];
        let mut trans = [F::zero(); TILE_PIXELS];
        trans.copy_from_slice(t_fin);
        let mut back = vec![F::zero(); TILE_PIXELS * c];
        let mut g_col = vec![F::zero(); TILE_PIXELS * c];
        let mut g_alpha = [F::zero(); TILE_PIXELS];
        let mut max_nc = 0u32;
        for y in oy..ey {
            for x in ox..ex {
                let p = ((y - oy) * TILE_SIZE + (x - ox)) as usize;
                let gi = (y as usize * w + x as usize) * stride;
                for ch in 0..c {
                    g_col[p * c + ch] = grad_image[gi + ch];
                    back[p * c + ch] = t_fin[p] * ctx.background[ch];
                }
                g_alpha[p] = grad_image[gi + c];
                max_nc = max_nc.max(nc[p]);
            }
        }
        let ids = &bins.ids[start as usize..end as usize];
        for k in (0..(max_nc as usize).min(ids.len())).rev() {
            let g = ids[k] as usize;
            let s = splats[g].as_ref().expect("binned splats are visible");
            let feat = &features[g * c..(g + 1) * c];
            let x0 = s.rect[0].max(ox);
            let x1 = s.rect[2].min(ex);
            let y0 = s.rect[1].max(oy);
            let y1 = s.rect[3].min(ey);
            let [ca, cb, cc] = s.conic;
            let row = &mut out[k * slot..(k + 1) * slot];
            let (mut du, mut dv, mut da, mut db, mut dc, mut dop) =
                (F::zero(), F::zero(), F::zero(), F::zero(), F::zero(), F::zero());
            for y in y0..y1 {
                let dy = F::c(f64::from(y) + 0.5) - s.xy[1];
                for x in x0..x1 {
                    let p = ((y - oy) * TILE_SIZE + (x - ox)) as usize;
                    if k as u32 >= nc[p] {
                        continue;
                    }
                    let dx = F::c(f64::from(x) + 0.5) - s.xy[0];
                    let (alpha, raw, gauss, dalpha_dcapped) = eval_alpha(s, dx, dy, ctx.cutoff);
                    if alpha <= F::zero() {
                        continue;
                    }
                    let om = one - alpha;
                    let t_i = trans[p] / om;
                    let w_i = alpha * t_i;
                    let mut d_alpha = g_alpha[p] * t_fin[p] / om;
                    for ch in 0..c {
                        let gcol = g_col[p * c + ch];
                        row[SLOT_FIXED + ch] = row[SLOT_FIXED + ch] + w_i * gcol;
                        d_alpha = d_alpha + gcol * (t_i * feat[ch] - back[p * c + ch] / om);
                        back[p * c + ch] = back[p * c + ch] + feat[ch] * w_i;
                    }
                    trans[p] = t_i;
                    if raw > F::c(ALPHA_MAX) {
                        continue; // capped: alpha does not depend on the parameters.
                    }
                    let d_raw = d_alpha * dalpha_dcapped;
                    dop = dop + d_raw * gauss;
                    let d_power = d_raw * raw;
                    du = du + d_power * (ca * dx + cb * dy);
                    dv = dv + d_power * (cb * dx + cc * dy);
                    da = da - half * d_power * dx * dx;
                    db = db - d_power * dx * dy;
                    dc = dc - half * d_power * dy * dy;
                }
            }
            row[0] = du;
            row[1] = dv;
            row[2] = da;
            row[3] = db;
            row[4] = dc;
            row[5] = dop;
        }
    });
    slots
}
