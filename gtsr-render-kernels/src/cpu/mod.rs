//! The CPU implementation: projection, depth sort + tile binning, blending, and the backward
//! pass, parallel over Gaussians and tiles with rayon, generic over `f32` / `f64`.
//!
//! These functions work on host slices; [`crate::backend`] wires them into Burn's NdArray
//! backend. They are public (in the `cpu` module) so that benchmarks and tools can call them
//! without Burn, and so that other backends can use them as a reference.

mod alloc;
mod arith;
mod bin;
mod host;
mod lanes;
mod project;
mod raster;
mod timing;

pub use alloc::keep_freed_memory;
pub use host::{HostBuffers, HostGaussians, HostGradients};
pub use lanes::{BlendPath, exp_lanes};
pub use timing::{KernelTimes, kernel_times};
pub(crate) use timing::{Phase, lap};

use std::time::Instant;

use rayon::prelude::*;

use crate::config::{SplatConfig, TILE_PIXELS, TILE_SIZE, status};
use crate::scalar::Real;
use bin::Bins;
use project::{CamF, Splat};
use raster::{RasterCtx, RasterState, SLOT_FIXED};

/// What the forward pass keeps for the backward pass.
#[derive(Debug)]
pub struct ForwardState<F> {
    /// Visible Gaussians in depth order (indices).
    order: Vec<u32>,
    bins: Bins<F>,
    raster: RasterState<F>,
    background: Vec<F>,
    channels: usize,
    path: BlendPath,
}

/// Output of [`forward`].
#[derive(Debug)]
pub struct ForwardOutput<F> {
    /// Row-major `[H, W, C + 1]`: the blended features over the background, then alpha.
    pub image: Vec<F>,
    /// Row-major `[N, 4]`: screen radius in pixels (max half extent), camera depth, number of
    /// tiles touched, status code ([`crate::config::status`]).
    pub aux: Vec<F>,
    /// Splat-pixel alpha evaluations performed by the blend.
    pub evaluations: u64,
    /// Tile-splat intersections.
    pub intersections: usize,
    /// State for [`backward`].
    pub state: ForwardState<F>,
}

/// Renders `g` with `cfg`. Shapes must be consistent (the Burn wrapper checks them). f32 blends
/// on [`BlendPath::default_path`].
pub fn forward<F: Real>(g: &HostGaussians<'_, F>, cfg: &SplatConfig) -> ForwardOutput<F> {
    forward_impl(g, cfg, None, BlendPath::default_path())
}

/// [`forward`] on a chosen blend implementation (one this CPU can run, else the portable
/// build of it). [`backward`] uses the same one.
pub fn forward_with<F: Real>(
    g: &HostGaussians<'_, F>,
    cfg: &SplatConfig,
    path: BlendPath,
) -> ForwardOutput<F> {
    forward_impl(g, cfg, None, path)
}

/// Output of [`crossing_features`].
#[derive(Debug, Clone)]
pub struct CrossingOutput<F> {
    /// Row-major `[H, W, C]`: per pixel the features of the splat whose blend took the pixel's
    /// transmittance to or below the threshold (0 where it stayed above).
    pub features: Vec<F>,
    /// Row-major `[H, W]`: 1 where the transmittance crossed the threshold, else 0.
    pub found: Vec<F>,
    /// Row-major `[H, W, C + 1]`: the ordinary render ([`ForwardOutput::image`]).
    pub image: Vec<F>,
    /// Per Gaussian (input order): blended at one pixel at least while the transmittance in
    /// front of it was above the threshold, i.e. among the splats that decide the pixel up to
    /// the crossing (PGSR's observation count of a view, as a flag). False for Gaussians that
    /// are culled, off screen, or always behind the crossing.
    pub observed: Vec<bool>,
}

