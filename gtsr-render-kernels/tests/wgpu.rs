//! The wgpu (CubeCL) kernels against the CPU kernels, which are the reference: forward within
//! 1e-4 and gradients within 1e-3 (relative to the largest reference value) on random scenes
//! and on every stiff case of the CPU suite; the GPU radix sort and prefix sum against the
//! host past 2^20 elements; the backward pass deterministic and independent of its banding.
//! In CI these run on Mesa's lavapipe (CPU Vulkan, Mesa 25).
#![cfg(feature = "wgpu")]
// Device::ndarray is deprecated upstream; NdArray stays the CPU and CI backend.
#![allow(deprecated)]

use burn::tensor::{DType, Device, DeviceKind, Tensor};
use gtsr_render_kernels::gpu::scan_sort::{exclusive_scan_host, sort_pairs};
use gtsr_render_kernels::scenes::{
    HostScene, INPUT_NAMES, RandomSceneSpec, random_scene, random_weights, stiff_cases,
    weighted_loss_gradients_on,
};
use gtsr_render_kernels::{AlphaCutoff, cpu, render};
use rand::{RngExt, SeedableRng, rngs::StdRng};

fn wgpu() -> Device {
    Device::wgpu(DeviceKind::DefaultDevice)
}

fn client() -> burn_cubecl::cubecl::client::Client {
    burn_cubecl::CubeDevice::Wgpu(Default::default()).client()
}

fn host<const D: usize>(t: Tensor<D>) -> Vec<f64> {
    t.into_data().iter::<f64>().collect()
}

/// `[H, W, C + 1]` output and `[N, 4]` aux of one render.
fn render_on(
    device: &Device,
    scene: &HostScene,
    dtype: DType,
    cutoff: AlphaCutoff,
) -> (Vec<f64>, Vec<f64>) {
    let out = render(scene.inputs(device, dtype), &scene.config(cutoff)).unwrap();
    let img = host(out.image);
    let alpha = host(out.alpha);
    let c = scene.channels;
    let mut v = Vec::with_capacity(alpha.len() * (c + 1));
    for (p, a) in alpha.iter().enumerate() {
        v.extend_from_slice(&img[p * c..(p + 1) * c]);
        v.push(*a);
    }
    (v, host(out.aux))
}

/// Largest absolute difference relative to the largest reference magnitude (at least 1e-12).
fn rel_err(got: &[f64], want: &[f64]) -> f64 {
    assert_eq!(got.len(), want.len());
    let scale = want.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-12);
    got.iter()
        .zip(want)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f64, f64::max)
        / scale
}

fn spec(count: usize, channels: usize, size: (u32, u32)) -> RandomSceneSpec {
    RandomSceneSpec {
        count,
        channels,
        size,
        radius: 0.6,
        scale_range: (0.02, 0.25),
        opacity_range: (0.05, 0.95),
        distance: 4.0,
        fov_x: 0.9,
    }
}

fn random_scenes() -> Vec<(String, HostScene)> {
    [
        (1, 3, (61, 47)),
        (40, 3, (64, 48)),
        (300, 1, (75, 33)),
        (800, 4, (96, 80)),
        (2000, 7, (128, 96)),
    ]
    .iter()
    .enumerate()
    .map(|(i, &(n, c, size))| {
        (
            format!("random n={n} c={c} {}x{}", size.0, size.1),
            random_scene(900 + i as u64, &spec(n, c, size)),
        )
    })
    .collect()
}

