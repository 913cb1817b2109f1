//! What the tests of this crate share: the tiny generated scene they train on.

use std::path::Path;

use gtsr_data::synthetic::{SceneConfig, ShapeKind, generate_scene};
use gtsr_data::transport::MaterialPreset;

/// A wax sphere, 24 px, 12 training and 2 test views, path-traced with 4 samples a pixel.
pub fn tiny_scene(dir: &Path) {
    let mut c = SceneConfig::new(ShapeKind::Sphere, MaterialPreset::Wax);
    c.resolution = 24;
    c.n_train = 12;
    c.n_test = 2;
    c.spp = 4;
    c.seed = 3;
    generate_scene(dir, &c, |_| {}).expect("generating the tiny scene");
}
