//! One Adam step as one pass over a parameter tensor, its gradient and its two moments.
//!
//! Burn's `Adam` updates a tensor in about a dozen element-wise ops, each a pass over memory
//! that allocates its result; on NdArray those passes run on one thread. [`adam_step`] does
//! the same arithmetic per element in one pass, parallel over chunks: on NdArray through a
//! backend extension ([`AdamBackend`]), elsewhere with the same expression in Burn ops
//! ([`adam_step_by_tensor_ops`]). Both follow Burn's `AdaptiveMomentum` (without AMSGrad)
//! operation by operation, in the same order and precision:
//!
//! ```text
//! m1' = m1 b1 + g (1 - b1)
//! m2' = m2 b2 + g^2 (1 - b2)
//! p'  = p - ((m1' c) / (sqrt(m2') + e s)) lr
//! ```
//!
//! with `s = sqrt(1 - b2^t)`, `c = s / (1 - b1^t)` and `t` the step's count, so the result is
//! Burn's to the bit.

use burn::backend::{Backend, Dispatch, NdArray, backend_extension, tensor::FloatTensor};
use burn::tensor::Tensor;
use burn_ndarray::NdArrayTensor;
use rayon::prelude::*;

use crate::backend::{host_slice, is_f64, on_ndarray, to_nd};
use crate::scalar::Real;

/// The constants of one Adam step (Burn's `AdamConfig` names, without AMSGrad or weight decay).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamStep {
    /// The learning rate (applied in the tensor's precision, as Burn's `mul_scalar` does).
    pub lr: f64,
    /// The first moment's decay.
    pub beta_1: f32,
    /// The second moment's decay.
    pub beta_2: f32,
    /// Added to the second moment's root (scaled by its bias correction).
    pub epsilon: f32,
    /// The step's count, from 1: the moments' bias corrections.
    pub time: usize,
}

impl AdamStep {
    /// `(b1, 1 - b1, b2, 1 - b2, c, e s)` computed as Burn computes them, in f32.
    fn scalars(&self) -> [f32; 6] {
        let t = self.time as i32;
        let correction_2 = (1.0 - self.beta_2.powi(t)).sqrt();
        let combined = correction_2 / (1.0 - self.beta_1.powi(t));
        [
            self.beta_1,
            1.0 - self.beta_1,
            self.beta_2,
            1.0 - self.beta_2,
            combined,
            self.epsilon * correction_2,
        ]
    }
}

/// The fused Adam step as a backend op. Use [`adam_step`], which picks this op or the tensor
/// ops by device.
#[backend_extension(NdArray)]
pub trait AdamBackend: Backend {
    /// `(param', moment_1', moment_2')` from tensors of one shape; see the module docs.
    fn adam_step(
        param: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        moment_1: FloatTensor<Self>,
        moment_2: FloatTensor<Self>,
        step: AdamStep,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>);
}

impl AdamBackend for NdArray {
    fn adam_step(
        param: NdArrayTensor,
        grad: NdArrayTensor,
        moment_1: NdArrayTensor,
        moment_2: NdArrayTensor,
        step: AdamStep,
    ) -> (NdArrayTensor, NdArrayTensor, NdArrayTensor) {
        if is_f64(&param) {
            nd_adam::<f64>(&param, &grad, &moment_1, &moment_2, step)
        } else {
            nd_adam::<f32>(&param, &grad, &moment_1, &moment_2, step)
        }
    }
}

/// Elements per parallel task.
const CHUNK: usize = 16_384;