fn check_forward(name: &str, scene: &HostScene, cutoff: AlphaCutoff) {
    let (want, want_aux) = render_on(&Device::ndarray(), scene, DType::F64, cutoff);
    let (got, got_aux) = render_on(&wgpu(), scene, DType::F32, cutoff);
    assert!(
        got.iter().all(|v| v.is_finite()),
        "{name}: non-finite wgpu output"
    );
    let e = rel_err(&got, &want);
    assert!(
        e <= 1e-4,
        "{name} {cutoff:?}: forward relative error {e:.3e} > 1e-4"
    );
    // Status and tile counts agree exactly; radius and depth to f32 rounding.
    for (i, (g, w)) in got_aux.chunks(4).zip(want_aux.chunks(4)).enumerate() {
        assert_eq!(g[3], w[3], "{name}: status of Gaussian {i}");
        assert_eq!(g[2], w[2], "{name}: tiles of Gaussian {i}");
        for k in 0..2 {
            assert!(
                (g[k] - w[k]).abs() <= 1e-4 * w[k].abs().max(1.0),
                "{name}: aux[{i}][{k}] {} vs {}",
                g[k],
                w[k]
            );
        }
    }
}

/// Relative error of each gradient against `want`. For quaternions the scale also includes
/// `max |s * dL/ds|`: a rotation by a small angle changes the covariance as much as a relative
/// change of the scales by that amount, and for an isotropic Gaussian the true quaternion
/// gradient is 0, so both backends return rounding noise (on "huge scales (1e3)" CPU f32 and
/// f64 differ by 100% of it).
fn grad_errors(scene: &HostScene, got: &[Vec<f64>; 6], want: &[Vec<f64>; 6]) -> [f64; 6] {
    let shape_scale = scene
        .scales
        .iter()
        .zip(&want[2])
        .map(|(s, g)| (s * g).abs())
        .fold(0.0f64, f64::max);
    std::array::from_fn(|k| {
        let e = rel_err(&got[k], &want[k]);
        if k == 1 {
            let peak = want[1]
                .iter()
                .fold(0.0f64, |m, v| m.max(v.abs()))
                .max(1e-12);
            e * peak / peak.max(shape_scale)
        } else {
            e
        }
    })
}

/// The CPU's f32 gradients on the per-pixel blend for `loss = sum(weights * [image, alpha])`.
fn per_pixel_f32(scene: &HostScene, cutoff: AlphaCutoff, weights: &[f64]) -> [Vec<f64>; 6] {
    let scene32 = scene.to_f32();
    let host = scene32.host();
    let weights: Vec<f32> = weights.iter().map(|&w| w as f32).collect();
    let cfg = scene.config(cutoff);
    let out = cpu::forward_with(&host, &cfg, cpu::BlendPath::PerPixel);
    cpu::backward(&host, &cfg, &out.state, &weights)
        .into_parts()
        .map(|v| v.iter().map(|&x| f64::from(x)).collect())
}

/// wgpu f32 gradients against the CPU's f64 ones: within 1e-3, or (stiff cases, where f32
/// itself is the limit) within three times the CPU's own f32 error.
fn check_gradients(name: &str, scene: &HostScene, cutoff: AlphaCutoff, stiff: bool) {
    let (h, w) = (scene.camera.height as usize, scene.camera.width as usize);
    let weights = random_weights(17, h * w * (scene.channels + 1));
    let cpu = |dtype| {
        weighted_loss_gradients_on(&Device::ndarray(), scene, dtype, cutoff, &weights)
            .unwrap()
            .grads
    };
    let want = cpu(DType::F64);
    let got = weighted_loss_gradients_on(&wgpu(), scene, DType::F32, cutoff, &weights)
        .unwrap()
        .grads;
    for (g, input) in got.iter().zip(INPUT_NAMES) {
        assert!(
            g.iter().all(|v| v.is_finite()),
            "{name} {cutoff:?}: non-finite wgpu gradient of {input}"
        );
    }
    let errors = grad_errors(scene, &got, &want);
    // The CPU's own f32 error: the larger of its two f32 blends (the lanes, which the Burn
    // path runs, and the per-pixel code, which is what the wgpu kernels port).
    let cpu_errors = if stiff {
        let lanes = grad_errors(scene, &cpu(DType::F32), &want);
        let per_pixel = grad_errors(scene, &per_pixel_f32(scene, cutoff, &weights), &want);
        std::array::from_fn(|k| lanes[k].max(per_pixel[k]))
    } else {
        [0.0; 6]
    };
    for k in 0..6 {
        let tol = 1e-3f64.max(3.0 * cpu_errors[k]);
        assert!(
            errors[k] <= tol,
            "{name} {cutoff:?}: gradient of {}: relative error {:.3e} > {tol:.1e} (CPU f32: {:.3e})",
            INPUT_NAMES[k],
            errors[k],
            cpu_errors[k]
        );
        if stiff && errors[k] > 1e-3 {
            eprintln!(
                "{name} {cutoff:?}: gradient of {}: wgpu f32 {:.2e}, CPU f32 {:.2e} (against f64)",
                INPUT_NAMES[k], errors[k], cpu_errors[k]
            );
        }
    }
}

