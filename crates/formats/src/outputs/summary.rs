//! `summary.json` (what a run did: counts, rates, the fixes' fate, the final BA) and
//! `timing.json` (per-module medians, the paper's Table VII). Keys are written sorted, so two
//! runs diff line by line.

use std::collections::BTreeMap;
use std::path::Path;

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use super::{read_text, write_text};
use crate::error::{FormatError, Result};

/// What the global bundle adjustment at the end of a run did.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct FinalBaStats {
    pub keyframes: usize,
    pub points: usize,
    pub observations: usize,
    pub global_factors: usize,
    /// Fix factors left out: their point farther than the inlier threshold from the fix at
    /// the start (a wrong fix), or their keyframe no longer in the map (retired by the cap).
    pub factors_left_out: usize,
    pub ground_factors: usize,
    pub iterations: usize,
    pub initial_cost: f64,
    pub final_cost: f64,
    pub ms: f64,
}

/// The fixes' common bias taken out by the terrain correction, metres.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct TerrainSummary {
    pub x: f64,
    pub y: f64,
    /// Estimates the correction was updated from.
    pub updates: usize,
}

/// The camera's mean tilt off nadir as the fusion estimated it from the fused attitudes,
/// degrees, `[about image x, about image y]` (a camera mounted off nadir, a UAV pitched to
/// cruise).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct CameraTiltSummary {
    /// The mean tilt of the fused attitudes at the last refit.
    pub estimated_deg: [f64; 2],
    /// What the fusion used: the estimate shrunk by `camera_tilt_min_deg`.
    pub used_deg: [f64; 2],
}

/// A replay at the camera rate: how far the processing lagged behind the camera.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RealtimeSummary {
    /// Replay speed (1: the camera rate).
    pub speed: f64,
    pub lag_median_ms: f64,
    pub lag_max_ms: f64,
    /// Frames due before the previous one was done.
    pub frames_late: usize,
}

/// `summary.json`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Summary {
    pub frames: usize,
    /// Frames written with a world pose in `trajectory.tum`.
    pub world_poses: usize,
    /// Index of the first frame with a world pose.
    pub geo_referenced_from: Option<usize>,
    /// Frames whose tracking was lost.
    pub lost: usize,
    /// SLAM maps started after a tracking loss.
    pub new_maps: usize,
    /// Of the maps set aside at those losses, those merged back into a later map.
    #[serde(default)]
    pub maps_merged: usize,
    /// Maps the end outputs come from (1: one consistent map).
    #[serde(default)]
    pub maps_at_end: usize,
    /// Loops the SLAM closed (over all its maps).
    #[serde(default)]
    pub loops_closed: usize,
    pub fixes_found: usize,
    pub fixes_used: usize,
    pub fixes_inliers: usize,
    /// Frames over the wall time of the run.
    pub hz: f64,
    /// Frames over the time spent processing them (what the loop could sustain).
    pub capacity_hz: f64,
    /// `sequential`, `threaded` or `threaded, real-time replay`.
    pub mode: String,
    pub absolute_attempts: usize,
    pub skipped_busy: usize,
    pub skipped_outage: usize,
    pub skipped_untracked: usize,
    /// Absolute searches made through a virtual frame (a mosaic of recent frames).
    #[serde(default)]
    pub virtual_frames: usize,
    /// Frames due for absolute localisation whose virtual frame covered too little (or had
    /// no tracked frames yet).
    #[serde(default)]
    pub skipped_no_view: usize,
    /// Frames due while searches with nothing to search around yet backed off (sequential
    /// mode, before the first fix).
    #[serde(default)]
    pub skipped_backoff: usize,
    pub fixes_injected_wrong: usize,
    pub first_fix_global: Option<bool>,
    pub first_fix_searched_tiles: Option<usize>,
    #[serde(rename = "terrain_correction_m")]
    pub terrain_correction: TerrainSummary,
    /// Absent when the estimate is switched off or the flight was never geo-referenced.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_tilt: Option<CameraTiltSummary>,
    pub final_ba: Option<FinalBaStats>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub realtime: Option<RealtimeSummary>,
    /// Bad input skipped, dropped or flagged instead of stopping the flight, by kind
    /// ([`crate::InputFaultKind::name`]); absent when there was none.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub input_faults: BTreeMap<String, usize>,
    /// The map coordinates the trajectories and fixes are written in (`--out-crs map`);
    /// absent: the local world frame of `map.toml`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub output_crs: Option<OutputCrs>,
    /// Evaluations added by the caller (e.g. `ape_translation` against ground truth).
    #[serde(flatten)]
    pub evaluation: BTreeMap<String, serde_json::Value>,
}

/// Outputs in the map's CRS: every position is the world position plus
/// `(easting_m, northing_m, 0)`; heights stay the map's (the DTM's) heights.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct OutputCrs {
    pub easting_m: f64,
    pub northing_m: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub epsg: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub citation: Option<String>,
}

/// `timing.json`: medians in milliseconds, and rates.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct TimingSummary {
    pub absolute_localisation_ms: f64,
    pub alignment_ms: f64,
    pub orb_extraction_ms: f64,
    pub tracking_ms: f64,
    pub local_mapping_ms: f64,
    pub local_ba_ms: f64,
    pub frame_ms: f64,
    pub hz: f64,
    pub capacity_hz: f64,
}

/// Writes `value` as pretty JSON with sorted keys and a final newline.
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<()> {
    let invalid = |e: serde_json::Error| FormatError::Invalid {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    // Through a `Value`, whose maps are sorted.
    let value = serde_json::to_value(value).map_err(invalid)?;
    let text = serde_json::to_string_pretty(&value).map_err(invalid)?;
    write_text(path, &(text + "\n"))
}

/// Reads a JSON file written by [`write_json`].
pub fn read_json<T: DeserializeOwned>(path: &Path) -> Result<T> {
    let text = read_text(path)?;
    serde_json::from_str(&text).map_err(|e| FormatError::parse(path, e.line(), e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn summary_round_trip_with_sorted_keys_and_evaluations() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("summary.json");
        let mut s = Summary {
            frames: 10,
            world_poses: 7,
            geo_referenced_from: Some(3),
            mode: "sequential".into(),
            final_ba: Some(FinalBaStats {
                keyframes: 4,
                ..Default::default()
            }),
            ..Default::default()
        };
        s.evaluation
            .insert("ape_translation".into(), serde_json::json!({"rmse": 0.05}));
        write_json(&path, &s).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let keys: Vec<&str> = text
            .lines()
            .filter(|l| l.starts_with("  \""))
            .map(|l| l.trim().split('"').nth(1).unwrap())
            .collect();
        let mut sorted = keys.clone();
        sorted.sort_unstable();
        assert_eq!(keys, sorted);
        assert!(!text.contains("realtime"), "{text}");
        assert_eq!(read_json::<Summary>(&path).unwrap(), s);
    }

    #[test]
    fn bad_json_names_the_file_and_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("timing.json");
        std::fs::write(&path, "{\n  \"hz\": 3,\n  oops\n}\n").unwrap();
        let e = read_json::<TimingSummary>(&path).unwrap_err().to_string();
        assert!(e.contains("timing.json:3:"), "{e}");
    }
}