fn nd_adam<F: Real + burn::tensor::Element>(
    param: &NdArrayTensor,
    grad: &NdArrayTensor,
    moment_1: &NdArrayTensor,
    moment_2: &NdArrayTensor,
    step: AdamStep,
) -> (NdArrayTensor, NdArrayTensor, NdArrayTensor) {
    let shape = burn::backend::TensorMetadata::shape(param).to_vec();
    let (p, g) = (host_slice::<F>(param), host_slice::<F>(grad));
    let (m1, m2) = (host_slice::<F>(moment_1), host_slice::<F>(moment_2));
    let n = p.len();
    // The chunks below must cover every output element.
    assert!(
        g.len() == n && m1.len() == n && m2.len() == n,
        "adam_step: a parameter of {n} values with a gradient of {} and moments of {} and {}",
        g.len(),
        m1.len(),
        m2.len()
    );
    let [b1, f1, b2, f2, combined, eps] = step.scalars().map(|v| F::c(f64::from(v)));
    // Burn converts the learning rate from f64 to the tensor's precision directly.
    let lr = F::c(step.lr);
    // The outputs are written once each, chunk by chunk, without being zeroed first (a pass
    // over memory as long as the update's own).
    let mut p_out: Vec<F> = Vec::with_capacity(n);
    let mut m1_out: Vec<F> = Vec::with_capacity(n);
    let mut m2_out: Vec<F> = Vec::with_capacity(n);
    let inputs = p
        .par_chunks(CHUNK)
        .zip(g.par_chunks(CHUNK))
        .zip(m1.par_chunks(CHUNK).zip(m2.par_chunks(CHUNK)));
    let outputs = p_out.spare_capacity_mut()[..n].par_chunks_mut(CHUNK).zip(
        m1_out.spare_capacity_mut()[..n]
            .par_chunks_mut(CHUNK)
            .zip(m2_out.spare_capacity_mut()[..n].par_chunks_mut(CHUNK)),
    );
    inputs
        .zip(outputs)
        .for_each(|(((p, g), (m1, m2)), (po, (m1o, m2o)))| {
            // Equal lengths, so that the loop below compiles without bounds checks and
            // vectorises (the square root and the division dominate it).
            let len = po.len();
            let (p, g, m1, m2) = (&p[..len], &g[..len], &m1[..len], &m2[..len]);
            let (m1o, m2o) = (&mut m1o[..len], &mut m2o[..len]);
            for i in 0..len {
                let gi = g[i];
                let m1n = m1[i] * b1 + gi * f1;
                let m2n = m2[i] * b2 + (gi * gi) * f2;
                let update = (m1n * combined) / (m2n.sqrt() + eps);
                po[i].write(p[i] - update * lr);
                m1o[i].write(m1n);
                m2o[i].write(m2n);
            }
        });
    // SAFETY: the chunks of the three outputs cover `[0, n)` and every element of each chunk
    // was written above, so the first `n` elements are initialised.
    unsafe {
        p_out.set_len(n);
        m1_out.set_len(n);
        m2_out.set_len(n);
    }
    (
        to_nd(p_out, &shape),
        to_nd(m1_out, &shape),
        to_nd(m2_out, &shape),
    )
}

/// [`adam_step`] in Burn ops, as Burn's `AdaptiveMomentum` computes it (any device).
pub fn adam_step_by_tensor_ops<const D: usize>(
    param: Tensor<D>,
    grad: Tensor<D>,
    moment_1: Tensor<D>,
    moment_2: Tensor<D>,
    step: AdamStep,
) -> (Tensor<D>, Tensor<D>, Tensor<D>) {
    let [b1, f1, b2, f2, combined, eps] = step.scalars();
    let m1 = moment_1.mul_scalar(b1).add(grad.clone().mul_scalar(f1));
    let m2 = moment_2.mul_scalar(b2).add(grad.square().mul_scalar(f2));
    let update = m1
        .clone()
        .mul_scalar(combined)
        .div(m2.clone().sqrt().add_scalar(eps));
    (param - update.mul_scalar(step.lr), m1, m2)
}

/// One Adam step on `param` (no autodiff: pass the inner tensors) with gradient `grad` and the
/// moments of the previous steps; returns `(param', moment_1', moment_2')`. On NdArray in f32 or
/// f64 it is one parallel pass ([`AdamBackend`]); elsewhere [`adam_step_by_tensor_ops`]. Either
/// gives what Burn's `Adam` gives for a state with these moments and `step.time`.
///
/// ```
/// use burn::tensor::{Device, Tensor};
/// use gtsr_render_kernels::adam::{AdamStep, adam_step};
///
/// let device = Device::ndarray();
/// let p = Tensor::<2>::ones([4, 3], &device);
/// let g = Tensor::<2>::ones([4, 3], &device);
/// let zero = Tensor::<2>::zeros([4, 3], &device);
/// let step = AdamStep { lr: 0.1, beta_1: 0.9, beta_2: 0.999, epsilon: 1e-15, time: 1 };
/// let (p, m1, m2) = adam_step(p, g, zero.clone(), zero, step);
/// // The first step moves every element by the learning rate.
/// assert!((p.into_data().to_vec::<f32>()?[0] - 0.9).abs() < 1e-6);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn adam_step<const D: usize>(
    param: Tensor<D>,
    grad: Tensor<D>,
    moment_1: Tensor<D>,
    moment_2: Tensor<D>,
    step: AdamStep,
) -> (Tensor<D>, Tensor<D>, Tensor<D>) {
    let float = matches!(
        param.dtype(),
        burn::tensor::DType::F32 | burn::tensor::DType::F64
    );
    let same = [&grad, &moment_1, &moment_2]
        .iter()
        .all(|t| t.dtype() == param.dtype() && t.dims() == param.dims());
    if float && same && on_ndarray(&param.device()) {
        let (p, m1, m2) = <Dispatch as AdamBackend>::adam_step(
            param.into_dispatch(),
            grad.into_dispatch(),
            moment_1.into_dispatch(),
            moment_2.into_dispatch(),
            step,
        );
        return (
            Tensor::from_dispatch(p),
            Tensor::from_dispatch(m1),
            Tensor::from_dispatch(m2),
        );
    }
    adam_step_by_tensor_ops(param, grad, moment_1, moment_2, step)
}

#[cfg(test)]
mod tests {
    use burn::optim::{AdamConfig, AdamState, AdaptiveMomentumState, Optimizer};
    use burn::tensor::{DType, TensorData};
    use rand::{RngExt, SeedableRng, rngs::StdRng};

