//! Merging a map set aside after a tracking loss back into the current one, once a similarity
//! between their SLAM frames is known (in JointLoc: through the world, from the fixes that tie
//! each map to it; ORB-SLAM3's map merging finds it by place recognition instead).

use jointloc_geometry::Sim3;

use super::{KeyFrameId, Map};
use crate::error::{Result, SlamError};

/// What a merge took in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct MergeReport {
    pub keyframes: usize,
    pub points: usize,
}

impl Map {
    /// The error [`Map::absorb`] would return, without changing anything.
    pub fn check_absorb(&self, earlier: &Map, earlier_to_this: &Sim3) -> Result<()> {
        let s = earlier_to_this;
        if !(s.scale.is_finite()
            && s.scale > 0.0
            && s.translation.iter().all(|v| v.is_finite())
            && s.rotation.coords.iter().all(|v| v.is_finite()))
        {
            return Err(SlamError::NonFinite("similarity of a map merge"));
        }
        let clash = earlier
            .keyframes
            .keys()
            .any(|k| self.keyframes.contains_key(k))
            || earlier.points.keys().any(|p| self.points.contains_key(p));
        if clash {
            return Err(SlamError::InvalidProblem(
                "map merge: the earlier map shares ids with this one".into(),
            ));
        }
        Ok(())
    }

    /// Takes in `earlier`, a map this one succeeded ([`Map::successor`]: its ids are all below
    /// this map's), moved into this map's frame by `earlier_to_this`: keyframe poses and
    /// points transformed, points' distance ranges scaled. The earlier map's newest keyframe
    /// becomes the spanning-tree parent of this map's first keyframe (one tree, so the
    /// essential graph of a later loop stays connected); no covisibility links the two parts
    /// until keyframes observe points of both. Errors (and no change) on a similarity that
    /// is not finite with a positive scale, or on an id of `earlier` that this map uses.
    pub fn absorb(&mut self, earlier: Map, earlier_to_this: &Sim3) -> Result<MergeReport> {
        self.check_absorb(&earlier, earlier_to_this)?;
        let s = earlier_to_this;
        let first_here = self.keyframes.keys().next().copied();
        let newest_earlier: Option<KeyFrameId> = earlier.keyframes.keys().next_back().copied();
        let report = MergeReport {
            keyframes: earlier.keyframes.len(),
            points: earlier.points.len(),
        };
        for (id, mut kf) in earlier.keyframes {
            kf.pose = s.transform_pose(&kf.pose.inverse()).inverse();
            for fix in &mut kf.global_fixes {
                fix.point_in_camera *= s.scale;
            }
            self.keyframes.insert(id, kf);
        }
        for (id, mut p) in earlier.points {
            p.position = s.transform_point(&p.position.into()).coords;
            p.normal = s.rotation * p.normal;
            p.min_distance *= s.scale;
            p.max_distance *= s.scale;
            self.points.insert(id, p);
        }
        self.next_keyframe = self.next_keyframe.max(earlier.next_keyframe);
        self.next_point = self.next_point.max(earlier.next_point);
        if let (Some(root), Some(parent)) = (first_here, newest_earlier)
            && self
                .keyframes
                .get(&root)
                .is_some_and(|k| k.parent.is_none())
        {
            self.set_parent(root, parent);
        }
        tracing::info!(
            keyframes = report.keyframes,
            points = report.points,
            scale = s.scale,
            "earlier map merged"
        );
        Ok(report)
    }
}
