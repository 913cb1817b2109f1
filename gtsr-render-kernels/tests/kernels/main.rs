//! Tests of the splatting kernels: forward against the brute-force reference, analytic
//! profiles, backward against central finite differences, stiff cases, determinism.

// Device::ndarray is deprecated upstream; NdArray stays the CPU and CI backend.
#![allow(deprecated)]

mod analytic;
mod antialias;
mod common;
mod crossing;
mod determinism;
mod errors;
mod forward;
mod gradients;
mod lanes;
mod shade;
mod stiff;
mod upstream;