#[test]
fn forward_matches_cpu_on_random_scenes() {
    for (name, scene) in random_scenes() {
        for cutoff in [AlphaCutoff::Smooth, AlphaCutoff::Hard] {
            check_forward(&name, &scene, cutoff);
        }
    }
}

#[test]
fn gradients_match_cpu_on_random_scenes() {
    for (name, scene) in random_scenes() {
        for cutoff in [AlphaCutoff::Smooth, AlphaCutoff::Hard] {
            check_gradients(&name, &scene, cutoff, false);
        }
    }
}

/// The screen-space blur is a setting (the camera buffer carries it): the pixel box's 1/12 and
/// 0 render as on the CPU, and differently from 3DGS's 0.3.
#[test]
fn blur_setting_matches_cpu() {
    let scene = random_scene(950, &spec(300, 3, (64, 48)));
    let mut renders = Vec::new();
    for blur in [
        gtsr_render_kernels::PIXEL_BOX_BLUR_PX2,
        0.0,
        gtsr_render_kernels::BLUR_PX2,
    ] {
        let mut cfg = scene.config(AlphaCutoff::Smooth);
        cfg.blur_px2 = blur;
        let cpu = render(scene.inputs(&Device::ndarray(), DType::F64), &cfg).unwrap();
        let gpu = render(scene.inputs(&wgpu(), DType::F32), &cfg).unwrap();
        let (want, got) = (host(cpu.image), host(gpu.image));
        let e = rel_err(&got, &want);
        assert!(e <= 1e-4, "blur {blur}: forward relative error {e:.3e}");
        renders.push(want);
    }
    let d = rel_err(&renders[0], &renders[2]);
    assert!(d > 1e-3, "blur 1/12 and 0.3 render alike ({d:e})");
}

#[test]
fn blur_compensation_matches_cpu() {
    let scene = random_scene(951, &spec(200, 2, (48, 40)));
    let mut cfg = scene.config(AlphaCutoff::Smooth);
    cfg.blur_px2 = gtsr_render_kernels::PIXEL_BOX_BLUR_PX2;
    cfg.compensate_blur = true;
    let (h, w) = (40, 48);
    let weights = gtsr_render_kernels::scenes::random_weights(52, h * w * 3);
    let run = |device: &Device, dtype| {
        gtsr_render_kernels::scenes::weighted_loss_gradients_with(
            device, &scene, dtype, &cfg, &weights,
        )
        .unwrap()
    };
    let (cpu, gpu) = (
        run(&Device::ndarray(), DType::F64),
        run(&wgpu(), DType::F32),
    );
    let e = rel_err(&gpu.output, &cpu.output);
    assert!(e <= 1e-4, "forward relative error {e:.3e}");
    for (e, input) in grad_errors(&scene, &gpu.grads, &cpu.grads)
        .iter()
        .zip(INPUT_NAMES)
    {
        assert!(*e <= 1e-3, "gradient of {input}: relative error {e:.3e}");
    }
}

