//! `cargo bench -p gtsr-model --bench sh`: the SH colours of `N` Gaussians at degree 3 in the
//! view directions of one camera, as a render prepares them, on the NdArray autodiff backend
//! (f32): [`gtsr_model::sh::colours`] (the CPU kernel) and the same in Burn tensor ops (the
//! path of other devices), forward alone and forward plus backward (into the coefficients and
//! the means), with glibc keeping freed memory as `gtsr-train` does. Prints a markdown table
//! of median times over the repetitions.

// Device::ndarray is deprecated upstream; NdArray stays the CPU and CI backend.
#![allow(deprecated)]

mod common;

use std::time::Instant;

use common::{WARM_UP, median_after_warm_up};

use burn::tensor::{Device, Tensor, TensorData};
use gtsr_model::sh;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};

fn random(n: usize, c: usize, scale: f32, rng: &mut StdRng, device: &Device) -> Tensor<2> {
    let v: Vec<f32> = (0..n * c)
        .map(|_| scale * rng.random_range(-1.0f32..1.0))
        .collect();
    Tensor::<2>::from_data(TensorData::new(v, [n, c]), device)
}

fn main() {
    gtsr_render_kernels::cpu::keep_freed_memory();
    let device = Device::ndarray().autodiff();
    let mut rng = StdRng::seed_from_u64(5);
    let centre = [0.3, -0.2, -4.0];
    println!("| Gaussians | path | forward (ms) | forward + backward (ms) |");
    println!("|---:|---|---:|---:|");
    for (n, by_ops) in [32_768usize, 98_304]
        .into_iter()
        .flat_map(|n| [(n, false), (n, true)])
    {
        let reps = 15;
        let (mut fwd, mut both) = (Vec::new(), Vec::new());
        for _ in 0..reps + WARM_UP {
            let means = random(n, 3, 1.0, &mut rng, &device).require_grad();
            let dc = random(n, 3, 1.0, &mut rng, &device).require_grad();
            let rest = random(n, 45, 0.2, &mut rng, &device).require_grad();
            let t0 = Instant::now();
            let c = if by_ops {
                gtsr_render_kernels::sh::sh_colours_by_tensor_ops(
                    dc.clone(),
                    Some(rest.clone()),
                    means.clone(),
                    gtsr_render_kernels::sh::ShView { centre, degree: 3 },
                )
            } else {
                sh::colours(&dc, Some(&rest), &means, centre, 3)
            };
            let loss = c.sum();
            let _: f32 = loss.clone().into_scalar();
            let t1 = Instant::now();
            let grads = loss.backward();
            let g = means.grad(&grads).expect("a gradient").sum()
                + rest.grad(&grads).expect("a gradient").sum()
                + dc.grad(&grads).expect("a gradient").sum();
            let _: f32 = g.into_scalar();
            let t2 = Instant::now();
            fwd.push(t1 - t0);
            both.push(t2 - t0);
        }
        let (fwd, both) = (median_after_warm_up(&fwd), median_after_warm_up(&both));
        println!(
            "| {n} | {} | {:.2} | {:.2} |",
            if by_ops { "tensor ops" } else { "kernel" },
            fwd.as_secs_f64() * 1e3,
            both.as_secs_f64() * 1e3
        );
    }
}
