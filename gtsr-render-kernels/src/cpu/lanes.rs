//! The f32 blend and its backward pass over 16-pixel tile rows ("lanes"), compiled once per
//! instruction set and chosen at run time ([`BlendPath`]).
//!
//! A tile row is 16 pixels, which is one AVX-512 vector of f32 or two AVX2 vectors. For every
//! splat and row the code evaluates all 16 pixels branch-free (lanes outside the splat's
//! rectangle or already saturated are masked by selects), so the compiler turns the row loops
//! into vector code. The per-pixel state of a tile lives in planes (`[channel][256]`).
//!
//! The exponential is [`exp_lanes`], a polynomial built from additions, multiplications and bit
//! operations only; no step is fused or reassociated, so the scalar fallback, AVX2 and AVX-512
//! give bit-identical results. The generic per-pixel code ([`super::raster`], which f64 uses)
//! differs from this only through the exponential (about one unit in the last place).

use std::any::Any;
use std::sync::OnceLock;

use pulp::{Simd, WithSimd};
use rayon::prelude::*;

use super::bin::Bins;
use super::project::Splat;
use super::raster::{
    RasterCtx, RasterState, RowPower, SLOT_FIXED, clip_to_tile, col_mask, per_tile, tile_bounds,
};
use crate::config::{ALPHA_MAX, ALPHA_MIN, TILE_PIXELS, TILE_SIZE, TRANSMITTANCE_MIN};
use crate::scalar::Real;

/// Pixels per tile row, the lane count of the row kernels.
const LANES: usize = TILE_SIZE as usize;

/// Pixels evaluated together: a row is walked in chunks of this many, and chunks without a
/// live pixel are skipped (splats a few pixels wide are the common case).
const CHUNK: usize = 8;
const CHUNK_MASK: u32 = (1 << CHUNK) - 1;

/// Column offset of each lane.
const LANE_X: [f32; LANES] = [
    0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0, 12.0, 13.0, 14.0, 15.0,
];

/// Which implementation blends f32 splats. f64 always takes [`BlendPath::PerPixel`]; so do the
/// smooth alpha cut-off ([`crate::AlphaCutoff::Smooth`]) and crossing renders.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BlendPath {
    /// The generic per-pixel code: visits only the live pixels of each splat's rectangle.
    PerPixel,
    /// 16-lane rows without SIMD target features (the portable fallback of the lane kernels).
    LanesScalar,
    /// 16-lane rows compiled for x86-64-v3 (AVX2, FMA).
    LanesAvx2,
    /// 16-lane rows compiled for x86-64-v4 (AVX-512 F/BW/CD/DQ/VL).
    LanesAvx512,
}

impl BlendPath {
    /// Every path, slowest first.
    pub const ALL: [BlendPath; 4] = [
        BlendPath::PerPixel,
        BlendPath::LanesScalar,
        BlendPath::LanesAvx2,
        BlendPath::LanesAvx512,
    ];

    /// Whether this CPU can run the path.
    pub fn available(self) -> bool {
        match self {
            BlendPath::PerPixel | BlendPath::LanesScalar => true,
            #[cfg(target_arch = "x86_64")]
            BlendPath::LanesAvx2 => pulp::x86::V3::is_available(),
            #[cfg(target_arch = "x86_64")]
            BlendPath::LanesAvx512 => pulp::x86::V4::is_available(),
            #[cfg(not(target_arch = "x86_64"))]
            BlendPath::LanesAvx2 | BlendPath::LanesAvx512 => false,
        }
    }

    /// The fastest path this CPU can run.
    pub fn best() -> Self {
        [BlendPath::LanesAvx512, BlendPath::LanesAvx2]
            .into_iter()
            .find(|p| p.available())
            .unwrap_or(BlendPath::LanesScalar)
    }

    /// The path [`super::forward`] uses: `GTSR_BLEND` (`per-pixel`, `scalar`, `avx2` or
    /// `avx512`) when it is set and this CPU can run it, else [`BlendPath::best`]. Read once.
    pub fn default_path() -> Self {
        static PATH: OnceLock<BlendPath> = OnceLock::new();
        *PATH.get_or_init(|| {
            std::env::var("GTSR_BLEND")
                .ok()
                .and_then(|v| BlendPath::parse(&v))
                .filter(|p| p.available())
                .unwrap_or_else(BlendPath::best)
        })
    }

