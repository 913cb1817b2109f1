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
/// 3DGS's screen-space low-pass filter: added to the diagonal of every 2D covariance, in
/// pixels^2. The default of [`SplatConfig::blur_px2`].
pub const BLUR_PX2: f64 = 0.3;
/// The variance of a unit box, 1/12 pixel^2: the blur of integrating over a pixel's area
/// (what an area-averaged, downscaled image holds). 3DGS's 0.3 blurs more than that: a
/// silhouette of dilated splats then spills past the mask, and a fit to the mask pulls the
/// splats inward (GTSR-rs trains with this value; see `gtsr-model`'s `TrainConfig::blur_px2`).
pub const PIXEL_BOX_BLUR_PX2: f64 = 1.0 / 12.0;
// Defined beside `Camera::jacobian_limits`, which applies it.
pub use crate::camera::FRUSTUM_MARGIN;
/// Quaternions with a squared norm below this are treated as degenerate and culled.
pub const QUAT_MIN_NORM2: f64 = 1e-8;

// The camera's tiling lives here, beside `TILE_SIZE`, so that the camera module needs nothing
// from this one.
impl Camera {
    /// Number of 16x16 tiles along x and y.
    pub fn tile_grid(&self) -> (u32, u32) {
        (
            self.width.div_ceil(TILE_SIZE),
            self.height.div_ceil(TILE_SIZE),
        )
    }
}

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
    /// Screen-space blur added to the diagonal of every 2D covariance, pixels^2 (finite,
    /// `>= 0`): [`BLUR_PX2`] (3DGS) or [`PIXEL_BOX_BLUR_PX2`]. It keeps edge-on flat splats
    /// at least this wide on screen; at 0 they are culled as degenerate.
    pub blur_px2: f64,
    /// Scale each opacity by `sqrt(det Sigma / det(Sigma + b I))` ([`crate::blur_compensation`],
    /// Mip-Splatting's 2D filter) so that the blur widens a thin splat without adding to what
    /// it covers: a flat splat seen edge-on fades instead of covering the blur's width.
    pub compensate_blur: bool,
}

impl SplatConfig {
    /// A configuration with a black background of `channels` channels, the hard 3DGS alpha
    /// cut-off and the 3DGS blur ([`BLUR_PX2`]), uncompensated.
    pub fn new(camera: Camera, channels: usize) -> Self {
        SplatConfig {
            camera,
            background: vec![0.0; channels],
            cutoff: AlphaCutoff::Hard,
            blur_px2: BLUR_PX2,
            compensate_blur: false,
        }
    }
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
