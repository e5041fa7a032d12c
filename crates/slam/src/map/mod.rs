//! The SLAM map (ORB-SLAM2's `Map`, `KeyFrame`, `MapPoint`): keyframes, map points, the
//! observations between them, the covisibility graph and the spanning tree.
//!
//! One owner mutates the map (tracking and local mapping take turns through a lock held by the
//! system); every collection is ordered by id so that runs are reproducible.

mod ids;
mod keyframe;
mod map_point;
mod merge;

use std::collections::BTreeMap;

use jointloc_features::orb::{Descriptor, hamming};
use nalgebra::Vector3;

pub use ids::{KeyFrameId, MapPointId};
pub use keyframe::{GlobalFix, KeyFrame, RetiredKeyFrame};
pub use map_point::MapPoint;
pub use merge::MergeReport;

/// Covisibility edges need at least this many shared points (ORB-SLAM2: 15).
pub const COVISIBILITY_THRESHOLD: usize = 15;

/// Keyframes and map points.
#[derive(Debug, Clone)]
pub struct Map {
    keyframes: BTreeMap<KeyFrameId, KeyFrame>,
    points: BTreeMap<MapPointId, MapPoint>,
    next_keyframe: u64,
    next_point: u64,
    /// Pyramid scale factor and levels of the features (for points' distance ranges).
    scale_factor: f64,
    n_levels: usize,
}

impl Map {
    /// An empty map for features from a pyramid with `scale_factor` and `n_levels`.
    pub fn new(scale_factor: f64, n_levels: usize) -> Self {
        Self {
            keyframes: BTreeMap::new(),
            points: BTreeMap::new(),
            next_keyframe: 0,
            next_point: 0,
            scale_factor,
            n_levels: n_levels.max(1),
        }
    }

    /// An empty map that continues this one's keyframe and point ids, so that an id of this
    /// map never names something in the new one (a new map after a tracking loss).
    pub fn successor(&self) -> Self {
        Self {
            next_keyframe: self.next_keyframe,
            next_point: self.next_point,
            ..Self::new(self.scale_factor, self.n_levels)
        }
    }

    pub fn scale_factor(&self) -> f64 {
        self.scale_factor
    }

    pub fn n_levels(&self) -> usize {
        self.n_levels
    }

    pub fn n_keyframes(&self) -> usize {
        self.keyframes.len()
    }

    pub fn n_points(&self) -> usize {
        self.points.len()
    }

    pub fn keyframe(&self, id: KeyFrameId) -> Option<&KeyFrame> {
        self.keyframes.get(&id)
    }

    pub fn keyframe_mut(&mut self, id: KeyFrameId) -> Option<&mut KeyFrame> {
        self.keyframes.get_mut(&id)
    }

    pub fn point(&self, id: MapPointId) -> Option<&MapPoint> {
        self.points.get(&id)
    }

    pub fn point_mut(&mut self, id: MapPointId) -> Option<&mut MapPoint> {
        self.points.get_mut(&id)
    }

    /// Keyframes in id order.
    pub fn keyframes(&self) -> impl Iterator<Item = &KeyFrame> {
        self.keyframes.values()
    }

    /// Map points in id order.
    pub fn points(&self) -> impl Iterator<Item = &MapPoint> {
        self.points.values()
    }

    /// The most recent keyframe.
    pub fn last_keyframe(&self) -> Option<&KeyFrame> {
        self.keyframes.values().next_back()
    }

    /// Adds a keyframe (its `id` is assigned here) and returns its id.
    pub fn insert_keyframe(&mut self, mut kf: KeyFrame) -> KeyFrameId {
        let id = KeyFrameId(self.next_keyframe);
        self.next_keyframe += 1;
        kf.id = id;
        kf.points = vec![None; kf.features.len()];
        self.keyframes.insert(id, kf);
        id
    }

