//! The wgpu backend (feature `wgpu`): the splatting op on Burn's `CubeBackend`, run lazily
//! through `Fusion` (which is what `Device::wgpu(..)` uses), and differentiable through the
//! same `Autodiff` node as the CPU kernels.
//!
//! Per render, on the device: projection ([`fn@project::project_forward`]), a radix sort of the
//! Gaussians by depth ([`scan_sort::radix_sort`]), the tile counts in depth order and their
//! exclusive scan ([`scan_sort::exclusive_scan`]), one 4-byte readback of the intersection
//! count (to size the intersection buffers), emission of (tile, emission) pairs, a stable
//! radix sort by tile (so each tile's list stays in depth order, ties by index, as on the
//! CPU), tile ranges, and the blend. The backward pass re-derives the same bins (the sorts are
//! deterministic), walks each tile back to front writing one gradient row per intersection,
//! then sums each Gaussian's rows and applies the projection VJP: no float atomics, and the
//! result does not depend on scheduling.
//!
//! The kernels, one module per stage as in [`crate::cpu`]: [`project`] (projection and its
//! VJP), [`mod@bin`] (tile binning), [`raster`] (the blend and its backward pass),
//! [`gather`] (the per-Gaussian sums of the backward's gradient rows), with what they share
//! in [`common`], and [`scan_sort`] (prefix sum and radix sort). They follow the CPU kernels
//! operation for operation (same row-wise power evaluation, same alpha cut-off, cap and
//! transmittance stop, same culling and status codes), so that the two agree to rounding.
//! Loops run over compile-time bounds or over per-splat tile rectangles.
//!
//! f32 only: f64 inputs are refused by [`crate::render`] on this backend.

// `#[cube(launch)]` generates undocumented modules and launch functions per kernel.
#[allow(missing_docs)]
pub mod bin;
pub mod common;
#[allow(missing_docs)]
pub mod gather;
#[allow(missing_docs)]
pub mod project;
#[allow(missing_docs)]
pub mod raster;
#[allow(missing_docs)]
pub mod scan_sort;

use burn::backend::{
    Backend, ExtensionType, backend_extension, fusion::Fusion, fusion::custom::TensorSpec,
    tensor::FloatTensor,
};
use burn::tensor::{DType, Shape};
use burn_cubecl::CubeBackend;
use burn_cubecl::cubecl;
use burn_cubecl::tensor::CubeTensor;
use cubecl::prelude::*;
use cubecl::server::Handle;

use crate::backend::{
    SplatBackend, SplatKernels, SplatPrimitives, SplatPrimitivesMetadata, splat_meta,
};
use crate::config::{AlphaCutoff, SplatConfig, TILE_SIZE};
use common::{CAM, PROJ};
use scan_sort::{Client, bits_for, buffer_arg, elementwise_flat, exclusive_scan, radix_sort, zero};

/// Everything the forward pass produces: the `[H, W, C + 1]` image, the `[N, 4]` aux rows, and
/// the `[H, W]` final transmittance and contributor counts the backward pass needs.
#[derive(ExtensionType, Debug)]
#[extension_type(fusion)]
pub struct GpuForward<B: Backend> {
    /// `[H, W, C + 1]`
    pub image: FloatTensor<B>,
    /// `[N, 4]`
    pub aux: FloatTensor<B>,
    /// `[H, W]` transmittance after the blend.
    pub t_final: FloatTensor<B>,
    /// `[H, W]` one past the index (in its tile's list) of the last splat blended, as f32
    /// (exact below 2^24).
    pub n_contrib: FloatTensor<B>,
}

fn spec(shape: Vec<usize>, like: &TensorSpec) -> TensorSpec {
    TensorSpec::new(Shape::from(shape), like.dtype)
}

/// The outputs of [`SplatBackend::splat`] (its [`splat_meta`]), and the transmittance and
/// contributor counts.
fn forward_meta(inputs: &SplatPrimitivesMetadata, config: &SplatConfig) -> GpuForwardMetadata {
    let (h, w) = (config.camera.height as usize, config.camera.width as usize);
    let means = &inputs.means;
    let (image, aux) = splat_meta(inputs, config);
    GpuForwardMetadata {
        image,
        aux,
        t_final: spec(vec![h, w], means),
        n_contrib: spec(vec![h, w], means),
    }
}

