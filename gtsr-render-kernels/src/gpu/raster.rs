//! Blending per 16x16 tile, front to back, and its backward pass (back to front, one gradient
//! row per intersection): one cube per tile, one thread per pixel, the tile's splat list
//! walked in batches through shared memory, as in 3DGS.

// Kernel code is CubeCL's dialect of Rust: `div_ceil` is written out on purpose.
#![allow(clippy::manual_div_ceil)]

use burn_cubecl::cubecl;
use cubecl::prelude::*;

use super::common::{ALPHA_MIN, PROJ};
use crate::config::TILE_SIZE;

/// Threads per tile (one per pixel).
pub const TILE_THREADS: u32 = TILE_SIZE * TILE_SIZE;
/// Splats loaded into shared memory per round in the forward pass.
const FWD_BATCH: u32 = TILE_THREADS;
/// Splats per round in the backward pass (smaller: it also needs reduction space).
const BWD_BATCH: u32 = 128;
/// Per-splat floats kept in shared memory by the blend: x, y, a, b, c, opacity, skip power.
const SPLAT: u32 = 7;
/// Gradient values reduced per step in the backward pass.
const RED: u32 = 8;

const ALPHA_MAX: f32 = 0.99;
const T_MIN: f32 = 1e-4;

/// The alpha of a splat at a pixel from its exponent, with the CPU's cap and cut-off:
/// `out = (alpha, raw, gauss, d alpha / d capped)`, alpha 0 when cut.
#[cube]
fn eval_alpha(opacity: f32, power: f32, out: &mut Array<f32>, #[comptime] smooth: bool) {
    let gauss = power.exp();
    let raw = opacity * gauss;
    let capped = select(raw < ALPHA_MAX, raw, ALPHA_MAX);
    out[1] = raw;
    out[2] = gauss;
    if capped < ALPHA_MIN {
        out[0] = 0.0;
        out[3] = 0.0;
    } else if smooth {
        let t = (capped - ALPHA_MIN) / ALPHA_MIN;
        if t >= 1.0 {
            out[0] = capped;
            out[3] = 1.0;
        } else {
            let w = t * t * (3.0 - 2.0 * t);
            let dw = 6.0 * t * (1.0 - t) / ALPHA_MIN;
            out[0] = capped * w;
            out[3] = w + capped * dw;
        }
    } else {
        out[0] = capped;
        out[3] = 1.0;
    }
}

/// The splat's exponent at a pixel, evaluated as the CPU does (`(ha dx + lin) dx + cst`).
#[cube]
fn power_at(a: f32, b: f32, c: f32, dx: f32, dy: f32) -> f32 {
    let ha = -0.5f32 * a;
    let lin = -(b * dy);
    let cst = (-0.5f32 * c) * dy * dy;
    (ha * dx + lin) * dx + cst
}

/// Loads the splat of sorted intersection `idx` into shared slot `slot`.
#[cube]
fn load_splat(
    proj: &[f32],
    sorted_gids: &[u32],
    idx: u32,
    slot: u32,
    s_splat: &mut Shared<[f32]>,
    s_rect: &mut Shared<[u32]>,
    s_gid: &mut Shared<[u32]>,
) {
    let g = sorted_gids[idx as usize];
    let b = g as usize * PROJ as usize;
    let s = slot as usize * SPLAT as usize;
    s_splat[s] = proj[b];
    s_splat[s + 1] = proj[b + 1];
    s_splat[s + 2] = proj[b + 2];
    s_splat[s + 3] = proj[b + 3];
    s_splat[s + 4] = proj[b + 4];
    s_splat[s + 5] = proj[b + 5];
    s_splat[s + 6] = proj[b + 7];
    let r = slot as usize * 4;
    s_rect[r] = u32::cast_from(proj[b + 8]);
    s_rect[r + 1] = u32::cast_from(proj[b + 9]);
    s_rect[r + 2] = u32::cast_from(proj[b + 10]);
    s_rect[r + 3] = u32::cast_from(proj[b + 11]);
    s_gid[slot as usize] = g;
}

/// This thread's pixel of a tile (one thread per pixel, `UNIT_POS` in the tile), and the tile's
/// range of the sorted list.
#[derive(CubeType)]
struct TilePixel {
    /// Tile-local column.
    lx: u32,
    tid: u32,
    px: u32,
    py: u32,
    /// Whether the pixel is in the image (tiles on the right and bottom edges overhang).
    inside: bool,
    start: u32,
    end: u32,
    /// `dx` of the tile's column 0 before the splat's centre is subtracted.
    dx0: f32,
    /// `dy` of the pixel's row before the splat's centre is subtracted.
    dyp: f32,
}

