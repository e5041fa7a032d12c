//! Relocalisation after tracking is lost (ORB-SLAM2's `Relocalization`): the frame's
//! descriptors are matched against the map points of recent keyframes, then of the keyframes
//! anywhere in the map that look most like it by bag of words, a pose is found by
//! PnP-RANSAC, refined by the pose-only optimisation, and completed by projecting the
//! candidate's points with a wide, then a narrow window.

use jointloc_features::orb::MatcherConfig;
use jointloc_geometry::PinholeCamera;
use jointloc_geometry::pnp::{PnpConfig, solve_pnp_ransac};
use nalgebra::{Point2, Point3};
use serde::{Deserialize, Serialize};

use crate::frame::Frame;
use crate::loop_closing::appearance::BowCache;
use crate::map::{KeyFrameId, Map, MapPointId};
use crate::place::{BowVector, Vocabulary};
use crate::tracking::pose_optimization::{PoseOptimizationConfig, optimize_pose};
use crate::tracking::projection::search_local_points;
use crate::tracking::reference::{keyframe_matcher, match_keyframe};

/// Settings of [`relocalise`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RelocalisationConfig {
    /// Most recent keyframes tried, newest first (ORB-SLAM2 asks its bag-of-words database;
    /// a UAV that lost track is usually still near where it last was).
    pub max_candidates: usize,
    /// Descriptor matches a candidate needs before PnP (ORB-SLAM2: 15).
    pub min_matches: usize,
    /// Ratio test of the descriptor matching (ORB-SLAM2: 0.75).
    pub ratio: f64,
    /// PnP-RANSAC settings.
    pub pnp: PnpConfig,
    /// Inliers for a relocalisation to be accepted (ORB-SLAM2: 50).
    pub min_inliers: usize,
    /// Keyframes from anywhere in the map tried after the recent ones, the best by bag of
    /// words (the embedded vocabulary, `crate::place`); 0: recent keyframes only. A UAV that
    /// comes back over old ground after a loss finds its place there.
    pub appearance_candidates: usize,
}

impl Default for RelocalisationConfig {
    fn default() -> Self {
        Self {
            max_candidates: 30,
            min_matches: 15,
            ratio: 0.75,
            pnp: PnpConfig::default(),
            min_inliers: 50,
            appearance_candidates: 10,
        }
    }
}

/// Tries the candidates newest first, then (with `place`) the keyframes that look most like
/// the frame; on success sets `frame.pose` and its matches and returns the keyframe it
/// relocalised against. On failure the frame is left without pose or matches.
pub fn relocalise(
    frame: &mut Frame,
    map: &mut Map,
    camera: &PinholeCamera,
    config: &RelocalisationConfig,
    pose_cfg: &PoseOptimizationConfig,
    place: Option<(&Vocabulary, &mut BowCache)>,
) -> Option<KeyFrameId> {
    let mut candidates: Vec<KeyFrameId> = map.keyframes().map(|k| k.id).collect();
    candidates.reverse();
    candidates.truncate(config.max_candidates);
    if let (Some((vocabulary, cache)), n @ 1..) = (place, config.appearance_candidates) {
        let query = BowVector::new(vocabulary, &frame.features.descriptors);
        cache.retain_in(map);
        let others: Vec<KeyFrameId> = map
            .keyframes()
            .map(|k| k.id)
            .filter(|id| !candidates.contains(id))
            .collect();
        let mut scored: Vec<(f64, KeyFrameId)> = others
            .into_iter()
            .filter_map(|id| Some((query.score(cache.get(vocabulary, map, id)?), id)))
            .filter(|(s, _)| *s > 0.0)
            .collect();
        scored.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        candidates.extend(scored.into_iter().take(n).map(|(_, id)| id));
    }
    for kf in candidates {
        if try_candidate(frame, map, kf, camera, config, pose_cfg) {
            tracing::info!(frame = frame.index, keyframe = %kf, "relocalised");
            return Some(kf);
        }
        frame.pose = None;
        frame.clear_matches();
    }
    None
}

fn try_candidate(
    frame: &mut Frame,
    map: &mut Map,
    kf_id: KeyFrameId,
    camera: &PinholeCamera,
    config: &RelocalisationConfig,
    pose_cfg: &PoseOptimizationConfig,
) -> bool {
    let Some(kf) = map.keyframe(kf_id) else {
        return false;
    };
    let matches = match_keyframe(frame, kf, map, &keyframe_matcher(config.ratio));
    if matches.len() < config.min_matches {
        return false;
    }
    let matches: Vec<(usize, MapPointId, Point3<f64>)> = matches
        .into_iter()
        .filter_map(|(i, id)| map.point(id).map(|p| (i, id, Point3::from(p.position))))
        .collect();
    let world: Vec<Point3<f64>> = matches.iter().map(|m| m.2).collect();
    let pixels: Vec<Point2<f64>> = matches.iter().map(|m| frame.pixel(m.0)).collect();
    let Ok(pnp) = solve_pnp_ransac(&world, &pixels, camera, &config.pnp) else {
        return false;
    };
    if pnp.inliers.len() < 10 {
        return false;
    }
    frame.clear_matches();
    for &j in &pnp.inliers {
        let (i, id, _) = matches[j];
        frame.points[i] = Some(id);
    }
    frame.pose = Some(pnp.pose);
    let mut n = optimize_pose(frame, map, camera, pose_cfg);
    frame.drop_outliers();
    if n < 10 {
        return false;
    }
    // Complete with the candidate's neighbourhood: wide window first, then narrow.
    let mut local: Vec<MapPointId> = Vec::new();
    if let Some(kf) = map.keyframe(kf_id) {
        local.extend(kf.points.iter().flatten());
        for nb in kf.best_covisible(10) {
            if let Some(nb) = map.keyframe(nb) {
                local.extend(nb.points.iter().flatten());
            }
        }
    }
    local.sort_unstable();
    local.dedup();
    let matcher = MatcherConfig {
        max_distance: 100,
        ratio: 0.9,
        mutual: false,
        check_orientation: true,
        orientation_bins: 30,
    };
    for th in [10.0, 3.0] {
        if n >= config.min_inliers {
            break;
        }
        let found: std::collections::BTreeSet<_> = frame.points.iter().flatten().copied().collect();
        let rest: Vec<MapPointId> = local
            .iter()
            .filter(|p| !found.contains(p))
            .copied()
            .collect();
        search_local_points(frame, map, &rest, camera, th, &matcher);
        n = optimize_pose(frame, map, camera, pose_cfg);
        frame.drop_outliers();
    }
    n >= config.min_inliers
}
