//! Data for GTSR-rs: dataset loaders into one camera convention, and a path-traced
//! translucent scene generator with ground truth.
//!
//! * [`camera`]: the internal camera convention (OpenCV; read it first).
//! * [`load_blender`] (NeRF synthetic layout) and [`load_colmap`] (COLMAP sparse models)
//!   return a [`Scene`]; options in [`LoadOptions`].
//! * [`image_io`]: PNG/JPEG/EXR reading (values kept in the file's encoding, see
//!   [`image_io::Encoding`]), downscaling, atomic PNG writing.
//! * [`transport`]: the CPU path tracer with random-walk subsurface scattering (the hollow
//!   search's forward model and the scene generator's renderer).
//! * [`synthetic`]: procedural shapes and [`synthetic::generate_scene`].
//! * [`parse`]: range-checked parsers for command-line values.
//! * [`ply`]: PLY meshes.
//! * [`light`]: whether the light moves with the camera, read from the images.
//!
//! Bad input gives a [`DataError`] naming the file (and frame) and the problem; nothing
//! panics on bad input.

#![warn(missing_docs)]

pub mod blender;
pub mod camera;
pub mod colmap;
mod error;
pub mod image_io;
pub mod light;
pub mod parse;
pub mod ply;
pub mod scene;
pub mod synthetic;
pub mod transport;

pub use blender::load_blender;
pub use camera::Camera;
pub use colmap::load_colmap;
pub use error::{DataError, Result};
pub use image_io::{Encoding, Image};
pub use scene::{Background, Downscale, LoadOptions, Normalisation, NormaliseFrom, Scene, View};

/// Loads a scene folder, detecting the layout: Blender/NeRF when `transforms_train.json`
/// exists, otherwise COLMAP.
pub fn load_scene(root: impl AsRef<std::path::Path>, opts: &LoadOptions) -> Result<Scene> {
    let root = root.as_ref();
    if root.join("transforms_train.json").is_file() {
        load_blender(root, opts)
    } else {
        load_colmap(root, opts)
    }
}
