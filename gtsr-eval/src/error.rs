//! The crate's error type.

use std::path::PathBuf;

use gtsr_mesh::MeshError;

/// Everything that can go wrong in evaluation. Inputs are checked up front, so a metric
/// either returns a finite number (or `+inf` where documented) or one of these.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// A mesh, image, argument or file refused (the same errors as the extraction's).
    #[error(transparent)]
    Input(#[from] MeshError),
    /// Drawing a plot failed.
    #[error("plotting {}: {message}", path.display())]
    Plot {
        /// The output file.
        path: PathBuf,
        /// The plotting library's message.
        message: String,
    },
}

impl From<gtsr_data::DataError> for EvalError {
    fn from(e: gtsr_data::DataError) -> Self {
        EvalError::Input(MeshError::Data(e))
    }
}

/// Result with [`EvalError`].
pub type Result<T, E = EvalError> = std::result::Result<T, E>;

/// Writes `bytes` to `path` atomically (temporary file in the same directory, then rename).
pub(crate) fn write_atomic(path: &std::path::Path, bytes: &[u8]) -> Result<()> {
    Ok(gtsr_data::image_io::write_atomic(path, bytes)?)
}
