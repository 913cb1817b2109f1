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
    /// When set, record per pixel the splat at which the transmittance first falls to or below
    /// this value ([`RasterState::crossing`]).
    pub crossing: Option<F>,
}

/// Forward results kept for the backward pass.
#[derive(Debug, Default)]
pub(crate) struct RasterState<F> {
    /// Final transmittance per pixel, tile-major (`tile * 256 + local`).
    pub t_final: Vec<F>,
    /// Per pixel, one past the index (in its tile's list) of the last splat blended.
    pub n_contrib: Vec<u32>,
    /// With [`RasterCtx::crossing`]: per pixel (tile-major), one past the index in its tile's
    /// list of the splat whose blend took the transmittance to or below the threshold; 0 where
    /// it stayed above. Empty otherwise.
    pub crossing: Vec<u32>,
    /// With [`RasterCtx::crossing`]: per intersection (the order of [`Bins::packed`]), 1 when
    /// the splat was blended at some pixel of that tile while the transmittance in front of it
    /// was above the threshold (PGSR's "observed"), else 0. Empty otherwise.
    pub observed: Vec<u8>,
}

/// The splat's exponent along one pixel row: `power(dx) = (ha * dx + lin) * dx + cst` with
/// `ha = -a/2`, `lin = -b dy`, `cst = -c dy^2 / 2`, so that each pixel costs two fused steps.
/// Forward and backward use this same evaluation, so their cut-off decisions agree exactly.
#[derive(Clone, Copy)]
pub(crate) struct RowPower<F> {
    ha: F,
    lin: F,
    cst: F,
}

impl<F: Real> RowPower<F> {
    #[inline(always)]
    pub(crate) fn new(s: &Splat<F>, dy: F) -> Self {
        let [a, b, c] = s.conic;
        let h = F::c(-0.5);
        Self {
            ha: h * a,
            lin: -(b * dy),
            cst: h * c * dy * dy,
        }
    }

    #[inline(always)]
    pub(crate) fn at(&self, dx: F) -> F {
        (self.ha * dx + self.lin) * dx + self.cst
    }
}

