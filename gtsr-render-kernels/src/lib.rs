//! Differentiable 3D Gaussian splatting kernels for [Burn](https://burn.dev).
//!
//! This crate knows Gaussians, cameras and pixels, nothing of any paper. Its backend
//! extension [`backend::SplatBackend`] splats `N` Gaussians with `C` feature channels into an
//! image, with its backward pass; a second, [`blur::BlurBackend`], blurs image planes with a
//! separable window (SSIM's Gaussian) on the CPU ([`blur_planes`]), and a third,
//! [`sh::ShBackend`], evaluates spherical-harmonic colours in each Gaussian's view direction
//! ([`sh::sh_colours`]), and a fourth, [`adam::AdamBackend`], takes one Adam step on a
//! parameter tensor in a single pass ([`adam::adam_step`]), and a fifth,
//! [`shade::ShadeBackend`], shades pixels from blended maps under a light at the camera
//! ([`shade::shade`]), and a sixth, [`planes::PlanesBackend`], gives each flat Gaussian's
//! normal and plane as a camera sees them ([`planes::gaussian_planes`]). Use the splats through [`render`]:
//!
//! - inputs are ordinary Burn tensors (see [`SplatInputs`]); on an autodiff device the image
//!   and alpha are differentiable with respect to means, rotations, scales, opacities, features
//!   and optional screen-space offsets, through whatever Burn expressions produced them;
//! - the backend is chosen by the device: NdArray (f32 or f64, parallel over tiles with rayon),
//!   or, with the `wgpu` feature, Burn's wgpu backend (f32; CubeCL kernels in the `gpu` module, run
//!   through `Fusion`);
//! - [`render_crossing`] (forward only, on the host) gives per pixel the features of the splat
//!   at which the transmittance falls to a threshold instead of their blend (median depth);
//! - [`mod@reference`] is an independent brute-force renderer (every pixel against every Gaussian)
//!   used to check the kernels.
//!
//! # Conventions (3DGS)
//! - Camera: OpenCV pinhole, see [`camera`]. Pixel centres at `(i + 0.5, j + 0.5)`.
//! - Projection: `Sigma' = J W Sigma W^T J^T + b I` with the blur `b` of
//!   [`SplatConfig::blur_px2`] (3DGS's 0.3 by default), the Jacobian evaluated at the mean with
//!   `x/z`, `y/z` clamped to 15% outside the image; means outside `[near, far]`, non-finite
//!   parameters and quaternions of squared norm below `1e-8` are culled (status in `aux`).
//!   With [`SplatConfig::compensate_blur`] the projection scales each opacity by
//!   `sqrt(det Sigma / det(Sigma + b I))` (Mip-Splatting's 2D filter), forward and backward;
//!   [`blur_compensation`] is the same factor as a Burn expression.
//! - Blending: `alpha = min(0.99, o * exp(-d^T Sigma'^-1 d / 2))`, skipped below `1/255`;
//!   front to back by camera depth; a pixel stops before its transmittance would drop below
//!   `1e-4`; `C = sum f_i alpha_i T_i + T_final * background`, `alpha_out = 1 - T_final`.
//! - Each splat touches the 16x16 tiles overlapped by its opacity-aware rectangle (where
//!   `alpha >= 1/255` is possible), so no contribution is cut off by the tiling.

#![warn(missing_docs)]
// burn-ndarray is deprecated upstream in favour of burn-flex; it stays the CPU and CI
// backend, and the kernels are written against it on purpose.
#![allow(deprecated)]

/// A value built from the six splat inputs of `src`, one expression per field in field order
/// (means, quats, scales, opacities, features, xy_offsets), with `v` bound in turn to each
/// field of `src` (`&src`: borrowed; `src`: moved):
/// - `splat_fields!(Type, src, |v| expr)` is `Type { means: expr, quats: expr, .. }`;
/// - `splat_fields!([], src, |v| expr)` is the array `[expr, expr, ..]`.
///
/// The one place that lists the inputs field by field ([`backend::SplatPrimitives`],
/// [`cpu::HostBuffers`], [`cpu::HostGaussians`], the scenes' `HostScene`).
macro_rules! splat_fields {
    ($out:tt, &$src:expr, |$v:ident| $e:expr) => {
        splat_fields!(@build $out, |$v| $e, &$src.means, &$src.quats, &$src.scales,
            &$src.opacities, &$src.features, &$src.xy_offsets)
    };
    ($out:tt, $src:expr, |$v:ident| $e:expr) => {
        splat_fields!(@build $out, |$v| $e, $src.means, $src.quats, $src.scales,
            $src.opacities, $src.features, $src.xy_offsets)
    };
    (@build [], |$v:ident| $e:expr, $($x:expr),*) => {
        [$({
            let $v = $x;
            $e
        }),*]
    };
    (@build $ty:ident, |$v:ident| $e:expr,
        $means:expr, $quats:expr, $scales:expr, $opacities:expr, $features:expr, $xy:expr) => {
        $ty {
            means: { let $v = $means; $e },
            quats: { let $v = $quats; $e },
            scales: { let $v = $scales; $e },
            opacities: { let $v = $opacities; $e },
            features: { let $v = $features; $e },
            xy_offsets: { let $v = $xy; $e },
        }
    };
}

pub mod adam;
pub mod antialias;
mod api;
mod autodiff;
pub mod backend;
pub mod blur;
pub mod camera;
pub mod config;
pub mod cpu;
#[cfg(feature = "wgpu")]
pub mod gpu;
pub mod planes;
pub mod reference;
pub mod scalar;
pub mod sh;
pub mod shade;

pub use antialias::blur_compensation;
pub use api::{
    CrossingOutput, RenderError, RenderOutput, SplatInputs, device_supported, render,
    render_crossing,
};
pub use blur::{BlurWindow, BlurWindowError, blur_planes};
pub use camera::{Camera, CameraError};
pub use config::{AlphaCutoff, BLUR_PX2, PIXEL_BOX_BLUR_PX2, SplatConfig, TILE_PIXELS, TILE_SIZE};

/// Seeded test and benchmark scenes (feature `test-utils`).
#[cfg(feature = "test-utils")]
pub mod scenes;
