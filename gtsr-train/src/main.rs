//! `gtsr-train`: images in, mesh and numbers out.
//!
//! With no arguments it generates (or reuses) a small built-in translucent scene (a wax bear,
//! path-traced by `gtsr-data`) and reconstructs it on the CPU. See `--help` for the options and
//! the README for what lands in `--out`.

#![allow(deprecated)] // burn-ndarray: the design card keeps it as the CPU backend.

mod outputs;
mod pipeline;

use std::path::PathBuf;

use clap::{Parser, ValueEnum};

/// Reconstruct the surface of a translucent object from posed images (GTSR).
#[derive(Parser, Debug, Clone)]
#[command(version, about)]
pub struct Args {
    /// Dataset folder (Blender/NeRF `transforms_*.json` or COLMAP). Default: the built-in
    /// synthetic scene, generated into `--scene-cache` on first use.
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Where the built-in scene is generated (and reused from).
    #[arg(long, default_value = "gtsr-cache/default-scene")]
    pub scene_cache: PathBuf,
    /// Output folder.
    #[arg(long, default_value = "gtsr-output")]
    pub out: PathBuf,
    /// Compute backend.
    #[arg(long, value_enum, default_value_t = Backend::Ndarray)]
    pub backend: Backend,
    /// Training steps.
    #[arg(long)]
    pub iterations: Option<usize>,
    /// Longest image side after downscaling (pixels).
    #[arg(long)]
    pub resolution: Option<u32>,
    /// Component preset: full, no-pbr, no-fresnel, no-interior, pgsr, auto.
    #[arg(long, default_value = "full")]
    pub preset: String,
    /// A JSON file with every training setting (as written to `config.json`); the switches
    /// below and `--iterations` / `--seed` override it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Leave out the interior set.
    #[arg(long)]
    pub no_interior: bool,
    /// Leave out the Fresnel weighting.
    #[arg(long)]
    pub no_fresnel: bool,
    /// Leave out C_PBR (and material smoothness).
    #[arg(long)]
    pub no_pbr: bool,
    /// Leave out the multi-view geometric term.
    #[arg(long)]
    pub no_multi_view: bool,
    /// Leave out the single-view depth-normal term.
    #[arg(long)]
    pub no_single_view: bool,
    /// Largest SH degree (0-3).
    #[arg(long)]
    pub sh_degree: Option<u32>,
    /// Initialisation: random (the paper), mask-carved (inside the masks' hull) or hull-surface
    /// (on its boundary).
    #[arg(long)]
    pub init: Option<String>,
    /// Weight of the surface opacities' binarisation in stage 2 (gtsr-model's
    /// `weights.opacity_entropy`; 0: off).
    #[arg(long)]
    pub opacity_entropy: Option<f64>,
    /// In stage 2 the mask term counts only missing coverage inside the masks (gtsr-model's
    /// `weights.mask_deficit_only`).
    #[arg(long)]
    pub mask_deficit_only: bool,
    /// Seed of every random choice.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Continue from `--out/checkpoint.safetensors`.
    #[arg(long)]
    pub resume: bool,
    /// Evaluations (test PSNR/SSIM, mesh chamfer) along the run for the error-against-time log.
    #[arg(long, default_value_t = 10)]
    pub eval_points: usize,
    /// How the mesh is extracted. `carve` (with a mask on every view): the masks at the
    /// dataset's own resolution bound the object with sub-pixel placement, and the rendered
    /// depth carves inside that bound where `--carve-views` views agree (gtsr-eval's `carve`).
    /// `tsdf`: TSDF fusion of the rendered depth (with the masks' hull when there are masks).
    /// Scenes without masks always use `tsdf`.
    #[arg(long, value_enum, default_value_t = Fusion::Carve)]
    pub fusion: Fusion,
    /// Carving: the depth views that must each put a point in front of their rendered surface.
    /// (1 to 16.)
    #[arg(long, default_value_t = 3)]
    pub carve_views: usize,
    /// Carving: how far in front, in that view's training-pixel footprints.
    #[arg(long, default_value_t = 3.0, allow_negative_numbers = true)]
    pub carve_margin: f32,
    /// Carving: the least share of the views that put a point in front of their surface among
    /// those that put it in front or near it (the rest see it hidden and do not count).
    #[arg(long, default_value_t = 0.5)]
    pub carve_free_ratio: f32,
    /// Carving: the grid spacing (scene units); default: 0.75 of the masks' pixel footprint
    /// at the object (dataset resolution).
    #[arg(long)]
    pub carve_voxel: Option<f32>,
    /// TSDF voxel size (scene units); default: the scene radius / 256.
    #[arg(long)]
    pub voxel: Option<f32>,
    /// TSDF truncation (scene units); default: the larger of 0.75 times the radius of the mesh
    /// box and 6 training-pixel footprints at the object.
    #[arg(long)]
    pub truncation: Option<f32>,
    /// TSDF truncation in training-pixel footprints (the median over the training views at the
    /// mesh box's centre): the same share of a pixel at every resolution.
    #[arg(long, conflicts_with = "truncation")]
    pub truncation_footprints: Option<f32>,
    /// Longest image side of the depth maps fused into the mesh (the trained Gaussians are
    /// rendered again at this size, with the dataset's masks at this size). Default: the training
    /// resolution; at most the dataset's own size.
    #[arg(long)]
    pub mesh_resolution: Option<u32>,
    /// Fuse the depth maps alone: without this, when every view has a mask, the TSDF keeps the
    /// masks' visual hull too and the surface never leaves a silhouette (see gtsr-eval's
    /// `TsdfVolume::with_silhouette_carving`). With this, pixels outside the masks cast no
    /// votes at all (depth is fused where the render has it, as PGSR and 2DGS do): shows what
    /// the rendered depth alone gives.
    #[arg(long)]
    pub no_silhouette_carving: bool,
    /// Fuse the masks alone, no rendered depth: the visual hull on the fusion grid. The
    /// baseline that says what the rendered depth adds to the mesh.
    #[arg(long, conflicts_with = "no_silhouette_carving")]
    pub silhouettes_only: bool,
    /// Fuse, per pixel, the depth of the one surface splat at which the transmittance falls to
    /// this value (0.5: the median depth of 2DGS), instead of the blended unbiased depth of
    /// PGSR; the test-view depth metrics then measure this depth. In (0, 1).
    #[arg(long)]
    pub depth_crossing: Option<f64>,
    /// With carving, where no depth was fused inside the masks' hull keep the hull's own
    /// (sub-voxel) distance instead of -truncation (gtsr-eval's
    /// `TsdfVolume::with_hull_inside_distance`).
    #[arg(long, conflicts_with = "no_silhouette_carving")]
    pub hull_inside_distance: bool,
    /// Replace each fused depth sample that lies less than this many pixel footprints behind
    /// the masks' hull (or in front of it) by the hull's depth: only the depth of concavities
    /// that no silhouette sees is fused (gtsr-eval's `tsdf::snap_to_hull`). Needs masks and
    /// silhouette carving. Off by default.
    #[arg(long, allow_negative_numbers = true, conflicts_with_all = ["no_silhouette_carving", "silhouettes_only"])]
    pub snap_to_hull: Option<f32>,
    /// Keep a fused depth sample only where at least this many of its neighbouring training
    /// views' depth maps agree with it (multi-view consistency, as MVS systems filter their
    /// depth maps; gtsr-eval's `consistency`). Off by default.
    #[arg(long)]
    pub depth_consistency: Option<usize>,
    /// The neighbouring views (nearest optical axes) that check each view's depth.
    #[arg(long, default_value_t = 8)]
    pub consistency_neighbours: usize,
    /// The consistency tolerance, in pixel footprints.
    #[arg(long, default_value_t = 1.0)]
    pub consistency_footprints: f32,
    /// Time every step by phase (kernels, Burn ops, Adam, densification) and print the mean
    /// per stage at the end (also written to `profile.md` in `--out`).
    #[arg(long)]
    pub profile: bool,
    /// Save a checkpoint every this many steps (0: only at the end or on Ctrl-C).
    #[arg(long, default_value_t = 500)]
    pub checkpoint_every: usize,
}

/// Mesh extraction.
#[derive(Copy, Clone, Debug, PartialEq, Eq, ValueEnum, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Fusion {
    /// The masks bound, the rendered depth carves (needs masks).
    Carve,
    /// TSDF fusion of the rendered depth.
    Tsdf,
}

/// Compute backend.
#[derive(Copy, Clone, Debug, PartialEq, Eq, ValueEnum)]
pub enum Backend {
    /// Burn's NdArray backend on the CPU.
    Ndarray,
    /// Burn's wgpu backend (GPU).
    Wgpu,
}

fn main() {
    let args = Args::parse();
    match pipeline::run(&args) {
        Ok(pipeline::Outcome::Finished) => {}
        Ok(pipeline::Outcome::Interrupted) => std::process::exit(130),
        Err(e) => {
            eprintln!("gtsr-train: error: {e:#}");
            std::process::exit(1);
        }
    }
}
