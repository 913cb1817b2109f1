//! The splatting op as a Burn backend extension.
//!
//! Two traits split the work as Burn's own ops do:
//! - [`SplatKernels`] (not dispatched): the forward pass that also returns a backend-specific
//!   state, and the backward pass that consumes it. A backend implements this to provide the
//!   kernels.
//! - [`SplatBackend`] (a `#[backend_extension]`, dispatched at run time by the device): the one
//!   op `splat`, implemented for every kernel backend (forward only) and for
//!   `Autodiff<B, C>` (forward + a registered `Backward` that calls
//!   [`SplatKernels::splat_backward`]).

use std::sync::Arc;

#[cfg(feature = "wgpu")]
use burn::backend::fusion::custom::TensorSpec;
use burn::backend::{Backend, ExtensionType, NdArray, backend_extension, tensor::FloatTensor};
#[cfg(feature = "wgpu")]
use burn::tensor::Shape;
use burn::tensor::{DType, TensorData};
use burn_ndarray::NdArrayTensor;

use crate::config::SplatConfig;
use crate::cpu::{self, ForwardState, HostBuffers};
use crate::scalar::Real;

/// The raw inputs of one splat op as backend primitives (also the layout of their gradients).
#[derive(Debug, Clone, ExtensionType)]
#[extension_type(fusion: cfg(feature = "wgpu"))]
pub struct SplatPrimitives<B: Backend> {
    /// `[N, 3]`
    pub means: FloatTensor<B>,
    /// `[N, 4]`
    pub quats: FloatTensor<B>,
    /// `[N, 3]`
    pub scales: FloatTensor<B>,
    /// `[N]`
    pub opacities: FloatTensor<B>,
    /// `[N, C]`
    pub features: FloatTensor<B>,
    /// `[N, 2]`
    pub xy_offsets: FloatTensor<B>,
}

/// Kernels a backend provides: forward with saved state, and backward.
pub trait SplatKernels: Backend {
    /// What the forward pass saves for the backward pass.
    type SplatState: Clone + Send + Sync + core::fmt::Debug + 'static;

    /// Renders: returns the `[H, W, C + 1]` image (features over the background, then alpha),
    /// the `[N, 4]` aux tensor (radius px, depth, tiles touched, status) and the saved state.
    fn splat_forward(
        inputs: SplatPrimitives<Self>,
        config: &SplatConfig,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, Self::SplatState);

    /// Gradients of means, quats, scales, opacities, features and xy offsets given the gradient
    /// of the `[H, W, C + 1]` output.
    fn splat_backward(state: Self::SplatState, grad: FloatTensor<Self>) -> [FloatTensor<Self>; 6];
}

/// The dispatched splatting op. Use [`crate::render`] rather than calling this directly.
#[backend_extension(
    Autodiff,
    NdArray,
    Cube: cfg(feature = "wgpu"),
    Fusion: cfg(feature = "wgpu")
)]
pub trait SplatBackend: Backend {
    /// Forward splat: returns `(image_and_alpha [H, W, C + 1], aux [N, 4])`. Only the first
    /// output is differentiable.
    #[fusion(meta = crate::backend::splat_meta)]
    fn splat(
        #[extension_type] inputs: SplatPrimitives<Self>,
        config: SplatConfig,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);
}

/// Output metadata of [`SplatBackend::splat`] for the lazy (`Fusion`) implementation: the
/// `[H, W, C + 1]` image and the `[N, 4]` aux rows, in the dtype of the means.
#[cfg(feature = "wgpu")]
pub fn splat_meta(
    inputs: &SplatPrimitivesMetadata,
    config: &SplatConfig,
) -> (TensorSpec, TensorSpec) {
    let (h, w) = (config.camera.height as usize, config.camera.width as usize);
    let means = &inputs.means;
    let n = means.shape[0];
    let c = inputs.features.shape[1];
    let spec = |shape: Vec<usize>| TensorSpec::new(Shape::from(shape), means.dtype);
    (spec(vec![h, w, c + 1]), spec(vec![n, 4]))
}

impl<B: Backend> SplatPrimitives<B> {
    /// The six tensors in field order: means, quats, scales, opacities, features, offsets
    /// (also the order of [`SplatKernels::splat_backward`]'s gradients).
    pub fn into_array(self) -> [FloatTensor<B>; 6] {
        splat_fields!([], self, |t| t)
    }

    /// The primitives with `f` applied to each tensor, in field order.
    pub fn map<C: Backend>(
        self,
        mut f: impl FnMut(FloatTensor<B>) -> FloatTensor<C>,
    ) -> SplatPrimitives<C> {
        splat_fields!(SplatPrimitives, self, |t| f(t))
    }
}

impl SplatBackend for NdArray {
    fn splat(
        inputs: SplatPrimitives<Self>,
        config: SplatConfig,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let (out, aux, _) = <Self as SplatKernels>::splat_forward(inputs, &config);
        (out, aux)
    }
}

// ---------------------------------------------------------------------------------------------
// NdArray kernels.

/// Saved state of the NdArray forward pass.
#[derive(Debug)]
pub struct NdArraySplatSaved<F> {
    inputs: HostBuffers<F>,
    config: SplatConfig,
    forward: ForwardState<F>,
    image_shape: [usize; 3],
}

/// The NdArray backend's saved state, in the precision of the inputs.
#[derive(Debug, Clone)]
pub enum NdArraySplatState {
    /// f32 inputs.
    F32(Arc<NdArraySplatSaved<f32>>),
    /// f64 inputs.
    F64(Arc<NdArraySplatSaved<f64>>),
}

