//! Cross-crate check from a downstream user's point of view: the splat op inside an ordinary
//! Burn training loop (parameters as autodiff leaves, activations upstream, Burn's Adam per
//! tensor) fits a target image rendered from a different scene.

// Device::ndarray is deprecated upstream; NdArray stays the CPU and CI backend.
#![allow(deprecated)]

use burn::optim::{AdamConfig, Optimizer};
use burn::tensor::activation::sigmoid;
use burn::tensor::{DType, Device, Tensor, TensorData};
use gtsr_render_kernels::scenes::{RandomSceneSpec, random_scene};
use gtsr_render_kernels::{AlphaCutoff, SplatInputs, render};

#[test]
fn adam_fits_a_target_render() {
    let spec = RandomSceneSpec {
        count: 40,
        channels: 3,
        size: (48, 40),
        radius: 0.7,
        scale_range: (0.05, 0.2),
        opacity_range: (0.4, 0.9),
        distance: 4.0,
        fov_x: 0.8,
    };
    let target_scene = random_scene(1, &spec);
    let cfg = target_scene.config(AlphaCutoff::Hard);
    let plain = Device::ndarray();
    let target = render(target_scene.inputs(&plain, DType::F32), &cfg)
        .unwrap()
        .image;

    // Start from a different random scene seen by the same camera.
    let mut start = random_scene(2, &spec);
    start.camera = target_scene.camera.clone();
    let device = Device::ndarray().autodiff();
    let n = start.len();
    let t2 = |v: Vec<f64>, c: usize| {
        Tensor::<2>::from_data(TensorData::new(v, [n, c]), (&device, DType::F32)).require_grad()
    };
    let mut means = t2(start.means.clone(), 3);
    let mut quats = t2(start.quats.clone(), 4);
    let mut log_scales = t2(start.scales.iter().map(|s| s.ln()).collect(), 3);
    let mut logits = t2(vec![0.0; n], 1);
    let mut colours = t2(start.features.clone(), 3);
    let adam = AdamConfig::new().with_epsilon(1e-15).build();
    let mut states: [Option<_>; 5] = Default::default();
    let lrs = [0.01, 0.01, 0.02, 0.05, 0.05];
    let mut losses = Vec::new();
    for _ in 0..80 {
        let inputs = SplatInputs {
            means: means.clone(),
            quats: quats.clone(),
            scales: log_scales.clone().exp(),
            opacities: sigmoid(logits.clone()).reshape([n]),
            features: colours.clone(),
            xy_offsets: None,
        };
        let out = render(inputs, &cfg).unwrap();
        let loss = (out.image - target.clone().autodiff()).abs().mean();
        losses.push(loss.clone().into_scalar::<f64>());
        let grads = loss.backward();
        let params = [
            &mut means,
            &mut quats,
            &mut log_scales,
            &mut logits,
            &mut colours,
        ];
        for (k, p) in params.into_iter().enumerate() {
            let g = p.grad(&grads).expect("every parameter receives a gradient");
            let (next, state) = adam.step(lrs[k], p.clone().inner(), g, states[k].take());
            states[k] = state;
            *p = Tensor::from_inner(next).require_grad();
        }
    }
    let first = losses[0];
    let last = *losses.last().unwrap();
    assert!(losses.iter().all(|l| l.is_finite()));
    assert!(last < 0.5 * first, "L1 went from {first} to {last} only");
}
