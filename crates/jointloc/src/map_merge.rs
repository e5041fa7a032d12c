//! One map at the end: a SLAM map set aside after a tracking loss is merged back into the
//! current one once both are tied to the world. Each map's alignment (SLAM → world, from its
//! own fixes) gives the similarity between their SLAM frames, `S_current⁻¹ · S_earlier`;
//! the earlier map's keyframes, points, frames and fix ties are moved through it, and from
//! then on the two are one map: the global BA at the end adjusts both with every fix, and the
//! end outputs go through one set of alignments. ORB-SLAM3 merges maps when place recognition
//! finds a common place; here the fixes already say where both are, so no common ground is
//! needed (after a loss the UAV is usually over ground the old map never saw).

use jointloc_geometry::Sim3;

use crate::end_outputs::EarlierMap;
use crate::system::JointLoc;
use crate::ties::Tie;

/// What merging a map set aside needs: the SLAM's index of it, its alignment as it stood at
/// the loss, its ties, and the time span it reported world poses over.
#[derive(Debug)]
pub(crate) struct Mergeable {
    pub(crate) slam_index: usize,
    pub(crate) slam_to_world: Sim3,
    pub(crate) ties: Vec<Tie>,
    /// Spans of time (first, last world pose) it reported world poses over, with those of
    /// the maps merged into it before.
    pub(crate) spans: Vec<(f64, f64)>,
}

impl JointLoc {
    /// Merges the geo-referenced maps set aside into the current map when the current map has
    /// its own alignment from as many fixes as `merge_maps_after_s` holds at the search rate
    /// (`at_end`: from any number); true when one was merged (the caller re-fits the
    /// alignment).
    pub(crate) fn merge_earlier_maps(&mut self, at_end: bool) -> bool {
        let after = self.config.merge_maps_after_s;
        let Some(current) = self.alignment.as_ref().map(|a| a.sim3) else {
            return false;
        };
        let own_ties = self.ties.len();
        if after <= 0.0 || (!at_end && own_ties < self.fixes_in(after, 1)) {
            return false;
        }
        let world_to_current = current.inverse();
        let mut merged = false;
        let mut kept: Vec<EarlierMap> = Vec::with_capacity(self.earlier_maps.len());
        let mut earlier_ties: Vec<Tie> = Vec::new();
        for mut earlier in std::mem::take(&mut self.earlier_maps) {
            let Some(m) = earlier.merge.take() else {
                kept.push(earlier);
                continue;
            };
            let s = world_to_current.compose(&m.slam_to_world);
            match self.slam.merge_set_aside(m.slam_index, &s) {
                Ok(Some(report)) => {
                    tracing::info!(
                        keyframes = report.keyframes,
                        points = report.points,
                        ties = m.ties.len(),
                        scale = s.scale,
                        "map set aside after a loss merged into the current one"
                    );
                    earlier_ties.extend(m.ties.into_iter().map(|t| moved(t, &s)));
                    self.merged_spans.extend(m.spans);
                    self.maps_merged += 1;
                    merged = true;
                }
                Ok(None) => kept.push(earlier),
                Err(e) => {
                    tracing::warn!(error = %e, "map set aside after a loss not merged");
                    kept.push(earlier);
                }
            }
        }
        self.earlier_maps = kept;
        if merged {
            // Ties stay in the order of their fixes: the alignment's window is the newest.
            earlier_ties.append(&mut self.ties);
            earlier_ties.sort_by_key(|t| t.record);
            self.ties = earlier_ties;
        }
        merged
    }

    /// Whether a pose at `timestamp` of the current map is reported in the world frame at the
    /// end: from the current map's first world pose on, and within the spans of the maps
    /// merged into it (the frames of a new map's initialisation in between are not).
    pub(crate) fn reported_at_end(&self, timestamp: f64) -> bool {
        self.first_world_timestamp.is_some_and(|t0| timestamp >= t0)
            || self
                .merged_spans
                .iter()
                .any(|&(a, b)| (a..=b).contains(&timestamp))
    }
}

/// A tie of the earlier map moved into the current map's frame by `s`: positions in a
/// keyframe's camera frame scale with the map, SLAM positions are transformed.
fn moved(mut t: Tie, s: &Sim3) -> Tie {
    t.centre_in_kf.coords *= s.scale;
    t.ground_in_kf.coords *= s.scale;
    t.slam_camera = s.transform_point(&t.slam_camera);
    t.slam_ground = s.transform_point(&t.slam_ground);
    t
}
