//! What the GPU kernels share: the layouts of the buffers they pass from stage to stage (the
//! projected splats, the camera), the alpha cut-off, and the tile rectangle of a projected
//! splat.

// Kernel code is CubeCL's dialect of Rust: `div_ceil` is written out on purpose.
#![allow(clippy::manual_div_ceil)]

use burn_cubecl::cubecl;
use cubecl::prelude::*;

use crate::config::TILE_SIZE;

/// Floats per projected splat: x, y, conic a, b, c, opacity, depth, skip power, rect x0, y0,
/// x1, y1 (the rectangle as exact small integers).
pub const PROJ: u32 = 12;
/// Floats in the camera buffer: rotation (row-major 3x3), translation, fx, fy, cx, cy, near,
/// far, x/z limits, y/z limits, screen-space blur (pixels^2), 1 to compensate the blur in the
/// opacity (else 0).
pub const CAM: u32 = 24;

pub(crate) const ALPHA_MIN: f32 = 1.0 / 255.0;

/// The tile rectangle `[tx0, tx1) x [ty0, ty1)` of a projected Gaussian.
#[derive(CubeType)]
pub(crate) struct TileRect {
    pub tx0: u32,
    pub ty0: u32,
    pub tx1: u32,
    pub ty1: u32,
}

/// The tile rectangle of projected Gaussian `g` (from its pixel rectangle, as the CPU's
/// `Splat::tile_rect`).
#[cube]
pub(crate) fn tile_rect(proj: &[f32], g: u32) -> TileRect {
    let b = g as usize * PROJ as usize;
    TileRect {
        tx0: u32::cast_from(proj[b + 8]) / TILE_SIZE,
        ty0: u32::cast_from(proj[b + 9]) / TILE_SIZE,
        tx1: (u32::cast_from(proj[b + 10]) + TILE_SIZE - 1) / TILE_SIZE,
        ty1: (u32::cast_from(proj[b + 11]) + TILE_SIZE - 1) / TILE_SIZE,
    }
}

/// A Gaussian's place in depth order: its rank `r`, and its emissions `[start, end)` (empty
/// when it touches no tile).
#[derive(CubeType)]
pub(crate) struct Ranked {
    pub r: u32,
    pub start: u32,
    pub end: u32,
}

/// The depth rank of this thread (`ABSOLUTE_POS`; threads past the `n` Gaussians end here) and
/// its emissions, from the exclusive scan `starts` of the tile counts in depth order.
#[cube]
pub(crate) fn ranked(starts: &[u32], n: u32) -> Ranked {
    let r = ABSOLUTE_POS as u32;
    if r >= n {
        terminate!();
    }
    Ranked {
        r,
        start: starts[r as usize],
        end: starts[r as usize + 1],
    }
}
