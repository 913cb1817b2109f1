//! Evaluation for GTSR-rs: mesh metrics (chamfer distance, F-score, normal consistency),
//! rendered depth and normals against a ground-truth mesh,
//! image metrics (PSNR, SSIM), TSDF fusion and marching cubes for mesh extraction, visual
//! hulls, normals from the images' shading and the refinement of a mesh by them,
//! error-against-run-time logs and plots, and markdown result tables.
//!
//! Meshes are [`gtsr_data::ply::TriMesh`] and cameras [`gtsr_data::Camera`] (OpenCV
//! convention). Signed fields are negative inside and positive outside; extracted meshes are
//! welded and outward oriented. Every entry point checks its inputs and returns
//! [`EvalError`] rather than panicking or producing NaN.

#![warn(missing_docs)]

pub mod carve;
pub mod consistency;
pub mod depth;
pub mod error;
pub mod extraction;
pub mod hollow;
pub mod hull;
pub mod marching;
pub mod mesh;
pub mod metrics;
pub mod refine;
pub mod report;
pub mod scatter;
pub mod shading;
pub mod subsurface;
pub mod timeline;
pub mod tsdf;
pub mod visible;

pub use carve::{CarveSettings, DepthMap, carve_grid, carve_mesh, debias_depth, hull_offset};
pub use consistency::{ConsistencySettings, DepthView, filter_consistent};
pub use depth::{DEPTH_QUANTILES, DepthComparison, DepthMetrics, MeshDepth, MeshRaycaster};
pub use error::{EvalError, Result};
pub use extraction::{
    DepthGeometry, EdgeHull, Fusion, FusionInputs, FusionView, MasksAlone, MeshConfig,
    OUTLINE_GAP_FOOTPRINTS, PlaneReadout, extract_mesh, prepare_depth,
};
pub use hollow::{HollowCandidate, HollowReading, HollowSettings, read_hollow};
pub use hull::{
    EdgeProfile, coverage_to_distance, coverage_to_distance_with, edge_width, hull_slack,
    masks_mesh, visual_hull,
};
pub use marching::{Grid, marching_cubes};
pub use mesh::{largest_component, sample_surface, weld};
pub use metrics::{
    HULL_BLIND_RADII, HullBlind, ImageRef, MeshMetrics, SCORE_SAMPLES, SEEN_MIN_EYES,
    SignedDistance, chamfer, chamfer_seen, chamfer_seen_and_whole, psnr,
    score_against_ground_truth, ssim,
};
pub use report::{ReportRow, RunMetrics, markdown_table, seed_summary_table};
pub use timeline::{FINAL_LABEL, Timeline, TimelinePoint, plot_png};
pub use tsdf::{TsdfVolume, default_voxel, default_voxel_for_radius};
pub use visible::{observed_faces, outer_surface, pixel_visible_faces, winding_numbers};
