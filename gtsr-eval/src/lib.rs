//! Evaluation: chamfer distance, F-score, normal consistency, PSNR and SSIM, and the
//! error-against-run-time report.
//!
//! Empty for now: this crate is filled by the gtsr-train / gtsr-eval issue. Nothing here
//! pretends to work.
