//! Shared helpers: a tiny path-traced scene, views on the device, a trainer.

use std::path::Path;

use burn::tensor::Device;
use gtsr_data::synthetic::{SceneConfig, ShapeKind, generate_scene};
use gtsr_data::transport::MaterialPreset;
use gtsr_data::{LoadOptions, Scene, load_scene};
use gtsr_model::config::{Components, TrainConfig};
use gtsr_model::trainer::{Trainer, initial_points};
use gtsr_model::views::{ViewTensors, upload_views};

/// Generates and loads a 32x32 sphere of wax, 8 training and 2 test views, 8 spp.
pub fn tiny_scene(dir: &Path) -> Scene {
    let mut cfg = SceneConfig::new(ShapeKind::Sphere, MaterialPreset::Wax);
    cfg.resolution = 32;
    cfg.n_train = 8;
    cfg.n_test = 2;
    cfg.spp = 8;
    cfg.seed = 3;
    generate_scene(dir, &cfg, |_| {}).expect("generate");
    load_scene(dir, &LoadOptions::default()).expect("load")
}

pub fn device() -> Device {
    Device::ndarray().autodiff()
}

pub fn views(scene: &Scene, device: &Device) -> Vec<ViewTensors> {
    upload_views(&scene.train, device).expect("views")
}

/// A small configuration: 60 steps, stage 2 from step 20, densification every 10 steps.
pub fn small_config(components: Components, iterations: usize) -> TrainConfig {
    let mut c = TrainConfig::for_iterations(components, iterations);
    c.init_surface = 400;
    c.init_interior = 150;
    c.init_radius = 1.1;
    c.stage2_start = iterations / 3;
    c.sh_increase_every = 5;
    // Eight views on a sphere are about 70 degrees apart.
    c.neighbour_max_angle_deg = 90.0;
    // Every term on every stage-2 step, whatever the default.
    c.multi_view_every = 1;
    c.densify.start = 10;
    c.densify.every = 10;
    c.densify.end = iterations;
    c.densify.opacity_reset_every = 0;
    c.densify.max_surface = 1500;
    c.densify.max_interior = 600;
    // Short runs need faster rates than PGSR's 30k-step schedule.
    c.lr.position_start = 1.6e-3;
    c.lr.position_end = 1.6e-4;
    c.lr.sh_dc = 0.02;
    c.lr.opacity = 0.05;
    c.lr.scale = 0.01;
    c
}

pub fn trainer(scene: &Scene, config: TrainConfig, device: &Device) -> Trainer {
    let views = views(scene, device);
    let pts = initial_points(&config, &views, &scene.train).expect("points");
    Trainer::new(config, views, 1.0, &pts, device).expect("trainer")
}
