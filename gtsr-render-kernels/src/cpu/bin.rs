//! Depth sort and 16x16 tile binning.

use rayon::prelude::*;

use super::project::Splat;
use crate::scalar::Real;

/// Visible Gaussians in depth order, ties by index: entry `j` is a Gaussian index.
pub(crate) fn depth_order<F: Real>(splats: &[Option<Splat<F>>]) -> Vec<u32> {
    // Visible depths are >= near > 0, so their (exact) f64 bit patterns sort like the values;
    // the index breaks ties deterministically.
    let mut keys: Vec<(u64, u32)> = splats
        .par_iter()
        .enumerate()
        .filter_map(|(i, s)| s.as_ref().map(|s| (s.depth.f64().to_bits(), i as u32)))
        .collect();
    keys.par_sort_unstable();
    keys.par_iter().map(|k| k.1).collect()
}

/// Depth-sorted splats binned into tiles, with each tile's splats (and features) copied
/// contiguously in front-to-back order, so that the blend reads memory sequentially.
#[derive(Debug, Default)]
pub(crate) struct Bins<F> {
    /// Per tile, `[start, end)` into the intersection arrays below.
    pub tile_ranges: Vec<[u32; 2]>,
    /// Per intersection, a copy of the splat.
    pub packed: Vec<Splat<F>>,
    /// Per intersection, a copy of the splat's `C` features.
    pub packed_features: Vec<F>,
    /// Per splat `j` (depth order), `[start, end)` into `isects_of_splat`.
    pub splat_ranges: Vec<[u32; 2]>,
    /// The intersections of each splat, in the row-major order of its tile rectangle.
    pub isects_of_splat: Vec<u32>,
}

/// Bins the depth-sorted splats `sorted` (features `sorted_features`, `c` per splat) into the
/// tile grid `tiles_x * tiles_y`. Parallel over rows of tiles: every row scans the splat list
/// front to back and fills its own (contiguous) part of the output, so each tile's list comes
/// out in depth order without any sort by tile.
pub(crate) fn bin<F: Real>(
    sorted: &[Splat<F>],
    sorted_features: &[F],
    c: usize,
    tiles_x: u32,
    tiles_y: u32,
) -> Bins<F> {
    let tx = tiles_x as usize;
    let rects: Vec<[u32; 4]> = sorted.par_iter().map(|s| s.tile_rect()).collect();
    // Intersections per tile, one tile row per task.
    let counts: Vec<u32> = (0..tiles_y)
        .into_par_iter()
        .flat_map_iter(|ty| {
            let mut row = vec![0u32; tx];
            for r in rects.iter().filter(|r| r[1] <= ty && ty < r[3]) {
                for c in &mut row[r[0] as usize..r[2] as usize] {
                    *c += 1;
                }
            }
            row
        })
        .collect();
    let mut acc = 0u32;
    let tile_ranges: Vec<[u32; 2]> = counts
        .iter()
        .map(|&n| {
            let r = [acc, acc + n];
            acc += n;
            r
        })
        .collect();
    let total = acc as usize;
    // Each splat's own list of intersection slots, in the row-major order of its rectangle.
    let mut splat_ranges = Vec::with_capacity(sorted.len());
    let mut acc = 0u32;
    for r in &rects {
        let n = (r[2] - r[0]) * (r[3] - r[1]);
        splat_ranges.push([acc, acc + n]);
        acc += n;
    }

    let mut packed = vec![Splat::default(); total];
    let mut packed_features = vec![F::zero(); total * c];
    // (tile row, slot of the splat's intersection) pairs, gathered per row then scattered.
    let row_bounds: Vec<usize> = (0..=tiles_y as usize)
        .map(|ty| {
            if ty == tiles_y as usize {
                total
            } else {
                tile_ranges[ty * tx][0] as usize
            }
        })
        .collect();
    let mut packed_rows: Vec<&mut [Splat<F>]> = Vec::new();
    let mut feat_rows: Vec<&mut [F]> = Vec::new();
    {
        let mut rest_p: &mut [Splat<F>] = &mut packed;
        let mut rest_f: &mut [F] = &mut packed_features;
        for ty in 0..tiles_y as usize {
            let len = row_bounds[ty + 1] - row_bounds[ty];
            let (a, b) = rest_p.split_at_mut(len);
            packed_rows.push(a);
            rest_p = b;
            let (a, b) = rest_f.split_at_mut(len * c);
            feat_rows.push(a);
            rest_f = b;
        }
    }
    let row_isects: Vec<Vec<(u32, u32)>> = packed_rows
        .into_par_iter()
        .zip(feat_rows)
        .enumerate()
        .map(|(ty, (prow, frow))| {
            let ty = ty as u32;
            let base = row_bounds[ty as usize] as u32;
            let mut cursor: Vec<u32> = (0..tx)
                .map(|t| tile_ranges[ty as usize * tx + t][0] - base)
                .collect();
            let mut isects = Vec::new();
            for (j, r) in rects.iter().enumerate() {
                if !(r[1] <= ty && ty < r[3]) {
                    continue;
                }
                let s = &sorted[j];
                let feat = &sorted_features[j * c..(j + 1) * c];
                let width = r[2] - r[0];
                for t in r[0]..r[2] {
                    let k = cursor[t as usize] as usize;
                    cursor[t as usize] += 1;
                    prow[k] = *s;
                    frow[k * c..(k + 1) * c].copy_from_slice(feat);
                    // Position within the splat's own list.
                    let local = (ty - r[1]) * width + (t - r[0]);
                    isects.push((splat_ranges[j][0] + local, base + k as u32));
                }
            }
            isects
        })
        .collect();
    let mut isects_of_splat = vec![0u32; total];
    for row in row_isects {
        for (pos, slot) in row {
            isects_of_splat[pos as usize] = slot;
        }
    }
    Bins {
        tile_ranges,
        packed,
        packed_features,
        splat_ranges,
        isects_of_splat,
    }
}
