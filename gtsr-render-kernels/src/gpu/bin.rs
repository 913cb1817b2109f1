//! Tile binning on the device: the tile counts in depth order, one (tile, emission) pair per
//! tile each visible Gaussian touches, and, after the sort by tile, the Gaussian of each
//! intersection and each tile's range of the sorted list. The sorts and the scan are
//! [`super::scan_sort`]'s.

// Kernel code is CubeCL's dialect of Rust: the `||` of two branches with side effects is
// written out on purpose.
#![allow(clippy::if_same_then_else)]

use burn_cubecl::cubecl;
use cubecl::prelude::*;

use super::common::{ranked, tile_rect};

/// `counts[r] = tiles[order[r]]` for `r < n`, and `counts[n] = 0` (so that the exclusive scan
/// of `counts` ends with the total).
#[cube(launch)]
pub fn gather_counts(order: &[u32], tiles: &[u32], counts: &mut [u32], n: u32) {
    let r = ABSOLUTE_POS as u32;
    if r < n {
        counts[r as usize] = tiles[order[r as usize] as usize];
    } else if r == n {
        counts[r as usize] = 0u32;
    }
}

/// One thread per Gaussian in depth order: writes one (tile id, emission index) pair per tile
/// its rectangle touches, row-major, and the Gaussian of each emission.
#[cube(launch)]
pub fn emit_intersections(
    order: &[u32],
    starts: &[u32],
    proj: &[f32],
    keys: &mut [u32],
    vals: &mut [u32],
    gids: &mut [u32],
    n: u32,
    tiles_x: u32,
) {
    let at = ranked(starts, n);
    if at.start < at.end {
        let g = order[at.r as usize];
        let rect = tile_rect(proj, g);
        let mut e = at.start;
        for ty in rect.ty0..rect.ty1 {
            for tx in rect.tx0..rect.tx1 {
                keys[e as usize] = ty * tiles_x + tx;
                vals[e as usize] = e;
                gids[e as usize] = g;
                e += 1;
            }
        }
    }
}

/// After the sort by tile: the Gaussian of each sorted intersection, the sorted position of
/// each emission, and each tile's `[start, end)` (`ranges` must be zeroed beforehand).
#[cube(launch)]
pub fn finish_bins(
    sorted_keys: &[u32],
    sorted_vals: &[u32],
    gids: &[u32],
    sorted_gids: &mut [u32],
    position: &mut [u32],
    ranges: &mut [u32],
    total: u32,
) {
    let i = ABSOLUTE_POS as u32;
    if i >= total {
        terminate!();
    }
    let iu = i as usize;
    let e = sorted_vals[iu];
    sorted_gids[iu] = gids[e as usize];
    position[e as usize] = i;
    let t = sorted_keys[iu];
    if i == 0u32 {
        ranges[2 * t as usize] = 0u32;
    } else if sorted_keys[iu - 1] != t {
        ranges[2 * t as usize] = i;
    }
    if i + 1 == total {
        ranges[2 * t as usize + 1] = i + 1;
    } else if sorted_keys[iu + 1] != t {
        ranges[2 * t as usize + 1] = i + 1;
    }
}
