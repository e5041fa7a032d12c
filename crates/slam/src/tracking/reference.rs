//! Matching a frame against the map points of one keyframe by descriptor alone, with no pose
//! prediction: ORB-SLAM2 does this with a bag of words (`SearchByBoW`); at ~1000 features per
//! image a brute-force mutual search with a ratio test and the rotation check costs about the
//! same and needs no vocabulary. Used to track the reference keyframe and to relocalise.

use jointloc_features::orb::{MatcherConfig, OrbFeatures, match_mutual};

use crate::frame::Frame;
use crate::map::{KeyFrame, Map, MapPointId};

/// ORB-SLAM2's matcher for keyframe tracking: distance ≤ 50 (TH_LOW), ratio 0.7, rotation
/// check.
pub fn keyframe_matcher(ratio: f64) -> MatcherConfig {
    MatcherConfig {
        max_distance: 50,
        ratio,
        mutual: true,
        check_orientation: true,
        orientation_bins: 30,
    }
}

/// Pairs `(frame keypoint, map point)` between `frame` and the points `kf` observes (the
/// points' representative descriptors against the frame's), ascending by keypoint.
pub fn match_keyframe(
    frame: &Frame,
    kf: &KeyFrame,
    map: &Map,
    cfg: &MatcherConfig,
) -> Vec<(usize, MapPointId)> {
    let mut ids = Vec::new();
    let mut subset = OrbFeatures {
        level_scales: kf.features.level_scales.clone(),
        ..OrbFeatures::default()
    };
    for (i, id) in kf.points.iter().enumerate() {
        let Some(p) = id.and_then(|id| map.point(id)) else {
            continue;
        };
        subset.keypoints.push(kf.features.keypoints[i]);
        subset.descriptors.push(p.descriptor);
        ids.push(p.id);
    }
    let mut out: Vec<(usize, MapPointId)> = match_mutual(&subset, &frame.features, cfg)
        .into_iter()
        .map(|m| (m.train, ids[m.query]))
        .collect();
    out.sort_unstable();
    out
}