    /// Parses the names of `GTSR_BLEND`.
    pub fn parse(name: &str) -> Option<Self> {
        match name.trim() {
            "per-pixel" => Some(BlendPath::PerPixel),
            "scalar" => Some(BlendPath::LanesScalar),
            "avx2" => Some(BlendPath::LanesAvx2),
            "avx512" => Some(BlendPath::LanesAvx512),
            _ => None,
        }
    }

    /// Runs `op` compiled for this path's instruction set (the portable build for
    /// `PerPixel` and `LanesScalar`, and where the CPU lacks the set).
    #[inline(always)]
    pub(crate) fn run<Op: WithSimd>(self, op: Op) -> Op::Output {
        #[cfg(target_arch = "x86_64")]
        match self {
            BlendPath::LanesAvx512 => {
                if let Some(simd) = pulp::x86::V4::try_new() {
                    return Simd::vectorize(simd, op);
                }
            }
            BlendPath::LanesAvx2 => {
                if let Some(simd) = pulp::x86::V3::try_new() {
                    return Simd::vectorize(simd, op);
                }
            }
            _ => {}
        }
        Simd::vectorize(pulp::Scalar::new(), op)
    }
}

/// `e^x` for the lane kernels: `2^n e^r` with `n = round(x / ln 2)` and `|r| <= ln 2 / 2`,
/// `e^r` by its Taylor series to degree 7 (relative error under 2e-7 on the reduced range).
/// `x` is clamped to `[-87, 88]`, where the result is a normal f32. Additions,
/// multiplications and bit operations only, so every instruction set rounds alike.
#[inline(always)]
pub fn exp_lanes(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    // ln 2 split so that n * LN2_HI is exact for |n| < 2^11.
    const LN2_HI: f32 = 0.693_145_75;
    const LN2_LO: f32 = 1.428_606_8e-6;
    // 1.5 * 2^23: adding it rounds to an integer, whose bits then sit in the mantissa.
    const ROUND: f32 = 12_582_912.0;
    let x = if x < -87.0 { -87.0 } else { x };
    let x = if x > 88.0 { 88.0 } else { x };
    let t = x * LOG2E + ROUND;
    let n = t - ROUND;
    let r = (x - n * LN2_HI) - n * LN2_LO;
    let mut p = 1.0 / 5040.0;
    p = p * r + 1.0 / 720.0;
    p = p * r + 1.0 / 120.0;
    p = p * r + 1.0 / 24.0;
    p = p * r + 1.0 / 6.0;
    p = p * r + 0.5;
    p = p * r + 1.0;
    p = p * r + 1.0;
    // n + 127 into the exponent field.
    let ni = t.to_bits() as i32 - 0x4B40_0000;
    let scale = f32::from_bits(((ni + 127) << 23) as u32);
    p * scale
}

/// Whether the lane kernels serve this pass.
pub(crate) fn serves<F: Real>(ctx: &RasterCtx<'_, F>, path: BlendPath) -> bool {
    path != BlendPath::PerPixel
        && F::slice_as_f32(ctx.background).is_some()
        && ctx.cutoff == crate::config::AlphaCutoff::Hard
        && ctx.crossing.is_none()
}

/// [`super::raster::rasterize`] on the lane kernels. The caller checks [`serves`].
pub(crate) fn rasterize<F: Real>(
    bins: &Bins<F>,
    ctx: &RasterCtx<'_, F>,
    path: BlendPath,
) -> (Vec<F>, RasterState<F>, u64) {
    let bins32 = (bins as &dyn Any)
        .downcast_ref::<Bins<f32>>()
        .expect("lane kernels run on f32");
    let background = F::slice_as_f32(ctx.background).expect("lane kernels run on f32");
    let out = rasterize_f32(bins32, ctx, background, path);
    *(Box::new(out) as Box<dyn Any>)
        .downcast::<(Vec<F>, RasterState<F>, u64)>()
        .expect("F is f32")
}

/// [`super::raster::rasterize_backward`] on the lane kernels. The caller checks [`serves`].
pub(crate) fn rasterize_backward<F: Real>(
    bins: &Bins<F>,
    ctx: &RasterCtx<'_, F>,
    state: &RasterState<F>,
    grad_image: &[F],
    path: BlendPath,
) -> Vec<F> {
    let bins32 = (bins as &dyn Any)
        .downcast_ref::<Bins<f32>>()
        .expect("lane kernels run on f32");
    let state32 = (state as &dyn Any)
        .downcast_ref::<RasterState<f32>>()
        .expect("lane kernels run on f32");
    let background = F::slice_as_f32(ctx.background).expect("lane kernels run on f32");
    let grad = F::slice_as_f32(grad_image).expect("lane kernels run on f32");
    let out = backward_f32(bins32, ctx, state32, background, grad, path);
    *(Box::new(out) as Box<dyn Any>)
        .downcast::<Vec<F>>()
        .expect("F is f32")
}