#[test]
fn stiff_cases_match_cpu() {
    for case in stiff_cases() {
        for cutoff in [AlphaCutoff::Smooth, AlphaCutoff::Hard] {
            check_forward(case.name, &case.scene, cutoff);
            check_gradients(case.name, &case.scene, cutoff, true);
        }
    }
}

#[test]
fn f64_is_refused_on_wgpu() {
    let scene = random_scene(3, &spec(5, 3, (32, 32)));
    let err = render(
        scene.inputs(&wgpu(), DType::F64),
        &scene.config(AlphaCutoff::Hard),
    );
    assert!(err.is_err(), "f64 on wgpu must be refused, not computed");
}

#[test]
fn radix_sort_matches_host_past_2_pow_20() {
    let client = client();
    let n = (1 << 20) + 4097;
    let mut rng = StdRng::seed_from_u64(5);
    // Full 32-bit keys, and 12-bit keys with many ties (stability shows in the values).
    for bits in [32u32, 12] {
        let keys: Vec<u32> = (0..n)
            .map(|_| {
                let k: u32 = rng.random();
                if bits == 32 { k } else { k & ((1 << bits) - 1) }
            })
            .collect();
        let vals: Vec<u32> = (0..n as u32).collect();
        let (gk, gv) = sort_pairs(&client, &keys, &vals, bits);
        let mut want: Vec<(u32, u32)> = keys.iter().copied().zip(vals.iter().copied()).collect();
        want.sort_by_key(|p| p.0); // stable
        let wk: Vec<u32> = want.iter().map(|p| p.0).collect();
        let wv: Vec<u32> = want.iter().map(|p| p.1).collect();
        assert!(gk == wk, "{bits}-bit keys are not sorted like the host's");
        assert!(
            gv == wv,
            "{bits}-bit sort is not stable (values differ from the host's)"
        );
    }
    // Small and empty inputs.
    for n in [0usize, 1, 2, 255, 1024, 1025] {
        let keys: Vec<u32> = (0..n as u32).rev().collect();
        let vals: Vec<u32> = (0..n as u32).collect();
        let (gk, _) = sort_pairs(&client, &keys, &vals, 32);
        let mut wk = keys.clone();
        wk.sort();
        assert_eq!(gk, wk, "n = {n}");
    }
}

#[test]
fn prefix_sum_matches_host_past_2_pow_20() {
    let client = client();
    let mut rng = StdRng::seed_from_u64(6);
    // 2^24 + 5 elements need more than 65,535 cubes of 256 threads: the grid goes 2D.
    for n in [1usize, 1023, 1024, 1025, (1 << 21) + 3, (1 << 24) + 5] {
        let data: Vec<u32> = (0..n).map(|_| rng.random_range(0..1000u32)).collect();
        let got = exclusive_scan_host(&client, &data);
        let mut acc = 0u32;
        let want: Vec<u32> = data
            .iter()
            .map(|&x| {
                let v = acc;
                acc = acc.wrapping_add(x);
                v
            })
            .collect();
        assert!(
            got == want,
            "exclusive scan of {n} elements differs from the host's"
        );
    }
}

#[test]
fn banded_backward_is_deterministic_and_bit_identical() {
    let scene = random_scene(77, &spec(1500, 3, (96, 80)));
    let weights = random_weights(3, 96 * 80 * 4);
    let run = || {
        weighted_loss_gradients_on(&wgpu(), &scene, DType::F32, AlphaCutoff::Hard, &weights)
            .unwrap()
            .grads
    };
    let first = run();
    assert!(first == run(), "two backward passes differ");
    // One band per tile row (4 KiB of gradient rows) instead of one for the whole image: each
    // Gaussian's rows are still added in the same order. SAFETY: other tests of this binary may
    // read the variable concurrently; every value gives the same results.
    unsafe { std::env::set_var("GTSR_WGPU_BAND_BYTES", "4096") };
    let banded = run();
    unsafe { std::env::remove_var("GTSR_WGPU_BAND_BYTES") };
    assert!(
        first == banded,
        "banded backward differs from the single-band one"
    );
}
