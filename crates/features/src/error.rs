//! Errors of the features crate.

use std::path::PathBuf;

/// Everything that can go wrong while reading weights, building graphs or running networks.
#[derive(Debug, thiserror::Error)]
pub enum FeaturesError {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// A PyTorch checkpoint is not in a format we read (or is corrupt).
    #[error("{path}: not a readable PyTorch checkpoint: {reason}")]
    Checkpoint { path: PathBuf, reason: String },
    /// A weight the network needs is missing from the checkpoint.
    #[error("{path}: missing weight `{name}`")]
    MissingWeight { path: PathBuf, name: String },
    /// A weight has a shape the network does not expect.
    #[error("weight `{name}` has shape {found:?}, expected {expected:?}")]
    WeightShape {
        name: String,
        expected: Vec<usize>,
        found: Vec<usize>,
    },
    /// The inference engine failed (library missing, graph rejected, run error).
    #[error("inference engine: {0}")]
    Engine(String),
    /// An input tensor or image has the wrong size or values.
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// A configuration value is out of its valid range.
    #[error("invalid configuration: {field} = {value} ({reason})")]
    InvalidConfig {
        field: &'static str,
        value: String,
        reason: &'static str,
    },
}

/// Result alias of the features crate.
pub type Result<T, E = FeaturesError> = std::result::Result<T, E>;
