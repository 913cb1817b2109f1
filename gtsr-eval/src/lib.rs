//! Scoring for GTSR-rs: mesh metrics against a ground truth (chamfer distance, accuracy /
//! completeness, F-score, normal consistency, the hull-blind split, the seen filter),
//! rendered depth and normals against a ground truth, image metrics (PSNR, SSIM),
//! error-against-run-time logs and plots, and markdown result tables.
//!
//! The mesh extraction these scores judge lives in `gtsr-mesh`. Meshes are
//! [`gtsr_data::ply::TriMesh`] and cameras [`gtsr_data::Camera`] (OpenCV convention). Every
//! entry point checks its inputs and returns [`EvalError`] rather than panicking or producing
//! NaN.
//!
//! ```
//! use gtsr_eval::{ImageRef, psnr};
//!
//! let gt = vec![0.5f32; 4 * 4 * 3];
//! let pred: Vec<f32> = gt.iter().map(|v| v + 0.01).collect();
//! let db = psnr(ImageRef::new(4, 4, 3, &pred), ImageRef::new(4, 4, 3, &gt), None)?;
//! assert!((db - 40.0).abs() < 1e-3);
//! # Ok::<(), gtsr_eval::EvalError>(())
//! ```

#![warn(missing_docs)]

mod depth;
mod error;
mod metrics;
mod report;
mod timeline;
mod truth;

pub use depth::{CONCAVE_GAP_FOOTPRINTS, DEPTH_QUANTILES, DepthComparison, DepthMetrics};
pub use error::{EvalError, Result};
pub use metrics::{
    HULL_BLIND_RADII, HullBlind, ImageRef, MeshMetrics, SCORE_SAMPLES, SEEN_MIN_EYES, chamfer,
    chamfer_seen, chamfer_seen_and_whole, psnr, score_against_ground_truth, ssim,
};
pub use report::{
    ReportRow, RunMetrics, format_duration, markdown_table, seed_summary_table, write_markdown,
};
pub use timeline::{CSV_HEADER, FINAL_LABEL, OPTIONAL_COLUMNS, Timeline, TimelinePoint, plot_png};
pub use truth::{ground_truth, native_masks_mesh, scene_name};
