//! Project tasks: `cargo xtask <command>`.

mod gen_scene;
mod stability;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "xtask", about = "GTSR-rs project tasks")]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Table of the stiff and extreme kernel cases: max |f32 - f64| of outputs and gradients
    /// and counts of non-finite values.
    Stability,
    /// Render a synthetic translucent scene with ground truth (Blender/NeRF layout, mesh.ply,
    /// meta.json) with the CPU path tracer of gtsr-data.
    GenScene(gen_scene::GenSceneArgs),
}

fn main() -> anyhow::Result<()> {
    match Cli::parse().command {
        Cmd::Stability => stability::run(),
        Cmd::GenScene(args) => gen_scene::run(&args),
    }
}