fn rasterize_f32<F: Real>(
    bins: &Bins<f32>,
    ctx: &RasterCtx<'_, F>,
    background: &[f32],
    path: BlendPath,
) -> (Vec<f32>, RasterState<f32>, u64) {
    let c = ctx.channels;
    let stride = c + 1;
    let n_tiles = bins.tile_ranges.len();
    let mut tile_buf = vec![0f32; n_tiles * TILE_PIXELS * stride];
    let mut t_final = vec![1f32; n_tiles * TILE_PIXELS];
    let mut n_contrib = vec![0u32; n_tiles * TILE_PIXELS];
    let evals: u64 = tile_buf
        .par_chunks_mut(TILE_PIXELS * stride)
        .zip(t_final.par_chunks_mut(TILE_PIXELS))
        .zip(n_contrib.par_chunks_mut(TILE_PIXELS))
        .enumerate()
        .map(|(t, ((img, trans), nc))| {
            let [start, end] = bins.tile_ranges[t];
            let (start, end) = (start as usize, end as usize);
            path.run(ForwardTile {
                splats: &bins.packed[start..end],
                feats: &bins.packed_features[start * c..end * c],
                c,
                bounds: tile_bounds(t, ctx),
                background,
                img,
                trans: trans.try_into().expect("tile of 256 pixels"),
                nc: nc.try_into().expect("tile of 256 pixels"),
            })
        })
        .sum();
    let image = super::raster::tiles_to_rows(&tile_buf, ctx, stride);
    (
        image,
        RasterState {
            t_final,
            n_contrib,
            crossing: Vec::new(),
            observed: Vec::new(),
        },
        evals,
    )
}

/// One tile of the forward blend.
struct ForwardTile<'a> {
    splats: &'a [Splat<f32>],
    feats: &'a [f32],
    c: usize,
    bounds: (u32, u32, u32, u32),
    background: &'a [f32],
    /// `[256, C + 1]` interleaved, as the generic path.
    img: &'a mut [f32],
    trans: &'a mut [f32; TILE_PIXELS],
    nc: &'a mut [u32; TILE_PIXELS],
}

impl WithSimd for ForwardTile<'_> {
    type Output = u64;

    #[inline(always)]
    fn with_simd<S: Simd>(self, _simd: S) -> u64 {
        forward_tile(self)
    }
}

/// `CHUNK` values of `v` from `at`.
#[inline(always)]
fn chunk<T>(v: &mut [T], at: usize) -> &mut [T; CHUNK] {
    (&mut v[at..at + CHUNK]).try_into().expect("a chunk")
}

#[inline(always)]
fn chunk_ref<T>(v: &[T], at: usize) -> &[T; CHUNK] {
    (&v[at..at + CHUNK]).try_into().expect("a chunk")
}