/// The splatting kernels as a CubeCL backend extension: forward with the state the backward
/// needs, and backward. `Fusion<CubeBackend>` gets a lazy implementation (the op is recorded
/// in the fusion stream and runs these kernels when flushed).
#[backend_extension(Cube: cfg(feature = "wgpu"), Fusion: cfg(feature = "wgpu"))]
pub trait SplatGpuOps: Backend {
    /// Forward splat (see [`GpuForward`]).
    #[fusion(meta = forward_meta)]
    fn splat_gpu_forward(
        #[extension_type] inputs: SplatPrimitives<Self>,
        config: SplatConfig,
    ) -> GpuForward<Self>;

    /// Backward splat: gradients of the inputs (in their layout) given the gradient of the
    /// image and the state saved by the forward pass.
    #[fusion(meta = |inputs, _t_final, _n_contrib, _grad, _config| inputs.clone())]
    fn splat_gpu_backward(
        #[extension_type] inputs: SplatPrimitives<Self>,
        t_final: FloatTensor<Self>,
        n_contrib: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        config: SplatConfig,
    ) -> SplatPrimitives<Self>;
}

// ---------------------------------------------------------------------------------------------
// Host side of the CubeBackend implementation.

/// A contiguous f32 input's buffer and element count.
fn buffer(t: CubeTensor, name: &str) -> (Handle, u32) {
    assert_eq!(
        t.dtype,
        DType::F32,
        "gtsr-render-kernels (wgpu): {name} must be f32, got {:?}",
        t.dtype
    );
    let t = burn_cubecl::kernel::into_contiguous(t);
    let len = t.meta.num_elements();
    (t.handle, len as u32)
}

fn arg(h: &Handle, len: u32) -> BufferArg {
    buffer_arg(h, len.max(1))
}

fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// Device buffers of the six inputs.
struct Inputs {
    means: Handle,
    quats: Handle,
    scales: Handle,
    opacities: Handle,
    features: Handle,
    offsets: Handle,
    n: u32,
    channels: usize,
}

impl Inputs {
    fn new(p: SplatPrimitives<CubeBackend>) -> (Self, Client, burn_cubecl::CubeDevice) {
        let client = p.means.client.clone();
        let device = p.means.device.clone();
        let c = p.features.meta.shape()[1];
        let (means, n) = buffer(p.means, "means");
        let n = n / 3;
        let inputs = Self {
            means,
            quats: buffer(p.quats, "quats").0,
            scales: buffer(p.scales, "scales").0,
            opacities: buffer(p.opacities, "opacities").0,
            features: buffer(p.features, "features").0,
            offsets: buffer(p.xy_offsets, "xy_offsets").0,
            n,
            channels: c,
        };
        (inputs, client, device)
    }
}

/// The camera as the kernels read it (see [`common::CAM`]).
fn camera_buffer(client: &Client, config: &SplatConfig) -> Handle {
    let c = &config.camera;
    let mut v = Vec::with_capacity(CAM as usize);
    for row in c.rotation {
        v.extend(row.map(|x| x as f32));
    }
    v.extend(c.translation.map(|x| x as f32));
    v.extend([c.fx, c.fy, c.cx, c.cy, c.near, c.far].map(|x| x as f32));
    let (lim_x, lim_y) = c.jacobian_limits();
    v.extend(lim_x.into_iter().chain(lim_y).map(|x| x as f32));
    v.push(config.blur_px2 as f32);
    v.push(if config.compensate_blur { 1.0 } else { 0.0 });
    debug_assert_eq!(v.len(), CAM as usize);
    client.create_from_slice(&f32_bytes(&v))
}

/// Projected and binned splats of one render.
struct Bins {
    cam: Handle,
    proj: Handle,
    aux: Handle,
    /// Gaussians in depth order (culled ones last).
    order: Handle,
    /// `[N + 1]` exclusive scan of the tile counts in depth order.
    starts: Handle,
    /// Number of intersections.
    total: u32,
    /// Per sorted intersection, its Gaussian.
    sorted_gids: Handle,
    /// Per emission, its position in the sorted list.
    position: Handle,
    /// Per tile, `[start, end)`.
    ranges: Handle,
    /// Per sorted intersection, its tile id.
    sorted_keys: Handle,
    tiles: (u32, u32),
}

