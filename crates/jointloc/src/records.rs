//! What the system reports: a processed frame, a fix as the fusion saw it, the per-module
//! times.

use jointloc_absloc::Outcome;
use jointloc_formats::outputs::FixRow;
use jointloc_geometry::CameraToWorld;
use jointloc_slam::map::KeyFrameId;
use jointloc_slam::tracking::TrackingState;
use serde::Serialize;

/// An absolute fix as the fusion saw it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FixRecord {
    pub frame: usize,
    pub timestamp: f64,
    /// World (x, y) of the map point under the image centre, z the altimeter reading.
    pub position: [f64; 3],
    /// The frame's rotation in the map as matched, radians ([`jointloc_absloc::Fix::heading`]).
    pub heading: f64,
    pub confidence: f64,
    pub ssim: f64,
    pub match_score: f64,
    pub tile: usize,
    pub inliers: usize,
    /// Tiles matched for this fix, and whether the whole map was searched.
    pub searched_tiles: usize,
    pub global: bool,
    /// Whether the fix went into the fusion (confidence high enough and a keyframe to tie it
    /// to) and, after the latest alignment, whether it was an inlier.
    pub used: bool,
    pub inlier: bool,
    /// Replaced by a wrong position by fault injection ([`crate::faults`]).
    pub injected: bool,
    pub ms: f64,
}

impl FixRecord {
    /// Its line in `fixes.txt`.
    pub fn to_row(&self) -> FixRow {
        FixRow {
            timestamp: self.timestamp,
            position: self.position,
            orientation: {
                let q = jointloc_absloc::localizer::nadir_orientation(self.heading);
                [q.i, q.j, q.k, q.w]
            },
            confidence: self.confidence,
            tile: self.tile,
            ssim: self.ssim,
            match_score: self.match_score,
            inliers: self.inliers,
            used: self.used,
            inlier: self.inlier,
            injected: self.injected,
        }
    }
}

/// One processed frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FusedFrame {
    pub index: usize,
    pub timestamp: f64,
    pub state: TrackingState,
    /// Camera-to-world in the SLAM frame, as tracked.
    pub slam_pose: Option<CameraToWorld>,
    /// Camera-to-world in the world frame (S · SLAM pose) with the alignment known at this
    /// frame; `None` while not geo-referenced or not tracked.
    pub world_pose: Option<CameraToWorld>,
    /// Absolute localisation results applied at this frame (the fix or its failure, w = 0),
    /// with the frame each was computed for: this frame in the sequential mode, an earlier
    /// one in the threaded mode.
    pub absolute: Vec<(usize, Outcome)>,
    pub keyframe: Option<KeyFrameId>,
}

/// Per-module wall times, milliseconds.
#[derive(Debug, Clone, Default, Serialize)]
pub struct FusionTiming {
    /// Absolute localisation (feature extraction + matching + homography + confidence), per fix.
    pub absolute_ms: Vec<f64>,
    /// Alignment re-fit and global-factor update, per fix.
    pub alignment_ms: Vec<f64>,
    /// Whole frame (SLAM + fusion), per frame.
    pub frame_ms: Vec<f64>,
    /// Frames due for absolute localisation that the busy thread skipped (threaded mode).
    pub skipped_busy: usize,
    /// Frames due for absolute localisation during an injected outage.
    pub skipped_outage: usize,
    /// Frames due for absolute localisation before the SLAM tracked them (threaded mode).
    pub skipped_untracked: usize,
    /// Searches made through a virtual frame ([`crate::virtual_frames`]).
    pub virtual_frames: usize,
    /// Frames due whose virtual frame could not be made (too little covered, not tracked).
    pub skipped_no_view: usize,
    /// Frames due while searches with nothing to search around back off (sequential mode,
    /// before the first fix; [`crate::JointLocConfig::blind_retry_max_s`]).
    pub skipped_backoff: usize,
}
