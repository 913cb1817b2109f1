use burn::tensor::DType;
use gtsr_render_kernels::AlphaCutoff;
use gtsr_render_kernels::scenes::{RandomSceneSpec, random_scene};

use crate::common::{autodiff_grads, loss_weights};

#[test]
fn renders_and_gradients_are_bit_identical() {
    let scene = random_scene(11, &RandomSceneSpec::bench(3000, 96, 80));
    let weights = loss_weights(2, 96 * 80 * 4);
    let (g1, o1) = autodiff_grads(&scene, DType::F32, AlphaCutoff::Hard, &weights);
    let (g2, o2) = autodiff_grads(&scene, DType::F32, AlphaCutoff::Hard, &weights);
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&o1), bits(&o2), "outputs differ between runs");
    for (a, b) in g1.iter().zip(&g2) {
        assert_eq!(bits(a), bits(b), "gradients differ between runs");
    }
    assert!(o1.iter().any(|v| *v != 0.0));
}
