//! Project tasks: `cargo xtask <command>`.

mod bench_recon;
mod concavity;
mod diagnose_surface;
mod fusion_ceiling;
mod gen_scene;
mod photo;
mod shading;
mod shading_depth;
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
    /// Fuse the ground truth's own depth maps as gtsr-train fuses rendered ones (same box,
    /// voxel, masks, carving) at several truncations: the best chamfer any rendered depth can
    /// reach through that fusion, against the masks alone.
    FusionCeiling(fusion_ceiling::FusionCeilingArgs),
    /// Where a trained run's surface Gaussians lie against the ground truth, how opaque they
    /// are there, and which loss term pushes their opacity and position which way (development
    /// scenes only: the ground truth diagnoses, never trains).
    DiagnoseSurface(diagnose_surface::DiagnoseSurfaceArgs),
    /// Normals from the images' shading under the light at the camera (photometric stereo
    /// with the light moving with each view), and the masks' mesh refined by them, scored
    /// against the ground truth when the scene has one.
    ShadingStereo(shading::ShadingStereoArgs),
    /// A plane sweep on the training images alone, scored by the ground truth: whether the
    /// images' multi-view photo-consistency puts a concavity the masks cannot see at its true
    /// depth or at the masks' lid (development scenes only).
    PhotoConsistency(photo::PhotoConsistencyArgs),
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
        Cmd::FusionCeiling(args) => fusion_ceiling::run(&args),
        Cmd::DiagnoseSurface(args) => diagnose_surface::run(&args),
        Cmd::ShadingStereo(args) => shading::run(&args),
        Cmd::PhotoConsistency(args) => photo::run(&args),
    }
}