/// The pixel of this thread in the tile at column `CUBE_POS_X` of tile row `tile_y`.
#[cube]
fn tile_pixel(ranges: &[u32], tile_y: u32, width: u32, height: u32) -> TilePixel {
    let tile = tile_y * CUBE_COUNT_X + CUBE_POS_X;
    let ox = CUBE_POS_X * TILE_SIZE;
    let oy = tile_y * TILE_SIZE;
    let lx = UNIT_POS_X;
    let ly = UNIT_POS_Y;
    let px = ox + lx;
    let py = oy + ly;
    TilePixel {
        lx,
        tid: UNIT_POS,
        px,
        py,
        inside: px < width && py < height,
        start: ranges[2 * tile as usize],
        end: ranges[2 * tile as usize + 1],
        dx0: f32::cast_from(ox) + 0.5,
        dyp: f32::cast_from(py) + 0.5,
    }
}

/// Whether pixel `(px, py)` lies in the rectangle of the splat in shared slot `j`.
#[cube]
fn in_rect(s_rect: &Shared<[u32]>, j: u32, px: u32, py: u32) -> bool {
    let r = j as usize * 4;
    px >= s_rect[r] && px < s_rect[r + 2] && py >= s_rect[r + 1] && py < s_rect[r + 3]
}

/// One cube per 16x16 tile, one thread per pixel: blends the tile's depth-sorted splats front
/// to back. Writes the `[H, W, C + 1]` image, and per pixel the final transmittance and the
/// number of list entries up to the last one blended.
#[cube(launch)]
pub fn rasterize_forward(
    proj: &[f32],
    sorted_gids: &[u32],
    ranges: &[u32],
    features: &[f32],
    background: &[f32],
    image: &mut [f32],
    t_final: &mut [f32],
    n_contrib: &mut [f32],
    width: u32,
    height: u32,
    #[comptime] channels: usize,
    #[comptime] smooth: bool,
) {
    let at = tile_pixel(ranges, CUBE_POS_Y, width, height);
    let mut s_splat = Shared::<[f32]>::new_slice((FWD_BATCH * SPLAT) as usize);
    let mut s_rect = Shared::<[u32]>::new_slice((FWD_BATCH * 4) as usize);
    let mut s_gid = Shared::<[u32]>::new_slice(FWD_BATCH as usize);
    let done_count = Shared::<[Atomic<u32>]>::new_slice(1usize);
    if at.tid == 0u32 {
        done_count[0].store(0u32);
    }
    sync_cube();
    let mut done = !at.inside;
    if done {
        done_count[0].fetch_add(1u32);
    }
    let mut trans = 1.0f32;
    let mut acc = Array::<f32>::new(channels);
    #[unroll]
    for c in 0..channels {
        acc[c] = 0.0;
    }
    let mut last = 0u32;
    let mut a_out = Array::<f32>::new(4usize);
    let count = at.end - at.start;
    let rounds = (count + FWD_BATCH - 1) / FWD_BATCH;
    for round in 0..rounds {
        sync_cube();
        if done_count[0].load() == TILE_THREADS {
            break;
        }
        let first = round * FWD_BATCH;
        if first + at.tid < count {
            load_splat(
                proj,
                sorted_gids,
                at.start + first + at.tid,
                at.tid,
                &mut s_splat,
                &mut s_rect,
                &mut s_gid,
            );
        }
        sync_cube();
        if !done {
            let batch = select(count - first < FWD_BATCH, count - first, FWD_BATCH);
            for j in 0..batch {
                if in_rect(&s_rect, j, at.px, at.py) {
                    let s = j as usize * SPLAT as usize;
                    let dx = (at.dx0 - s_splat[s]) + f32::cast_from(at.lx);
                    let dy = at.dyp - s_splat[s + 1];
                    let power = power_at(s_splat[s + 2], s_splat[s + 3], s_splat[s + 4], dx, dy);
                    if power >= s_splat[s + 6] {
                        eval_alpha(s_splat[s + 5], power, &mut a_out, smooth);
                        let alpha = a_out[0];
                        if alpha > 0.0 {
                            let next_t = trans * (1.0 - alpha);
                            if next_t < T_MIN {
                                done = true;
                                done_count[0].fetch_add(1u32);
                                break;
                            }
                            let w = alpha * trans;
                            let g = s_gid[j as usize] as usize;
                            #[unroll]
                            for c in 0..channels {
                                acc[c] += features[g * channels + c] * w;
                            }
                            trans = next_t;
                            last = first + j + 1;
                        }
                    }
                }
            }
        }
    }
    if at.inside {
        let pix = (at.py * width + at.px) as usize;
        let o = pix * (channels + 1);
        #[unroll]
        for c in 0..channels {
            image[o + c] = acc[c] + trans * background[c];
        }
        image[o + channels] = 1.0 - trans;
        t_final[pix] = trans;
        n_contrib[pix] = f32::cast_from(last);
    }
}

