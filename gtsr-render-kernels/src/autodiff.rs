//! `Autodiff<B, C>`: the splat op as a node of Burn's autograd graph whose backward step calls
//! [`SplatKernels::splat_backward`].

use burn::backend::{AutodiffBackend, Backend, tensor::FloatTensor};
use burn_autodiff::{
    Autodiff,
    checkpoint::{base::Checkpointer, strategy::CheckpointStrategy},
    grads::Gradients,
    ops::{Backward, Ops, OpsKind},
};

use crate::backend::{SplatBackend, SplatKernels, SplatPrimitives};
use crate::config::SplatConfig;

/// The backward step of an op with `N` differentiable inputs: takes the gradient of the op's
/// output, turns it (with the op's saved state) into the inputs' gradients with
/// `input_grads`, and registers each with its input's node (inputs that need none have none).
pub(crate) fn backward_step<B: Backend, S, const N: usize>(
    ops: Ops<S, N>,
    grads: &mut Gradients,
    input_grads: impl FnOnce(S, FloatTensor<B>) -> [FloatTensor<B>; N],
) {
    let grad = grads.consume::<B>(&ops.node);
    let input_grads = input_grads(ops.state, grad);
    for (parent, g) in ops.parents.into_iter().zip(input_grads) {
        if let Some(node) = parent {
            grads.register::<B>(node.id, g);
        }
    }
}

#[derive(Debug)]
struct SplatBackward;

impl<B: SplatKernels> Backward<B, 6> for SplatBackward {
    type State = B::SplatState;

    fn backward(self, ops: Ops<Self::State, 6>, grads: &mut Gradients, _: &mut Checkpointer) {
        backward_step::<B, _, 6>(ops, grads, B::splat_backward);
    }
}

impl<B: SplatKernels, C: CheckpointStrategy> SplatBackend for Autodiff<B, C> {
    fn splat(
        inputs: SplatPrimitives<Self>,
        config: SplatConfig,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let guards = splat_fields!([], &inputs, |t| t.node());
        let inputs = inputs.map(|t| t.into_primitive());
        let (image, aux, state) = B::splat_forward(inputs, &config);
        let image = match SplatBackward
            .prepare::<C>(guards)
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish(state, image),
            OpsKind::UnTracked(prep) => prep.finish(image),
        };
        (image, <Self as AutodiffBackend>::from_inner(aux))
    }
}
