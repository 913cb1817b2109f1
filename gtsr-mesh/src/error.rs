//! The error type of the extraction, also the input errors of `gtsr-eval`'s scores.

use std::path::PathBuf;

/// Everything that can go wrong in extraction or with a mesh, image or argument given to it.
/// Inputs are checked up front, so a function either returns finite values (or `+inf` where
/// documented) or one of these.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    /// A mesh has no triangles of positive area (or no triangles at all).
    #[error("{what} mesh is empty (no triangles of positive area)")]
    EmptyMesh {
        /// Which mesh (`"predicted"`, `"ground-truth"`, ...).
        what: String,
    },
    /// A mesh has a vertex with a non-finite coordinate, or a triangle index out of range.
    #[error("{what} mesh is invalid: {message}")]
    InvalidMesh {
        /// Which mesh.
        what: String,
        /// What is wrong with it.
        message: String,
    },
    /// Two inputs that must have the same size do not.
    #[error("size mismatch for {what}: expected {expected}, got {got}")]
    SizeMismatch {
        /// What was compared (`"image"`, `"mask"`, `"depth map"`, ...).
        what: String,
        /// The size required.
        expected: String,
        /// The size given.
        got: String,
    },
    /// A mask selects no pixel (`mask > 0.5` nowhere).
    #[error("the mask selects no pixel (no value > 0.5)")]
    EmptyMask,
    /// An input holds NaN or infinity where finite values are required.
    #[error("{what} holds a non-finite value")]
    NonFinite {
        /// Which input.
        what: String,
    },
    /// An argument is outside its valid range.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// A file could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// A file could not be parsed.
    #[error("{}: {message}", path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// What is wrong, with the line where known.
        message: String,
    },
    /// An error from `gtsr-data` (PLY and image reading).
    #[error(transparent)]
    Data(#[from] gtsr_data::DataError),
}

impl MeshError {
    /// A file error on `path`.
    pub fn io(path: &std::path::Path, source: std::io::Error) -> Self {
        MeshError::Io {
            path: path.to_path_buf(),
            source,
        }
    }

    /// Two sizes of `what` that must agree do not.
    pub fn size(what: &str, expected: impl ToString, got: impl ToString) -> Self {
        MeshError::SizeMismatch {
            what: what.to_string(),
            expected: expected.to_string(),
            got: got.to_string(),
        }
    }
}

/// Result with [`MeshError`].
pub type Result<T, E = MeshError> = std::result::Result<T, E>;
