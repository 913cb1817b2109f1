//! Render settings shared by every backend, and the rasterisation constants.

use crate::camera::Camera;

/// Side of the square screen tiles the rasteriser bins splats into.
pub const TILE_SIZE: u32 = 16;
/// Pixels per tile.
pub const TILE_PIXELS: usize = (TILE_SIZE * TILE_SIZE) as usize;
/// A splat contributes to a pixel only where its alpha reaches this (3DGS: 1/255).
pub const ALPHA_MIN: f64 = 1.0 / 255.0;
/// Alpha is capped here so that the backward pass can divide by `1 - alpha` (3DGS: 0.99).
pub const ALPHA_MAX: f64 = 0.99;
/// A pixel stops accumulating before its transmittance would fall below this (3DGS: 1e-4).
pub const TRANSMITTANCE_MIN: f64 = 1e-4;
/// Screen-space low-pass filter added to the diagonal of every 2D covariance, in pixels^2.
pub const BLUR_PX2: f64 = 0.3;
/// The EWA Jacobian is evaluated at a mean clamped to this fraction of the image outside the
/// frame (x/z and y/z limited to `[-0.15 W, 1.15 W]` in pixels), which keeps splats far outside
/// the frustum from blowing up.
pub const FRUSTUM_MARGIN: f64 = 0.15;
/// Quaternions with a squared norm below this are treated as degenerate and culled.
pub const QUAT_MIN_NORM2: f64 = 1e-8;

/// How alpha is cut off at [`ALPHA_MIN`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum AlphaCutoff {
    /// 3DGS: contributions with `alpha < 1/255` are dropped (a step).
    #[default]
    Hard,
    /// Test mode: alpha is multiplied by a C1 smoothstep that rises from 0 at `1/255` to 1 at
    /// `2/255`, so that finite differences of the render are meaningful.
    Smooth,
}

/// Everything a render needs besides the Gaussian tensors.
#[derive(Clone, Debug, PartialEq)]
pub struct SplatConfig {
    /// The camera (validated by [`Camera::new`]).
    pub camera: Camera,
    /// Background value per feature channel, composited as `T_final * background`.
    pub background: Vec<f64>,
    /// Alpha cut-off behaviour.
    pub cutoff: AlphaCutoff,
}

/// Per-Gaussian status codes written to column 3 of the aux output.
pub mod status {
    /// Rendered (touches at least one tile).
    pub const VISIBLE: f32 = 0.0;
    /// Mean outside `[near, far]` (or behind the camera).
    pub const CLIPPED: f32 = 1.0;
    /// A parameter was NaN or infinite: culled, its gradients are zero.
    pub const NON_FINITE: f32 = 2.0;
    /// Degenerate: quaternion norm below `QUAT_MIN_NORM2`, or a 2D covariance that is not
    /// positive definite.
    pub const DEGENERATE: f32 = 3.0;
    /// Off screen, or opacity below `1/255` (it can never reach the alpha cut-off).
    pub const NOT_ON_SCREEN: f32 = 4.0;
}
