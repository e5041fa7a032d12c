//! A keyframe: a frame kept in the map with its features, pose, the map points its keypoints
//! observe, and its place in the covisibility graph and spanning tree.

use std::collections::{BTreeMap, BTreeSet};

use jointloc_features::orb::{FeatureGrid, OrbFeatures};
use jointloc_geometry::WorldToCamera;
use nalgebra::{Point3, Vector3};

use super::ids::{KeyFrameId, MapPointId};

/// An absolute position fix attached to a keyframe by the fusion (paper §III-C): the world
/// position of a point rigidly attached to the keyframe's camera (its centre, or the ground
/// point on the optical axis of a frame tied to it) and the fix's confidence.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GlobalFix {
    /// The point in the keyframe's camera frame, SLAM units; zero: the camera centre.
    pub point_in_camera: Vector3<f64>,
    /// Its world position, metres.
    pub position: Vector3<f64>,
    /// Confidence w in [0, 1].
    pub weight: f64,
    /// Multiplies the local BA's `global_sigma`: how much looser this fix is than a map fix of
    /// a ground point.
    pub sigma_scale: f64,
}

/// What is kept of a keyframe retired by the sliding-window cap: enough for the keyframe and
/// frame trajectories (a few dozen bytes instead of its features and points).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RetiredKeyFrame {
    pub id: KeyFrameId,
    pub frame_index: usize,
    pub timestamp: f64,
    /// SLAM-frame pose `T_cw` when it was retired (it is not optimised any more).
    pub pose: WorldToCamera,
}

/// A keyframe of the map.
#[derive(Debug, Clone)]
pub struct KeyFrame {
    pub id: KeyFrameId,
    /// Index of the source frame in the sequence.
    pub frame_index: usize,
    pub timestamp: f64,
    /// SLAM-frame pose `T_cw`.
    pub pose: WorldToCamera,
    /// Keypoints (undistorted pixels) and descriptors.
    pub features: OrbFeatures,
    /// Spatial index over `features.keypoints`.
    pub grid: FeatureGrid,
    /// The map point each keypoint observes, if any.
    pub points: Vec<Option<MapPointId>>,
    /// Altimeter reading at this frame, metres above ground, if available.
    pub altitude: Option<f64>,
    /// Absolute fixes attached by the fusion ([`crate::system::System::set_global_fixes`]).
    pub(crate) global_fixes: Vec<GlobalFix>,
    pub(super) covisibility: BTreeMap<KeyFrameId, usize>,
    /// Covisible keyframes by decreasing weight, ties by id.
    pub(super) ordered: Vec<(KeyFrameId, usize)>,
    pub(super) parent: Option<KeyFrameId>,
    pub(super) children: BTreeSet<KeyFrameId>,
}

impl KeyFrame {
    /// The absolute fixes the fusion attached (global-position factors of the local BA).
    pub fn global_fixes(&self) -> &[GlobalFix] {
        &self.global_fixes
    }

    /// A keyframe with no map points and no connections yet.
    pub fn new(
        frame_index: usize,
        timestamp: f64,
        pose: WorldToCamera,
        features: OrbFeatures,
        grid: FeatureGrid,
    ) -> Self {
        let n = features.len();
        Self {
            id: KeyFrameId(u64::MAX),
            frame_index,
            timestamp,
            pose,
            features,
            grid,
            points: vec![None; n],
            altitude: None,
            global_fixes: Vec::new(),
            covisibility: BTreeMap::new(),
            ordered: Vec::new(),
            parent: None,
            children: BTreeSet::new(),
        }
    }

    /// Camera centre in the SLAM frame.
    pub fn centre(&self) -> Vector3<f64> {
        let inv = self.pose.0.inverse();
        inv.translation.vector
    }

    /// A SLAM-frame point in this camera's frame.
    pub fn to_camera(&self, p: &Vector3<f64>) -> Vector3<f64> {
        (self.pose.0 * Point3::from(*p)).coords
    }

    /// Covisible keyframes and their shared-point counts, strongest first.
    pub fn covisible(&self) -> &[(KeyFrameId, usize)] {
        &self.ordered
    }

    /// The `n` strongest covisible keyframes.
    pub fn best_covisible(&self, n: usize) -> Vec<KeyFrameId> {
        self.ordered.iter().take(n).map(|&(id, _)| id).collect()
    }

    /// Shared-point count with `other` (0 if not connected).
    pub fn covisibility_weight(&self, other: KeyFrameId) -> usize {
        self.covisibility.get(&other).copied().unwrap_or(0)
    }

    /// Parent in the spanning tree (`None` for the first keyframe).
    pub fn parent(&self) -> Option<KeyFrameId> {
        self.parent
    }

    /// Children in the spanning tree.
    pub fn children(&self) -> &BTreeSet<KeyFrameId> {
        &self.children
    }

    /// Number of keypoints with a map point.
    pub fn n_points(&self) -> usize {
        self.points.iter().filter(|p| p.is_some()).count()
    }
}
