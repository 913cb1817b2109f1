//! `cargo bench -p gtsr-model --bench losses`: the photometric loss (L1 + SSIM) of one render
//! against its target on the NdArray autodiff backend (f32), forward alone and forward plus
//! backward, at the training resolutions (64, 128, 256 px; 512 px with
//! `GTSR_BENCH_LARGE=1`), with glibc keeping freed memory as `gtsr-train` does. Prints a
//! markdown table of median times over the repetitions.

// Device::ndarray is deprecated upstream; NdArray stays the CPU and CI backend.
#![allow(deprecated)]

mod common;

use std::time::Instant;

use common::{WARM_UP, median_after_warm_up};

use burn::tensor::{Device, Tensor, TensorData};
use gtsr_model::losses;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};

fn image(side: usize, rng: &mut StdRng, device: &Device) -> Tensor<3> {
    let v: Vec<f32> = (0..side * side * 3)
        .map(|_| rng.random_range(0.0..1.0))
        .collect();
    Tensor::<3>::from_data(TensorData::new(v, [side, side, 3]), device)
}

fn main() {
    // As gtsr-train does: freed buffers stay mapped instead of going back to the system.
    gtsr_render_kernels::cpu::keep_freed_memory();
    let device = Device::ndarray().autodiff();
    let mut rng = StdRng::seed_from_u64(3);
    let mut sides = vec![64, 128, 256];
    if std::env::var("GTSR_BENCH_LARGE").is_ok_and(|v| v == "1") {
        sides.push(512);
    }
    println!("| size | forward (ms) | forward + backward (ms) |");
    println!("|---|---:|---:|");
    for side in sides {
        let reps = if side <= 128 { 40 } else { 15 };
        let target = image(side, &mut rng, &device);
        let mut fwd = Vec::new();
        let mut both = Vec::new();
        for _ in 0..reps + WARM_UP {
            let render = image(side, &mut rng, &device).require_grad();
            let t0 = Instant::now();
            let loss = losses::photometric(render.clone(), target.clone(), 0.8);
            let _: f32 = loss.clone().into_scalar();
            let t1 = Instant::now();
            let grads = loss.backward();
            let g = render.grad(&grads).expect("a gradient");
            let _: f32 = g.sum().into_scalar();
            let t2 = Instant::now();
            fwd.push(t1 - t0);
            both.push(t2 - t0);
        }
        let (fwd, both) = (median_after_warm_up(&fwd), median_after_warm_up(&both));
        println!(
            "| {side}x{side} | {:.2} | {:.2} |",
            fwd.as_secs_f64() * 1e3,
            both.as_secs_f64() * 1e3
        );
    }
}
