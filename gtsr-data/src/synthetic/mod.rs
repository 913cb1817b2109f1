//! Synthetic translucent scenes with ground truth: procedural shapes, rendered by the path
//! tracer of [`crate::transport`], written in the Blender/NeRF layout. See the crate README
//! for the design.

pub mod shapes;
pub mod writer;

pub use shapes::ShapeKind;
pub use writer::{GeneratedScene, Progress, SceneConfig, generate_scene, scene_cameras};
