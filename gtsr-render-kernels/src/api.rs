//! The public entry point: [`render`] on Burn tensors.

use burn::backend::Dispatch;
use burn::tensor::{Device, Tensor, TensorData};
use thiserror::Error;

use crate::backend::{SplatBackend, SplatPrimitives, supported_dtype};
use crate::config::SplatConfig;

/// The Gaussians to render, as Burn tensors on one device (any expression: activations, SH
/// evaluation or a Fresnel factor upstream are differentiated through).
#[derive(Clone, Debug)]
pub struct SplatInputs {
    /// `[N, 3]` world-space means.
    pub means: Tensor<2>,
    /// `[N, 4]` rotations as quaternions `(w, x, y, z)`; need not be unit (normalised inside;
    /// squared norms below [`crate::config::QUAT_MIN_NORM2`] are culled).
    pub quats: Tensor<2>,
    /// `[N, 3]` scales: standard deviations along the local axes (positive: apply `exp` to
    /// log-scales upstream).
    pub scales: Tensor<2>,
    /// `[N]` opacities in `[0, 1]` (apply `sigmoid` upstream; a view-dependent factor such as a
    /// Fresnel term may already be multiplied in).
    pub opacities: Tensor<1>,
    /// `[N, C]` features blended per pixel (RGB, normals, plane distances, material maps...).
    pub features: Tensor<2>,
    /// Optional `[N, 2]` screen-space offsets in pixels added to the projected means. Pass zeros
    /// that require grad to obtain the screen-space positional gradient (`dL/d(mean2d)`, what
    /// 3DGS densification thresholds); `None` uses zeros.
    pub xy_offsets: Option<Tensor<2>>,
}

/// The result of [`render`].
#[derive(Clone, Debug)]
pub struct RenderOutput {
    /// `[H, W, C]`: `sum_i f_i alpha_i T_i + T_final * background`. Differentiable.
    pub image: Tensor<3>,
    /// `[H, W]`: accumulated alpha `1 - T_final`. Differentiable.
    pub alpha: Tensor<2>,
    /// `[N, 4]`, not differentiated: per Gaussian the screen radius in pixels (largest half
    /// extent of the region where its alpha can reach 1/255), its camera-space depth, the number
    /// of 16x16 tiles it touches, and a status code ([`crate::config::status`]: 0 visible,
    /// 1 clipped by near/far, 2 non-finite parameter, 3 degenerate, 4 off screen / too
    /// transparent). Culled Gaussians have radius 0 and zero gradients.
    pub aux: Tensor<2>,
}

impl RenderOutput {
    /// `[N]` screen radius in pixels (0 when culled).
    pub fn radii(&self) -> Tensor<1> {
        self.aux
            .clone()
            .slice([0..self.aux.dims()[0], 0..1])
            .squeeze_dim(1)
    }

    /// `[N]` status codes (see [`crate::config::status`]).
    pub fn status(&self) -> Tensor<1> {
        self.aux
            .clone()
            .slice([0..self.aux.dims()[0], 3..4])
            .squeeze_dim(1)
    }
}

/// Why a render was refused.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum RenderError {
    /// A tensor has the wrong shape.
    #[error("{name} must have shape {expected}, got {got:?}")]
    Shape {
        /// Which input.
        name: &'static str,
        /// The expected shape, in words.
        expected: String,
        /// The actual shape.
        got: Vec<usize>,
    },
    /// The background has a different channel count from the features.
    #[error("background has {background} channels but features have {features}")]
    Background {
        /// Background length.
        background: usize,
        /// Feature channels.
        features: usize,
    },
    /// At least one feature channel is needed.
    #[error("features must have at least one channel")]
    NoChannels,
    /// The background contains NaN or infinity.
    #[error("background value {0} is not finite")]
    NonFiniteBackground(f64),
    /// The screen-space blur is negative, NaN or infinite.
    #[error("blur_px2 must be finite and non-negative, got {0}")]
    Blur(f64),
    /// Inputs on different devices, or of different float types.
    #[error("all inputs must share one device and one float dtype ({0})")]
    Mixed(String),
    /// The device's backend has no splatting kernels.
    #[error(
        "no splatting kernels for device {0:?}: supported are NdArray and, with the `wgpu` feature of gtsr-render-kernels, wgpu (with or without autodiff)"
    )]
    UnsupportedDevice(Device),
    /// The transmittance threshold of [`render_crossing`] is not in `(0, 1)`.
    #[error("crossing threshold must be in (0, 1), got {0}")]
    Threshold(f64),
    /// Only f32 and f64 are supported.
    #[error(
        "unsupported float dtype {0:?} on this device: NdArray takes f32 or f64, wgpu takes f32"
    )]
    UnsupportedDType(burn::tensor::DType),
}

