//! Errors of the absolute localisation. Bad input (map, frame, altimeter, configuration) is an
//! error with the offending file or value; a search that finds nothing is not an error but a
//! failed fix (see [`crate::Outcome`]).

use std::path::PathBuf;

/// Everything that can go wrong before or around a search.
#[derive(Debug, thiserror::Error)]
pub enum AbslocError {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// An image file could not be decoded.
    #[error("{path}: unreadable image: {message}")]
    Image { path: PathBuf, message: String },
    /// A text file has a malformed line (`line` 0: the file as a whole).
    #[error("{path}:{line}: {message}")]
    Parse {
        path: PathBuf,
        line: usize,
        message: String,
    },
    /// Neither `map.toml` with its map image nor a tile folder was found.
    #[error("{path}: no map here ({reason})")]
    MapMissing { path: PathBuf, reason: String },
    /// A tile folder was given without a ground sampling distance.
    #[error(
        "{path}: the map's ground sampling distance is unknown (no map.toml; pass the GSD in metres per pixel)"
    )]
    GsdMissing { path: PathBuf },
    /// Tiles must have the UAV frame's size (the paper's tiling).
    #[error(
        "map tiles are {tile_width}x{tile_height} px but the frame is {frame_width}x{frame_height} px: \
         the map must be tiled at the UAV image size"
    )]
    TileSizeMismatch {
        tile_width: u32,
        tile_height: u32,
        frame_width: u32,
        frame_height: u32,
    },
    /// The altimeter reading is missing, not finite or not positive.
    #[error("altimeter reading {value} is not a usable altitude (needs a finite value > 0 m)")]
    InvalidAltitude { value: f64 },
    /// A configuration value is out of range.
    #[error("invalid configuration: {field} = {value} ({reason})")]
    InvalidConfig {
        field: &'static str,
        value: String,
        reason: String,
    },
    /// A matcher name that is not known at all.
    #[error("unknown matcher `{name}` (known: {known})")]
    UnknownMatcher { name: String, known: String },
    /// A known matcher whose networks or weights cannot be used here.
    #[error("matcher `{name}` is not available: {reason}")]
    MatcherUnavailable { name: String, reason: String },
    /// Features or matching failed.
    #[error(transparent)]
    Features(#[from] jointloc_features::FeaturesError),
    /// Geometry failed (other than "no consensus", which is a failed candidate).
    #[error(transparent)]
    Geometry(#[from] jointloc_geometry::GeometryError),
    /// Reading a dataset file (map.toml, the elevation model, camera.yaml, the sequence)
    /// failed.
    #[error(transparent)]
    Format(#[from] jointloc_formats::FormatError),
}

/// Result with [`AbslocError`].
pub type Result<T, E = AbslocError> = std::result::Result<T, E>;

/// `Io` error for `path`.
pub(crate) fn io_err(path: impl Into<PathBuf>) -> impl FnOnce(std::io::Error) -> AbslocError {
    let path = path.into();
    move |source| AbslocError::Io { path, source }
}

/// Reads a grey image (any format the `image` crate decodes here; colour is converted).
pub(crate) fn read_gray(path: &std::path::Path) -> Result<image::GrayImage> {
    if !path.is_file() {
        return Err(AbslocError::Io {
            path: path.to_path_buf(),
            source: std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
        });
    }
    image::open(path)
        .map(|img| img.into_luma8())
        .map_err(|e| AbslocError::Image {
            path: path.to_path_buf(),
            message: e.to_string(),
        })
}
