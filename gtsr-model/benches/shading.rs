//! `cargo bench -p gtsr-model --bench shading`: C_PBR of one 256x256 view as training computes
//! it (scattering map, sRGB-encoded), on the NdArray autodiff backend (f32):
//! [`gtsr_model::pbr::c_pbr`] (the CPU kernel) and the same in Burn tensor ops (the path of other
//! devices), forward alone and forward plus backward (into every map and the light), the two
//! paths taking turns, with glibc keeping freed memory as `gtsr-train` does. Prints a markdown
//! table of median times over the repetitions.

// Device::ndarray is deprecated upstream; NdArray stays the CPU and CI backend.
#![allow(deprecated)]

mod common;

use std::time::{Duration, Instant};

use common::{WARM_UP, median_after_warm_up};

use burn::tensor::{Device, Tensor, TensorData};
use gtsr_model::pbr::{self, GBuffer, ShadingParams};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};

const SIZE: usize = 256;

fn map<const D: usize>(
    shape: [usize; D],
    range: std::ops::Range<f32>,
    rng: &mut StdRng,
    device: &Device,
) -> Tensor<D> {
    let n = shape.iter().product();
    let v: Vec<f32> = (0..n).map(|_| rng.random_range(range.clone())).collect();
    Tensor::<D>::from_data(TensorData::new(v, shape), device)
}

fn gbuffer(rng: &mut StdRng, device: &Device) -> GBuffer {
    let (h, w) = (SIZE, SIZE);
    let normal = map([h, w, 3], -0.4..0.4, rng, device)
        + Tensor::<1>::from_floats([0.0, 0.0, -1.0], device).reshape([1, 1, 3]);
    let rays = gtsr_model::geometry::pixel_rays(
        &gtsr_render_kernels::Camera::look_at(
            [0.0, 0.0, -4.0],
            [0.0, 0.0, 0.0],
            [0.0, -1.0, 0.0],
            0.8,
            SIZE as u32,
            SIZE as u32,
        )
        .expect("a camera"),
        device,
    );
    GBuffer {
        normal: normal.require_grad(),
        depth: map([h, w], 2.0..5.0, rng, device).require_grad(),
        coverage: map([h, w], 0.0..1.0, rng, device).require_grad(),
        base: map([h, w, 3], 0.0..1.0, rng, device).require_grad(),
        roughness: map([h, w], 0.0..1.0, rng, device).require_grad(),
        scatter: Some(map([h, w, 3], 0.0..1.0, rng, device).require_grad()),
        rays,
    }
}

fn main() {
    gtsr_render_kernels::cpu::keep_freed_memory();
    let device = Device::ndarray().autodiff();
    let mut rng = StdRng::seed_from_u64(5);
    let params = ShadingParams {
        f0: 0.04,
        gamma: 0.3,
        min_roughness: 0.08,
        scatter_lambert: false,
        scatter_srgb: false,
    };
    let reps = 30;
    let mut times: [(Vec<Duration>, Vec<Duration>); 2] = Default::default();
    for _ in 0..reps + WARM_UP {
        for (path, t) in times.iter_mut().enumerate() {
            let g = gbuffer(&mut rng, &device);
            let light = Tensor::<2>::from_floats([[12.0]], &device).require_grad();
            let t0 = Instant::now();
            let c = if path == 0 {
                pbr::c_pbr(&g, light.clone(), params, true)
            } else {
                pbr::linear_to_srgb(pbr::shade(&g, light.clone(), params).colour)
            };
            let loss = c.sum();
            let _: f32 = loss.clone().into_scalar();
            let t1 = Instant::now();
            let grads = loss.backward();
            let s = g.normal.grad(&grads).expect("a gradient").sum()
                + g.depth.grad(&grads).expect("a gradient").sum()
                + light.grad(&grads).expect("a gradient").sum();
            let _: f32 = s.into_scalar();
            let t2 = Instant::now();
            t.0.push(t1 - t0);
            t.1.push(t2 - t0);
        }
    }
    println!("| {SIZE}x{SIZE} C_PBR | forward (ms) | forward + backward (ms) |");
    println!("|---|---:|---:|");
    for (name, (fwd, both)) in ["kernel", "tensor ops"].iter().zip(&times) {
        println!(
            "| {name} | {:.2} | {:.2} |",
            median_after_warm_up(fwd).as_secs_f64() * 1e3,
            median_after_warm_up(both).as_secs_f64() * 1e3
        );
    }
}