/// Whether this build has splatting kernels for `device`.
pub fn device_supported(device: &Device) -> bool {
    use burn::backend::DispatchDevice;
    let inner = device.clone().without_autodiff();
    match inner.as_dispatch() {
        DispatchDevice::NdArray(_) => true,
        #[cfg(feature = "wgpu")]
        DispatchDevice::Cube(burn_cubecl::CubeDevice::Wgpu(_)) => true,
        _ => false,
    }
}

/// Whether the kernels of `device` compute in `dtype` (NdArray: f32 and f64; wgpu: f32).
fn dtype_supported_on(device: &Device, dtype: burn::tensor::DType) -> bool {
    use burn::backend::DispatchDevice;
    match device.clone().without_autodiff().as_dispatch() {
        DispatchDevice::NdArray(_) => supported_dtype(dtype),
        _ => dtype == burn::tensor::DType::F32,
    }
}

fn check_shape(
    name: &'static str,
    got: &[usize],
    expected: &[usize],
    words: &str,
) -> Result<(), RenderError> {
    if got != expected {
        return Err(RenderError::Shape {
            name,
            expected: words.to_string(),
            got: got.to_vec(),
        });
    }
    Ok(())
}

/// Checks shapes, devices, dtypes and settings; returns the offsets (zeros when absent).
fn validate(inputs: &SplatInputs, config: &SplatConfig) -> Result<Tensor<2>, RenderError> {
    let n = inputs.means.dims()[0];
    check_shape("means", &inputs.means.dims(), &[n, 3], "[N, 3]")?;
    check_shape("quats", &inputs.quats.dims(), &[n, 4], "[N, 4]")?;
    check_shape("scales", &inputs.scales.dims(), &[n, 3], "[N, 3]")?;
    check_shape("opacities", &inputs.opacities.dims(), &[n], "[N]")?;
    let c = inputs.features.dims()[1];
    check_shape("features", &inputs.features.dims(), &[n, c], "[N, C]")?;
    if c == 0 {
        return Err(RenderError::NoChannels);
    }
    if config.background.len() != c {
        return Err(RenderError::Background {
            background: config.background.len(),
            features: c,
        });
    }
    if let Some(b) = config.background.iter().find(|b| !b.is_finite()) {
        return Err(RenderError::NonFiniteBackground(*b));
    }
    if !config.blur_px2.is_finite() || config.blur_px2 < 0.0 {
        return Err(RenderError::Blur(config.blur_px2));
    }
    let device = inputs.means.device();
    let dtype = inputs.means.dtype();
    if !supported_dtype(dtype) {
        return Err(RenderError::UnsupportedDType(dtype));
    }
    if !device_supported(&device) {
        return Err(RenderError::UnsupportedDevice(device));
    }
    if !dtype_supported_on(&device, dtype) {
        return Err(RenderError::UnsupportedDType(dtype));
    }
    let xy_offsets = match &inputs.xy_offsets {
        Some(t) => {
            check_shape("xy_offsets", &t.dims(), &[n, 2], "[N, 2]")?;
            t.clone()
        }
        None => Tensor::zeros([n, 2], (&device, dtype)),
    };
    let all = [
        (inputs.quats.device(), inputs.quats.dtype()),
        (inputs.scales.device(), inputs.scales.dtype()),
        (inputs.opacities.device(), inputs.opacities.dtype()),
        (inputs.features.device(), inputs.features.dtype()),
        (xy_offsets.device(), xy_offsets.dtype()),
    ];
    for (d, t) in all {
        if d.clone().without_autodiff() != device.clone().without_autodiff() || t != dtype {
            return Err(RenderError::Mixed(format!(
                "means are {dtype:?} on {device:?}, another input is {t:?} on {d:?}"
            )));
        }
    }
    Ok(xy_offsets)
}

