//! Errors of the simulator.

use std::path::PathBuf;

/// Everything that can go wrong while synthesising terrain or writing a dataset.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// A configuration value is out of its valid range.
    #[error("invalid configuration: {field} = {value} ({reason})")]
    InvalidConfig { field: &'static str, value: String, reason: String },
    /// A file or folder could not be read or written.
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    /// An image could not be encoded or written.
    #[error("{path}: {message}")]
    Image { path: PathBuf, message: String },
}

/// Result alias of the simulator.
pub type Result<T, E = SimError> = std::result::Result<T, E>;