pub(crate) fn read_host<F: Real>(t: &NdArrayTensor) -> Vec<F> {
    match t {
        NdArrayTensor::F32(s) => {
            let v = s.view();
            match v.as_slice() {
                Some(sl) => sl.iter().map(|&x| F::c(f64::from(x))).collect(),
                None => v.iter().map(|&x| F::c(f64::from(x))).collect(),
            }
        }
        NdArrayTensor::F64(s) => {
            let v = s.view();
            match v.as_slice() {
                Some(sl) => sl.iter().map(|&x| F::c(x)).collect(),
                None => v.iter().map(|&x| F::c(x)).collect(),
            }
        }
        other => panic!(
            "gtsr-render-kernels: expected an f32 or f64 tensor, got {:?}",
            burn::backend::TensorMetadata::dtype(other)
        ),
    }
}

/// Whether `device` is NdArray (with or without autodiff): the CPU extensions of this crate
/// ([`crate::blur::BlurBackend`], [`crate::sh::ShBackend`], [`crate::adam::AdamBackend`]) run
/// there, other devices take their Burn-ops paths.
pub(crate) fn on_ndarray(device: &burn::tensor::Device) -> bool {
    use burn::backend::DispatchDevice;
    matches!(
        device.clone().without_autodiff().as_dispatch(),
        DispatchDevice::NdArray(_)
    )
}

/// The tensor's data as `&[F]` without a copy where it is contiguous, in standard order and of
/// precision `F`; otherwise converted ([`read_host`]).
pub(crate) fn host_slice<F: Real>(t: &NdArrayTensor) -> std::borrow::Cow<'_, [F]> {
    let borrowed = match t {
        NdArrayTensor::F32(s) => s.view().to_slice().and_then(F::slice_from_f32),
        NdArrayTensor::F64(s) => s.view().to_slice().and_then(F::slice_from_f64),
        _ => None,
    };
    match borrowed {
        Some(b) => std::borrow::Cow::Borrowed(b),
        None => std::borrow::Cow::Owned(read_host(t)),
    }
}

pub(crate) fn is_f64(t: &NdArrayTensor) -> bool {
    matches!(t, NdArrayTensor::F64(_))
}

pub(crate) fn to_nd<F: Real + burn::tensor::Element>(v: Vec<F>, shape: &[usize]) -> NdArrayTensor {
    NdArrayTensor::from_data(TensorData::new(v, shape.to_vec()))
}

fn host_inputs<F: Real>(p: &SplatPrimitives<NdArray>) -> HostBuffers<F> {
    splat_fields!(HostBuffers, &p, |t| read_host(t))
}

fn nd_forward<F: Real + burn::tensor::Element>(
    p: &SplatPrimitives<NdArray>,
    config: &SplatConfig,
) -> (NdArrayTensor, NdArrayTensor, Arc<NdArraySplatSaved<F>>) {
    let start = std::time::Instant::now();
    let inputs = host_inputs::<F>(p);
    cpu::lap(cpu::Phase::HostCopies, start);
    let n = inputs.opacities.len();
    let c = config.background.len();
    let out = cpu::forward(&inputs.host(), config);
    let start = std::time::Instant::now();
    let image_shape = [
        config.camera.height as usize,
        config.camera.width as usize,
        c + 1,
    ];
    let image = to_nd(out.image, &image_shape);
    let aux = to_nd(out.aux, &[n, 4]);
    let saved = Arc::new(NdArraySplatSaved {
        inputs,
        config: config.clone(),
        forward: out.state,
        image_shape,
    });
    cpu::lap(cpu::Phase::HostCopies, start);
    (image, aux, saved)
}

fn nd_backward<F: Real + burn::tensor::Element>(
    saved: &NdArraySplatSaved<F>,
    grad: &NdArrayTensor,
) -> [NdArrayTensor; 6] {
    let start = std::time::Instant::now();
    let grad: Vec<F> = read_host(grad);
    cpu::lap(cpu::Phase::HostCopies, start);
    assert_eq!(
        grad.len(),
        saved.image_shape.iter().product::<usize>(),
        "gradient of the splat output has the wrong size"
    );
    let n = saved.inputs.opacities.len();
    let c = saved.config.background.len();
    let g = cpu::backward(&saved.inputs.host(), &saved.config, &saved.forward, &grad);
    let start = std::time::Instant::now();
    let out = [
        to_nd(g.means, &[n, 3]),
        to_nd(g.quats, &[n, 4]),
        to_nd(g.scales, &[n, 3]),
        to_nd(g.opacities, &[n]),
        to_nd(g.features, &[n, c]),
        to_nd(g.xy_offsets, &[n, 2]),
    ];
    cpu::lap(cpu::Phase::HostCopies, start);
    out
}

impl SplatKernels for NdArray {
    type SplatState = NdArraySplatState;

    fn splat_forward(
        inputs: SplatPrimitives<Self>,
        config: &SplatConfig,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, Self::SplatState) {
        if is_f64(&inputs.means) {
            let (i, a, s) = nd_forward::<f64>(&inputs, config);
            (i, a, NdArraySplatState::F64(s))
        } else {
            let (i, a, s) = nd_forward::<f32>(&inputs, config);
            (i, a, NdArraySplatState::F32(s))
        }
    }

    fn splat_backward(state: Self::SplatState, grad: FloatTensor<Self>) -> [FloatTensor<Self>; 6] {
        match state {
            NdArraySplatState::F32(s) => nd_backward(&s, &grad),
            NdArraySplatState::F64(s) => nd_backward(&s, &grad),
        }
    }
}

/// Whether `dtype` is one the CPU kernels compute in.
pub(crate) fn supported_dtype(dtype: DType) -> bool {
    matches!(dtype, DType::F32 | DType::F64)
}