/// Splats `inputs` into the camera of `config`.
///
/// Projection (EWA, `config.blur_px2` screen-space blur, compensated in the opacity with
/// `config.compensate_blur`, Jacobian clamp, near/far and non-finite culling), depth sort and
/// 16x16 tile binning, and front-to-back blending follow the 3DGS conventions; see the crate
/// docs. On an autodiff device the image and alpha are differentiable with respect to every
/// input tensor.
///
/// ```
/// use burn::tensor::{Device, Tensor, TensorData};
/// use gtsr_render_kernels::{Camera, SplatConfig, SplatInputs, render};
///
/// let device = Device::ndarray();
/// let camera = Camera::look_at([0.0, 0.0, -4.0], [0.0; 3], [0.0, -1.0, 0.0], 0.69, 64, 64)?;
/// let inputs = SplatInputs {
///     means: Tensor::from_floats([[0.0, 0.0, 0.0]], &device),
///     quats: Tensor::from_floats([[1.0, 0.0, 0.0, 0.0]], &device),
///     scales: Tensor::from_floats([[0.2, 0.2, 0.2]], &device),
///     opacities: Tensor::from_floats([0.8], &device),
///     features: Tensor::from_floats([[1.0, 0.5, 0.0]], &device),
///     xy_offsets: None,
/// };
/// let config = SplatConfig::new(camera, 3);
/// let out = render(inputs, &config)?;
/// assert_eq!(out.image.dims(), [64, 64, 3]);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn render(inputs: SplatInputs, config: &SplatConfig) -> Result<RenderOutput, RenderError> {
    let xy_offsets = validate(&inputs, config)?;
    let c = inputs.features.dims()[1];
    let (h, w) = (config.camera.height as usize, config.camera.width as usize);
    let primitives = SplatPrimitives {
        means: inputs.means.into_dispatch(),
        quats: inputs.quats.into_dispatch(),
        scales: inputs.scales.into_dispatch(),
        opacities: inputs.opacities.into_dispatch(),
        features: inputs.features.into_dispatch(),
        xy_offsets: xy_offsets.into_dispatch(),
    };
    let (out, aux) = <Dispatch as SplatBackend>::splat(primitives, config.clone());
    let out: Tensor<3> = Tensor::from_dispatch(out);
    let aux: Tensor<2> = Tensor::from_dispatch(aux);
    // Image and alpha as products with 0/1 selection matrices rather than last-axis slices:
    // on the NdArray backend a slice along the last axis is a strided view, and every op that
    // reads one (here each loss term, forward and backward) runs several times slower than on
    // contiguous memory. The values are the same.
    let flat = out.reshape([h * w, c + 1]);
    let (device, dtype) = (flat.device(), flat.dtype());
    let select = |cols: std::ops::Range<usize>| {
        let k = cols.len();
        let mut v = vec![0f32; (c + 1) * k];
        for (j, col) in cols.enumerate() {
            v[col * k + j] = 1.0;
        }
        Tensor::<2>::from_data(TensorData::new(v, [c + 1, k]), &device).cast(dtype)
    };
    let image = flat.clone().matmul(select(0..c)).reshape([h, w, c]);
    let alpha = flat.matmul(select(c..c + 1)).reshape([h, w]);
    Ok(RenderOutput { image, alpha, aux })
}

/// The result of [`render_crossing`] (not differentiable).
#[derive(Clone, Debug)]
pub struct CrossingOutput {
    /// `[H, W, C]`: per pixel the features of the one splat whose blend took the pixel's
    /// transmittance to or below the threshold; 0 where it stayed above.
    pub features: Tensor<3>,
    /// `[H, W]`: 1 where the transmittance crossed the threshold, else 0.
    pub found: Tensor<2>,
    /// `[H, W]`: accumulated alpha `1 - T_final` of the same render (as [`RenderOutput::alpha`]).
    pub alpha: Tensor<2>,
    /// Per Gaussian: blended at one pixel at least while the transmittance in front of it was
    /// above the threshold (at 0.5, PGSR's "observed" in this view). Counted over the training
    /// views, it tells the Gaussians that decide some pixel from those always hidden behind
    /// others, which PGSR prunes.
    pub observed: Vec<bool>,
}

