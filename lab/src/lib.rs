//! The GTSR-rs laboratory: diagnostics that read a development scene's ground truth to say
//! where a run's surface lies and why, and the experiments behind the dated logs of
//! `docs/log/`. Nothing of the product depends on it; an idea enters the product only with
//! a measured gain on scenes that did not choose it.
//!
//! The `lab` binary runs the diagnostics (`cargo run --release -p lab -- --help`); the
//! examples (`lab/examples`) are one-off studies of the hull-blind part and the trench.

#![allow(missing_docs)]

pub mod concavity;
pub mod diagnose_surface;
mod face_filters;
pub mod fusion_ceiling;
pub mod photo;
pub mod shading;
pub mod shading_depth;
pub mod subsurface;
