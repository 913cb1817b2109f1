//! Laboratory diagnostics: `cargo run --release -p lab -- <command>`.

use clap::{Parser, Subcommand};
use lab::{diagnose_surface, fusion_ceiling, photo, shading};

#[derive(Parser)]
#[command(
    name = "lab",
    about = "GTSR-rs laboratory diagnostics (development scenes only)"
)]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
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
    let result = match Cli::parse().command {
        Cmd::FusionCeiling(args) => fusion_ceiling::run(&args),
        Cmd::DiagnoseSurface(args) => diagnose_surface::run(&args),
        Cmd::ShadingStereo(args) => shading::run(&args),
        Cmd::PhotoConsistency(args) => photo::run(&args),
    };
    if let Err(e) = result {
        eprintln!("lab: error: {e:#}");
        std::process::exit(1);
    }
}
