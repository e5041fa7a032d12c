//! Culling (ORB-SLAM2's `MapPointCulling` and `KeyFrameCulling`): recent points that tracking
//! rarely finds or too few keyframes see are erased; keyframes whose points are ≥ 90 % seen by
//! three other keyframes at the same or a finer scale are redundant and erased.

use jointloc_geometry::WorldToCamera;
use nalgebra::Isometry3;

use crate::map::{KeyFrameId, Map, MapPointId};

/// Erases bad recent points and retires those old enough to be trusted; returns how many were
/// erased. `recent` keeps the points still under probation.
pub fn cull_recent_points(
    map: &mut Map,
    recent: &mut Vec<MapPointId>,
    current: KeyFrameId,
    min_found_ratio: f64,
) -> usize {
    let mut erased = 0;
    recent.retain(|&id| {
        let Some(p) = map.point(id) else {
            return false;
        };
        let age = current.0.saturating_sub(p.first_keyframe.0);
        if p.found_ratio() < min_found_ratio || (age >= 2 && p.n_observations() <= 2) {
            map.erase_point(id);
            erased += 1;
            false
        } else {
            age < 3
        }
    });
    erased
}

/// A keyframe removed by culling, remembered relative to its spanning-tree parent so that the
/// frames tracked against it keep a pose (ORB-SLAM2's `mTcp`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CulledKeyFrame {
    pub id: KeyFrameId,
    pub parent: KeyFrameId,
    /// `T_c,parent`: the culled keyframe's pose relative to its parent.
    pub relative: Isometry3<f64>,
}

/// Erases redundant keyframes among `kf`'s covisible neighbours (never `kf` itself or the first
/// keyframe): those with more than `redundancy` of their points observed by at least three other
/// keyframes at the same, a finer or one coarser level.
pub fn cull_keyframes(map: &mut Map, kf: KeyFrameId, redundancy: f64) -> Vec<CulledKeyFrame> {
    let Some(k) = map.keyframe(kf) else {
        return Vec::new();
    };
    let first = map.keyframes().next().map(|k| k.id);
    let candidates: Vec<KeyFrameId> = k.covisible().iter().map(|&(id, _)| id).collect();
    let mut out = Vec::new();
    for c in candidates {
        if Some(c) == first || c == kf {
            continue;
        }
        let Some(ck) = map.keyframe(c) else {
            continue;
        };
        let (mut total, mut redundant) = (0usize, 0usize);
        for (i, id) in ck.points.iter().enumerate() {
            let Some(p) = id.and_then(|id| map.point(id)) else {
                continue;
            };
            total += 1;
            if p.n_observations() <= 3 {
                continue;
            }
            let level = ck.features.keypoints[i].octave;
            let others = p
                .observations()
                .iter()
                .filter(|&(&o, _)| o != c)
                .filter(|&(o, &j)| {
                    map.keyframe(*o)
                        .and_then(|ok| ok.features.keypoints.get(j))
                        .is_some_and(|kp| kp.octave <= level + 1)
                })
                .count();
            if others >= 3 {
                redundant += 1;
            }
        }
        if total == 0 || (redundant as f64) <= redundancy * total as f64 {
            continue;
        }
        let parent = ck.parent();
        let pose: WorldToCamera = ck.pose;
        let parent_pose = parent.and_then(|p| map.keyframe(p)).map(|p| p.pose);
        if map.erase_keyframe(c)
            && let (Some(parent), Some(pp)) = (parent, parent_pose)
        {
            out.push(CulledKeyFrame {
                id: c,
                parent,
                relative: pose.0 * pp.0.inverse(),
            });
        }
    }
    out
}
