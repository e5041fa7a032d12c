//! Errors of the SLAM crate.

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
    /// An input value is NaN or infinite.
    #[error("non-finite input: {0}")]
    NonFinite(&'static str),
    /// An optimisation problem is malformed (unknown variable, empty problem, ...).
    #[error("invalid problem: {0}")]
    InvalidProblem(String),
    /// Monocular initialisation did not find a reliable two-view reconstruction.
    #[error("initialisation failed: {reason}")]
    InitializationFailed { reason: String },
    /// The two views of an initialisation attempt are too close together: the triangulated
    /// points' median parallax is below the configured minimum. More baseline will come, so
    /// the tracker keeps its reference frame.
    #[error("initialisation failed: median parallax {median_deg:.2}° below {required_deg:.2}°")]
    ParallaxTooLow { median_deg: f64, required_deg: f64 },
    /// ORB extraction failed (image too small or malformed, bad ORB settings).
    #[error(transparent)]
    Features(#[from] jointloc_features::FeaturesError),
    /// A geometric estimation failed.
    #[error(transparent)]
    Geometry(#[from] jointloc_geometry::GeometryError),
    /// A frame given to the system is unusable (wrong size, timestamps out of order, ...).
    #[error("invalid frame {index}: {reason}")]
    InvalidFrame { index: usize, reason: String },
    /// An input file (the sequence, its images, the camera) could not be read.
    #[error(transparent)]
    Format(#[from] jointloc_formats::FormatError),
}

/// Result alias of the SLAM crate.
pub type Result<T, E = SlamError> = std::result::Result<T, E>;