/// Forward only: per pixel the features of the splat at which the front-to-back transmittance
/// first falls to or below `threshold` (in `(0, 1)`; 0.5 gives the "median" splat of 2DGS's and
/// RaDe-GS's median depth), not a blend. With per-splat plane features this gives the depth of
/// one splat's plane along the ray instead of a weighted mean over every layer the ray crosses.
///
/// # Panics
/// If `threshold` is not in `(0, 1)` (the Burn wrapper [`crate::render_crossing`] checks it).
pub fn crossing_features<F: Real>(
    g: &HostGaussians<'_, F>,
    cfg: &SplatConfig,
    threshold: f64,
) -> CrossingOutput<F> {
    assert!(
        threshold > 0.0 && threshold < 1.0,
        "crossing threshold must be in (0, 1), got {threshold}"
    );
    let out = forward_impl(g, cfg, Some(F::c(threshold)), BlendPath::PerPixel);
    let c = out.state.channels;
    let bins = &out.state.bins;
    let cross = &out.state.raster.crossing;
    let (w, h) = (cfg.camera.width as usize, cfg.camera.height as usize);
    let tiles_x = cfg.camera.tile_grid().0 as usize;
    let ts = TILE_SIZE as usize;
    let mut features = vec![F::zero(); w * h * c];
    let mut found = vec![F::zero(); w * h];
    features
        .par_chunks_mut(w * c)
        .zip(found.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, (row, frow))| {
            for x in 0..w {
                let t = (y / ts) * tiles_x + x / ts;
                let k = cross[t * TILE_PIXELS + (y % ts) * ts + x % ts] as usize;
                if k == 0 {
                    continue;
                }
                let j = bins.tile_ranges[t][0] as usize + k - 1;
                row[x * c..(x + 1) * c].copy_from_slice(&bins.packed_features[j * c..(j + 1) * c]);
                frow[x] = F::one();
            }
        });
    let state = &out.state;
    let mut observed = vec![false; g.len()];
    for (j, &i) in state.order.iter().enumerate() {
        let [a, b] = bins.splat_ranges[j];
        observed[i as usize] = bins.isects_of_splat[a as usize..b as usize]
            .iter()
            .any(|&slot| state.raster.observed[slot as usize] != 0);
    }
    CrossingOutput {
        features,
        found,
        image: out.image,
        observed,
    }
}

fn forward_impl<F: Real>(
    g: &HostGaussians<'_, F>,
    cfg: &SplatConfig,
    crossing: Option<F>,
    path: BlendPath,
) -> ForwardOutput<F> {
    timing::count_call(false);
    let start = Instant::now();
    let cam = CamF::<F>::new(cfg);
    let n = g.len();
    let c = cfg.background.len();
    let projected: Vec<Result<Splat<F>, f32>> =
        project_f32_lanes(g, cfg, path).unwrap_or_else(|| {
            (0..n)
                .into_par_iter()
                .with_min_len(1024)
                .map(|i| {
                    if g.feature_not_finite(i, c) {
                        return Err(status::NON_FINITE);
                    }
                    project::project_one(&g.get(i), &cam)
                })
                .collect()
        });
    let mut aux = vec![F::zero(); n * 4];
    for (i, p) in projected.iter().enumerate() {
        match p {
            Ok(s) => {
                aux[4 * i] = s.extent[0].max(s.extent[1]);
                aux[4 * i + 1] = s.depth;
                aux[4 * i + 2] = F::c(s.tile_count() as f64);
                aux[4 * i + 3] = F::c(f64::from(status::VISIBLE));
            }
            Err(code) => aux[4 * i + 3] = F::c(f64::from(*code)),
        }
    }
    let splats: Vec<Option<Splat<F>>> = projected.into_iter().map(Result::ok).collect();
    let start = lap(Phase::Project, start);
    let (tiles_x, tiles_y) = cfg.camera.tile_grid();
    let order = bin::depth_order(&splats);
    let sorted: Vec<Splat<F>> = order
        .par_iter()
        .map(|&i| splats[i as usize].expect("sorted splats are visible"))
        .collect();
    let sorted_features: Vec<F> = order
        .par_iter()
        .flat_map_iter(|&i| {
            g.features[i as usize * c..(i as usize + 1) * c]
                .iter()
                .copied()
        })
        .collect();
    let bins = bin::bin(&sorted, &sorted_features, c, tiles_x, tiles_y);
    let background: Vec<F> = cfg.background.iter().map(|&b| F::c(b)).collect();
    let ctx = RasterCtx {
        width: cfg.camera.width,
        height: cfg.camera.height,
        tiles_x,
        channels: c,
        background: &background,
        cutoff: cfg.cutoff,
        crossing,
    };
    let start = lap(Phase::SortBin, start);
    let (image, raster, evaluations) = if lanes::serves(&ctx, path) {
        lanes::rasterize(&bins, &ctx, path)
    } else {
        raster::rasterize(&bins, &ctx)
    };
    lap(Phase::BlendForward, start);
    let intersections = bins.packed.len();
    ForwardOutput {
        image,
        aux,
        evaluations,
        intersections,
        state: ForwardState {
            order,
            bins,
            raster,
            background,
            channels: c,
            path,
        },
    }
}

