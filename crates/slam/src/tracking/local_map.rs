//! The local map of a frame (ORB-SLAM2's `UpdateLocalKeyFrames` / `UpdateLocalPoints`): the
//! keyframes that see its matched points, their strongest covisible neighbours and spanning-tree
//! relatives, and every point those keyframes observe.

use std::collections::{BTreeMap, BTreeSet};

use crate::frame::Frame;
use crate::map::{KeyFrameId, Map, MapPointId};

/// Keyframes and points around the current frame.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LocalMap {
    /// Local keyframes, those sharing points with the frame first.
    pub keyframes: Vec<KeyFrameId>,
    /// Points observed by the local keyframes, ascending.
    pub points: Vec<MapPointId>,
    /// The keyframe sharing most points with the frame.
    pub reference: Option<KeyFrameId>,
}

/// Builds the local map of `frame` from its inlier matches, with at most `max_keyframes`
/// keyframes (ORB-SLAM2: 80) and up to 10 covisible neighbours added per keyframe.
pub fn build_local_map(frame: &Frame, map: &Map, max_keyframes: usize) -> LocalMap {
    let mut counts: BTreeMap<KeyFrameId, usize> = BTreeMap::new();
    for (id, outlier) in frame.points.iter().zip(&frame.outliers) {
        let (Some(id), false) = (id, outlier) else {
            continue;
        };
        if let Some(p) = map.point(*id) {
            for kf in p.observations().keys() {
                *counts.entry(*kf).or_default() += 1;
            }
        }
    }
    let mut first: Vec<(KeyFrameId, usize)> = counts.into_iter().collect();
    first.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    let reference = first.first().map(|&(k, _)| k);
    let mut keyframes: Vec<KeyFrameId> = first.iter().map(|&(k, _)| k).collect();
    keyframes.truncate(max_keyframes);
    let mut seen: BTreeSet<KeyFrameId> = keyframes.iter().copied().collect();
    let direct = keyframes.clone();
    'outer: for k in direct {
        let Some(kf) = map.keyframe(k) else {
            continue;
        };
        let relatives = kf
            .best_covisible(10)
            .into_iter()
            .chain(kf.children().iter().copied())
            .chain(kf.parent());
        for r in relatives {
            if keyframes.len() >= max_keyframes {
                break 'outer;
            }
            if map.keyframe(r).is_some() && seen.insert(r) {
                keyframes.push(r);
            }
        }
    }
    let mut points = BTreeSet::new();
    for k in &keyframes {
        if let Some(kf) = map.keyframe(*k) {
            points.extend(kf.points.iter().flatten().copied());
        }
    }
    LocalMap {
        keyframes,
        points: points.into_iter().collect(),
        reference,
    }
}
