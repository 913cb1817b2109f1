//! The GTSR model (translucent-object surface reconstruction with Gaussian splatting), generic
//! over the Burn device: two Gaussian sets, the Fresnel-weighted C_SH blend, PGSR geometry
//! (normals, plane distances, unbiased depth), deferred C_PBR under a co-located light, the
//! losses, densification, the two-stage training step, checkpoints and PLY export.
//!
//! Modules follow the paper's vocabulary:
//! - [`gaussians`]: the sets as `[N, width]` Burn tensors, activations, host copies;
//! - [`sh`], [`geometry`], [`pbr`] (with the Schlick Fresnel term): per-Gaussian and per-pixel
//!   formulas as Burn ops, differentiated by Burn's autodiff;
//! - [`model`]: the render passes (C_SH, geometry/material, scattering) through
//!   `gtsr-render-kernels`, and C_PBR;
//! - [`losses`]: photometric (L1 + SSIM), single- and multi-view geometry, interior
//!   containment, smoothness, flattening, mask;
//! - [`config`]: components (what to leave out), presets, `auto`, weights and schedule;
//! - [`trainer`]: the step, Adam with resizable state (module `optim`), density control (`densify`);
//! - [`readout`]: the model read out for the mesh (depth, normals, radiance per view);
//! - [`checkpoint`], [`export`]: saving and resuming, 3DGS-compatible PLY.

#![warn(missing_docs)]
// NdArray is deprecated upstream in favour of burn-flex; it stays the CPU and CI backend.
#![allow(deprecated)]

pub mod checkpoint;
pub mod config;
mod densify;
mod error;
pub mod export;
pub mod gaussians;
pub mod geometry;
mod layout;
pub mod losses;
pub mod model;
mod optim;
pub mod pbr;
pub mod readout;
pub mod sh;
pub mod trainer;
pub mod views;

pub use error::ModelError;
