//! Fusion of duplicate points (ORB-SLAM2's `SearchInNeighbors` / `Fuse`): the new keyframe's
//! points are projected into its neighbours and theirs into it; a point that lands on a keypoint
//! with a matching descriptor either adds that observation or, when the keypoint already has a
//! point, the two are merged into the one with more observations.

use std::collections::BTreeSet;

use jointloc_features::orb::hamming;
use jointloc_geometry::PinholeCamera;
use nalgebra::Point2;

use crate::map::{KeyFrameId, Map, MapPointId};
use crate::tracking::projection::visibility;

/// Window factor of the projection search (ORB-SLAM2: 3) and the descriptor cap (TH_LOW).
const FUSE_TH: f64 = 3.0;
const MAX_DISTANCE: u32 = 50;
const CHI2: f64 = 5.991;

/// Fuses between `kf` and its neighbours (`neighbours` strongest, plus 5 of each of theirs);
/// returns the number of observations added or points merged.
pub fn fuse_with_neighbours(
    map: &mut Map,
    kf: KeyFrameId,
    camera: &PinholeCamera,
    neighbours: usize,
) -> usize {
    let Some(k) = map.keyframe(kf) else {
        return 0;
    };
    let mut targets: Vec<KeyFrameId> = Vec::new();
    let mut seen = BTreeSet::from([kf]);
    for n in k.best_covisible(neighbours) {
        if seen.insert(n) {
            targets.push(n);
        }
        if let Some(nk) = map.keyframe(n) {
            for n2 in nk.best_covisible(5) {
                if seen.insert(n2) {
                    targets.push(n2);
                }
            }
        }
    }
    let mut fused = 0;
    for &t in &targets {
        let points: Vec<MapPointId> = map
            .keyframe(kf)
            .map_or(Vec::new(), |k| k.points.iter().flatten().copied().collect());
        fused += fuse(map, t, &points, camera);
    }
    let mut candidates = BTreeSet::new();
    for &t in &targets {
        if let Some(tk) = map.keyframe(t) {
            candidates.extend(tk.points.iter().flatten().copied());
        }
    }
    let candidates: Vec<MapPointId> = candidates.into_iter().collect();
    fused += fuse(map, kf, &candidates, camera);
    if let Some(k) = map.keyframe(kf) {
        let own: Vec<MapPointId> = k.points.iter().flatten().copied().collect();
        for id in own {
            map.update_descriptor(id);
            map.update_normal_and_depth(id);
        }
    }
    map.update_connections(kf);
    fused
}

/// Projects `points` into keyframe `target` and fuses them; returns the changes made.
pub fn fuse(
    map: &mut Map,
    target: KeyFrameId,
    points: &[MapPointId],
    camera: &PinholeCamera,
) -> usize {
    let Some(tk) = map.keyframe(target) else {
        return 0;
    };
    let (pose, centre) = (tk.pose, tk.centre());
    let sf = map.scale_factor();
    let mut decisions: Vec<(MapPointId, usize)> = Vec::new();
    for &id in points {
        let Some(p) = map.point(id) else {
            continue;
        };
        if p.observations().contains_key(&target) {
            continue;
        }
        let Some(v) = visibility(p, &pose, &centre, camera, map) else {
            continue;
        };
        let radius = FUSE_TH * sf.powi(v.level as i32);
        let cands = tk.grid.in_area(
            v.pixel.x,
            v.pixel.y,
            radius,
            &(v.level.saturating_sub(1)..=v.level),
        );
        let mut best = (u32::MAX, usize::MAX);
        for i in cands {
            let kp = &tk.features.keypoints[i];
            let e2 = (v.pixel - Point2::new(kp.x, kp.y)).norm_squared();
            if e2 > CHI2 * sf.powi(2 * kp.octave as i32) {
                continue;
            }
            let d = hamming(&p.descriptor, &tk.features.descriptors[i]);
            if d < best.0 {
                best = (d, i);
            }
        }
        if best.0 <= MAX_DISTANCE {
            decisions.push((id, best.1));
        }
    }
    let mut changes = 0;
    for (id, i) in decisions {
        if map
            .point(id)
            .is_none_or(|p| p.observations().contains_key(&target))
        {
            continue;
        }
        let existing = map.keyframe(target).and_then(|k| k.points[i]);
        match existing {
            Some(other) if other == id => {}
            Some(other) => {
                let (n_id, n_other) = (
                    map.point(id).map_or(0, |p| p.n_observations()),
                    map.point(other).map_or(0, |p| p.n_observations()),
                );
                if n_other > n_id {
                    map.replace_point(id, other);
                } else {
                    map.replace_point(other, id);
                }
                changes += 1;
            }
            None => {
                if map.add_observation(id, target, i) {
                    changes += 1;
                }
            }
        }
    }
    changes
}
