//! The crate's error type.
//!
//! Every variant names the file it is about and, where there is one, the frame
//! (index into the split's `frames` array, or COLMAP image id) and what is wrong.
//! No loader panics on bad input: everything comes back as a [`DataError`].

use std::path::PathBuf;

/// Result alias for this crate.
pub type Result<T, E = DataError> = std::result::Result<T, E>;

/// Everything that can go wrong while loading or writing data.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    /// An operating-system I/O error on a file.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },

    /// A required file (transforms, COLMAP model, mesh) does not exist.
    #[error("{path}: file not found ({what})")]
    MissingFile {
        /// The file that was looked for.
        path: PathBuf,
        /// What it was needed for.
        what: String,
    },

    /// The image of a frame does not exist under any of the tried names.
    #[error("{json}: frame {frame}: image not found (tried {tried})")]
    MissingImage {
        /// The transforms file or COLMAP `images` file that names the image.
        json: PathBuf,
        /// Frame index (Blender) or image id (COLMAP).
        frame: usize,
        /// The candidate paths, comma-separated.
        tried: String,
    },

    /// A JSON file could not be parsed or lacks a field.
    #[error("{path}: malformed JSON: {message}")]
    MalformedJson {
        /// The file.
        path: PathBuf,
        /// Parser message (with line and column) or the missing field.
        message: String,
    },

    /// A text or binary file (COLMAP, PLY) is malformed.
    #[error("{path}: {message}")]
    Malformed {
        /// The file.
        path: PathBuf,
        /// What is wrong, with the line or record where known.
        message: String,
    },

    /// A camera matrix is not rigid (rotation not orthonormal, det not +1, bad last row, NaN).
    #[error("{path}: frame {frame}: camera matrix is not rigid: {message}")]
    NonRigid {
        /// The file with the matrix.
        path: PathBuf,
        /// Frame index (Blender) or image id (COLMAP).
        frame: usize,
        /// Which test failed, with the measured value.
        message: String,
    },

    /// The image size disagrees with the intrinsics or with the other frames.
    #[error(
        "{path}: frame {frame}: image is {got_w}x{got_h} but the intrinsics say {want_w}x{want_h}"
    )]
    SizeMismatch {
        /// The image file.
        path: PathBuf,
        /// Frame index (Blender) or image id (COLMAP).
        frame: usize,
        /// Width of the decoded image.
        got_w: u32,
        /// Height of the decoded image.
        got_h: u32,
        /// Width the intrinsics / first frame imply.
        want_w: u32,
        /// Height the intrinsics / first frame imply.
        want_h: u32,
    },

    /// A mask's size disagrees with its image.
    #[error("{path}: mask is {got_w}x{got_h} but its image is {want_w}x{want_h}")]
    MaskSizeMismatch {
        /// The mask file.
        path: PathBuf,
        /// Mask width.
        got_w: u32,
        /// Mask height.
        got_h: u32,
        /// Image width.
        want_w: u32,
        /// Image height.
        want_h: u32,
    },

    /// A split (transforms file, or COLMAP model) has no frames.
    #[error("{path}: split '{split}' has no frames")]
    EmptySplit {
        /// The transforms file or COLMAP model folder.
        path: PathBuf,
        /// Split name.
        split: String,
    },

    /// A COLMAP camera model with non-zero distortion (the images must be undistorted
    /// first, e.g. with `colmap image_undistorter`), or a model this crate does not know.
    #[error("{path}: camera {camera_id}: {message}")]
    UnsupportedCamera {
        /// The COLMAP `cameras` file.
        path: PathBuf,
        /// COLMAP camera id.
        camera_id: u32,
        /// What is wrong and what to do.
        message: String,
    },

    /// An image file could not be decoded (corrupt, truncated, unsupported format).
    #[error("{path}: cannot decode image: {message}")]
    Decode {
        /// The image file.
        path: PathBuf,
        /// Decoder message.
        message: String,
    },

    /// An image could not be encoded or written.
    #[error("{path}: cannot encode image: {message}")]
    Encode {
        /// The output file.
        path: PathBuf,
        /// Encoder message.
        message: String,
    },

    /// Inconsistent or invalid options or parameters.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
}

impl DataError {
    /// Wraps an I/O error with its path.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        DataError::Io {
            path: path.into(),
            source,
        }
    }

    /// A [`DataError::Malformed`] for `path`.
    pub fn malformed(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        DataError::Malformed {
            path: path.into(),
            message: message.into(),
        }
    }
}
