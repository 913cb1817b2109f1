//! Depth sort and 16x16 tile binning.

use rayon::prelude::*;

use super::project::Splat;

/// Splats binned into tiles, each tile's list in front-to-back order.
#[derive(Debug, Default)]
pub(crate) struct Bins {
    /// Per tile, `[start, end)` into `ids`.
    pub tile_ranges: Vec<[u32; 2]>,
    /// Gaussian index of every (tile, splat) intersection.
    pub ids: Vec<u32>,
    /// Per Gaussian, `[start, end)` into `isect_of_gauss` (empty when culled).
    pub gauss_ranges: Vec<[u32; 2]>,
    /// Intersection slots (indices into `ids`) of each Gaussian, in tile order.
    pub isect_of_gauss: Vec<u32>,
}

/// Sorts the visible splats by camera depth (ties by index, so the order is deterministic) and
/// bins them into the tile grid `tiles_x * tiles_y`.
pub(crate) fn bin<F: crate::scalar::Real>(
    splats: &[Option<Splat<F>>],
    tiles_x: u32,
    tiles_y: u32,
) -> Bins {
    let mut order: Vec<u32> = splats
        .iter()
        .enumerate()
        .filter_map(|(i, s)| s.as_ref().map(|_| i as u32))
        .collect();
    order.par_sort_unstable_by(|&a, &b| {
        let da = splats[a as usize].as_ref().map(|s| s.depth).unwrap_or_default();
        let db = splats[b as usize].as_ref().map(|s| s.depth).unwrap_or_default();
        da.partial_cmp(&db)
            .unwrap_or(core::cmp::Ordering::Equal)
            .then(a.cmp(&b))
    });

    let n_tiles = (tiles_x * tiles_y) as usize;
    let mut counts = vec![0u32; n_tiles + 1];
    let mut gauss_ranges = vec![[0u32; 2]; splats.len()];
    let mut total = 0u32;
    for (i, s) in splats.iter().enumerate() {
        if let Some(s) = s {
            let [tx0, ty0, tx1, ty1] = s.tile_rect();
            for ty in ty0..ty1 {
                for tx in tx0..tx1 {
                    counts[(ty * tiles_x + tx) as usize] += 1;
                }
            }
            let n = s.tile_count() as u32;
            gauss_ranges[i] = [total, total + n];
            total += n;
        }
    }
    // Exclusive prefix sum.
    let mut acc = 0u32;
    let mut tile_ranges = vec![[0u32; 2]; n_tiles];
    for t in 0..n_tiles {
        tile_ranges[t] = [acc, acc + counts[t]];
        acc += counts[t];
    }
    let mut cursor: Vec<u32> = tile_ranges.iter().map(|r| r[0]).collect();
    let mut ids = vec![0u32; total as usize];
    let mut isect_of_gauss = vec![0u32; total as usize];
    for &g in &order {
        let s = splats[g as usize].as_ref().expect("ordered splats are visible");
        let [tx0, ty0, tx1, ty1] = s.tile_rect();
        let mut k = gauss_ranges[g as usize][0] as usize;
        for ty in ty0..ty1 {
            for tx in tx0..tx1 {
                let t = (ty * tiles_x + tx) as usize;
                let slot = cursor[t];
                cursor[t] += 1;
                ids[slot as usize] = g;
                isect_of_gauss[k] = slot;
                k += 1;
            }
        }
    }
    Bins {
        tile_ranges,
        ids,
        gauss_ranges,
        isect_of_gauss,
    }
}
