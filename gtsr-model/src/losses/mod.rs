//! The training objective, one term per module as the paper names them.

pub mod geometric;
pub mod photometric;
pub mod regular;

pub use geometric::{
    MultiViewTerm, NCC_HALF, NCC_MAX, NccTerm, grey, interior_containment, multi_view,
    multi_view_ncc, single_view,
};
pub use photometric::{l1, photometric, photometric_masked, ssim, ssim_map};
pub use regular::{
    FRONT_TRANSMITTANCE, HULL_DEPTH_BAND, INTERIOR_FRONT_BAND, INTERIOR_FRONT_TRANSMITTANCE,
    edge_aware_smoothness, flatten, front_depth, hull_depth, interior_front, layer_spread,
    mask_deficit, mask_l1, mask_l1_band_hinge, mask_l1_outside_band, opacity_entropy, opacity_l1,
    outside_band,
};