    use burn::tensor::Device;

    use super::*;

    const SHAPE: [usize; 2] = [3001, 7];

    /// Values over many scales and both signs, with exact zeros.
    fn random(rng: &mut StdRng, dtype: DType, device: &Device) -> Tensor<2> {
        let v: Vec<f64> = (0..SHAPE[0] * SHAPE[1])
            .map(|_| {
                if rng.random_bool(0.05) {
                    0.0
                } else {
                    let sign = if rng.random_bool(0.5) { -1.0 } else { 1.0 };
                    sign * 10f64.powf(rng.random_range(-20.0..6.0))
                }
            })
            .collect();
        Tensor::<2>::from_data(TensorData::new(v, SHAPE), device).cast(dtype)
    }

    fn bits(t: &Tensor<2>) -> Vec<u64> {
        let data = t.clone().into_data();
        match t.dtype() {
            DType::F32 => data
                .to_vec::<f32>()
                .unwrap()
                .iter()
                .map(|v| u64::from(v.to_bits()))
                .collect(),
            _ => data
                .to_vec::<f64>()
                .unwrap()
                .iter()
                .map(|v| v.to_bits())
                .collect(),
        }
    }

    /// Five Adam steps by Burn's `Adam` and by the fused step (after Burn's first, which starts
    /// the state), on f32 and f64: parameters and moments equal bit for bit at every step.
    #[test]
    fn the_fused_step_is_burns_adam_to_the_bit() {
        let device = Device::ndarray();
        for dtype in [DType::F32, DType::F64] {
            let mut rng = StdRng::seed_from_u64(11);
            let (beta_1, beta_2, epsilon) = (0.9, 0.999, 1e-15);
            let burn_adam = AdamConfig::new()
                .with_beta_1(beta_1)
                .with_beta_2(beta_2)
                .with_epsilon(epsilon)
                .build();
            let p0 = random(&mut rng, dtype, &device);
            let grads: Vec<Tensor<2>> = (0..5).map(|_| random(&mut rng, dtype, &device)).collect();
            let rates = [1e-3, 0.16, 2.5e-5, 1.0, 7e-3];

            let (mut p_burn, mut s_burn): (Tensor<2>, Option<AdamState<2>>) = (p0.clone(), None);
            let (mut p_ours, mut s_ours): (Tensor<2>, Option<AdamState<2>>) = (p0, None);
            for (t, (g, &lr)) in grads.iter().zip(&rates).enumerate() {
                let (p, s) = burn_adam.step(lr, p_burn, g.clone(), s_burn);
                (p_burn, s_burn) = (p, s);
                (p_ours, s_ours) = match s_ours {
                    None => burn_adam.step(lr, p_ours, g.clone(), None),
                    Some(s) => {
                        let m = s.momentum;
                        let step = AdamStep {
                            lr,
                            beta_1,
                            beta_2,
                            epsilon,
                            time: m.time + 1,
                        };
                        let (p, m1, m2) =
                            adam_step(p_ours, g.clone(), m.moment_1, m.moment_2, step);
                        let momentum = AdaptiveMomentumState::new(step.time, m1, m2);
                        (p, Some(AdamState::new(momentum)))
                    }
                };
                let (b, o) = (
                    &s_burn.as_ref().unwrap().momentum,
                    &s_ours.as_ref().unwrap().momentum,
                );
                assert_eq!(b.time, o.time);
                assert!(
                    bits(&p_burn) == bits(&p_ours),
                    "{dtype:?} step {t}: parameters"
                );
                assert!(
                    bits(&b.moment_1) == bits(&o.moment_1),
                    "{dtype:?} step {t}: m1"
                );
                assert!(
                    bits(&b.moment_2) == bits(&o.moment_2),
                    "{dtype:?} step {t}: m2"
                );
            }
        }
    }

    /// The tensor-ops path (every device but NdArray) against the fused kernel, at a late
    /// step with tiny and huge moments: the same bits.
    #[test]
    fn the_tensor_ops_path_matches_the_kernel() {
        let device = Device::ndarray();
        for dtype in [DType::F32, DType::F64] {
            let mut rng = StdRng::seed_from_u64(5);
            let [p, g, m1] = [0; 3].map(|_| random(&mut rng, dtype, &device));
            let m2 = random(&mut rng, dtype, &device).abs();
            let step = AdamStep {
                lr: 0.05,
                beta_1: 0.9,
                beta_2: 0.999,
                epsilon: 1e-15,
                time: 10_000,
            };
            let fused = adam_step(p.clone(), g.clone(), m1.clone(), m2.clone(), step);
            let ops = adam_step_by_tensor_ops(p, g, m1, m2, step);
            for (a, b) in [(&fused.0, &ops.0), (&fused.1, &ops.1), (&fused.2, &ops.2)] {
                assert!(bits(a) == bits(b), "{dtype:?}");
                assert!(
                    a.clone().is_finite().all().into_scalar::<bool>(),
                    "{dtype:?}: non-finite"
                );
            }
        }
    }
}
