//! The shading op (`gtsr_render_kernels::shade`): against the Burn-ops path forward and
//! backward, against central differences in f64, and on stiff pixels.

use burn::tensor::DType::{self, F32, F64};
use burn::tensor::{Device, Tensor, TensorData};
use gtsr_render_kernels::shade::{
    Pixels, ShadeMaps, ShadeParams, backward_host, forward_host, shade, shade_by_tensor_ops,
};
use rand::{RngExt, SeedableRng, rngs::StdRng};

/// Host maps of `n` pixels away from every clamp and toe (so central differences hold).
struct Host {
    normal: Vec<f64>,
    depth: Vec<f64>,
    coverage: Vec<f64>,
    base: Vec<f64>,
    roughness: Vec<f64>,
    scatter: Vec<f64>,
    rays: Vec<f64>,
}

fn random_maps(n: usize, seed: u64) -> Host {
    let mut rng = StdRng::seed_from_u64(seed);
    let mut h = Host {
        normal: Vec::new(),
        depth: Vec::new(),
        coverage: Vec::new(),
        base: Vec::new(),
        roughness: Vec::new(),
        scatter: Vec::new(),
        rays: Vec::new(),
    };
    for _ in 0..n {
        let a = rng.random_range(0.05..1.0);
        h.coverage.push(a);
        h.rays.extend([
            rng.random_range(-0.4..0.4),
            rng.random_range(-0.4..0.4),
            1.0,
        ]);
        h.normal.extend([
            a * rng.random_range(-0.4..0.4),
            a * rng.random_range(-0.4..0.4),
            -a * rng.random_range(0.5..1.0),
        ]);
        h.depth.push(rng.random_range(1.0..4.0));
        h.base
            .extend((0..3).map(|_| a * rng.random_range(0.0..1.0)));
        h.roughness.push(a * rng.random_range(0.12..0.95));
        h.scatter
            .extend((0..3).map(|_| rng.random_range(0.06..0.9)));
    }
    h
}

const LIGHT: f64 = 3.0;

fn params(scatter_lambert: bool, scatter_srgb: bool) -> ShadeParams {
    ShadeParams {
        f0: 0.04,
        gamma: 0.3,
        min_roughness: 0.08,
        scatter_lambert,
        scatter_srgb,
    }
}

/// Every combination of the switches and the encoding, with and without a scattering map:
/// `(params, scattering map, sRGB encoding)`.
fn variants() -> Vec<(ShadeParams, bool, bool)> {
    let mut v = Vec::new();
    for bits in 0..8u32 {
        let (p, encode) = (params(bits & 1 != 0, bits & 2 != 0), bits & 4 != 0);
        v.push((p, true, encode));
        if bits & 3 == 0 {
            v.push((p, false, encode));
        }
    }
    v
}

/// The maps as leaves on `device` (`require_grad` on an autodiff device).
fn tensors(
    h: &Host,
    [rows, cols]: [usize; 2],
    device: &Device,
    dtype: DType,
    scatter: bool,
) -> (ShadeMaps, Tensor<2>) {
    let grad = device.is_autodiff();
    let t3 = |v: &Vec<f64>| {
        let t =
            Tensor::<3>::from_data(TensorData::new(v.clone(), [rows, cols, 3]), (device, dtype));
        if grad { t.require_grad() } else { t }
    };
    let t2 = |v: &Vec<f64>| {
        let t = Tensor::<2>::from_data(TensorData::new(v.clone(), [rows, cols]), (device, dtype));
        if grad { t.require_grad() } else { t }
    };
    let light = Tensor::<2>::from_data(TensorData::new(vec![LIGHT], [1, 1]), (device, dtype));
    let maps = ShadeMaps {
        normal: t3(&h.normal),
        depth: t2(&h.depth),
        coverage: t2(&h.coverage),
        base: t3(&h.base),
        roughness: t2(&h.roughness),
        scatter: scatter.then(|| t3(&h.scatter)),
        rays: Tensor::<3>::from_data(
            TensorData::new(h.rays.clone(), [rows, cols, 3]),
            (device, dtype),
        ),
    };
    (maps, if grad { light.require_grad() } else { light })
}

