//! Gradients flow through arbitrary Burn expressions upstream of the splat op: exp
//! activations, quaternion normalisation, degree-1 spherical harmonics and a Schlick Fresnel
//! factor multiplied into the opacity. Checked against finite differences of the whole
//! composition in f64.

use burn::tensor::{DType, Device, Tensor, TensorData};
use gtsr_render_kernels::scenes::{RandomSceneSpec, random_scene};
use gtsr_render_kernels::{AlphaCutoff, SplatConfig, SplatInputs, render};
use rand::{RngExt, SeedableRng, rngs::StdRng};

use crate::common::{host, loss_weights};

const N: usize = 8;

/// The learnable parameters, as host vectors: means, log-scales, quats, opacity logits,
/// SH DC and SH degree-1 coefficients.
#[derive(Clone)]
struct Params(Vec<Vec<f64>>);

const COLS: [usize; 6] = [3, 3, 4, 1, 3, 9];

fn model_loss(
    p: &Params,
    cfg: &SplatConfig,
    device: &Device,
    weights: &[f64],
) -> (Tensor<1>, Vec<Tensor<2>>) {
    let leaves: Vec<Tensor<2>> = p
        .0
        .iter()
        .zip(COLS)
        .map(|(v, c)| {
            let t =
                Tensor::<2>::from_data(TensorData::new(v.clone(), [N, c]), (device, DType::F64));
            if device.is_autodiff() {
                t.require_grad()
            } else {
                t
            }
        })
        .collect();
    let [means, log_scales, quats, logits, sh0, sh1] =
        [0, 1, 2, 3, 4, 5].map(|k| leaves[k].clone());
    let cam = cfg.camera.centre();
    let centre =
        Tensor::<2>::from_data(TensorData::new(cam.to_vec(), [1, 3]), (device, DType::F64));
    // View directions.
    let d = means.clone() - centre;
    let dn = d.clone() / (d.clone() * d).sum_dim(1).sqrt();
    let (x, y, z) = (
        dn.clone().slice([0..N, 0..1]),
        dn.clone().slice([0..N, 1..2]),
        dn.clone().slice([0..N, 2..3]),
    );
    // Degree-1 SH colour.
    let c1 = 0.488_602_511_902_919_9;
    let sh1 = sh1.reshape([N, 3, 3]);
    let band = |k: usize| sh1.clone().slice([0..N, k..k + 1, 0..3]).reshape([N, 3]);
    let colour = sh0 * 0.282_094_791_773_878_1 - band(0) * y.clone() * c1
        + band(1) * z.clone() * c1
        - band(2) * x.clone() * c1
        + 0.5;
    // Normal = the local z axis of the (normalised) rotation; Schlick Fresnel with F0 = 0.04.
    let qn = quats.clone() / (quats.clone() * quats).sum_dim(1).sqrt();
    let [qw, qx, qy, qz] = [0, 1, 2, 3].map(|k| qn.clone().slice([0..N, k..k + 1]));
    let nx = (qx.clone() * qz.clone() + qw.clone() * qy.clone()) * 2.0;
    let ny = (qy.clone() * qz.clone() - qw.clone() * qx.clone()) * 2.0;
    let nz = (qx.clone() * qx.clone() + qy.clone() * qy.clone()) * -2.0 + 1.0;
    let cos = nx * x + ny * y + nz * z;
    let cos_abs = (cos.clone() * cos + 1e-6).sqrt();
    let fresnel = (cos_abs.neg() + 1.0).powi_scalar(5) * 0.96 + 0.04;
    // A logistic written out: Burn 0.22.1's `sigmoid` on NdArray computes in f32 even for f64
    // tensors (errors ~1e-8), too coarse for finite differences.
    let opacity = (logits.neg().exp() + 1.0).recip() * fresnel;
    let inputs = SplatInputs {
        means,
        quats: leaves[2].clone(),
        scales: log_scales.exp(),
        opacities: opacity.reshape([N]),
        features: colour,
        xy_offsets: None,
    };
    let out = render(inputs, cfg).unwrap();
    let (h, w) = (cfg.camera.height as usize, cfg.camera.width as usize);
    let joined = Tensor::cat(vec![out.image, out.alpha.reshape([h, w, 1])], 2);
    let wt = Tensor::<3>::from_data(
        TensorData::new(weights.to_vec(), [h, w, 4]),
        (device, DType::F64),
    );
    ((joined * wt).sum(), leaves)
}

#[test]
fn gradients_flow_through_upstream_burn_expressions() {
    let scene = random_scene(
        41,
        &RandomSceneSpec {
            count: N,
            channels: 3,
            size: (40, 30),
            radius: 0.5,
            scale_range: (0.05, 0.3),
            opacity_range: (0.3, 0.9),
            distance: 4.0,
            fov_x: 0.9,
        },
    );
    let cfg = scene.config(AlphaCutoff::Smooth);
    let mut rng = StdRng::seed_from_u64(8);
    let mut rnd = |n: usize, lo: f64, hi: f64| {
        (0..n)
            .map(|_| rng.random_range(lo..hi))
            .collect::<Vec<f64>>()
    };
    let params = Params(vec![
        scene.means.clone(),
        scene.scales.iter().map(|s| s.ln()).collect(),
        scene.quats.clone(),
        rnd(N, -1.0, 2.0),
        rnd(3 * N, -0.5, 1.5),
        rnd(9 * N, -0.5, 0.5),
    ]);
    let weights = loss_weights(77, 40 * 30 * 4);
    let ad = Device::ndarray().autodiff();
    let (loss, leaves) = model_loss(&params, &cfg, &ad, &weights);
    let grads = loss.backward();
    let plain = Device::ndarray();
    let eval = |p: &Params| host(model_loss(p, &cfg, &plain, &weights).0)[0];
    let names = ["means", "log_scales", "quats", "logits", "sh0", "sh1"];
    for (k, leaf) in leaves.iter().enumerate() {
        let g = host(leaf.grad(&grads).expect("leaf gradient"));
        let scale = g.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(scale > 0.0, "{}: zero gradient", names[k]);
        let mut p = params.clone();
        for (i, &gi) in g.iter().enumerate() {
            let x = p.0[k][i];
            let h = 1e-6 * x.abs().max(1.0);
            p.0[k][i] = x + h;
            let up = eval(&p);
            p.0[k][i] = x - h;
            let down = eval(&p);
            p.0[k][i] = x;
            let fd = (up - down) / (2.0 * h);
            let rel = (gi - fd).abs() / gi.abs().max(fd.abs()).max(1e-3 * scale).max(1e-9);
            assert!(
                rel <= 1e-4,
                "{}[{i}]: autodiff {gi:e} vs finite difference {fd:e}",
                names[k]
            );
        }
    }
}