#[inline(always)]
fn forward_tile(op: ForwardTile<'_>) -> u64 {
    let ForwardTile {
        splats,
        feats,
        c,
        bounds: (ox, oy, ex, ey),
        background,
        img,
        trans,
        nc,
    } = op;
    let amax = ALPHA_MAX as f32;
    let amin = ALPHA_MIN as f32;
    let t_min = TRANSMITTANCE_MIN as f32;
    let mut alive = [0u32; LANES];
    let full = col_mask(0, ex - ox);
    for row in alive.iter_mut().take((ey - oy) as usize) {
        *row = full;
    }
    let mut n_alive = (ex - ox) * (ey - oy);
    // planes[ch * 256 + p]: accumulated feature ch of pixel p.
    let mut planes = vec![0f32; c * TILE_PIXELS];
    let mut evals = 0u64;
    for (k, s) in splats.iter().enumerate() {
        if n_alive == 0 {
            break;
        }
        let feat = &feats[k * c..(k + 1) * c];
        let (y0, y1, cols, dx0) = clip_to_tile(s, ox, oy, ex, ey);
        let k1 = k as u32 + 1;
        for y in y0..y1 {
            let ly = (y - oy) as usize;
            let bits = alive[ly] & cols;
            if bits == 0 {
                continue;
            }
            evals += u64::from(bits.count_ones());
            let dy = (y as f32 + 0.5) - s.xy[1];
            let rp = RowPower::new(s, dy);
            for o in (0..LANES).step_by(CHUNK) {
                let cb_bits = (bits >> o) & CHUNK_MASK;
                if cb_bits == 0 {
                    continue;
                }
                let at = ly * LANES + o;
                let xs = *chunk_ref(&LANE_X, o);
                // Everything is computed on local copies (which the compiler knows do not
                // alias), then stored back: this is what lets the loops vectorise.
                let t_old = *chunk(trans, at);
                let nc_old = *chunk(nc, at);
                let mut t_new = [0f32; CHUNK];
                let mut nc_new = [0u32; CHUNK];
                let mut w = [0f32; CHUNK];
                let mut kill = [0u32; CHUNK];
                for i in 0..CHUNK {
                    let dx = dx0 + xs[i];
                    let power = rp.at(dx);
                    let raw = s.opacity * exp_lanes(power);
                    let alpha = if raw < amax { raw } else { amax };
                    let live = (cb_bits >> i) & 1 == 1;
                    let ok = live & (power >= s.skip_power) & (alpha >= amin);
                    let tp = t_old[i];
                    let next_t = tp * (1.0 - alpha);
                    let dies = ok & (next_t < t_min);
                    let adds = ok & !dies;
                    // Lanes that add nothing get weight 0 and keep their transmittance and
                    // count. No stored value is a select of the old one: that compiles to
                    // masked stores, which are slow on some CPUs.
                    w[i] = if adds { alpha * tp } else { 0.0 };
                    t_new[i] = tp * (1.0 - if adds { alpha } else { 0.0 });
                    nc_new[i] = nc_old[i].max(if adds { k1 } else { 0 });
                    kill[i] = if dies { 1 << i } else { 0 };
                }
                *chunk(trans, at) = t_new;
                *chunk(nc, at) = nc_new;
                for (ch, &f) in feat.iter().enumerate() {
                    let old = *chunk(&mut planes[ch * TILE_PIXELS..], at);
                    let mut new = [0f32; CHUNK];
                    for i in 0..CHUNK {
                        new[i] = old[i] + f * w[i];
                    }
                    *chunk(&mut planes[ch * TILE_PIXELS..], at) = new;
                }
                let killed = kill.iter().fold(0u32, |a, &b| a | b) << o;
                if killed != 0 {
                    alive[ly] &= !killed;
                    n_alive -= killed.count_ones();
                }
            }
        }
    }
    let stride = c + 1;
    for p in 0..TILE_PIXELS {
        let tp = trans[p];
        for ch in 0..c {
            img[p * stride + ch] = planes[ch * TILE_PIXELS + p] + tp * background[ch];
        }
        img[p * stride + c] = 1.0 - tp;
    }
    evals
}

fn backward_f32<F: Real>(
    bins: &Bins<f32>,
    ctx: &RasterCtx<'_, F>,
    state: &RasterState<f32>,
    background: &[f32],
    grad_image: &[f32],
    path: BlendPath,
) -> Vec<f32> {
    let c = ctx.channels;
    let slot = SLOT_FIXED + c;
    let mut slots = vec![0f32; bins.packed.len() * slot];
    let views = per_tile(&mut slots, &bins.tile_ranges, slot);
    views.into_par_iter().enumerate().for_each(|(t, out)| {
        let [start, end] = bins.tile_ranges[t];
        if start == end {
            return;
        }
        let (start, end) = (start as usize, end as usize);
        let base = t * TILE_PIXELS;
        path.run(BackwardTile {
            splats: &bins.packed[start..end],
            feats: &bins.packed_features[start * c..end * c],
            c,
            bounds: tile_bounds(t, ctx),
            width: ctx.width as usize,
            background,
            grad_image,
            t_fin: (&state.t_final[base..base + TILE_PIXELS])
                .try_into()
                .expect("tile of 256 pixels"),
            nc: (&state.n_contrib[base..base + TILE_PIXELS])
                .try_into()
                .expect("tile of 256 pixels"),
            out,
        });
    });
    slots
}

/// One tile of the backward pass.
struct BackwardTile<'a> {
    splats: &'a [Splat<f32>],
    feats: &'a [f32],
    c: usize,
    bounds: (u32, u32, u32, u32),
    width: usize,
    background: &'a [f32],
    grad_image: &'a [f32],
    t_fin: &'a [f32; TILE_PIXELS],
    nc: &'a [u32; TILE_PIXELS],
    /// One gradient row per splat of the tile (`SLOT_FIXED + C` values).
    out: &'a mut [f32],
}