fn bin(client: &Client, x: &Inputs, config: &SplatConfig) -> Bins {
    let n = x.n;
    let c = x.channels;
    let cam = camera_buffer(client, config);
    let (width, height) = (config.camera.width, config.camera.height);
    let tiles_x = width.div_ceil(TILE_SIZE);
    let tiles_y = height.div_ceil(TILE_SIZE);
    let num_tiles = tiles_x * tiles_y;
    let words = |k: u32| client.empty(k.max(1) as usize * 4);
    let proj = words(n * PROJ);
    let aux = words(n * 4);
    let tile_counts = words(n);
    let keys = words(n);
    let vals = words(n);
    let (count, dim) = elementwise_flat(n);
    if n > 0 {
        project::project_forward::launch(
            client,
            count.clone(),
            dim,
            arg(&x.means, 3 * n),
            arg(&x.quats, 4 * n),
            arg(&x.scales, 3 * n),
            arg(&x.opacities, n),
            arg(&x.features, n * c as u32),
            arg(&x.offsets, 2 * n),
            arg(&cam, CAM),
            arg(&proj, n * PROJ),
            arg(&aux, 4 * n),
            arg(&tile_counts, n),
            arg(&keys, n),
            arg(&vals, n),
            n,
            width,
            height,
            c,
        );
    }
    let (_, order) = radix_sort(client, keys, vals, n, 32);
    let starts = words(n + 1);
    let (count1, dim1) = elementwise_flat(n + 1);
    bin::gather_counts::launch(
        client,
        count1,
        dim1,
        arg(&order, n),
        arg(&tile_counts, n),
        arg(&starts, n + 1),
        n,
    );
    exclusive_scan(client, &starts, n + 1);
    let total = scan_sort::read_u32(client, &starts, n + 1, n);
    let ranges = words(2 * num_tiles);
    zero(client, &ranges, 2 * num_tiles);
    let sorted_gids = words(total);
    let position = words(total);
    let mut sorted_keys = words(1);
    if total > 0 {
        let ikeys = words(total);
        let ivals = words(total);
        let gids = words(total);
        bin::emit_intersections::launch(
            client,
            count,
            dim,
            arg(&order, n),
            arg(&starts, n + 1),
            arg(&proj, n * PROJ),
            arg(&ikeys, total),
            arg(&ivals, total),
            arg(&gids, total),
            n,
            tiles_x,
        );
        let (skeys, svals) = radix_sort(client, ikeys, ivals, total, bits_for(num_tiles - 1));
        let (tc, td) = elementwise_flat(total);
        bin::finish_bins::launch(
            client,
            tc,
            td,
            arg(&skeys, total),
            arg(&svals, total),
            arg(&gids, total),
            arg(&sorted_gids, total),
            arg(&position, total),
            arg(&ranges, 2 * num_tiles),
            total,
        );
        sorted_keys = skeys;
    }
    Bins {
        cam,
        proj,
        aux,
        order,
        starts,
        total,
        sorted_gids,
        position,
        ranges,
        sorted_keys,
        tiles: (tiles_x, tiles_y),
    }
}

/// The backward pass writes one gradient row per intersection; rows are produced and summed
/// per band of tile rows so that their buffer stays below this size (lavapipe, for one, binds
/// at most 128 MiB per storage buffer). `GTSR_WGPU_BAND_BYTES` overrides it (the tests use a
/// tiny value to exercise many bands; results are bit-identical either way, because each
/// Gaussian's rows are added in the same order).
const BAND_BYTES: usize = 64 << 20;

