//! A map point: a 3-D landmark with the keyframes that observe it, its representative
//! descriptor, mean viewing direction and the distance range it can be recognised at.

use std::collections::BTreeMap;

use jointloc_features::orb::Descriptor;
use nalgebra::Vector3;

use super::ids::{KeyFrameId, MapPointId};

/// A landmark of the map.
#[derive(Debug, Clone)]
pub struct MapPoint {
    pub id: MapPointId,
    /// Position in the SLAM frame.
    pub position: Vector3<f64>,
    /// The observation descriptor with the least median distance to the others.
    pub descriptor: Descriptor,
    /// Mean unit viewing direction (from the cameras to the point).
    pub normal: Vector3<f64>,
    /// Distances between which the point's scale-invariant descriptor is expected to match.
    pub min_distance: f64,
    pub max_distance: f64,
    /// Keyframe whose observation defines the scale range.
    pub reference: KeyFrameId,
    /// Keyframe that created the point (culling looks at how long ago that was).
    pub first_keyframe: KeyFrameId,
    /// Frames in which the point was predicted visible, and in which it was matched.
    pub visible: u32,
    pub found: u32,
    pub(super) observations: BTreeMap<KeyFrameId, usize>,
}

impl MapPoint {
    /// Keyframes observing the point and the keypoint index in each.
    pub fn observations(&self) -> &BTreeMap<KeyFrameId, usize> {
        &self.observations
    }

    /// Number of observing keyframes.
    pub fn n_observations(&self) -> usize {
        self.observations.len()
    }

    /// found / visible: ORB-SLAM's tracking-quality ratio used by point culling.
    pub fn found_ratio(&self) -> f64 {
        if self.visible == 0 {
            0.0
        } else {
            f64::from(self.found) / f64::from(self.visible)
        }
    }

    /// Pyramid level at which the point should appear when seen from `distance`, clamped to the
    /// pyramid (ORB-SLAM's `PredictScale`).
    pub fn predict_level(&self, distance: f64, scale_factor: f64, n_levels: usize) -> u32 {
        if distance.is_nan()
            || distance <= 0.0
            || self.max_distance.is_nan()
            || self.max_distance <= 0.0
        {
            return 0;
        }
        let ratio = self.max_distance / distance;
        let level = (ratio.ln() / scale_factor.ln()).ceil();
        level.clamp(0.0, (n_levels.max(1) - 1) as f64) as u32
    }
}