/// The f32 inputs as f32 slices (`None` for f64).
fn as_f32<'a, F: Real>(g: &HostGaussians<'a, F>) -> Option<HostGaussians<'a, f32>> {
    Some(HostGaussians {
        means: F::slice_as_f32(g.means)?,
        quats: F::slice_as_f32(g.quats)?,
        scales: F::slice_as_f32(g.scales)?,
        opacities: F::slice_as_f32(g.opacities)?,
        features: F::slice_as_f32(g.features)?,
        xy_offsets: F::slice_as_f32(g.xy_offsets)?,
    })
}

/// The projection of f32 inputs on a lane path, 16 Gaussians at a time (`None` for f64 and the
/// per-pixel path). Bit-identical to the per-Gaussian projection.
fn project_f32_lanes<F: Real>(
    g: &HostGaussians<'_, F>,
    cfg: &SplatConfig,
    path: BlendPath,
) -> Option<Vec<Result<Splat<F>, f32>>> {
    if path == BlendPath::PerPixel {
        return None;
    }
    let g32 = as_f32(g)?;
    let cam = CamF::<f32>::new(cfg);
    let cam16 = cam.lanes();
    let c = cfg.background.len();
    const RUN: usize = 1024;
    let mut out: Vec<Result<Splat<f32>, f32>> = vec![Err(status::NON_FINITE); g.len()];
    out.par_chunks_mut(RUN).enumerate().for_each(|(k, out)| {
        path.run(project::ProjectLanes {
            g: &g32,
            channels: c,
            cam: &cam,
            cam16: &cam16,
            first: k * RUN,
            out,
        });
    });
    // `F` is f32 here (`as_f32` succeeded); the downcast only restores the generic type.
    let out: Box<dyn std::any::Any> = Box::new(out);
    out.downcast::<Vec<Result<Splat<F>, f32>>>()
        .ok()
        .map(|b| *b)
}