/// Alpha of a splat from its exponent: `(alpha, raw, gauss, d alpha / d capped)` where
/// `raw = opacity * gauss` before the cap and `alpha` is after cap and cut-off (0 when cut).
#[inline(always)]
fn eval_alpha<F: Real>(s: &Splat<F>, power: F, cutoff: AlphaCutoff) -> (F, F, F, F) {
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

/// Bit mask of tile columns `[x0, x1)` (tile-local).
#[inline(always)]
pub(crate) fn col_mask(x0: u32, x1: u32) -> u32 {
    ((1u64 << x1) as u32).wrapping_sub(1) & !((1u32 << x0) - 1)
}

/// The part of a splat's rectangle inside the tile `[ox, ex) x [oy, ey)`: its rows `[y0, y1)`,
/// its columns as a tile-local bit mask, and the `dx` of the tile's column 0 (column `lx` adds
/// `lx`).
#[inline(always)]
pub(crate) fn clip_to_tile<F: Real>(
    s: &Splat<F>,
    ox: u32,
    oy: u32,
    ex: u32,
    ey: u32,
) -> (u32, u32, u32, F) {
    let x0 = s.rect[0].max(ox);
    let x1 = s.rect[2].min(ex);
    let cols = col_mask(x0 - ox, x1 - ox);
    let dx0 = F::c(f64::from(ox) + 0.5) - s.xy[0];
    (s.rect[1].max(oy), s.rect[3].min(ey), cols, dx0)
}

#[inline(always)]
pub(crate) fn tile_bounds(t: usize, ctx: &RasterCtx<'_, impl Real>) -> (u32, u32, u32, u32) {
    let ox = (t as u32 % ctx.tiles_x) * TILE_SIZE;
    let oy = (t as u32 / ctx.tiles_x) * TILE_SIZE;
    let ex = (ox + TILE_SIZE).min(ctx.width);
    let ey = (oy + TILE_SIZE).min(ctx.height);
    (ox, oy, ex, ey)
}

/// Blends every tile. Returns the image (row-major `[H, W, C + 1]`, the last channel is alpha),
/// the state for the backward pass and the number of splat-pixel alpha evaluations.
pub(crate) fn rasterize<F: Real>(
    bins: &Bins<F>,
    ctx: &RasterCtx<'_, F>,
) -> (Vec<F>, RasterState<F>, u64) {
    // Common channel counts get a copy with the count known at compile time (unrolled channel
    // loops, no bounds checks); the rest take the general path.
    match ctx.channels {
        1 => rasterize_n::<F, 1>(bins, ctx),
        2 => rasterize_n::<F, 2>(bins, ctx),
        3 => rasterize_n::<F, 3>(bins, ctx),
        4 => rasterize_n::<F, 4>(bins, ctx),
        _ => rasterize_n::<F, 0>(bins, ctx),
    }
}

fn rasterize_n<F: Real, const CH: usize>(
    bins: &Bins<F>,
    ctx: &RasterCtx<'_, F>,
) -> (Vec<F>, RasterState<F>, u64) {
    let c = if CH > 0 { CH } else { ctx.channels };
    let stride = c + 1;
    let n_tiles = bins.tile_ranges.len();
    let mut tile_buf = vec![F::zero(); n_tiles * TILE_PIXELS * stride];
    let mut t_final = vec![F::one(); n_tiles * TILE_PIXELS];
    let mut n_contrib = vec![0u32; n_tiles * TILE_PIXELS];
    let mut crossing = vec![
        0u32;
        if ctx.crossing.is_some() {
            n_tiles * TILE_PIXELS
        } else {
            0
        }
    ];
    let mut crossing_chunks: Vec<&mut [u32]> = if ctx.crossing.is_some() {
        crossing.chunks_mut(TILE_PIXELS).collect()
    } else {
        (0..n_tiles).map(|_| &mut [][..]).collect()
    };
    let mut observed = vec![
        0u8;
        if ctx.crossing.is_some() {
            bins.packed.len()
        } else {
            0
        }
    ];
    let mut observed_chunks: Vec<&mut [u8]> = if ctx.crossing.is_some() {
        per_tile(&mut observed, &bins.tile_ranges, 1)
    } else {
        (0..n_tiles).map(|_| &mut [][..]).collect()
    };
    let t_min = F::c(TRANSMITTANCE_MIN);

    let evals: u64 = tile_buf
        .par_chunks_mut(TILE_PIXELS * stride)
        .zip(t_final.par_chunks_mut(TILE_PIXELS))
        .zip(n_contrib.par_chunks_mut(TILE_PIXELS))
        .zip(crossing_chunks.par_iter_mut())
        .zip(observed_chunks.par_iter_mut())
        .enumerate()
        .map(|(t, ((((img, trans), nc), cross), obs))| {
            let (ox, oy, ex, ey) = tile_bounds(t, ctx);
            // Bit x of alive[y] is set while pixel (x, y) of the tile still accumulates.
            let mut alive = [0u32; TILE_SIZE as usize];
            let full = col_mask(0, ex - ox);
            for row in alive.iter_mut().take((ey - oy) as usize) {
                *row = full;
            }
            let mut n_alive = ((ex - ox) * (ey - oy)) as usize;
            let [start, end] = bins.tile_ranges[t];
            let mut evals = 0u64;
            let (start, end) = (start as usize, end as usize);
            let tile_feats = bins.packed_features[start * c..end * c].chunks_exact(c.max(1));
            for (k, (s, feat)) in bins.packed[start..end].iter().zip(tile_feats).enumerate() {
                if n_alive == 0 {
                    break;
                }
                let (y0, y1, cols, dx0) = clip_to_tile(s, ox, oy, ex, ey);
                for y in y0..y1 {
                    let ly = (y - oy) as usize;
                    let mut bits = alive[ly] & cols;
                    if bits == 0 {
                        continue;
                    }
                    let dy = F::c(f64::from(y) + 0.5) - s.xy[1];
                    let rp = RowPower::new(s, dy);
                    while bits != 0 {
                        let lx = bits.trailing_zeros();
                        bits &= bits - 1;
                        evals += 1;
                        let dx = dx0 + F::c(f64::from(lx));
                        let power = rp.at(dx);
                        if power < s.skip_power {
                            continue;
                        }
                        let (alpha, _, _, _) = eval_alpha(s, power, ctx.cutoff);
                        if alpha <= F::zero() {
                            continue;
                        }
                        let p = ly * TILE_SIZE as usize + lx as usize;
                        let tp = trans[p];
                        let next_t = tp * (F::one() - alpha);
                        if next_t < t_min {
                            alive[ly] &= !(1u32 << lx);
                            n_alive -= 1;
                            continue;
                        }
                        let w = alpha * tp;
                        let px = &mut img[p * stride..p * stride + c];
                        for (acc, &f) in px.iter_mut().zip(feat) {
                            *acc = *acc + f * w;
                        }
                        trans[p] = next_t;
                        nc[p] = k as u32 + 1;
                        if let Some(threshold) = ctx.crossing
                            && tp > threshold
                        {
                            obs[k] = 1;
                            if next_t <= threshold {
                                cross[p] = k as u32 + 1;
                            }
                        }
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

    let image = tiles_to_rows(&tile_buf, ctx, stride);
    drop(crossing_chunks);
    drop(observed_chunks);
    (
        image,
        RasterState {
            t_final,
            n_contrib,
            crossing,
            observed,
        },
        evals,
    )
}

/// Tile-major `[tile, 256, stride]` to the row-major image `[H, W, stride]`.
pub(crate) fn tiles_to_rows<F: Real, G: Real>(
    tile_buf: &[F],
    ctx: &RasterCtx<'_, G>,
    stride: usize,
) -> Vec<F> {
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
    image
}

/// Disjoint per-tile views of a buffer holding `per_isect` values per intersection.
pub(crate) fn per_tile<'a, T>(
    buf: &'a mut [T],
    tile_ranges: &[[u32; 2]],
    per_isect: usize,
) -> Vec<&'a mut [T]> {
    let mut views = Vec::with_capacity(tile_ranges.len());
    let mut rest = buf;
    for r in tile_ranges {
        let (head, tail) = rest.split_at_mut((r[1] - r[0]) as usize * per_isect);
        views.push(head);
        rest = tail;
    }
    views
}

/// Number of gradient values stored per (tile, splat) intersection: screen mean (2), conic (3),
/// opacity (1), then the features.
pub(crate) const SLOT_FIXED: usize = 6;

/// Backward pass of [`rasterize`]: from the gradient of the image (row-major `[H, W, C + 1]`) to
/// one gradient row per intersection (layout: `d_xy[2], d_conic[3], d_opacity, d_features[C]`).
pub(crate) fn rasterize_backward<F: Real>(
    bins: &Bins<F>,
    ctx: &RasterCtx<'_, F>,
    state: &RasterState<F>,
    grad_image: &[F],
) -> Vec<F> {
    let args = (bins, ctx, state, grad_image);
    match ctx.channels {
        1 => rasterize_backward_n::<F, 1>(args),
        2 => rasterize_backward_n::<F, 2>(args),
        3 => rasterize_backward_n::<F, 3>(args),
        4 => rasterize_backward_n::<F, 4>(args),
        _ => rasterize_backward_n::<F, 0>(args),
    }
}

type BackwardArgs<'a, 'b, F> = (
    &'a Bins<F>,
    &'a RasterCtx<'b, F>,
    &'a RasterState<F>,
    &'a [F],
);

fn rasterize_backward_n<F: Real, const CH: usize>(args: BackwardArgs<'_, '_, F>) -> Vec<F> {
    let (bins, ctx, state, grad_image) = args;
    let c = if CH > 0 { CH } else { ctx.channels };
    let stride = c + 1;
    let slot = SLOT_FIXED + c;
    let mut slots = vec![F::zero(); bins.packed.len() * slot];
    let views = per_tile(&mut slots, &bins.tile_ranges, slot);
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
        // Pixels in decreasing order of their contributor count: walking the list backwards,
        // pixel p joins (its bit in `active` is set) once k < n_contrib[p].
        let mut by_nc: Vec<(u32, u8)> = Vec::with_capacity(TILE_PIXELS);
        for y in oy..ey {
            let ly = (y - oy) as usize;
            for x in ox..ex {
                let p = ly * TILE_SIZE as usize + (x - ox) as usize;
                let gi = (y as usize * w + x as usize) * stride;
                for ch in 0..c {
                    g_col[p * c + ch] = grad_image[gi + ch];
                    back[p * c + ch] = t_fin[p] * ctx.background[ch];
                }
                g_alpha[p] = grad_image[gi + c];
                if nc[p] > 0 {
                    by_nc.push((nc[p], p as u8));
                }
            }
        }
        by_nc.sort_unstable_by(|a, b| b.cmp(a));
        let mut next_pixel = 0usize;
        let mut active = [0u32; TILE_SIZE as usize];
        let max_nc = by_nc.first().map_or(0, |e| e.0);
        let (start, end) = (start as usize, end as usize);
        let tile_splats = &bins.packed[start..end];
        let tile_feats = &bins.packed_features[start * c..end * c];
        for k in (0..(max_nc as usize).min(end - start)).rev() {
            while next_pixel < by_nc.len() && by_nc[next_pixel].0 as usize > k {
                let p = by_nc[next_pixel].1 as usize;
                active[p / TILE_SIZE as usize] |= 1 << (p % TILE_SIZE as usize);
                next_pixel += 1;
            }
            let s = &tile_splats[k];
            let feat = &tile_feats[k * c..(k + 1) * c];
            let (y0, y1, cols, dx0) = clip_to_tile(s, ox, oy, ex, ey);
            let [ca, cb, cc] = s.conic;
            let row = &mut out[k * slot..(k + 1) * slot];
            let (mut du, mut dv, mut da, mut db, mut dc, mut dop) = (
                F::zero(),
                F::zero(),
                F::zero(),
                F::zero(),
                F::zero(),
                F::zero(),
            );
            for y in y0..y1 {
                let ly = (y - oy) as usize;
                let mut bits = active[ly] & cols;
                if bits == 0 {
                    continue;
                }
                let dy = F::c(f64::from(y) + 0.5) - s.xy[1];
                let rp = RowPower::new(s, dy);
                while bits != 0 {
                    let lx = bits.trailing_zeros();
                    bits &= bits - 1;
                    let p = ly * TILE_SIZE as usize + lx as usize;
                    let dx = dx0 + F::c(f64::from(lx));
                    let power = rp.at(dx);
                    if power < s.skip_power {
                        continue;
                    }
                    let (alpha, raw, gauss, dalpha_dcapped) = eval_alpha(s, power, ctx.cutoff);
                    if alpha <= F::zero() {
                        continue;
                    }
                    let inv_om = one / (one - alpha);
                    let t_i = trans[p] * inv_om;
                    let w_i = alpha * t_i;
                    let mut d_alpha = g_alpha[p] * t_fin[p] * inv_om;
                    for ch in 0..c {
                        let gcol = g_col[p * c + ch];
                        row[SLOT_FIXED + ch] = row[SLOT_FIXED + ch] + w_i * gcol;
                        d_alpha = d_alpha + gcol * (t_i * feat[ch] - back[p * c + ch] * inv_om);
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
