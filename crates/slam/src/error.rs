//! Errors of the SLAM crate.

use std::path::PathBuf;

/// Everything that can go wrong in feature extraction, tracking, mapping or optimisation.
#[derive(Debug, thiserror::Error)]
pub enum SlamError {
    /// A configuration value is out of its valid range.
    #[error("invalid configuration: {field} = {value} ({reason})")]
    InvalidConfig {
        field: &'static str,
        value: String,
        reason: &'static str,
    },
    /// An image has a size the stage cannot use.
    #[error("image of {width}x{height} px is too small: {reason}")]
    ImageTooSmall {
        width: u32,
        height: u32,
        reason: &'static str,
    },
    /// An image buffer does not hold width × height pixels.
    #[error("image buffer of {len} bytes does not match {width}x{height} px")]
    InvalidImage {
        width: usize,
        height: usize,
        len: usize,
    },
    /// An input value is NaN or infinite.
    #[error("non-finite input: {0}")]
    NonFinite(&'static str),
    /// An optimisation problem is malformed (unknown variable, empty problem, ...).
    #[error("invalid problem: {0}")]
    InvalidProblem(String),
    /// Monocular initialisation did not find a reliable two-view reconstruction.
    #[error("initialisation failed: {reason}")]
    InitializationFailed { reason: String },
    /// A geometric estimation failed.
    #[error(transparent)]
    Geometry(#[from] jointloc_geometry::GeometryError),
    /// A line of an input file could not be parsed.
    #[error("{path}:{line}: {message}")]
    Parse {
        path: PathBuf,
        line: usize,
        message: String,
    },
    /// An image file could not be decoded.
    #[error("{path}: cannot decode image: {message}")]
    ImageDecode { path: PathBuf, message: String },
    /// A frame given to the system is unusable (wrong size, timestamps out of order, ...).
    #[error("invalid frame {index}: {reason}")]
    InvalidFrame { index: usize, reason: String },
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// Result alias of the SLAM crate.
pub type Result<T, E = SlamError> = std::result::Result<T, E>;