/// Gradients of the inputs given the gradient of the `[H, W, C + 1]` output.
pub fn backward<F: Real>(
    g: &HostGaussians<'_, F>,
    cfg: &SplatConfig,
    state: &ForwardState<F>,
    grad_image: &[F],
) -> HostGradients<F> {
    timing::count_call(true);
    let start = Instant::now();
    let cam = CamF::<F>::new(cfg);
    let n = g.len();
    let c = state.channels;
    let (tiles_x, _) = cfg.camera.tile_grid();
    let ctx = RasterCtx {
        width: cfg.camera.width,
        height: cfg.camera.height,
        tiles_x,
        channels: c,
        background: &state.background,
        cutoff: cfg.cutoff,
        crossing: None,
    };
    let slots = if lanes::serves(&ctx, state.path) {
        lanes::rasterize_backward(&state.bins, &ctx, &state.raster, grad_image, state.path)
    } else {
        raster::rasterize_backward(&state.bins, &ctx, &state.raster, grad_image)
    };
    let start = lap(Phase::BlendBackward, start);
    let slot = SLOT_FIXED + c;
    let bins = &state.bins;

    // Per Gaussian (in parallel, in the input layout): the sum of its splat's intersection rows
    // in a fixed order (hence deterministic); zeros where it was culled.
    let mut position = vec![u32::MAX; n];
    for (j, &i) in state.order.iter().enumerate() {
        position[i as usize] = j as u32;
    }
    let mut sums = vec![F::zero(); n * slot];
    sums.par_chunks_mut(slot)
        .zip(position.par_iter())
        .with_min_len(256)
        .for_each(|(acc, &j)| {
            if j == u32::MAX {
                return;
            }
            let [s0, s1] = bins.splat_ranges[j as usize];
            for &k in &bins.isects_of_splat[s0 as usize..s1 as usize] {
                let row = &slots[k as usize * slot..(k as usize + 1) * slot];
                for (a, &r) in acc.iter_mut().zip(row) {
                    *a = *a + r;
                }
            }
        });
    // The screen gradients of the offsets and the features' rows are the gradients of those
    // inputs; the projection VJP gives the mean's, rotation's, scales' and opacity's (the
    // opacity blended is the input's times the blur's compensation, when on).
    let mut out = HostGradients {
        means: vec![F::zero(); 3 * n],
        quats: vec![F::zero(); 4 * n],
        scales: vec![F::zero(); 3 * n],
        opacities: vec![F::zero(); n],
        features: vec![F::zero(); c * n],
        xy_offsets: vec![F::zero(); 2 * n],
    };
    out.opacities
        .par_iter_mut()
        .zip(out.xy_offsets.par_chunks_mut(2))
        .zip(out.features.par_chunks_mut(c))
        .zip(sums.par_chunks(slot))
        .with_min_len(1024)
        .for_each(|(((dop, dxy), df), acc)| {
            // Culled Gaussians keep it (zero); the projection VJP replaces the others'.
            *dop = acc[5];
            dxy.copy_from_slice(&acc[..2]);
            df.copy_from_slice(&acc[SLOT_FIXED..]);
        });
    const RUN: usize = 512;
    let lanes_f32 = match (as_f32(g), F::slice_as_f32(&sums)) {
        (Some(g32), Some(sums32)) if state.path != BlendPath::PerPixel => Some((g32, sums32)),
        _ => None,
    };
    if let Some((g32, sums32)) = lanes_f32 {
        // f32 on a lane path: 16 Gaussians at a time, written in place.
        let cam16 = CamF::<f32>::new(cfg).lanes();
        let means = F::slice_as_f32_mut(&mut out.means).expect("f32");
        let quats = F::slice_as_f32_mut(&mut out.quats).expect("f32");
        let scales = F::slice_as_f32_mut(&mut out.scales).expect("f32");
        let opacities = F::slice_as_f32_mut(&mut out.opacities).expect("f32");
        means
            .par_chunks_mut(RUN * 3)
            .zip(quats.par_chunks_mut(RUN * 4))
            .zip(scales.par_chunks_mut(RUN * 3))
            .zip(opacities.par_chunks_mut(RUN))
            .enumerate()
            .for_each(|(k, (((dm, dq), ds), dop))| {
                let first = k * RUN;
                state.path.run(project::VjpLanes {
                    g: &g32,
                    cam: &cam16,
                    first,
                    visible: &position[first..(first + RUN).min(n)],
                    sums: &sums32[first * slot..],
                    stride: slot,
                    means: dm,
                    quats: dq,
                    scales: ds,
                    opacities: dop,
                });
            });
    } else {
        out.means
            .par_chunks_mut(3)
            .zip(out.quats.par_chunks_mut(4))
            .zip(out.scales.par_chunks_mut(3))
            .zip(out.opacities.par_iter_mut())
            .zip(sums.par_chunks(slot))
            .zip(position.par_iter())
            .enumerate()
            .with_min_len(256)
            .for_each(|(i, (((((dm, dq), ds), dop), acc), &j))| {
                if j == u32::MAX {
                    return; // culled: zero gradients
                }
                let d = project::ScreenGrad {
                    xy: [acc[0], acc[1]],
                    conic: [acc[2], acc[3], acc[4]],
                    opacity: acc[5],
                };
                let gg = project::project_vjp(&g.get(i), &cam, d);
                dm.copy_from_slice(&gg.mean);
                dq.copy_from_slice(&gg.quat);
                ds.copy_from_slice(&gg.scale);
                *dop = gg.opacity;
            });
    }
    lap(Phase::Gather, start);
    out
}
