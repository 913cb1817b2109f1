//! Synthetic translucent scenes with ground truth: procedural shapes, a CPU path tracer and
//! a writer for the Blender/NeRF layout. See the crate README for the design.

pub mod bvh;
pub mod material;
pub mod rng;
pub mod shapes;
pub mod tracer;
pub mod writer;

pub use material::{Material, MaterialPreset};
pub use shapes::ShapeKind;
pub use tracer::{Lighting, Rendered, Tracer};
pub use writer::{GeneratedScene, Progress, SceneConfig, generate_scene, scene_cameras};
