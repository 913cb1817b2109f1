//! The GTSR model: two Gaussian sets, C_SH and C_PBR renders, losses, densification and the
//! training step.
//!
//! Empty for now: this crate is filled by the gtsr-model issue, on top of
//! `gtsr-render-kernels`. Nothing here pretends to work.