    /// Creates a point at `position` observed by keypoint `index` of `keyframe`.
    /// Returns `None` if the keyframe or keypoint does not exist or the keypoint is taken.
    pub fn insert_point(
        &mut self,
        position: Vector3<f64>,
        keyframe: KeyFrameId,
        index: usize,
    ) -> Option<MapPointId> {
        let kf = self.keyframes.get(&keyframe)?;
        if kf.points.get(index).is_none_or(Option::is_some)
            || !position.iter().all(|v| v.is_finite())
        {
            return None;
        }
        let descriptor = kf.features.descriptors[index];
        let id = MapPointId(self.next_point);
        self.next_point += 1;
        self.points.insert(
            id,
            MapPoint {
                id,
                position,
                descriptor,
                normal: Vector3::z(),
                min_distance: 0.0,
                max_distance: f64::INFINITY,
                reference: keyframe,
                first_keyframe: keyframe,
                visible: 1,
                found: 1,
                observations: BTreeMap::new(),
            },
        );
        self.add_observation(id, keyframe, index);
        self.update_normal_and_depth(id);
        Some(id)
    }

    /// Records that keypoint `index` of `keyframe` observes `point`. False (and no change) if the
    /// keypoint already observes another point or the point is already seen by the keyframe.
    pub fn add_observation(
        &mut self,
        point: MapPointId,
        keyframe: KeyFrameId,
        index: usize,
    ) -> bool {
        let (Some(kf), Some(p)) = (
            self.keyframes.get_mut(&keyframe),
            self.points.get_mut(&point),
        ) else {
            return false;
        };
        match kf.points.get(index) {
            Some(None) => {}
            _ => return false,
        }
        if p.observations.contains_key(&keyframe) {
            return false;
        }
        kf.points[index] = Some(point);
        p.observations.insert(keyframe, index);
        true
    }

    /// Removes `keyframe`'s observation of `point`; a point left with fewer than two
    /// observations is erased (ORB-SLAM2's `EraseObservation`).
    pub fn remove_observation(&mut self, point: MapPointId, keyframe: KeyFrameId) {
        let Some(p) = self.points.get_mut(&point) else {
            return;
        };
        let Some(index) = p.observations.remove(&keyframe) else {
            return;
        };
        if p.reference == keyframe
            && let Some((&first, _)) = p.observations.iter().next()
        {
            p.reference = first;
        }
        let erase = p.observations.len() < 2;
        if let Some(kf) = self.keyframes.get_mut(&keyframe)
            && kf.points.get(index) == Some(&Some(point))
        {
            kf.points[index] = None;
        }
        if erase {
            self.erase_point(point);
        }
    }

    /// Erases a point and every observation of it.
    pub fn erase_point(&mut self, point: MapPointId) {
        let Some(p) = self.points.remove(&point) else {
            return;
        };
        for (kf, index) in p.observations {
            if let Some(kf) = self.keyframes.get_mut(&kf)
                && kf.points.get(index) == Some(&Some(point))
            {
                kf.points[index] = None;
            }
        }
    }

    /// Merges `old` into `new` (duplicate landmarks found by fusion): `old`'s observations move
    /// to `new` where the keyframe does not see `new` already; `old` is erased.
    pub fn replace_point(&mut self, old: MapPointId, new: MapPointId) {
        if old == new || !self.points.contains_key(&new) {
            return;
        }
        let Some(o) = self.points.remove(&old) else {
            return;
        };
        for (kf_id, index) in &o.observations {
            let Some(kf) = self.keyframes.get_mut(kf_id) else {
                continue;
            };
            if kf.points.get(*index) != Some(&Some(old)) {
                continue;
            }
            kf.points[*index] = None;
            let n = self.points.get_mut(&new).expect("checked above");
            if !n.observations.contains_key(kf_id) {
                kf.points[*index] = Some(new);
                n.observations.insert(*kf_id, *index);
            }
        }
        let n = self.points.get_mut(&new).expect("checked above");
        n.visible += o.visible;
        n.found += o.found;
        self.update_descriptor(new);
    }

    /// Chooses the observation descriptor with the smallest median Hamming distance to the
    /// others as the point's descriptor.
    pub fn update_descriptor(&mut self, point: MapPointId) {
        let Some(p) = self.points.get(&point) else {
            return;
        };
        let descs: Vec<Descriptor> = p
            .observations
            .iter()
            .filter_map(|(kf, &i)| self.keyframes.get(kf)?.features.descriptors.get(i).copied())
            .collect();
        if descs.is_empty() {
            return;
        }
        let mut best = (u32::MAX, 0);
        for (i, a) in descs.iter().enumerate() {
            let mut d: Vec<u32> = descs.iter().map(|b| hamming(a, b)).collect();
            d.sort_unstable();
            let median = d[(d.len() - 1) / 2];
            if median < best.0 {
                best = (median, i);
            }
        }
        if let Some(p) = self.points.get_mut(&point) {
            p.descriptor = descs[best.1];
        }
    }

