//! Mesh extraction for GTSR-rs, without Burn: from a trained model's rendered depth (and its
//! normals and radiance), the training masks and cameras to a welded, outward-oriented mesh.
//!
//! The recipe ([`extract_mesh`], configured by [`MeshConfig`]), one module per step:
//! 1. [`hull`]: the masks bound the object at their own resolution, with sub-pixel edges
//!    ([`MasksAlone`] holds them and what they give alone).
//! 2. [`carve`] (with [`consistency`] and [`tsdf`]): the rendered depth carves inside that
//!    bound where the views agree, never opening a silhouette; [`hollow`] reads the depth of a
//!    hollow behind a gap from the images' dark pixels.
//! 3. [`shading`] (with [`refine`] and [`scatter`]): under a light at the camera the mesh is
//!    refined by the normals its shading reads.
//!
//! [`marching`] extracts iso-surfaces, [`raycast`] casts rays at meshes (depth maps, signed
//! distance), [`visible`] tells which faces the cameras see, and [`mesh`] holds the mesh
//! utilities (welding, components, sampling).
//!
//! Meshes are [`gtsr_data::ply::TriMesh`] and cameras [`gtsr_data::Camera`] (OpenCV
//! convention). Signed fields are negative inside and positive outside. Every entry point
//! checks its inputs and returns [`MeshError`] rather than panicking or producing NaN.
//!
//! ```
//! use gtsr_mesh::mesh::icosphere;
//! use gtsr_mesh::marching::{Grid, marching_cubes};
//! use glam::Vec3;
//!
//! // A sphere's signed distance on a grid, and its iso-surface.
//! let n = 24;
//! let (lo, voxel) = (Vec3::splat(-1.2), 2.4 / (n - 1) as f32);
//! let mut values = vec![0.0f32; n * n * n];
//! for k in 0..n {
//!     for j in 0..n {
//!         for i in 0..n {
//!             let p = lo + voxel * Vec3::new(i as f32, j as f32, k as f32);
//!             values[(k * n + j) * n + i] = p.length() - 1.0;
//!         }
//!     }
//! }
//! let observed = vec![true; values.len()];
//! let grid = Grid { dims: [n, n, n], origin: lo, voxel, values, observed };
//! let mesh = marching_cubes(&grid, 0.0);
//! assert!(!mesh.triangles.is_empty());
//! # let _ = icosphere(Vec3::ZERO, 1.0, 2);
//! ```

#![warn(missing_docs)]

pub mod carve;
mod config;
pub mod consistency;
mod error;
mod extract;
pub mod hollow;
pub mod hull;
mod inputs;
pub mod marching;
mod masks;
pub mod mesh;
pub mod pixels;
pub mod raycast;
pub mod refine;
pub mod scatter;
pub mod shading;
pub mod tsdf;
pub mod visible;

pub use config::{
    DEFAULT_CARVE_MARGIN, DEFAULT_CARVE_MAX_OPENED, DEFAULT_CARVE_MAX_SPREAD,
    DEFAULT_CARVE_MIN_LID_DEPARTURE, DEFAULT_CARVE_VIEWS, DEFAULT_CONCAVITY_GATE,
    DEFAULT_CULL_UNOBSERVED, DEFAULT_SHADING_ANCHOR, DEFAULT_SHADING_DEPTH_THRESHOLD,
    DEFAULT_SHADING_RADIANCE_RENDERED, DEFAULT_SHADING_ROUNDS, DEFAULT_SHADING_SLACK,
    DEFAULT_SHADING_STEEP_TILT, DEFAULT_SHADING_UNSCATTER, Fusion, MeshConfig,
    OUTLINE_GAP_FOOTPRINTS, PlaneReadout,
};
pub use error::{MeshError, Result};
pub use extract::extract_mesh;
pub use inputs::{DepthGeometry, FusionInputs, FusionView, prepare_depth};
pub use masks::{EdgeHull, MasksAlone};
