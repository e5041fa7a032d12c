//! Loop candidates by appearance (ORB-SLAM2's `DetectLoopCandidates`): the keyframes whose bag
//! of words scores at least as well against the new keyframe as its own covisible neighbours
//! do, grouped with their covisible neighbours so that a place seen by several keyframes wins
//! over one lucky keyframe.

use std::collections::BTreeMap;

use crate::map::{KeyFrameId, Map};
use crate::place::{BowVector, Vocabulary};

/// Each keyframe's bag of words, computed once (keyframe ids are never reused, also across
/// merged maps).
#[derive(Debug, Clone, Default)]
pub struct BowCache {
    vectors: BTreeMap<KeyFrameId, BowVector>,
}

impl BowCache {
    /// The vector of `kf`, computed from its descriptors on first use; `None` if it is not
    /// in the map.
    pub(crate) fn get(
        &mut self,
        vocabulary: &Vocabulary,
        map: &Map,
        kf: KeyFrameId,
    ) -> Option<&BowVector> {
        let k = map.keyframe(kf)?;
        Some(
            self.vectors
                .entry(kf)
                .or_insert_with(|| BowVector::new(vocabulary, &k.features.descriptors)),
        )
    }

    /// Forgets keyframes no longer in the map.
    pub fn retain_in(&mut self, map: &Map) {
        self.vectors.retain(|k, _| map.keyframe(*k).is_some());
    }
}

/// Older keyframes, not covisible with `kf`, that look like it, best group first; at most
/// `max` (one per group: its best-scoring keyframe).
pub fn appearance_candidates(
    map: &Map,
    kf: KeyFrameId,
    vocabulary: &Vocabulary,
    cache: &mut BowCache,
    max: usize,
) -> Vec<KeyFrameId> {
    let Some(k) = map.keyframe(kf) else {
        return Vec::new();
    };
    let connected: Vec<KeyFrameId> = k.covisible().iter().map(|&(id, _)| id).collect();
    let Some(query) = cache.get(vocabulary, map, kf).cloned() else {
        return Vec::new();
    };
    // The bar: the worst score among the keyframes that do share the view.
    let mut min_score = f64::INFINITY;
    for c in &connected {
        if let Some(v) = cache.get(vocabulary, map, *c) {
            min_score = min_score.min(query.score(v));
        }
    }
    if !min_score.is_finite() {
        return Vec::new();
    }
    let older: Vec<KeyFrameId> = map
        .keyframes()
        .map(|o| o.id)
        .filter(|id| *id < kf && !connected.contains(id))
        .collect();
    let mut scores: BTreeMap<KeyFrameId, f64> = BTreeMap::new();
    for id in older {
        if let Some(v) = cache.get(vocabulary, map, id) {
            let s = query.score(v);
            if s >= min_score && s > 0.0 {
                scores.insert(id, s);
            }
        }
    }
    // Each candidate's group: itself and its 10 best covisible keyframes that also passed.
    let mut groups: Vec<(f64, f64, KeyFrameId)> = scores
        .iter()
        .map(|(&id, &s)| {
            let (mut total, mut best, mut best_id) = (s, s, id);
            for n in map
                .keyframe(id)
                .map(|o| o.best_covisible(10))
                .unwrap_or_default()
            {
                if let Some(&sn) = scores.get(&n) {
                    total += sn;
                    if sn > best {
                        (best, best_id) = (sn, n);
                    }
                }
            }
            (total, best, best_id)
        })
        .collect();
    let Some(top) = groups.iter().map(|g| g.0).reduce(f64::max) else {
        return Vec::new();
    };
    groups.retain(|g| g.0 >= 0.75 * top);
    groups.sort_by(|a, b| {
        b.0.total_cmp(&a.0)
            .then(b.1.total_cmp(&a.1))
            .then(a.2.cmp(&b.2))
    });
    let mut out: Vec<KeyFrameId> = Vec::new();
    for (_, _, id) in groups {
        if !out.contains(&id) {
            out.push(id);
        }
        if out.len() == max {
            break;
        }
    }
    tracing::debug!(?kf, min_score, candidates = ?out, "appearance loop candidates");
    out
}