    /// Recomputes the mean viewing direction and the scale-invariance distance range from the
    /// reference keyframe's observation (ORB-SLAM2's `UpdateNormalAndDepth`).
    pub fn update_normal_and_depth(&mut self, point: MapPointId) {
        let Some(p) = self.points.get(&point) else {
            return;
        };
        let mut normal = Vector3::zeros();
        let mut n = 0;
        for kf in p.observations.keys() {
            if let Some(kf) = self.keyframes.get(kf) {
                let dir = p.position - kf.centre();
                if dir.norm() > 0.0 {
                    normal += dir.normalize();
                    n += 1;
                }
            }
        }
        let range = self.keyframes.get(&p.reference).and_then(|kf| {
            let index = *p.observations.get(&p.reference)?;
            let level = kf.features.keypoints.get(index)?.octave;
            let dist = (p.position - kf.centre()).norm();
            let max = dist * self.scale_factor.powi(level as i32);
            let min = max / self.scale_factor.powi(self.n_levels as i32 - 1);
            Some((min, max))
        });
        let p = self.points.get_mut(&point).expect("present");
        if n > 0 && normal.norm() > 0.0 {
            p.normal = (normal / f64::from(n)).normalize();
        }
        if let Some((min, max)) = range {
            p.min_distance = min;
            p.max_distance = max;
        }
    }

    /// Rebuilds `keyframe`'s covisibility edges from shared points (an edge needs
    /// [`COVISIBILITY_THRESHOLD`] shared points; with none above it, the strongest neighbour is
    /// connected), mirrors them on the neighbours, and gives a new keyframe its spanning-tree
    /// parent: the strongest covisible keyframe.
    pub fn update_connections(&mut self, keyframe: KeyFrameId) {
        let Some(kf) = self.keyframes.get(&keyframe) else {
            return;
        };
        let mut counts: BTreeMap<KeyFrameId, usize> = BTreeMap::new();
        for p in kf.points.iter().flatten() {
            if let Some(p) = self.points.get(p) {
                for other in p.observations.keys().filter(|&&o| o != keyframe) {
                    *counts.entry(*other).or_default() += 1;
                }
            }
        }
        if counts.is_empty() {
            return;
        }
        let mut edges: BTreeMap<KeyFrameId, usize> = counts
            .iter()
            .filter(|&(_, &c)| c >= COVISIBILITY_THRESHOLD)
            .map(|(&k, &c)| (k, c))
            .collect();
        if edges.is_empty() {
            let (&k, &c) = counts
                .iter()
                .max_by(|a, b| a.1.cmp(b.1).then(b.0.cmp(a.0)))
                .expect("non-empty");
            edges.insert(k, c);
        }
        for (&other, &w) in &edges {
            if let Some(o) = self.keyframes.get_mut(&other) {
                o.covisibility.insert(keyframe, w);
                o.ordered = ordered(&o.covisibility);
            }
        }
        let is_first = self.keyframes.keys().next() == Some(&keyframe);
        let kf = self.keyframes.get_mut(&keyframe).expect("present");
        kf.covisibility = edges;
        kf.ordered = ordered(&kf.covisibility);
        // Only a keyframe without children gets a parent here: it has no descendants, so the
        // tree stays acyclic when a root left by a retired keyframe is reconnected.
        if kf.parent.is_none() && kf.children.is_empty() && !is_first {
            let parent = kf.ordered[0].0;
            kf.parent = Some(parent);
            if let Some(p) = self.keyframes.get_mut(&parent) {
                p.children.insert(keyframe);
            }
        }
    }

