//! `cargo bench -p gtsr-model --bench normals`: the planes of `N` surface Gaussians for one
//! camera as a render prepares them (facing normal, camera normal, plane distance, cosine to
//! the camera), on the NdArray autodiff backend (f32): the CPU kernel
//! ([`gtsr_render_kernels::planes::gaussian_planes`]) and the same in Burn tensor ops (the path
//! of other devices), forward alone and forward plus backward, the two taking turns. Prints a
//! markdown table of median times over the repetitions.

// Device::ndarray is deprecated upstream; NdArray stays the CPU and CI backend.
#![allow(deprecated)]

mod common;

use std::time::{Duration, Instant};

use common::{WARM_UP, median_after_warm_up};

use burn::tensor::{Device, Tensor, TensorData};
use gtsr_render_kernels::Camera;
use gtsr_render_kernels::planes::{gaussian_planes, gaussian_planes_by_tensor_ops};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};

fn random(n: usize, c: usize, rng: &mut StdRng, device: &Device) -> Tensor<2> {
    let v: Vec<f32> = (0..n * c).map(|_| rng.random_range(-1.0f32..1.0)).collect();
    Tensor::<2>::from_data(TensorData::new(v, [n, c]), device)
}

type Planes = fn(Tensor<2>, Tensor<2>, Tensor<2>, &Camera) -> Tensor<2>;

fn main() {
    gtsr_render_kernels::cpu::keep_freed_memory();
    let device = Device::ndarray().autodiff();
    let mut rng = StdRng::seed_from_u64(5);
    let camera = Camera::look_at([0.0, 0.0, -4.0], [0.0; 3], [0.0, -1.0, 0.0], 0.8, 256, 256)
        .expect("a camera");
    let paths: [(&str, Planes); 2] = [
        ("kernel", gaussian_planes),
        ("tensor ops", gaussian_planes_by_tensor_ops),
    ];
    println!("| Gaussians | path | forward (ms) | forward + backward (ms) |");
    println!("|---:|---|---:|---:|");
    for n in [32_768usize, 65_536] {
        let mut times: [(Vec<Duration>, Vec<Duration>); 2] = Default::default();
        for _ in 0..20 + WARM_UP {
            for ((_, planes), t) in paths.iter().zip(times.iter_mut()) {
                let q = random(n, 4, &mut rng, &device).require_grad();
                let s = random(n, 3, &mut rng, &device).require_grad();
                let m = random(n, 3, &mut rng, &device).require_grad();
                let t0 = Instant::now();
                let loss = planes(q.clone(), s, m.clone(), &camera).sum();
                let _: f32 = loss.clone().into_scalar();
                let t1 = Instant::now();
                let g = loss.backward();
                let s =
                    q.grad(&g).expect("a gradient").sum() + m.grad(&g).expect("a gradient").sum();
                let _: f32 = s.into_scalar();
                let t2 = Instant::now();
                t.0.push(t1 - t0);
                t.1.push(t2 - t0);
            }
        }
        for ((name, _), (fwd, both)) in paths.iter().zip(&times) {
            println!(
                "| {n} | {name} | {:.2} | {:.2} |",
                median_after_warm_up(fwd).as_secs_f64() * 1e3,
                median_after_warm_up(both).as_secs_f64() * 1e3
            );
        }
    }
}
