//! Errors of the geometry core.

use std::path::PathBuf;

/// Everything that can go wrong in a geometric estimation or while reading geometry files.
#[derive(Debug, thiserror::Error)]
pub enum GeometryError {
    /// Fewer correspondences than the estimator's minimal sample.
    #[error("too few correspondences: {required} required, {found} found")]
    TooFewPoints { required: usize, found: usize },
    /// Inputs that must have equal lengths do not.
    #[error("length mismatch: {what} ({left} vs {right})")]
    LengthMismatch {
        what: &'static str,
        left: usize,
        right: usize,
    },
    /// A configuration value is out of its valid range.
    #[error("invalid configuration: {field} = {value} ({reason})")]
    InvalidConfig {
        field: &'static str,
        value: String,
        reason: &'static str,
    },
    /// The data do not determine a model (collinear points, zero baseline, ...).
    #[error("degenerate configuration: {0}")]
    Degenerate(String),
    /// RANSAC found no model with enough inliers.
    #[error("no consensus: best model had {inliers} inliers, {required} required")]
    NoConsensus { inliers: usize, required: usize },
    /// An input value is NaN or infinite.
    #[error("non-finite input: {0}")]
    NonFinite(&'static str),
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// A line of a text file could not be parsed.
    #[error("{path}:{line}: {message}")]
    Parse {
        path: PathBuf,
        line: usize,
        message: String,
    },
}

/// Result alias of the geometry crate.
pub type Result<T, E = GeometryError> = std::result::Result<T, E>;
