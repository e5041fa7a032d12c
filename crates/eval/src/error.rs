//! Errors of the evaluation crate.

use std::path::PathBuf;

use jointloc_geometry::GeometryError;

/// Everything that can stop an evaluation.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// Reading a trajectory or aligning failed.
    #[error(transparent)]
    Geometry(#[from] GeometryError),
    /// Timestamp association found no pair within the tolerance.
    #[error(
        "found no matching timestamps between reference and estimate \
         (max. time diff {max_diff} s, estimate time offset {offset} s)"
    )]
    NoMatchingTimestamps { max_diff: f64, offset: f64 },
    /// The RPE pairing rule selected no pose pair.
    #[error("RPE delta = {delta} ({unit}) produced no pose pairs; try a smaller delta")]
    NoRpePairs { delta: f64, unit: &'static str },
    /// Statistics of an empty error list were requested.
    #[error("no errors to summarise")]
    Empty,
    /// A configuration value is out of range.
    #[error("invalid configuration: {field} = {value} ({reason})")]
    InvalidConfig {
        field: &'static str,
        value: String,
        reason: &'static str,
    },
    /// Drawing or writing a plot failed.
    #[error("{path}: plot failed: {message}")]
    Plot { path: PathBuf, message: String },
}

/// Result alias of the evaluation crate.
pub type Result<T, E = EvalError> = std::result::Result<T, E>;
