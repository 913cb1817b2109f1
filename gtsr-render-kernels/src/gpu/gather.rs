//! The backward pass's gather: where each tile row's intersections start (the gradient rows
//! are produced in bands of tile rows), and each Gaussian's sum of its gradient rows, band by
//! band, in a fixed order.

use burn_cubecl::cubecl;
use cubecl::prelude::*;

use super::common::{ranked, tile_rect};

/// First sorted intersection of every tile row: `row_starts[ty]` for `ty <= tiles_y` (the
/// last entry is the total). One thread per sorted intersection; rows without intersections
/// get the start of the next non-empty one.
#[cube(launch)]
pub fn tile_row_starts(
    sorted_keys: &[u32],
    row_starts: &mut [u32],
    total: u32,
    tiles_x: u32,
    tiles_y: u32,
) {
    let i = ABSOLUTE_POS as u32;
    if i >= total {
        terminate!();
    }
    let row = sorted_keys[i as usize] / tiles_x;
    let mut first = 0u32;
    if i > 0u32 {
        first = sorted_keys[i as usize - 1] / tiles_x + 1;
    }
    if first <= row {
        for r in first..row + 1 {
            row_starts[r as usize] = i;
        }
    }
    if i + 1 == total {
        for r in row + 1..tiles_y + 1 {
            row_starts[r as usize] = total;
        }
    }
}

/// Adds the gradient rows of one band of tile rows `[band_lo, band_hi)` (rows stored from
/// sorted intersection `base`) to each Gaussian's sums. A Gaussian's emissions run row-major
/// over its tile rectangle, so its emissions in the band are one contiguous range, summed in
/// order; bands are added one launch after another, so the result is deterministic.
#[cube(launch)]
pub fn accumulate_band(
    order: &[u32],
    starts: &[u32],
    proj: &[f32],
    position: &[u32],
    rows: &[f32],
    sums: &mut [f32],
    n: u32,
    band_lo: u32,
    band_hi: u32,
    base: u32,
    #[comptime] channels: usize,
) {
    let values = channels + 6;
    let at = ranked(starts, n);
    if at.start < at.end {
        let g = order[at.r as usize];
        let rect = tile_rect(proj, g);
        let ty0 = rect.ty0;
        let lo = select(band_lo > ty0, band_lo, ty0);
        let hi = select(band_hi < rect.ty1, band_hi, rect.ty1);
        if lo < hi {
            let w = rect.tx1 - rect.tx0;
            let mut acc = Array::<f32>::new(values);
            let o = g as usize * values;
            #[unroll]
            for v in 0..values {
                acc[v] = sums[o + v];
            }
            for e in at.start + (lo - ty0) * w..at.start + (hi - ty0) * w {
                let row = (position[e as usize] - base) as usize * values;
                #[unroll]
                for v in 0..values {
                    acc[v] += rows[row + v];
                }
            }
            #[unroll]
            for v in 0..values {
                sums[o + v] = acc[v];
            }
        }
    }
}
