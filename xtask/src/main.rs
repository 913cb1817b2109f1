//! Project tasks: `cargo xtask <command>`.

mod bench_recon;
mod exposure;
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
    /// Reconstruct each scene with the full model, the three ablations of the paper and the
    /// PGSR-like baseline (via gtsr-train), plus the masks alone at the dataset's resolution; write a markdown table
    /// and one combined error-against-time plot.
    BenchRecon(bench_recon::BenchReconArgs),
    /// Copy a scene with each view's exposure changed by up to a given number of stops, as a
    /// phone's auto exposure does (the stops drawn go to `exposures.json`).
    Exposure(exposure::ExposureArgs),
}

fn main() {
    if let Err(e) = run(Cli::parse().command) {
        eprintln!("xtask: error: {e:#}");
        std::process::exit(1);
    }
}

fn run(command: Cmd) -> anyhow::Result<()> {
    match command {
        Cmd::Stability => stability::run(),
        Cmd::GenScene(args) => gen_scene::run(&args),
        Cmd::BenchRecon(args) => bench_recon::run(&args),
        Cmd::Exposure(args) => exposure::run(&args),
    }
}
