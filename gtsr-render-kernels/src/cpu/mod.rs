//! The CPU implementation: projection, depth sort + tile binning, blending, and the backward
//! pass, parallel over Gaussians and tiles with rayon, generic over `f32` / `f64`.
//!
//! These functions work on host slices; [`crate::backend`] wires them into Burn's NdArray
//! backend. They are public (in the `cpu` module) so that benchmarks and tools can call them
//! without Burn, and so that other backends can use them as a reference.

mod bin;
mod project;
mod raster;

use rayon::prelude::*;

use crate::config::{SplatConfig, status};
use crate::scalar::Real;
use bin::Bins;
use project::{CamF, GaussIn, Splat};
use raster::{RasterCtx, RasterState, SLOT_FIXED};

/// The Gaussians of one render as host slices (row-major, `N` rows).
#[derive(Clone, Copy, Debug)]
pub struct HostGaussians<'a, F> {
    /// `[N, 3]` world-space means.
    pub means: &'a [F],
    /// `[N, 4]` quaternions (w, x, y, z), normalised inside.
    pub quats: &'a [F],
    /// `[N, 3]` scales (standard deviations along the local axes).
    pub scales: &'a [F],
    /// `[N]` opacities.
    pub opacities: &'a [F],
    /// `[N, C]` features.
    pub features: &'a [F],
    /// `[N, 2]` screen-space offsets added to the projected means (zeros normally; their
    /// gradient is the screen-space positional gradient used for densification).
    pub xy_offsets: &'a [F],
}

impl<F: Real> HostGaussians<'_, F> {
    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.opacities.len()
    }

    /// Whether there are no Gaussians.
    pub fn is_empty(&self) -> bool {
        self.opacities.is_empty()
    }

    fn get(&self, i: usize) -> GaussIn<F> {
        let m = &self.means[3 * i..3 * i + 3];
        let q = &self.quats[4 * i..4 * i + 4];
        let s = &self.scales[3 * i..3 * i + 3];
        let o = &self.xy_offsets[2 * i..2 * i + 2];
        GaussIn {
            mean: [m[0], m[1], m[2]],
            quat: [q[0], q[1], q[2], q[3]],
            scale: [s[0], s[1], s[2]],
            opacity: self.opacities[i],
            xy_offset: [o[0], o[1]],
        }
    }
}

/// What the forward pass keeps for the backward pass.
#[derive(Debug)]
pub struct ForwardState<F> {
    /// Visible Gaussians in depth order (indices).
    order: Vec<u32>,
    bins: Bins<F>,
    raster: RasterState<F>,
    background: Vec<F>,
    channels: usize,
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

/// Gradients of the raw inputs, laid out as the inputs.
#[derive(Debug, Clone)]
pub struct HostGradients<F> {
    /// `[N, 3]`
    pub means: Vec<F>,
    /// `[N, 4]`
    pub quats: Vec<F>,
    /// `[N, 3]`
    pub scales: Vec<F>,
    /// `[N]`
    pub opacities: Vec<F>,
    /// `[N, C]`
    pub features: Vec<F>,
    /// `[N, 2]`
    pub xy_offsets: Vec<F>,
}

/// Renders `g` with `cfg`. Shapes must be consistent (the Burn wrapper checks them).
pub fn forward<F: Real>(g: &HostGaussians<'_, F>, cfg: &SplatConfig) -> ForwardOutput<F> {
    let cam = CamF::<F>::new(cfg);
    let n = g.len();
    let c = cfg.background.len();
    let projected: Vec<Result<Splat<F>, f32>> = (0..n)
        .into_par_iter()
        .with_min_len(1024)
        .map(|i| {
            if g.features[i * c..(i + 1) * c]
                .iter()
                .any(|f| !f.is_finite())
            {
                return Err(status::NON_FINITE);
            }
            project::project_one(&g.get(i), &cam)
        })
        .collect();
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
    };
    let (image, raster, evaluations) = raster::rasterize(&bins, &ctx);
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
        },
    }
}

/// Gradients of the inputs given the gradient of the `[H, W, C + 1]` output.
pub fn backward<F: Real>(
    g: &HostGaussians<'_, F>,
    cfg: &SplatConfig,
    state: &ForwardState<F>,
    grad_image: &[F],
) -> HostGradients<F> {
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
    };
    let slots = raster::rasterize_backward(&state.bins, &ctx, &state.raster, grad_image);
    let slot = SLOT_FIXED + c;
    let bins = &state.bins;

    // Per splat (depth order, in parallel): sum its intersection rows in a fixed order (hence
    // deterministic), then the projection VJP.
    let mut splat_features = vec![F::zero(); state.order.len() * c];
    let per_splat: Vec<project::GaussGrad<F>> = state
        .order
        .par_iter()
        .zip(bins.splat_ranges.par_iter())
        .zip(splat_features.par_chunks_mut(c))
        .with_min_len(256)
        .map(|((&i, &[s0, s1]), feat)| {
            let mut acc = [F::zero(); SLOT_FIXED];
            for &k in &bins.isects_of_splat[s0 as usize..s1 as usize] {
                let row = &slots[k as usize * slot..(k as usize + 1) * slot];
                for (a, &r) in acc.iter_mut().zip(&row[..SLOT_FIXED]) {
                    *a = *a + r;
                }
                for (a, &r) in feat.iter_mut().zip(&row[SLOT_FIXED..]) {
                    *a = *a + r;
                }
            }
            project::project_vjp(
                &g.get(i as usize),
                &cam,
                [acc[0], acc[1]],
                [acc[2], acc[3], acc[4]],
                acc[5],
            )
        })
        .collect();
    // Scatter to the input layout, in parallel over Gaussians through the inverse order.
    let mut position = vec![u32::MAX; n];
    for (j, &i) in state.order.iter().enumerate() {
        position[i as usize] = j as u32;
    }
    let mut out = HostGradients {
        means: vec![F::zero(); 3 * n],
        quats: vec![F::zero(); 4 * n],
        scales: vec![F::zero(); 3 * n],
        opacities: vec![F::zero(); n],
        features: vec![F::zero(); c * n],
        xy_offsets: vec![F::zero(); 2 * n],
    };
    out.means
        .par_chunks_mut(3)
        .zip(out.quats.par_chunks_mut(4))
        .zip(out.scales.par_chunks_mut(3))
        .zip(out.opacities.par_iter_mut())
        .zip(out.features.par_chunks_mut(c))
        .zip(out.xy_offsets.par_chunks_mut(2))
        .zip(position.par_iter())
        .with_min_len(1024)
        .for_each(|((((((dm, dq), ds), dop), df), dxy), &j)| {
            if j == u32::MAX {
                return; // culled: zero gradients
            }
            let gg = &per_splat[j as usize];
            let feat = &splat_features[j as usize * c..(j as usize + 1) * c];
            dm.copy_from_slice(&gg.mean);
            dq.copy_from_slice(&gg.quat);
            ds.copy_from_slice(&gg.scale);
            *dop = gg.opacity;
            df.copy_from_slice(feat);
            dxy.copy_from_slice(&gg.xy_offset);
        });
    out
}
