//! The files `jointloc run` writes, each with its writer and its reader, so the CLI, the
//! bench and users' scripts read them back the same way:
//!
//! - `trajectory.tum`: one line per frame as known online, TUM for geo-referenced frames and
//!   a comment line (`# timestamp not geo-referenced` / `not tracked`) for the others, so
//!   `evo` reads it as it is and a person sees every frame ([`online`]);
//! - `fixes.txt`: the absolute fixes with their confidence and fate in the fusion
//!   ([`fixes`]);
//! - `summary.json` and `timing.json`: counts, rates and per-module medians ([`summary`]);
//! - `config.toml`: the settings the run used ([`settings`]).
//!
//! The trajectories as known at the end (`trajectory-final.tum`, `keyframes.tum`) are plain
//! TUM, written by [`jointloc_geometry::trajectory::Trajectory::write_tum`].

pub mod fixes;
pub mod online;
pub mod settings;
pub mod summary;

pub use fixes::{FixRow, read_fixes, write_fixes};
pub use online::{OnlineFrame, OnlineStatus, read_online_tum, write_online_tum};
pub use settings::{settings_toml, write_settings_toml};
pub use summary::{
    CameraTiltSummary, FinalBaStats, OutputCrs, RealtimeSummary, Summary, TerrainSummary,
    TimingSummary, read_json, write_json,
};

use std::path::Path;

use crate::error::{FormatError, Result};

/// Writes `text` to `path`, naming the file on failure.
pub(crate) fn write_text(path: &Path, text: &str) -> Result<()> {
    std::fs::write(path, text).map_err(|e| FormatError::io(path, e))
}

/// Reads `path` as text, naming the file on failure.
pub(crate) fn read_text(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).map_err(|e| FormatError::io(path, e))
}

/// `(line number, fields)` of the non-empty lines, comments included (trimmed).
pub(crate) fn lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty())
}

/// A finite number in column `what` of `path:line`.
pub(crate) fn number(path: &Path, line: usize, what: &str, s: &str) -> Result<f64> {
    let v: f64 = s
        .parse()
        .map_err(|_| FormatError::parse(path, line, format!("{what} `{s}` is not a number")))?;
    if !v.is_finite() {
        return Err(FormatError::parse(
            path,
            line,
            format!("{what} `{s}` is not finite"),
        ));
    }
    Ok(v)
}