fn band_bytes() -> usize {
    std::env::var("GTSR_WGPU_BAND_BYTES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(BAND_BYTES)
}

/// Bands of tile rows `[a, b)` holding at most `budget` intersections each (a single row
/// holding more is a band of its own), from the first intersection of every tile row.
fn bands(row_starts: &[u32], budget: u32) -> Vec<(u32, u32)> {
    let rows = row_starts.len() as u32 - 1;
    let mut out = Vec::new();
    let mut a = 0;
    while a < rows {
        let mut b = a + 1;
        while b < rows && row_starts[b as usize + 1] - row_starts[a as usize] <= budget {
            b += 1;
        }
        out.push((a, b));
        a = b;
    }
    out
}

fn tensor(
    client: &Client,
    device: &burn_cubecl::CubeDevice,
    handle: Handle,
    shape: Vec<usize>,
) -> CubeTensor {
    CubeTensor::new_contiguous(
        client.clone(),
        device.clone(),
        Shape::from(shape),
        handle,
        DType::F32,
    )
}

fn background_buffer(client: &Client, config: &SplatConfig) -> Handle {
    let bg: Vec<f32> = config.background.iter().map(|&b| b as f32).collect();
    client.create_from_slice(&f32_bytes(&bg))
}

fn gpu_forward(p: SplatPrimitives<CubeBackend>, config: &SplatConfig) -> GpuForward<CubeBackend> {
    let (x, client, device) = Inputs::new(p);
    let c = x.channels;
    let b = bin(&client, &x, config);
    let (width, height) = (config.camera.width, config.camera.height);
    let pixels = width * height;
    let image = client.empty(pixels as usize * (c + 1) * 4);
    let t_final = client.empty(pixels as usize * 4);
    let n_contrib = client.empty(pixels as usize * 4);
    let bg = background_buffer(&client, config);
    raster::rasterize_forward::launch(
        &client,
        CubeCount::Static(b.tiles.0, b.tiles.1, 1),
        CubeDim::new_2d(TILE_SIZE, TILE_SIZE),
        arg(&b.proj, x.n * PROJ),
        arg(&b.sorted_gids, b.total),
        arg(&b.ranges, 2 * b.tiles.0 * b.tiles.1),
        arg(&x.features, x.n * c as u32),
        arg(&bg, c as u32),
        arg(&image, pixels * (c as u32 + 1)),
        arg(&t_final, pixels),
        arg(&n_contrib, pixels),
        width,
        height,
        c,
        config.cutoff == AlphaCutoff::Smooth,
    );
    let (h, w) = (height as usize, width as usize);
    GpuForward {
        image: tensor(&client, &device, image, vec![h, w, c + 1]),
        aux: tensor(&client, &device, b.aux, vec![x.n as usize, 4]),
        t_final: tensor(&client, &device, t_final, vec![h, w]),
        n_contrib: tensor(&client, &device, n_contrib, vec![h, w]),
    }
}

fn gpu_backward(
    p: SplatPrimitives<CubeBackend>,
    t_final: CubeTensor,
    n_contrib: CubeTensor,
    grad: CubeTensor,
    config: &SplatConfig,
) -> SplatPrimitives<CubeBackend> {
    let (x, client, device) = Inputs::new(p);
    let (t_final, pixels) = buffer(t_final, "t_final");
    let (n_contrib, _) = buffer(n_contrib, "n_contrib");
    let (grad, grad_len) = buffer(grad, "the image gradient");
    let c = x.channels;
    assert_eq!(
        grad_len,
        pixels * (c as u32 + 1),
        "gtsr-render-kernels (wgpu): the gradient of the splat output has the wrong size"
    );
    let n = x.n;
    let b = bin(&client, &x, config);
    let values = c as u32 + 6;
    let bg = background_buffer(&client, config);
    let (width, height) = (config.camera.width, config.camera.height);
    let zeros = |k: u32| {
        let h = client.empty(k.max(1) as usize * 4);
        zero(&client, &h, k);
        h
    };
    // Per-Gaussian sums of the gradient rows (Gaussian order).
    let sums = zeros(n * values);
    if b.total > 0 {
        let (tiles_x, tiles_y) = b.tiles;
        let row_starts = client.empty((tiles_y as usize + 1) * 4);
        let (count, dim) = elementwise_flat(b.total);
        gather::tile_row_starts::launch(
            &client,
            count,
            dim,
            arg(&b.sorted_keys, b.total),
            arg(&row_starts, tiles_y + 1),
            b.total,
            tiles_x,
            tiles_y,
        );
        // A second small readback: where each tile row's intersections start.
        let row_starts = scan_sort::download(&client, row_starts, tiles_y as usize + 1);
        let budget = (band_bytes() / (values as usize * 4)).max(1) as u32;
        let bands = bands(&row_starts, budget);
        let most = bands
            .iter()
            .map(|&(a, z)| row_starts[z as usize] - row_starts[a as usize])
            .max()
            .unwrap_or(0);
        let rows = client.empty((most * values).max(1) as usize * 4);
        for (lo, hi) in bands {
            let base = row_starts[lo as usize];
            let len = row_starts[hi as usize] - base;
            if len == 0 {
                continue;
            }
            zero(&client, &rows, len * values);
            raster::rasterize_backward::launch(
                &client,
                CubeCount::Static(tiles_x, hi - lo, 1),
                CubeDim::new_2d(TILE_SIZE, TILE_SIZE),
                arg(&b.proj, n * PROJ),
                arg(&b.sorted_gids, b.total),
                arg(&b.ranges, 2 * tiles_x * tiles_y),
                arg(&x.features, n * c as u32),
                arg(&bg, c as u32),
                arg(&grad, grad_len),
                arg(&t_final, pixels),
                arg(&n_contrib, pixels),
                arg(&rows, most * values),
                width,
                height,
                lo,
                base,
                c,
                config.cutoff == AlphaCutoff::Smooth,
            );
            let (count, dim) = elementwise_flat(n);
            gather::accumulate_band::launch(
                &client,
                count,
                dim,
                arg(&b.order, n),
                arg(&b.starts, n + 1),
                arg(&b.proj, n * PROJ),
                arg(&b.position, b.total),
                arg(&rows, most * values),
                arg(&sums, n * values),
                n,
                lo,
                hi,
                base,
                c,
            );
        }
    }
    let g_means = zeros(3 * n);
    let g_quats = zeros(4 * n);
    let g_scales = zeros(3 * n);
    let g_opacities = zeros(n);
    let g_features = zeros(n * c as u32);
    let g_offsets = zeros(2 * n);
    if n > 0 && b.total > 0 {
        let (count, dim) = elementwise_flat(n);
        project::project_backward::launch(
            &client,
            count,
            dim,
            arg(&b.order, n),
            arg(&b.starts, n + 1),
            arg(&sums, n * values),
            arg(&x.means, 3 * n),
            arg(&x.quats, 4 * n),
            arg(&x.scales, 3 * n),
            arg(&x.opacities, n),
            arg(&x.offsets, 2 * n),
            arg(&b.cam, CAM),
            arg(&g_means, 3 * n),
            arg(&g_quats, 4 * n),
            arg(&g_scales, 3 * n),
            arg(&g_opacities, n),
            arg(&g_features, n * c as u32),
            arg(&g_offsets, 2 * n),
            n,
            c,
        );
    }
    let n = n as usize;
    SplatPrimitives {
        means: tensor(&client, &device, g_means, vec![n, 3]),
        quats: tensor(&client, &device, g_quats, vec![n, 4]),
        scales: tensor(&client, &device, g_scales, vec![n, 3]),
        opacities: tensor(&client, &device, g_opacities, vec![n]),
        features: tensor(&client, &device, g_features, vec![n, c]),
        xy_offsets: tensor(&client, &device, g_offsets, vec![n, 2]),
    }
}

impl SplatGpuOps for CubeBackend {
    fn splat_gpu_forward(inputs: SplatPrimitives<Self>, config: SplatConfig) -> GpuForward<Self> {
        gpu_forward(inputs, &config)
    }

    fn splat_gpu_backward(
        inputs: SplatPrimitives<Self>,
        t_final: FloatTensor<Self>,
        n_contrib: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        config: SplatConfig,
    ) -> SplatPrimitives<Self> {
        gpu_backward(inputs, t_final, n_contrib, grad, &config)
    }
}

impl SplatBackend for CubeBackend {
    fn splat(
        inputs: SplatPrimitives<Self>,
        config: SplatConfig,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let out = Self::splat_gpu_forward(inputs, config);
        (out.image, out.aux)
    }
}

/// What the autodiff node keeps on a CubeCL backend: the inputs (handles, not copies), the
/// final transmittance and contributor counts, and the settings.
#[derive(Debug, Clone)]
pub struct GpuSplatState<B: Backend> {
    inputs: SplatPrimitives<B>,
    t_final: FloatTensor<B>,
    n_contrib: FloatTensor<B>,
    config: SplatConfig,
}

macro_rules! gpu_kernels {
    ($ty:ty) => {
        impl SplatKernels for $ty {
            type SplatState = GpuSplatState<$ty>;

            fn splat_forward(
                inputs: SplatPrimitives<Self>,
                config: &SplatConfig,
            ) -> (FloatTensor<Self>, FloatTensor<Self>, Self::SplatState) {
                let out = <$ty as SplatGpuOps>::splat_gpu_forward(inputs.clone(), config.clone());
                let state = GpuSplatState {
                    inputs,
                    t_final: out.t_final,
                    n_contrib: out.n_contrib,
                    config: config.clone(),
                };
                (out.image, out.aux, state)
            }

            fn splat_backward(
                state: Self::SplatState,
                grad: FloatTensor<Self>,
            ) -> [FloatTensor<Self>; 6] {
                <$ty as SplatGpuOps>::splat_gpu_backward(
                    state.inputs,
                    state.t_final,
                    state.n_contrib,
                    grad,
                    state.config,
                )
                .into_array()
            }
        }
    };
}

gpu_kernels!(CubeBackend);
gpu_kernels!(Fusion<CubeBackend>);

#[cfg(test)]
mod tests {
    use super::bands;

    #[test]
    fn bands_respect_the_budget_and_cover_every_row() {
        // Rows hold 5, 0, 7, 2, 9 intersections.
        let starts = [0, 5, 5, 12, 14, 23];
        assert_eq!(bands(&starts, 100), vec![(0, 5)]);
        assert_eq!(bands(&starts, 12), vec![(0, 3), (3, 5)]);
        // A row over the budget is a band of its own.
        assert_eq!(bands(&starts, 6), vec![(0, 2), (2, 3), (3, 4), (4, 5)]);
        assert_eq!(bands(&[0, 0], 1), vec![(0, 1)]);
    }
}
