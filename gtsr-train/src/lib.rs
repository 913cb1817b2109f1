//! GTSR-rs reconstruction as a library: images in, mesh, splats, renders and metrics out.
//!
//! [`run`] does what the `gtsr-train` binary does with [`Args`] ([`run_with`] also reports each
//! step, evaluation and checkpoint to an observer, [`RunEvent`]): it resolves the settings (a
//! configuration file overlaid by the flags given, `--resume` from a run folder), loads the
//! data (or generates the built-in scene), trains with evaluations along the run (off the
//! training clock) and checkpoints, extracts the mesh and writes every output. The pieces it is
//! made of are public for the tools that reuse them (the benchmarks, the laboratory):
//! [`mesh`] reads a trained model out into `gtsr-mesh`'s recipe, [`evaluation`] scores it.
//!
//! ```no_run
//! use clap::Parser;
//! use gtsr_train::{Args, Outcome, run};
//!
//! let args = Args::parse_from(["gtsr-train", "--data", "scene", "--out", "runs/scene"]);
//! assert!(matches!(run(&args)?, Outcome::Finished));
//! # Ok::<(), anyhow::Error>(())
//! ```

#![allow(deprecated)] // burn-ndarray: deprecated upstream, kept as the CPU backend.

mod args;
pub mod evaluation;
pub mod mesh;
mod outputs;
mod prepare;
mod profile;
mod run;
mod settings;
mod settle;

pub use args::{Args, Backend, DEFAULT_EVAL_SHADING_ROUNDS, ExposureMode};
pub use run::{Outcome, RunEvent, run, run_with};
pub use settings::ConfigError;
