//! Errors of the model crate: each names the file, view or parameter and the problem.

use std::path::{Path, PathBuf};

use thiserror::Error;

/// Why a model operation failed.
#[derive(Debug, Error)]
pub enum ModelError {
    /// A camera the kernels refuse (degenerate rotation, non-finite values...).
    #[error("view {view}: unusable camera: {reason}")]
    Camera {
        /// The view.
        view: String,
        /// What is wrong.
        reason: String,
    },
    /// Bad input data.
    #[error("{0}")]
    Data(String),
    /// A configuration that cannot run.
    #[error("invalid configuration: {0}")]
    Config(String),
    /// The kernels refused a render.
    #[error("render failed: {0}")]
    Render(Box<gtsr_render_kernels::RenderError>),
    /// File system errors.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// A checkpoint that cannot be read.
    #[error("checkpoint {path}: {reason}")]
    Checkpoint {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
}

impl ModelError {
    /// An I/O error on `path`.
    pub fn io(path: &Path, source: std::io::Error) -> ModelError {
        ModelError::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}

impl From<gtsr_render_kernels::RenderError> for ModelError {
    fn from(e: gtsr_render_kernels::RenderError) -> Self {
        ModelError::Render(Box::new(e))
    }
}