fn host<const D: usize>(t: Tensor<D>) -> Vec<f64> {
    t.cast(F64).into_data().to_vec::<f64>().unwrap()
}

type Shade = fn(&ShadeMaps, Tensor<2>, ShadeParams, bool) -> Tensor<3>;

#[test]
fn the_op_equals_the_tensor_ops_forward_and_backward() {
    let size = [40, 60]; // more than two chunks
    let h = random_maps(size[0] * size[1], 5);
    let plain = Device::ndarray();
    let device = Device::ndarray().autodiff();
    let mut rng = StdRng::seed_from_u64(6);
    let u: Vec<f64> = (0..3 * size[0] * size[1])
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    for (p, scatter, encode) in variants() {
        let run = |shade: Shade, dtype| {
            let (maps, light) = tensors(&h, size, &plain, dtype, scatter);
            host(shade(&maps, light, p, encode))
        };
        // NdArray's `powf_scalar` takes its exponent as an f32, so the tensor ops' sRGB
        // curves are f64 curves with exponents 2.4 and 1/2.4 rounded to f32 (some 1e-8).
        let tol = if p.scatter_srgb || encode {
            1e-7
        } else {
            1e-12
        };
        let op = run(shade, F64);
        let ops = run(shade_by_tensor_ops, F64);
        for (a, b) in op.iter().zip(&ops) {
            assert!(
                (a - b).abs() < tol * (1.0 + b.abs()),
                "{p:?} (encode {encode}): {a} against {b}"
            );
        }
        // f32 against f64: the inputs' rounding alone moves a sharp specular peak by a few
        // 1e-5 of its value, in either evaluation.
        let (op32, ops32) = (run(shade, F32), run(shade_by_tensor_ops, F32));
        for ((a, b), c) in op32.iter().zip(&op).zip(&ops32) {
            let tol = 2e-4 * (1.0 + b.abs());
            assert!(
                (a - b).abs() < tol,
                "{p:?} (encode {encode}) f32: {a} against {b}"
            );
            assert!(
                (c - b).abs() < tol,
                "{p:?} (encode {encode}) f32 tensor ops: {c} against {b}"
            );
        }
        // The gradients of sum(u * colour), every input.
        let grads = |shade: Shade| {
            let (maps, light) = tensors(&h, size, &device, F64, scatter);
            let out = shade(&maps, light.clone(), p, encode);
            let weights = Tensor::<3>::from_data(
                TensorData::new(u.clone(), [size[0], size[1], 3]),
                (&device, F64),
            );
            let g = (out * weights).sum().backward();
            let mut all = vec![
                host(maps.normal.grad(&g).unwrap()),
                host(maps.depth.grad(&g).unwrap()),
                host(maps.coverage.grad(&g).unwrap()),
                host(maps.base.grad(&g).unwrap()),
                host(maps.roughness.grad(&g).unwrap()),
                host(light.grad(&g).unwrap()),
            ];
            if let Some(s) = &maps.scatter {
                all.push(host(s.grad(&g).unwrap()));
            }
            all
        };
        // Per input, to 1e-10 of its largest gradient: at a sharp specular peak the terms
        // of one gradient reach a thousand times their sum, in either order of evaluation.
        for (k, (a, b)) in grads(shade)
            .iter()
            .zip(grads(shade_by_tensor_ops))
            .enumerate()
        {
            let scale = b.iter().fold(1.0f64, |m, y| m.max(y.abs()));
            for (x, y) in a.iter().zip(&b) {
                assert!(
                    (x - y).abs() < tol.max(1e-10) * scale,
                    "{p:?} (encode {encode}), input {k}: {x} against {y} (largest {scale})"
                );
            }
        }
    }
}

