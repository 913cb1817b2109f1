//! Trains the model on a Blender/NeRF scene folder and reports test-view PSNR of C_SH and
//! C_PBR and the time per step. No mesh extraction (that is `gtsr-train`).
//!
//! ```text
//! cargo run --release -p gtsr-model --example train_scene -- DIR [ITERATIONS] [PRESET] [INIT] [MAX_SIDE]
//! cargo run --release -p gtsr-model --example train_scene -- ../shared/data/wax_knot 1500 full random 128
//! ```
//! PRESET: full, no-pbr, no-fresnel, no-interior, pgsr, auto. INIT: random, mask-carved.

#![allow(deprecated)]

use std::time::Instant;

use burn::tensor::Device;
use gtsr_data::{Downscale, LoadOptions, load_scene};
use gtsr_model::config::{Init, Preset, TrainConfig, auto_components};
use gtsr_model::trainer::{Trainer, initial_points};
use gtsr_model::views::{ViewTensors, scene_evidence, upload_views};

fn psnr(a: &[f32], b: &[f32]) -> f64 {
    let mse = a
        .iter()
        .zip(b)
        .map(|(x, y)| f64::from(x.clamp(0.0, 1.0) - y).powi(2))
        .sum::<f64>()
        / a.len() as f64;
    -10.0 * mse.max(1e-12).log10()
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let dir = args
        .first()
        .ok_or("usage: train_scene DIR [ITERATIONS] [PRESET] [INIT] [MAX_SIDE]")?;
    let iterations: usize = args.get(1).map_or(Ok(1500), |s| s.parse())?;
    let preset_name = args.get(2).map_or("full", String::as_str);
    let preset =
        Preset::from_name(preset_name).ok_or_else(|| format!("unknown preset {preset_name}"))?;
    let init = match args.get(3).map_or("random", String::as_str) {
        "random" => Init::Random,
        "mask-carved" => Init::MaskCarved,
        other => return Err(format!("unknown init {other}").into()),
    };
    let max_side: u32 = args.get(4).map_or(Ok(128), |s| s.parse())?;
    let opts = LoadOptions {
        downscale: Downscale::MaxSide(max_side),
        ..LoadOptions::default()
    };
    let scene = load_scene(dir, &opts)?;
    let components = match preset.components() {
        Some(c) => c,
        None => {
            let (c, decisions) = auto_components(&scene_evidence(&scene, 30.0)?);
            for d in decisions {
                println!(
                    "auto: {} {} ({})",
                    d.component,
                    if d.enabled { "on" } else { "off" },
                    d.reason
                );
            }
            c
        }
    };
    let mut config = TrainConfig::for_iterations(components, iterations);
    config.init = init;
    let device = Device::ndarray().autodiff();
    let views = upload_views(&scene.train, &device)?;
    let points = initial_points(&config, &views, &scene.train)?;
    let mut trainer = Trainer::new(config, views, 1.0, &points, &device)?;
    let t0 = Instant::now();
    for i in 0..iterations {
        let r = trainer.step()?;
        if (i + 1) % (iterations / 10).max(1) == 0 {
            println!(
                "step {:5}  stage {}  loss {:.4}  gaussians {:?}  passes {}  {:.0} ms/step",
                i + 1,
                r.stage,
                r.loss,
                r.counts,
                r.passes,
                t0.elapsed().as_secs_f64() * 1e3 / (i + 1) as f64
            );
        }
    }
    let train_s = t0.elapsed().as_secs_f64();
    let (mut p_sh, mut p_pbr, mut n) = (0.0, 0.0, 0);
    let model = trainer.model().detached();
    for (i, v) in scene.test.iter().enumerate() {
        let vt = ViewTensors::new(v, i, &device)?;
        let opts = trainer.render_options(iterations, false);
        let r = model.render(&vt.camera, &vt.rays, opts)?;
        let sh: Vec<f32> = r
            .c_sh
            .into_data()
            .convert::<f32>()
            .into_vec()
            .map_err(|e| format!("{e:?}"))?;
        p_sh += psnr(&sh, &v.rgb);
        if let Some(pbr) = r.c_pbr {
            let pbr: Vec<f32> = pbr
                .into_data()
                .convert::<f32>()
                .into_vec()
                .map_err(|e| format!("{e:?}"))?;
            p_pbr += psnr(&pbr, &v.rgb);
        }
        n += 1;
    }
    println!(
        "{preset_name} init={:?} {iterations} steps in {train_s:.1} s ({:.0} ms/step); skipped {}; test PSNR C_SH {:.2} dB, C_PBR {:.2} dB over {n} views; gaussians {:?}",
        trainer.config().init,
        train_s * 1e3 / iterations as f64,
        trainer.counters().skipped_steps,
        p_sh / n.max(1) as f64,
        p_pbr / n.max(1) as f64,
        trainer.model().counts()
    );
    Ok(())
}
