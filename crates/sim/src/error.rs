//! Errors of the simulator.

use std::path::PathBuf;

/// Everything that can go wrong while synthesising terrain or writing a dataset.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// A configuration value is out of its valid range.
    #[error("invalid configuration: {field} = {value} ({reason})")]
    InvalidConfig {
        field: &'static str,
        value: String,
        reason: String,
    },
    /// A file or folder could not be read or written.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// The configuration file (`sim.toml`) could not be parsed.
    #[error("{path}:{line}: {message}")]
    Parse {
        path: PathBuf,
        line: usize,
        message: String,
    },
    /// A dataset file (map.toml, camera.yaml, the sequence, …) could not be read or written.
    #[error(transparent)]
    Format(#[from] jointloc_formats::FormatError),
    /// The output folder already holds files and overwriting was not allowed.
    #[error("output directory {path} is not empty; refusing to overwrite it")]
    OutputNotEmpty { path: PathBuf },
}

/// Result alias of the simulator.
pub type Result<T, E = SimError> = std::result::Result<T, E>;