#[test]
fn the_gradients_match_central_differences_in_f64() {
    let (n, eps) = (9, 1e-6);
    let h = random_maps(n, 8);
    let mut rng = StdRng::seed_from_u64(10);
    let u: Vec<f64> = (0..3 * n).map(|_| rng.random_range(-1.0..1.0)).collect();
    for (p, scatter, encode) in variants() {
        let pixels = |m: &Host, light: f64| -> f64 {
            let px = Pixels {
                normal: &m.normal,
                depth: &m.depth,
                coverage: &m.coverage,
                base: &m.base,
                roughness: &m.roughness,
                scatter: scatter.then_some(&m.scatter[..]),
                rays: &m.rays,
                light,
            };
            forward_host(&px, p, encode)
                .iter()
                .zip(&u)
                .map(|(a, b)| a * b)
                .sum()
        };
        let px = Pixels {
            normal: &h.normal,
            depth: &h.depth,
            coverage: &h.coverage,
            base: &h.base,
            roughness: &h.roughness,
            scatter: scatter.then_some(&h.scatter[..]),
            rays: &h.rays,
            light: LIGHT,
        };
        let g = backward_host(&px, p, encode, &u);
        let close = |what: &str, k: usize, got: f64, fd: f64| {
            assert!(
                (got - fd).abs() < 1e-7 * (1.0 + fd.abs()),
                "{p:?} (encode {encode}), {what} {k}: {got} against {fd}"
            );
        };
        type Field = fn(&mut Host) -> &mut Vec<f64>;
        let fields: [(&str, Field, &Vec<f64>); 6] = [
            ("normal", |m| &mut m.normal, &g.normal),
            ("depth", |m| &mut m.depth, &g.depth),
            ("coverage", |m| &mut m.coverage, &g.coverage),
            ("base", |m| &mut m.base, &g.base),
            ("roughness", |m| &mut m.roughness, &g.roughness),
            ("scatter", |m| &mut m.scatter, &g.scatter),
        ];
        for (what, field, got) in fields {
            if what == "scatter" && !scatter {
                continue;
            }
            assert_eq!(got.len(), field(&mut random_maps(n, 8)).len());
            for (k, g_k) in got.iter().enumerate() {
                let mut plus = random_maps(n, 8);
                field(&mut plus)[k] += eps;
                let mut minus = random_maps(n, 8);
                field(&mut minus)[k] -= eps;
                let fd = (pixels(&plus, LIGHT) - pixels(&minus, LIGHT)) / (2.0 * eps);
                close(what, k, *g_k, fd);
            }
        }
        let fd = (pixels(&h, LIGHT + eps) - pixels(&h, LIGHT - eps)) / (2.0 * eps);
        close("light", 0, g.light, fd);
    }
}

#[test]
fn stiff_pixels_give_finite_colours_and_gradients() {
    let n = 8;
    let mut h = random_maps(n, 12);
    // No coverage; a zero normal; a normal perpendicular to the ray (grazing); depth 0; zero
    // roughness; a huge depth; a negative and an over-bright scattering colour; a huge
    // coverage-premultiplied normal.
    h.coverage[0] = 0.0;
    h.normal[3..6].copy_from_slice(&[0.0, 0.0, 0.0]);
    h.normal[6..9].copy_from_slice(&[h.rays[7], -h.rays[6], 0.0]);
    h.depth[3] = 0.0;
    h.roughness[4] = 0.0;
    h.depth[5] = 1e6;
    h.scatter[18..21].copy_from_slice(&[-0.3, 0.0, 30.0]);
    h.normal[21..24].copy_from_slice(&[1e20, -1e20, -1e20]);
    let device = Device::ndarray().autodiff();
    for (p, scatter, encode) in variants() {
        let (maps, light) = tensors(&h, [2, 4], &device, F32, scatter);
        let out = shade(&maps, light.clone() * 1e6, p, encode);
        assert!(
            host(out.clone()).iter().all(|v| v.is_finite()),
            "{p:?} (encode {encode})"
        );
        let g = out.sum().backward();
        for t in [
            host(maps.normal.grad(&g).unwrap()),
            host(maps.depth.grad(&g).unwrap()),
            host(maps.coverage.grad(&g).unwrap()),
            host(maps.roughness.grad(&g).unwrap()),
            host(light.grad(&g).unwrap()),
        ] {
            assert!(
                t.iter().all(|v| v.is_finite()),
                "{p:?} (encode {encode}): {t:?}"
            );
        }
    }
}