    /// Removes a keyframe (keyframe culling): its observations, its covisibility edges, and its
    /// place in the spanning tree, whose children are re-attached to the remaining keyframe
    /// they share most points with among the erased keyframe's parent and already re-attached
    /// siblings (ORB-SLAM2's `SetBadFlag`). The first keyframe and spanning-tree roots (the
    /// children of retired keyframes) are never erased: a culled keyframe is remembered
    /// relative to its parent.
    pub fn erase_keyframe(&mut self, keyframe: KeyFrameId) -> bool {
        if self.keyframes.keys().next() == Some(&keyframe) {
            return false;
        }
        let Some(kf) = self.keyframes.get(&keyframe) else {
            return false;
        };
        if kf.parent.is_none() {
            return false;
        }
        let neighbours: Vec<KeyFrameId> = kf.covisibility.keys().copied().collect();
        let observed: Vec<MapPointId> = kf.points.iter().flatten().copied().collect();
        let parent = kf.parent;
        let mut children: Vec<KeyFrameId> = kf.children.iter().copied().collect();
        for n in neighbours {
            if let Some(o) = self.keyframes.get_mut(&n) {
                o.covisibility.remove(&keyframe);
                o.ordered = ordered(&o.covisibility);
            }
        }
        for p in observed {
            self.remove_observation(p, keyframe);
        }
        let mut candidates: Vec<KeyFrameId> = parent.into_iter().collect();
        while !children.is_empty() {
            let mut best: Option<(usize, usize, KeyFrameId)> = None;
            for (ci, c) in children.iter().enumerate() {
                let Some(child) = self.keyframes.get(c) else {
                    continue;
                };
                for cand in &candidates {
                    let w = child.covisibility_weight(*cand);
                    if best.is_none_or(|(bw, _, _)| w > bw) {
                        best = Some((w, ci, *cand));
                    }
                }
            }
            let (ci, new_parent) = match best {
                Some((w, ci, cand)) if w > 0 => (ci, cand),
                _ => break,
            };
            let child = children.remove(ci);
            self.set_parent(child, new_parent);
            candidates.push(child);
        }
        if let Some(parent) = parent {
            for child in children {
                self.set_parent(child, parent);
            }
            if let Some(p) = self.keyframes.get_mut(&parent) {
                p.children.remove(&keyframe);
            }
        }
        self.keyframes.remove(&keyframe);
        true
    }

    /// Removes a keyframe for the sliding-window cap (see `SystemConfig::max_keyframes`):
    /// unlike culling, its points stay while any other keyframe observes them (only those seen
    /// by it alone are erased), its covisibility edges go, and its spanning-tree children
    /// become roots. Returns what the trajectory needs to keep of it.
    pub fn retire_keyframe(&mut self, keyframe: KeyFrameId) -> Option<RetiredKeyFrame> {
        let kf = self.keyframes.remove(&keyframe)?;
        for n in kf.covisibility.keys() {
            if let Some(o) = self.keyframes.get_mut(n) {
                o.covisibility.remove(&keyframe);
                o.ordered = ordered(&o.covisibility);
            }
        }
        for id in kf.points.iter().flatten() {
            let Some(p) = self.points.get_mut(id) else {
                continue;
            };
            p.observations.remove(&keyframe);
            match p.observations.keys().next() {
                None => {
                    self.points.remove(id);
                }
                Some(&first) if p.reference == keyframe => {
                    p.reference = first;
                    self.update_normal_and_depth(*id);
                }
                Some(_) => {}
            }
        }
        if let Some(parent) = kf.parent
            && let Some(p) = self.keyframes.get_mut(&parent)
        {
            p.children.remove(&keyframe);
        }
        for c in &kf.children {
            if let Some(c) = self.keyframes.get_mut(c) {
                c.parent = None;
            }
        }
        Some(RetiredKeyFrame {
            id: keyframe,
            frame_index: kf.frame_index,
            timestamp: kf.timestamp,
            pose: kf.pose,
        })
    }

    fn set_parent(&mut self, child: KeyFrameId, parent: KeyFrameId) {
        if let Some(c) = self.keyframes.get_mut(&child) {
            c.parent = Some(parent);
        }
        if let Some(p) = self.keyframes.get_mut(&parent) {
            p.children.insert(child);
        }
    }

    /// The local window of `keyframe`: itself and its `n` strongest covisible keyframes.
    pub fn local_window(&self, keyframe: KeyFrameId, n: usize) -> Vec<KeyFrameId> {
        let Some(kf) = self.keyframes.get(&keyframe) else {
            return Vec::new();
        };
        let mut out = vec![keyframe];
        out.extend(kf.best_covisible(n));
        out
    }
}

fn ordered(edges: &BTreeMap<KeyFrameId, usize>) -> Vec<(KeyFrameId, usize)> {
    let mut v: Vec<(KeyFrameId, usize)> = edges.iter().map(|(&k, &w)| (k, w)).collect();
    v.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    v
}

#[cfg(test)]
mod tests;