/// Forward only, not differentiable: per pixel, the features of the splat at which the
/// front-to-back transmittance first falls to or below `threshold` (in `(0, 1)`), instead of
/// their blend. At 0.5 this is the "median" splat behind 2DGS's median depth: with per-splat
/// plane features, one splat's ray-plane depth, where the blend averages every layer the ray
/// crosses. Same projection, sort and blending as [`render`]; the result is on the inputs'
/// device and dtype.
///
/// The kernels run on the host ([`crate::cpu::crossing_features`], f64 for f64 inputs, else
/// f32): on wgpu the inputs are read back first. Meant for one-off passes such as mesh
/// extraction, not for a training loop.
///
/// ```
/// use burn::tensor::{Device, Tensor, TensorData};
/// use gtsr_render_kernels::{Camera, SplatConfig, SplatInputs, render_crossing};
///
/// let device = Device::ndarray();
/// let camera = Camera::look_at([0.0, 0.0, -4.0], [0.0; 3], [0.0, -1.0, 0.0], 0.69, 64, 64)?;
/// // Two opaque discs, the front one at depth 3.5 (feature 3.5), the back one at 4.5.
/// let inputs = SplatInputs {
///     means: Tensor::from_floats([[0.0, 0.0, -0.5], [0.0, 0.0, 0.5]], &device),
///     quats: Tensor::from_floats([[1.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]], &device),
///     scales: Tensor::from_floats([[0.5, 0.5, 1e-3], [0.5, 0.5, 1e-3]], &device),
///     opacities: Tensor::from_floats([0.9, 0.9], &device),
///     features: Tensor::from_floats([[3.5], [4.5]], &device),
///     xy_offsets: None,
/// };
/// let out = render_crossing(inputs, &SplatConfig::new(camera, 1), 0.5)?;
/// let centre: f32 = out.features.slice([32..33, 32..33, 0..1]).into_scalar();
/// assert!((centre - 3.5).abs() < 1e-6);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn render_crossing(
    inputs: SplatInputs,
    config: &SplatConfig,
    threshold: f64,
) -> Result<CrossingOutput, RenderError> {
    if !(threshold > 0.0 && threshold < 1.0) {
        return Err(RenderError::Threshold(threshold));
    }
    let xy_offsets = validate(&inputs, config)?;
    let device = inputs.means.device();
    let dtype = inputs.means.dtype();
    if dtype == burn::tensor::DType::F64 {
        crossing_on_host::<f64>(inputs, xy_offsets, config, threshold, &device)
    } else {
        crossing_on_host::<f32>(inputs, xy_offsets, config, threshold, &device)
    }
}

fn crossing_on_host<F: crate::scalar::Real + burn::tensor::Element>(
    inputs: SplatInputs,
    xy_offsets: Tensor<2>,
    config: &SplatConfig,
    threshold: f64,
    device: &Device,
) -> Result<CrossingOutput, RenderError> {
    fn host<F: burn::tensor::Element, const D: usize>(
        name: &str,
        t: Tensor<D>,
    ) -> Result<Vec<F>, RenderError> {
        t.into_data()
            .convert::<F>()
            .into_vec::<F>()
            .map_err(|e| RenderError::Mixed(format!("reading {name} back: {e:?}")))
    }
    let means = host::<F, 2>("means", inputs.means)?;
    let quats = host::<F, 2>("quats", inputs.quats)?;
    let scales = host::<F, 2>("scales", inputs.scales)?;
    let opacities = host::<F, 1>("opacities", inputs.opacities)?;
    let features = host::<F, 2>("features", inputs.features)?;
    let offsets = host::<F, 2>("xy_offsets", xy_offsets)?;
    let g = crate::cpu::HostGaussians {
        means: &means,
        quats: &quats,
        scales: &scales,
        opacities: &opacities,
        features: &features,
        xy_offsets: &offsets,
    };
    let out = crate::cpu::crossing_features(&g, config, threshold);
    let (h, w) = (config.camera.height as usize, config.camera.width as usize);
    let c = config.background.len();
    let dtype = F::dtype();
    let alpha: Vec<F> = out.image.chunks_exact(c + 1).map(|px| px[c]).collect();
    Ok(CrossingOutput {
        features: Tensor::from_data(TensorData::new(out.features, [h, w, c]), (device, dtype)),
        found: Tensor::from_data(TensorData::new(out.found, [h, w]), (device, dtype)),
        alpha: Tensor::from_data(TensorData::new(alpha, [h, w]), (device, dtype)),
        observed: out.observed,
    })
}
