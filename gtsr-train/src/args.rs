//! The command line: every setting of a run, with the training and mesh settings flattened in
//! (each also a field of the run's `config.json`).

use std::path::PathBuf;

use clap::{CommandFactory, FromArgMatches, Parser, ValueEnum};
use gtsr_mesh::MeshConfig;
use gtsr_model::config::{Preset, TrainConfig};

/// The default of [`Args::eval_shading_rounds`]: one round, so that the in-run mesh follows
/// the model at a fraction of the whole refinement's time.
pub const DEFAULT_EVAL_SHADING_ROUNDS: usize = 1;

/// Reconstruct the surface of a translucent object from posed images (GTSR).
///
/// Every training and mesh setting below is also a field of the run's `config.json`; `--config`
/// reads one back, and the flags given beside it override its fields.
#[derive(Parser, Debug, Clone)]
#[command(version, about, long_about = None, max_term_width = 100, disable_help_flag = true, allow_negative_numbers = true)]
pub struct Args {
    /// Print help.
    #[arg(short = 'h', long = "help", action = clap::ArgAction::HelpShort)]
    pub help: Option<bool>,
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
    /// Training steps. Default: 3000 (1500 on the built-in scene).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    pub iterations: Option<u64>,
    /// Longest image side after downscaling by a whole factor (pixels). Default: 256, the
    /// data's own size where it is smaller (64 on the built-in scene).
    #[arg(long, value_parser = clap::value_parser!(u32).range(8..))]
    pub resolution: Option<u32>,
    /// Each view's exposure: `auto` reads it from the images (the views' brightness on the
    /// masks' hull) and brings every view to their mean where one departs from it by more than
    /// half a stop, as a phone's auto exposure makes them; `off` leaves the images as they are.
    /// Default: auto.
    #[arg(long, value_enum)]
    pub exposure: Option<ExposureMode>,
    /// Components: `full` (the paper's model), the ablations `no-pbr`, `no-fresnel` and
    /// `no-interior`, `pgsr` (surface set, PGSR's terms), or `auto` (the full model less what
    /// the scene shows it does not need; the run's first lines say what).
    #[arg(long, value_enum, default_value_t = Preset::Auto)]
    pub preset: Preset,
    /// A run's `config.json`, a bare training configuration (its `train` part), or any part of
    /// either (`{"train": {"weights": {"mask": 2}}}`): the settings it gives, its dataset
    /// included, over the scene's defaults; the flags given beside it override. A field that is
    /// not a setting is an error that names it (exit status 2).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Continue from `--out/checkpoint.safetensors`, with the settings and the dataset of
    /// `--out/config.json` unless `--config` or the flags say otherwise.
    #[arg(long)]
    pub resume: bool,
    /// Stop at this step of the schedule: write the checkpoint and every output of the model
    /// as it stands there, and exit; `--resume` continues the schedule from it. With
    /// `--resume` on a run already at this step: only the outputs (the mesh, the evaluation)
    /// of that step's model, e.g. in a copy of a run folder with other mesh settings.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    pub stop_at: Option<u64>,
    /// Evaluations (test PSNR/SSIM, mesh chamfer) along the run for the error-against-time log
    /// (0: none; the final evaluation always runs).
    #[arg(long, default_value_t = 10)]
    pub eval_points: usize,
    /// Rounds of the carving's shading refinement in the evaluations along the run (0: none,
    /// the in-run mesh is the carved bound; the final extraction runs all of
    /// `mesh.shading_rounds`). With the refinement reading the model's render
    /// (`mesh.shading_radiance_rendered`) the curve's chamfer follows the training.
    #[arg(long, default_value_t = DEFAULT_EVAL_SHADING_ROUNDS)]
    pub eval_shading_rounds: usize,
    /// Run the evaluations along the run beside the training, each on a snapshot of the model,
    /// on the cores the training leaves idle (its threads yield to the training's). `false`:
    /// in turn with the training, one evaluation's working set less in memory at once, as
    /// `--profile` does so that its step timers see the training alone.
    #[arg(long, value_name = "BOOL", default_value_t = true, action = clap::ArgAction::Set)]
    pub eval_beside_training: bool,
    /// Time every step by phase (kernels, Burn ops, Adam, densification) and print the mean
    /// per stage at the end (also written to `profile.md` in `--out`).
    #[arg(long)]
    pub profile: bool,
    /// Start the surface set on this mesh (PLY, in the dataset's own frame) instead of
    /// `--init`: `--init-surface` points sampled uniformly by area on its faces, e.g. a mesh
    /// from photogrammetry or an earlier run. The rest of the schedule is unchanged.
    #[arg(long, value_name = "PLY")]
    pub init_mesh: Option<PathBuf>,
    /// Save a checkpoint every this many steps (0: only at the end or on Ctrl-C).
    #[arg(long, default_value_t = 500)]
    pub checkpoint_every: usize,
    /// Mesh extraction.
    #[command(flatten, next_help_heading = "Mesh extraction")]
    pub mesh: MeshConfig,
    /// Training.
    #[command(flatten, next_help_heading = "Training")]
    pub train: TrainConfig,
    /// The ids of the settings given on the command line (paths in `config.json`): only these
    /// override the scene's defaults or `--config`.
    #[arg(skip)]
    pub given: Vec<String>,
}

impl Args {
    /// Parses the command line, recording which settings it gave.
    pub fn parse_with_sources() -> Args {
        let matches = Args::command().get_matches();
        let mut args = Args::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
        args.given = matches
            .ids()
            .filter(|id| {
                matches.value_source(id.as_str()) == Some(clap::parser::ValueSource::CommandLine)
            })
            .map(|id| id.as_str().to_string())
            .collect();
        args
    }
}

/// What a run does with the views' exposures ([`Args::exposure`]).
#[derive(
    Copy, Clone, Debug, Default, PartialEq, Eq, ValueEnum, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "kebab-case")]
pub enum ExposureMode {
    /// Read from the images and taken out where the views differ.
    #[default]
    Auto,
    /// The images as they are.
    Off,
}

/// Compute backend.
#[derive(Copy, Clone, Debug, PartialEq, Eq, ValueEnum)]
pub enum Backend {
    /// Burn's NdArray backend on the CPU.
    Ndarray,
    /// Burn's wgpu backend (GPU).
    Wgpu,
}
