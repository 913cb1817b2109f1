//! Light transport in translucent objects: a CPU path tracer with random-walk subsurface
//! scattering (`tracer`) through a mesh's BVH (`bvh`), under a dielectric boundary with a
//! participating medium inside (`material`). The forward model of the hollow search
//! (`gtsr-mesh`) and the renderer of the synthetic scenes (`crate::synthetic`).

pub mod bvh;
pub mod material;
pub mod rng;
pub mod tracer;

pub use material::{Material, MaterialPreset};
pub use tracer::{Lighting, Rendered, Tracer};