/// One cube per tile of the band of tile rows starting at `first_tile_row`, one thread per
/// pixel: walks the tile's splats back to front from the last one any pixel blended and
/// writes, per sorted intersection `i` (at row `i - base`), the tile's gradient row
/// `d_xy[2], d_conic[3], d_opacity, d_features[C]` (summed over the tile's pixels in a fixed
/// order, so the result is deterministic).
#[cube(launch)]
pub fn rasterize_backward(
    proj: &[f32],
    sorted_gids: &[u32],
    ranges: &[u32],
    features: &[f32],
    background: &[f32],
    grad: &[f32],
    t_final: &[f32],
    n_contrib: &[f32],
    rows: &mut [f32],
    width: u32,
    height: u32,
    first_tile_row: u32,
    base: u32,
    #[comptime] channels: usize,
    #[comptime] smooth: bool,
) {
    let values = channels + 6;
    let at = tile_pixel(ranges, CUBE_POS_Y + first_tile_row, width, height);
    let pix = (at.py * width + at.px) as usize;
    let mut trans = 1.0f32;
    let mut nc = 0u32;
    let mut g_alpha = 0.0f32;
    let mut back = Array::<f32>::new(channels);
    let mut g_col = Array::<f32>::new(channels);
    #[unroll]
    for c in 0..channels {
        back[c] = 0.0;
        g_col[c] = 0.0;
    }
    if at.inside {
        trans = t_final[pix];
        nc = u32::cast_from(n_contrib[pix]);
        let o = pix * (channels + 1);
        #[unroll]
        for c in 0..channels {
            back[c] = trans * background[c];
            g_col[c] = grad[o + c];
        }
        g_alpha = grad[o + channels];
    }
    let t_fin = trans;
    let max_nc = Shared::<[Atomic<u32>]>::new_slice(1usize);
    let mut vote = Shared::<[u32]>::new_slice(3usize);
    if at.tid == 0u32 {
        max_nc[0].store(0u32);
        vote[0] = 0u32;
        vote[1] = 0u32;
        vote[2] = 0u32;
    }
    sync_cube();
    max_nc[0].fetch_max(nc);
    sync_cube();
    let total = at.end - at.start;
    let most = max_nc[0].load();
    let count = select(most < total, most, total);
    let mut s_splat = Shared::<[f32]>::new_slice((BWD_BATCH * SPLAT) as usize);
    let mut s_rect = Shared::<[u32]>::new_slice((BWD_BATCH * 4) as usize);
    let mut s_gid = Shared::<[u32]>::new_slice(BWD_BATCH as usize);
    let mut red = Shared::<[f32]>::new_slice((RED * TILE_THREADS) as usize);
    let mut part = Shared::<[f32]>::new_slice((RED * TILE_SIZE) as usize);
    let mut cv = Array::<f32>::new(values);
    let chunks = (values + RED as usize - 1) / RED as usize;
    let mut step = 0u32;
    let mut a_out = Array::<f32>::new(4usize);
    let rounds = (count + BWD_BATCH - 1) / BWD_BATCH;
    for round in 0..rounds {
        let hi = count - round * BWD_BATCH;
        let lo = select(hi > BWD_BATCH, hi - BWD_BATCH, 0u32);
        sync_cube();
        if at.tid < hi - lo {
            load_splat(
                proj,
                sorted_gids,
                at.start + lo + at.tid,
                at.tid,
                &mut s_splat,
                &mut s_rect,
                &mut s_gid,
            );
        }
        sync_cube();
        for jj in 0..(hi - lo) {
            let j = hi - lo - 1 - jj;
            let k = lo + j;
            #[unroll]
            for v in 0..values {
                cv[v] = 0.0;
            }
            let mut contributed = false;
            if k < nc && in_rect(&s_rect, j, at.px, at.py) {
                let s = j as usize * SPLAT as usize;
                let dx = (at.dx0 - s_splat[s]) + f32::cast_from(at.lx);
                let dy = at.dyp - s_splat[s + 1];
                let ca = s_splat[s + 2];
                let cb = s_splat[s + 3];
                let cc = s_splat[s + 4];
                let power = power_at(ca, cb, cc, dx, dy);
                if power >= s_splat[s + 6] {
                    eval_alpha(s_splat[s + 5], power, &mut a_out, smooth);
                    let alpha = a_out[0];
                    if alpha > 0.0 {
                        contributed = true;
                        let raw = a_out[1];
                        let inv_om = 1.0 / (1.0 - alpha);
                        let t_i = trans * inv_om;
                        let w_i = alpha * t_i;
                        let mut d_alpha = g_alpha * t_fin * inv_om;
                        let g = s_gid[j as usize] as usize;
                        #[unroll]
                        for c in 0..channels {
                            let f = features[g * channels + c];
                            cv[6 + c] = w_i * g_col[c];
                            d_alpha += g_col[c] * (t_i * f - back[c] * inv_om);
                            back[c] += f * w_i;
                        }
                        trans = t_i;
                        if raw <= ALPHA_MAX {
                            let d_raw = d_alpha * a_out[3];
                            cv[5] = d_raw * a_out[2];
                            let d_power = d_raw * raw;
                            cv[0] = d_power * (ca * dx + cb * dy);
                            cv[1] = d_power * (cb * dx + cc * dy);
                            cv[2] = -0.5f32 * d_power * dx * dx;
                            cv[3] = -d_power * dx * dy;
                            cv[4] = -0.5f32 * d_power * dy * dy;
                        }
                    }
                }
            }
            // Sum the tile's pixels, RED values at a time: rows of 16, then the 16 row sums.
            // The first chunk's stores share a barrier with a vote on whether any pixel blended
            // this splat at all; when none did (its rectangle's corners, or pixels saturated
            // in front of it), the rest is skipped. The vote uses three rotating flags: flag
            // `f` is cleared two splats ahead, when nobody can still be reading or writing it.
            let f = (step % 3) as usize;
            if contributed {
                vote[f] = 1u32;
            }
            #[unroll]
            for q in 0..RED as usize {
                if q < values {
                    red[q * TILE_THREADS as usize + at.tid as usize] = cv[q];
                } else {
                    red[q * TILE_THREADS as usize + at.tid as usize] = 0.0;
                }
            }
            sync_cube();
            let any = vote[f] != 0u32;
            if at.tid == 0u32 {
                vote[((step + 2) % 3) as usize] = 0u32;
            }
            step += 1;
            if any {
                let row_out = (at.start + k - base) as usize * values;
                #[unroll]
                for vb in 0..chunks {
                    if vb > 0 {
                        #[unroll]
                        for q in 0..RED as usize {
                            let v = vb * RED as usize + q;
                            if v < values {
                                red[q * TILE_THREADS as usize + at.tid as usize] = cv[v];
                            } else {
                                red[q * TILE_THREADS as usize + at.tid as usize] = 0.0;
                            }
                        }
                        sync_cube();
                    }
                    if at.tid < RED * TILE_SIZE {
                        let q = (at.tid / TILE_SIZE) as usize;
                        let row = (at.tid % TILE_SIZE) as usize;
                        let b = q * TILE_THREADS as usize + row * TILE_SIZE as usize;
                        let mut sum = 0.0f32;
                        #[unroll]
                        for m in 0..TILE_SIZE as usize {
                            sum += red[b + m];
                        }
                        part[q * TILE_SIZE as usize + row] = sum;
                    }
                    sync_cube();
                    if at.tid < RED {
                        let v = vb * RED as usize + at.tid as usize;
                        if v < values {
                            let mut sum = 0.0f32;
                            #[unroll]
                            for m in 0..TILE_SIZE as usize {
                                sum += part[at.tid as usize * TILE_SIZE as usize + m];
                            }
                            rows[row_out + v] = sum;
                        }
                    }
                }
            }
        }
    }
}
