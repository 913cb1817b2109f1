//! Adam per parameter tensor (one Burn `AdamState` per tensor) with state that follows the
//! Gaussians when densification keeps, drops, clones or splits them: Burn's `ModuleOptimizer`
//! cannot change a parameter's size, so the states are held and resized here. A tensor's first
//! step is Burn's `Adam`; every later one is [`gtsr_render_kernels::adam::adam_step`], the same
//! arithmetic in one pass (on NdArray parallel, elsewhere Burn's ops).

use std::collections::HashMap;

use burn::optim::{Adam, AdamConfig, AdamState, AdaptiveMomentumState, Optimizer};
use burn::tensor::{Int, Tensor, TensorData};
use gtsr_render_kernels::adam::{AdamStep, adam_step};

use crate::gaussians::{GaussianSet, ParamKind, host_vec};

/// Adam states for the tensors of one set, keyed by parameter.
pub struct SetOptimizer {
    adam: Adam,
    states: HashMap<ParamKind, AdamState<2>>,
}

impl std::fmt::Debug for SetOptimizer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SetOptimizer")
            .field("states", &self.states.keys().collect::<Vec<_>>())
            .finish()
    }
}

/// Adam's first-moment decay (Burn's and 3DGS's default).
pub const ADAM_BETA_1: f32 = 0.9;
/// Adam's second-moment decay (Burn's and 3DGS's default).
pub const ADAM_BETA_2: f32 = 0.999;
/// Adam's epsilon (3DGS: 1e-15).
pub const ADAM_EPSILON: f32 = 1e-15;

/// The Adam configuration used everywhere ([`ADAM_BETA_1`], [`ADAM_BETA_2`], [`ADAM_EPSILON`]).
pub fn adam() -> Adam {
    AdamConfig::new()
        .with_beta_1(ADAM_BETA_1)
        .with_beta_2(ADAM_BETA_2)
        .with_epsilon(ADAM_EPSILON)
        .build()
}

impl Default for SetOptimizer {
    fn default() -> Self {
        SetOptimizer {
            adam: adam(),
            states: HashMap::new(),
        }
    }
}

/// Host copy of one Adam state: `(time, moment_1, moment_2)` row-major `[N, width]`.
pub type HostAdamState = (usize, Vec<f32>, Vec<f32>);

impl SetOptimizer {
    /// One Adam step on every parameter of `set` that has a gradient in `grads` and a rate in
    /// `lr`; returns the updated set (new autodiff leaves).
    pub fn step(
        &mut self,
        set: GaussianSet,
        grads: &HashMap<ParamKind, Tensor<2>>,
        lr: &dyn Fn(ParamKind) -> f64,
    ) -> GaussianSet {
        let params = set
            .params
            .into_iter()
            .map(|(k, p)| {
                let rate = lr(k);
                match grads.get(&k) {
                    Some(g) if rate > 0.0 => {
                        let next = match self.states.remove(&k) {
                            // Every later step: one fused pass (Burn's arithmetic, to the bit).
                            Some(state) if state.momentum.max_moment_2.is_none() => {
                                let m = state.momentum;
                                let time = m.time + 1;
                                let step = AdamStep {
                                    lr: rate,
                                    beta_1: ADAM_BETA_1,
                                    beta_2: ADAM_BETA_2,
                                    epsilon: ADAM_EPSILON,
                                    time,
                                };
                                let (next, moment_1, moment_2) = adam_step(
                                    p.clone().inner(),
                                    g.clone(),
                                    m.moment_1,
                                    m.moment_2,
                                    step,
                                );
                                let momentum = AdaptiveMomentumState {
                                    time,
                                    moment_1,
                                    moment_2,
                                    max_moment_2: None,
                                };
                                self.states.insert(k, AdamState::new(momentum));
                                next
                            }
                            // The first step starts the state as Burn does.
                            state => {
                                let (next, state) =
                                    self.adam.step(rate, p.clone().inner(), g.clone(), state);
                                if let Some(s) = state {
                                    self.states.insert(k, s);
                                }
                                next
                            }
                        };
                        (k, Tensor::from_inner(next).require_grad())
                    }
                    _ => (k, p),
                }
            })
            .collect();
        GaussianSet {
            kind: set.kind,
            params,
        }
    }

    /// Rebuilds every state for a set whose rows became `keep` (old row indices) followed by
    /// `added` new rows, which start with zero moments (as 3DGS does).
    pub fn reindex(&mut self, keep: &[usize], added: usize) {
        for state in self.states.values_mut() {
            let m = &mut state.momentum;
            let device = m.moment_1.device();
            let idx = Tensor::<1, Int>::from_data(
                TensorData::new(
                    keep.iter().map(|&i| i as i64).collect::<Vec<_>>(),
                    [keep.len()],
                ),
                &device,
            );
            let w = m.moment_1.dims()[1];
            let grow = |t: Tensor<2>| {
                let kept = t.select(0, idx.clone());
                if added == 0 {
                    kept
                } else {
                    let z = Tensor::zeros([added, w], (&kept.device(), kept.dtype()));
                    Tensor::cat(vec![kept, z], 0)
                }
            };
            m.moment_1 = grow(m.moment_1.clone());
            m.moment_2 = grow(m.moment_2.clone());
            m.max_moment_2 = m.max_moment_2.take().map(grow);
        }
    }

    /// Zeroes the moments of one parameter (opacity reset replaces the tensor, as in 3DGS).
    pub fn reset(&mut self, kind: ParamKind) {
        if let Some(s) = self.states.get_mut(&kind) {
            let m = &mut s.momentum;
            m.moment_1 = m.moment_1.zeros_like();
            m.moment_2 = m.moment_2.zeros_like();
        }
    }

    /// Host copies of the states (for checkpoints).
    pub fn to_host(&self) -> Vec<(ParamKind, usize, HostAdamState)> {
        let host = |t: &Tensor<2>| host_vec(t.clone());
        let mut v: Vec<_> = self
            .states
            .iter()
            .map(|(k, s)| {
                let m = &s.momentum;
                (
                    *k,
                    m.moment_1.dims()[1],
                    (m.time, host(&m.moment_1), host(&m.moment_2)),
                )
            })
            .collect();
        v.sort_by_key(|(k, _, _)| k.name());
        v
    }

    /// Restores states saved by [`SetOptimizer::to_host`] onto `device` (the inner backend
    /// device of the parameters).
    pub fn from_host(
        states: Vec<(ParamKind, usize, HostAdamState)>,
        device: &burn::tensor::Device,
    ) -> Self {
        let mut s = SetOptimizer::default();
        for (k, w, (time, m1, m2)) in states {
            let n = m1.len() / w.max(1);
            let t = |v: Vec<f32>| Tensor::<2>::from_data(TensorData::new(v, [n, w]), device);
            s.states.insert(
                k,
                AdamState::new(AdaptiveMomentumState {
                    time,
                    moment_1: t(m1),
                    moment_2: t(m2),
                    max_moment_2: None,
                }),
            );
        }
        s
    }
}
