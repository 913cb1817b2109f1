//! `Autodiff<B, C>`: the splat op as a node of Burn's autograd graph whose backward step calls
//! [`SplatKernels::splat_backward`].

use burn::backend::{AutodiffBackend, tensor::FloatTensor};
use burn_autodiff::{
    Autodiff,
    checkpoint::{base::Checkpointer, strategy::CheckpointStrategy},
    grads::Gradients,
    ops::{Backward, Ops, OpsKind},
};

use crate::backend::{SplatBackend, SplatKernels, SplatPrimitives};
use crate::config::SplatConfig;

#[derive(Debug)]
struct SplatBackward;

impl<B: SplatKernels> Backward<B, 6> for SplatBackward {
    type State = B::SplatState;

    fn backward(self, ops: Ops<Self::State, 6>, grads: &mut Gradients, _: &mut Checkpointer) {
        let grad = grads.consume::<B>(&ops.node);
        let input_grads = B::splat_backward(ops.state, grad);
        for (parent, g) in ops.parents.into_iter().zip(input_grads) {
            if let Some(node) = parent {
                grads.register::<B>(node.id, g);
            }
        }
    }
}

impl<B: SplatKernels, C: CheckpointStrategy> SplatBackend for Autodiff<B, C> {
    fn splat(
        means: FloatTensor<Self>,
        quats: FloatTensor<Self>,
        scales: FloatTensor<Self>,
        opacities: FloatTensor<Self>,
        features: FloatTensor<Self>,
        xy_offsets: FloatTensor<Self>,
        config: SplatConfig,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let guards = [
            means.node(),
            quats.node(),
            scales.node(),
            opacities.node(),
            features.node(),
            xy_offsets.node(),
        ];
        let inputs = SplatPrimitives::<B> {
            means: means.into_primitive(),
            quats: quats.into_primitive(),
            scales: scales.into_primitive(),
            opacities: opacities.into_primitive(),
            features: features.into_primitive(),
            xy_offsets: xy_offsets.into_primitive(),
        };
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
