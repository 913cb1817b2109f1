//! `cargo xtask gen-scene`: renders a synthetic translucent scene with ground truth
//! (Blender/NeRF layout, `mesh.ply`, `meta.json`) with `gtsr_data::synthetic`.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use gtsr_data::synthetic::{SceneConfig, ShapeKind, generate_scene};
use gtsr_data::transport::MaterialPreset;

/// Arguments of `cargo xtask gen-scene`.
#[derive(clap::Args, Debug, Clone)]
pub struct GenSceneArgs {
    /// Output folder (created; existing files with the same names are replaced).
    #[arg(long, short)]
    pub out: PathBuf,
    /// Shape: sphere, torus, bear, torus_knot, dented_sphere, cube, slotted_cube, capped_well,
    /// narrow_capped_well or shallow_capped_well.
    #[arg(long, default_value = "sphere")]
    pub shape: ShapeKind,
    /// Material preset, opaque-like to very translucent: chalk, marble, wax, jade, amber, glassy.
    #[arg(long, default_value = "wax")]
    pub material: MaterialPreset,
    /// Image width and height in pixels.
    #[arg(long, default_value_t = 128)]
    pub resolution: u32,
    /// Number of training views (Fibonacci sphere).
    #[arg(long, default_value_t = 100)]
    pub train: usize,
    /// Number of held-out test views (another Fibonacci sphere).
    #[arg(long, default_value_t = 20)]
    pub test: usize,
    /// Samples per pixel.
    #[arg(long, default_value_t = 64)]
    pub spp: u32,
    /// Random seed (the output is identical for a seed, whatever the thread count).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Point-light intensity in W/sr (light at the camera centre).
    #[arg(long, default_value_t = gtsr_data::synthetic::writer::DEFAULT_INTENSITY)]
    pub intensity: f32,
}

/// Runs the generator and prints progress and where the files went.
pub fn run(args: &GenSceneArgs) -> anyhow::Result<()> {
    let cfg = SceneConfig {
        resolution: args.resolution,
        n_train: args.train,
        n_test: args.test,
        spp: args.spp,
        seed: args.seed,
        light_intensity: args.intensity,
        ..SceneConfig::new(args.shape, args.material)
    };
    println!(
        "gen-scene: {} / {} at {}x{}, {} train + {} test views, {} spp, seed {} -> {}",
        args.shape,
        args.material,
        args.resolution,
        args.resolution,
        args.train,
        args.test,
        args.spp,
        args.seed,
        args.out.display()
    );
    let t0 = Instant::now();
    let scene = generate_scene(&args.out, &cfg, |p| {
        if p.done == p.total || p.done % 10 == 0 {
            println!(
                "  {} {}/{} ({:.1} s)",
                p.split,
                p.done,
                p.total,
                t0.elapsed().as_secs_f64()
            );
        }
    })
    .with_context(|| format!("generating the scene into {}", args.out.display()))?;
    println!(
        "done in {:.1} s (mesh and acceleration {:.1} s, rendering {:.1} s); {} triangles",
        t0.elapsed().as_secs_f64(),
        scene.setup_seconds,
        scene.render_seconds,
        scene.triangles
    );
    println!(
        "wrote {} files under {}: transforms_train.json, transforms_test.json, train/, test/, mesh.ply, meta.json{}",
        scene.files.len(),
        scene.root.display(),
        if scene.files.iter().any(|f| f.ends_with("hidden.ply")) {
            ", hidden.ply (the part no silhouette sees)"
        } else {
            ""
        }
    );
    Ok(())
}
