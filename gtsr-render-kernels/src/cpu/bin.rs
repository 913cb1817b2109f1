//! Depth sort and 16x16 tile binning.

use std::mem::MaybeUninit;

use rayon::prelude::*;

use super::project::Splat;
use crate::scalar::Real;

/// Visible Gaussians in depth order, ties by index: entry `j` is a Gaussian index.
pub(crate) fn depth_order<F: Real>(splats: &[Option<Splat<F>>]) -> Vec<u32> {
    // Visible depths are >= near > 0, so their (exact) f64 bit patterns sort like the values.
    // The radix sort is stable and the keys are collected in index order, so ties stay in
    // index order; it skips the bytes that every key shares (the low ones, for f32 depths).
    let mut keys: Vec<(u64, u32)> = splats
        .par_iter()
        .enumerate()
        .filter_map(|(i, s)| s.as_ref().map(|s| (s.depth.f64().to_bits(), i as u32)))
        .collect();
    radsort::sort_by_key(&mut keys, |k| k.0);
    keys.into_iter().map(|k| k.1).collect()
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
/// tile grid `tiles_x * tiles_y`. Parallel over rows of tiles: every row walks the splats that
/// span it ([`splats_by_row`]) front to back and fills its own (contiguous) part of the output,
/// so each tile's list comes out in depth order without any sort by tile.
pub(crate) fn bin<F: Real>(
    sorted: &[Splat<F>],
    sorted_features: &[F],
    c: usize,
    tiles_x: u32,
    tiles_y: u32,
) -> Bins<F> {
    let tx = tiles_x as usize;
    let rects: Vec<[u32; 4]> = sorted.par_iter().map(|s| s.tile_rect()).collect();
    let rows = splats_by_row(&rects, tiles_y as usize);
    // Intersections per tile, one tile row per task.
    let counts: Vec<u32> = rows
        .par_iter()
        .flat_map_iter(|row_splats| {
            let mut row = vec![0u32; tx];
            for &j in row_splats {
                let r = &rects[j as usize];
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

    // Every slot is written exactly once below (each tile row fills its tiles' ranges, whose
    // sizes were counted with the same test), so the buffers are not zeroed first: at 256 px
    // with 100k Gaussians that zeroing alone took as long as the sort.
    let mut packed: Vec<Splat<F>> = Vec::with_capacity(total);
    let mut packed_features: Vec<F> = Vec::with_capacity(total * c);
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
    let mut packed_rows: Vec<&mut [MaybeUninit<Splat<F>>]> = Vec::new();
    let mut feat_rows: Vec<&mut [MaybeUninit<F>]> = Vec::new();
    {
        let mut rest_p = &mut packed.spare_capacity_mut()[..total];
        let mut rest_f = &mut packed_features.spare_capacity_mut()[..total * c];
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
            let mut isects = Vec::with_capacity(prow.len());
            for &j in &rows[ty as usize] {
                let j = j as usize;
                let r = &rects[j];
                let s = &sorted[j];
                let feat = &sorted_features[j * c..(j + 1) * c];
                let width = r[2] - r[0];
                for t in r[0]..r[2] {
                    let k = cursor[t as usize] as usize;
                    cursor[t as usize] += 1;
                    prow[k].write(*s);
                    for (d, &v) in frow[k * c..(k + 1) * c].iter_mut().zip(feat) {
                        d.write(v);
                    }
                    // Position within the splat's own list.
                    let local = (ty - r[1]) * width + (t - r[0]);
                    isects.push((splat_ranges[j][0] + local, base + k as u32));
                }
            }
            // Each tile's cursor has reached the start of the next tile: its range is full.
            for t in 0..tx {
                assert_eq!(
                    cursor[t] + base,
                    tile_ranges[ty as usize * tx + t][1],
                    "tile ({t}, {ty}) filled short"
                );
            }
            isects
        })
        .collect();
    // SAFETY: the rows cover `[0, total)` (and `[0, total * c)`) without overlap, and in each
    // row every tile's range was written in full (checked above): all slots are initialised.
    unsafe {
        packed.set_len(total);
        packed_features.set_len(total * c);
    }
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

/// Per tile row, the splats (indices into `rects`, in order) whose tile rectangle spans it.
/// Built over chunks of splats in parallel, then joined per row in chunk order, so that each
/// row's list keeps the depth order.
fn splats_by_row(rects: &[[u32; 4]], tiles_y: usize) -> Vec<Vec<u32>> {
    const CHUNK: usize = 8192;
    let chunks: Vec<Vec<Vec<u32>>> = rects
        .par_chunks(CHUNK)
        .enumerate()
        .map(|(k, chunk)| {
            let mut rows = vec![Vec::new(); tiles_y];
            for (o, r) in chunk.iter().enumerate() {
                let j = (k * CHUNK + o) as u32;
                for row in &mut rows[r[1] as usize..r[3] as usize] {
                    row.push(j);
                }
            }
            rows
        })
        .collect();
    (0..tiles_y)
        .into_par_iter()
        .map(|ty| {
            let mut row = Vec::with_capacity(chunks.iter().map(|c| c[ty].len()).sum());
            for c in &chunks {
                row.extend_from_slice(&c[ty]);
            }
            row
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use rand::{RngExt, SeedableRng, rngs::StdRng};

    use crate::config::TILE_SIZE;

    use super::*;

    /// Random pixel rectangles on a 640x480 image (40x30 tiles), more splats than three chunks
    /// of [`splats_by_row`], and every tile list against the definition.
    #[test]
    fn bins_hold_each_tiles_splats_in_depth_order() {
        let (tiles_x, tiles_y) = (40u32, 30u32);
        let (w, h) = (tiles_x * TILE_SIZE, tiles_y * TILE_SIZE);
        let mut rng = StdRng::seed_from_u64(7);
        let n = 20_000;
        let sorted: Vec<Splat<f32>> = (0..n)
            .map(|j| {
                let x0 = rng.random_range(0..w);
                let y0 = rng.random_range(0..h);
                let (dx, dy) = (rng.random_range(1..70), rng.random_range(1..70));
                Splat {
                    depth: j as f32,
                    rect: [x0, y0, (x0 + dx).min(w), (y0 + dy).min(h)],
                    ..Splat::default()
                }
            })
            .collect();
        let c = 2;
        let feats: Vec<f32> = (0..n * c).map(|k| k as f32).collect();
        let bins = bin(&sorted, &feats, c, tiles_x, tiles_y);

        let mut expected_total = 0;
        for ty in 0..tiles_y {
            for tx in 0..tiles_x {
                let want: Vec<usize> = (0..n)
                    .filter(|&j| {
                        let r = sorted[j].tile_rect();
                        r[0] <= tx && tx < r[2] && r[1] <= ty && ty < r[3]
                    })
                    .collect();
                let [a, b] = bins.tile_ranges[(ty * tiles_x + tx) as usize];
                let got: Vec<usize> = bins.packed[a as usize..b as usize]
                    .iter()
                    .map(|s| s.depth as usize)
                    .collect();
                assert_eq!(got, want, "tile ({tx}, {ty})");
                for (k, &j) in (a as usize..).zip(&want) {
                    assert_eq!(
                        bins.packed_features[k * c..(k + 1) * c],
                        feats[j * c..(j + 1) * c]
                    );
                }
                expected_total += want.len();
            }
        }
        assert_eq!(bins.packed.len(), expected_total);
        // Each splat's own list points at its intersections, row-major over its tile rectangle.
        for (j, s) in sorted.iter().enumerate() {
            let [tx0, ty0, tx1, ty1] = s.tile_rect();
            let [a, b] = bins.splat_ranges[j];
            let slots = &bins.isects_of_splat[a as usize..b as usize];
            assert_eq!(slots.len() as u32, (tx1 - tx0) * (ty1 - ty0));
            for (&slot, (ty, tx)) in slots
                .iter()
                .zip((ty0..ty1).flat_map(|ty| (tx0..tx1).map(move |tx| (ty, tx))))
            {
                let [ta, tb] = bins.tile_ranges[(ty * tiles_x + tx) as usize];
                assert!(
                    ta <= slot && slot < tb,
                    "splat {j}: slot outside tile ({tx}, {ty})"
                );
                assert_eq!(bins.packed[slot as usize].depth as usize, j);
            }
        }
    }
}