impl WithSimd for BackwardTile<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, _simd: S) {
        backward_tile(self);
    }
}

#[inline(always)]
fn lane_sum(v: &[f32; LANES]) -> f32 {
    v.iter().fold(0.0, |a, &b| a + b)
}

#[inline(always)]
fn backward_tile(op: BackwardTile<'_>) {
    let BackwardTile {
        splats,
        feats,
        c,
        bounds: (ox, oy, ex, ey),
        width,
        background,
        grad_image,
        t_fin,
        nc,
        out,
    } = op;
    let amax = ALPHA_MAX as f32;
    let amin = ALPHA_MIN as f32;
    let stride = c + 1;
    let slot = SLOT_FIXED + c;
    let ts = TILE_SIZE as usize;
    let mut trans = *t_fin;
    // Planes [ch * 256 + p]: colour behind the current splat, and the image gradient.
    let mut back = vec![0f32; c * TILE_PIXELS];
    let mut g_col = vec![0f32; c * TILE_PIXELS];
    let mut g_alpha = [0f32; TILE_PIXELS];
    let mut by_nc: Vec<(u32, u8)> = Vec::with_capacity(TILE_PIXELS);
    for y in oy..ey {
        let ly = (y - oy) as usize;
        for x in ox..ex {
            let p = ly * ts + (x - ox) as usize;
            let gi = (y as usize * width + x as usize) * stride;
            for ch in 0..c {
                g_col[ch * TILE_PIXELS + p] = grad_image[gi + ch];
                back[ch * TILE_PIXELS + p] = t_fin[p] * background[ch];
            }
            g_alpha[p] = grad_image[gi + c];
            if nc[p] > 0 {
                by_nc.push((nc[p], p as u8));
            }
        }
    }
    // Walking the list backwards, pixel p joins once k < n_contrib[p].
    by_nc.sort_unstable_by(|a, b| b.cmp(a));
    let mut next_pixel = 0usize;
    let mut active = [0u32; LANES];
    let max_nc = by_nc.first().map_or(0, |e| e.0) as usize;
    // Per-lane partial sums of one splat's feature gradients.
    let mut d_feat = vec![[0f32; LANES]; c];
    for k in (0..max_nc.min(splats.len())).rev() {
        while next_pixel < by_nc.len() && by_nc[next_pixel].0 as usize > k {
            let p = by_nc[next_pixel].1 as usize;
            active[p / ts] |= 1 << (p % ts);
            next_pixel += 1;
        }
        let s = &splats[k];
        let feat = &feats[k * c..(k + 1) * c];
        let (y0, y1, cols, dx0) = clip_to_tile(s, ox, oy, ex, ey);
        let [ca, cb, cc] = s.conic;
        let mut du = [0f32; LANES];
        let mut dv = [0f32; LANES];
        let mut da = [0f32; LANES];
        let mut db = [0f32; LANES];
        let mut dc = [0f32; LANES];
        let mut dop = [0f32; LANES];
        for d in d_feat.iter_mut() {
            *d = [0.0; LANES];
        }
        let mut touched = false;
        for y in y0..y1 {
            let ly = (y - oy) as usize;
            let bits = active[ly] & cols;
            if bits == 0 {
                continue;
            }
            touched = true;
            let dy = (y as f32 + 0.5) - s.xy[1];
            let rp = RowPower::new(s, dy);
            for o in (0..LANES).step_by(CHUNK) {
                let cb_bits = (bits >> o) & CHUNK_MASK;
                if cb_bits == 0 {
                    continue;
                }
                let at = ly * LANES + o;
                let xs = *chunk_ref(&LANE_X, o);
                let t_old = *chunk(&mut trans, at);
                let tf_row = *chunk_ref(t_fin, at);
                let ga_row = *chunk_ref(&g_alpha, at);
                let mut t_new = [0f32; CHUNK];
                let mut ok = [0u32; CHUNK];
                let mut inv_om = [0f32; CHUNK];
                let mut t_i = [0f32; CHUNK];
                let mut w_i = [0f32; CHUNK];
                let mut w_on = [0f32; CHUNK];
                let mut d_alpha = [0f32; CHUNK];
                let mut raw = [0f32; CHUNK];
                let mut gauss = [0f32; CHUNK];
                let mut dxs = [0f32; CHUNK];
                for i in 0..CHUNK {
                    let dx = dx0 + xs[i];
                    let power = rp.at(dx);
                    let g = exp_lanes(power);
                    let r = s.opacity * g;
                    let alpha = if r < amax { r } else { amax };
                    let live = (cb_bits >> i) & 1 == 1;
                    let on = live & (power >= s.skip_power) & (alpha >= amin);
                    let io = 1.0 / (1.0 - alpha);
                    let ti = t_old[i] * io;
                    ok[i] = if on { u32::MAX } else { 0 };
                    inv_om[i] = io;
                    t_i[i] = ti;
                    w_i[i] = alpha * ti;
                    w_on[i] = if on { alpha * ti } else { 0.0 };
                    d_alpha[i] = ga_row[i] * tf_row[i] * io;
                    raw[i] = r;
                    gauss[i] = g;
                    dxs[i] = dx;
                    t_new[i] = t_old[i] * if on { io } else { 1.0 };
                }
                *chunk(&mut trans, at) = t_new;
                for (ch, &f) in feat.iter().enumerate() {
                    let gc = *chunk_ref(&g_col[ch * TILE_PIXELS..], at);
                    let bk = *chunk(&mut back[ch * TILE_PIXELS..], at);
                    let df = *chunk(&mut d_feat[ch], o);
                    let mut bk_new = [0f32; CHUNK];
                    let mut df_new = [0f32; CHUNK];
                    for i in 0..CHUNK {
                        // w_on is 0 on lanes that blend nothing.
                        df_new[i] = df[i] + w_on[i] * gc[i];
                        d_alpha[i] += gc[i] * (t_i[i] * f - bk[i] * inv_om[i]);
                        bk_new[i] = bk[i] + f * w_on[i];
                    }
                    *chunk(&mut back[ch * TILE_PIXELS..], at) = bk_new;
                    *chunk(&mut d_feat[ch], o) = df_new;
                }
                let (du, dv, da) = (chunk(&mut du, o), chunk(&mut dv, o), chunk(&mut da, o));
                let (db, dc, dop) = (chunk(&mut db, o), chunk(&mut dc, o), chunk(&mut dop, o));
                for i in 0..CHUNK {
                    // A capped alpha does not depend on the parameters.
                    let on = (ok[i] != 0) & (raw[i] <= amax);
                    let d_raw = if on { d_alpha[i] } else { 0.0 };
                    let d_power = d_raw * raw[i];
                    let dx = dxs[i];
                    du[i] += d_power * (ca * dx + cb * dy);
                    dv[i] += d_power * (cb * dx + cc * dy);
                    da[i] -= 0.5 * d_power * dx * dx;
                    db[i] -= d_power * dx * dy;
                    dc[i] -= 0.5 * d_power * dy * dy;
                    dop[i] += d_raw * gauss[i];
                }
            }
        }
        if !touched {
            continue;
        }
        let row = &mut out[k * slot..(k + 1) * slot];
        row[0] = lane_sum(&du);
        row[1] = lane_sum(&dv);
        row[2] = lane_sum(&da);
        row[3] = lane_sum(&db);
        row[4] = lane_sum(&dc);
        row[5] = lane_sum(&dop);
        for (r, d) in row[SLOT_FIXED..].iter_mut().zip(&d_feat) {
            *r = lane_sum(d);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_lanes_matches_std_to_two_ulp_on_the_blend_range() {
        let mut worst = 0f64;
        let mut x = -90.0f32;
        while x <= 1.0 {
            let got = f64::from(exp_lanes(x));
            let want = f64::from(x.max(-87.0)).exp();
            worst = worst.max(((got - want) / want).abs());
            x += 1.0 / 1024.0;
        }
        assert!(worst < 2.5e-7, "worst relative error {worst:e}");
        assert_eq!(exp_lanes(0.0), 1.0);
        assert!(exp_lanes(f32::NEG_INFINITY) > 0.0 && exp_lanes(f32::NEG_INFINITY).is_normal());
    }

    #[test]
    fn paths_parse_and_the_portable_ones_are_always_available() {
        for p in BlendPath::ALL {
            let name = match p {
                BlendPath::PerPixel => "per-pixel",
                BlendPath::LanesScalar => "scalar",
                BlendPath::LanesAvx2 => "avx2",
                BlendPath::LanesAvx512 => "avx512",
            };
            assert_eq!(BlendPath::parse(name), Some(p));
        }
        assert_eq!(BlendPath::parse("sse9"), None);
        assert!(BlendPath::PerPixel.available() && BlendPath::LanesScalar.available());
        assert!(BlendPath::best().available());
    }
}
