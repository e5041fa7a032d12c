//! Errors of the fused system.

use thiserror::Error;

#[derive(Debug, Error)]
pub enum JointLocError {
    #[error(transparent)]
    Slam(#[from] jointloc_slam::error::SlamError),
    #[error(transparent)]
    Absloc(#[from] jointloc_absloc::AbslocError),
    #[error(transparent)]
    Format(#[from] jointloc_formats::FormatError),
    #[error(transparent)]
    Geometry(#[from] jointloc_geometry::GeometryError),
    #[error("{}: already exists", path.display())]
    WouldOverwrite { path: std::path::PathBuf },
    #[error("invalid setting {field} = {value}: {reason}")]
    InvalidConfig {
        field: &'static str,
        value: String,
        reason: &'static str,
    },
    #[error("absolute-localisation thread: {message}")]
    Thread { message: String },
}

pub type Result<T> = std::result::Result<T, JointLocError>;
