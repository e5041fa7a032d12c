//! The outputs known as a whole at the end of a run: every tracked frame and every keyframe in
//! the world frame, through alignments centred in time and the global BA of
//! [`crate::final_ba`], after the maps set aside at tracking losses.

use std::collections::BTreeMap;

use jointloc_geometry::trajectory::Trajectory;
use jointloc_geometry::{CameraToWorld, Sim3};
use jointloc_slam::local_mapping::GroundModel;
use jointloc_slam::map::KeyFrameId;

use crate::alignment::Tolerance;
use crate::error::Result;
use crate::final_ba::{FinalBaStats, FinalTie, RefinedKeyFrames};
use crate::ground::ElevationGround;
use crate::system::JointLoc;
use crate::ties::Tie;

/// A SLAM-frame trajectory with, per pose, the keyframe the SLAM expresses it through
/// (`None`: the poses are keyframes themselves).
struct Referenced<'a> {
    trajectory: &'a Trajectory,
    keyframes: Option<&'a [KeyFrameId]>,
}

/// The trajectories as known at the end.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct EndOutputs {
    /// Every tracked frame (`trajectory-final.tum`).
    pub frames: Option<Trajectory>,
    /// The keyframes (`keyframes.tum`).
    pub keyframes: Option<Trajectory>,
    /// The current map's global BA, when it ran.
    pub final_ba: Option<FinalBaStats>,
}

/// A map set aside after a tracking loss: its frames and keyframes in the world frame, through
/// its own alignment as it stood (`None` when it was never geo-referenced).
#[derive(Debug)]
pub(crate) struct EarlierMap {
    pub(crate) frames: Option<Trajectory>,
    pub(crate) keyframes: Option<Trajectory>,
    /// What merging it into the current map needs; `None` when it was never geo-referenced.
    pub(crate) merge: Option<crate::map_merge::Mergeable>,
}

impl JointLoc {
    /// The outputs known as a whole at the end: every tracked frame and every keyframe in the
    /// world frame (empty before the first alignment), from the first frame reported in the
    /// world frame on, as ORB-SLAM2 saves trajectories (through the keyframes' final poses;
    /// `trajectory.tum` is what was known online). The frames of the two-view initialisation
    /// before it are left out (up to 1 m off after the map settled, on crater-easy-s103), so
    /// the online and end files cover the same frames.
    ///
    /// Each pose goes through the alignment fitted to the fixes nearest to it in time, as many
    /// as the alignment's window holds online (`alignment_window_fixes`): the latest alignment
    /// alone fits the recent fixes, and SLAM drift since an early frame would carry into it.
    /// Then, with [`JointLocConfig::final_ba`], the whole map is bundle-adjusted once more in
    /// the world frame with every fix ([`crate::final_ba`]). z is altimeter-aided as online,
    /// over a window centred on the pose, from every frame's reading. Maps set aside after a
    /// loss come first, each as it was at the loss.
    pub(crate) fn end_outputs(&self) -> Result<EndOutputs> {
        let current = self.map_end_outputs()?;
        let frames = self.earlier_maps.iter().map(|m| m.frames.as_ref());
        let keyframes = self.earlier_maps.iter().map(|m| m.keyframes.as_ref());
        Ok(EndOutputs {
            frames: concat(frames.chain([current.frames.as_ref()]))?,
            keyframes: concat(keyframes.chain([current.keyframes.as_ref()]))?,
            final_ba: current.final_ba,
        })
    }

    /// [`JointLoc::end_outputs`] of the current map alone.
    pub(crate) fn map_end_outputs(&self) -> Result<EndOutputs> {
        let none = EndOutputs {
            frames: None,
            keyframes: None,
            final_ba: None,
        };
        let (Some(_), Some(_)) = (&self.alignment, self.first_world_timestamp) else {
            return Ok(none);
        };
        let mut aligner = self.centred_aligner();
        // The refinement is an improvement, not a requirement: if it fails, the end outputs
        // still go out through the local alignments.
        let refined = if self.config.final_ba.enabled {
            self.refine_map(&mut aligner).unwrap_or_else(|e| {
                tracing::warn!(error = %e, "final global BA failed; end outputs through the local alignments");
                None
            })
        } else {
            None
        };
        let frames = self.slam.trajectory()?;
        let frame_keyframes = self.slam.trajectory_keyframes();
        let frames = Referenced {
            trajectory: &frames,
            keyframes: Some(&frame_keyframes),
        };
        let keyframes = self.slam.keyframe_trajectory()?;
        let keyframes = Referenced {
            trajectory: &keyframes,
            keyframes: None,
        };
        let refined = refined.as_ref();
        Ok(EndOutputs {
            frames: self.offline_world(&frames, &frames, &mut aligner, refined)?,
            keyframes: self.offline_world(&keyframes, &frames, &mut aligner, refined)?,
            final_ba: refined.map(|r| r.stats),
        })
    }

    /// The global BA of the current map in the world frame, starting from the local
    /// alignments, with every fix tied to a keyframe still in the map.
    fn refine_map(&self, aligner: &mut CentredAligner<'_>) -> Result<Option<RefinedKeyFrames>> {
        let mut ties = Vec::with_capacity(2 * self.ties.len());
        let threshold = self.config.inlier_threshold_m;
        let map = self.slam.map();
        for t in &self.ties {
            // On a keyframe still in the map (one culled since hands its fixes on).
            let mut t = t.clone();
            t.refresh(map, self.fixes[t.record].timestamp);
            let t = &t;
            let loose = self.config.range_looseness(t.altitude);
            ties.push(FinalTie {
                keyframe: t.keyframe,
                point_in_camera: t.ground_in_kf,
                world: self.corrected(&t.world_ground),
                weight: t.weight,
                sigma_scale: 1.0,
                vertical_sigma_scale: loose,
                tolerance: Tolerance {
                    horizontal_m: threshold,
                    vertical_m: threshold * loose,
                },
            });
            if self.config.nadir_sigma_scale > 0.0 {
                ties.push(FinalTie {
                    keyframe: t.keyframe,
                    point_in_camera: t.centre_in_kf,
                    world: self.corrected(&t.world_camera),
                    weight: t.weight,
                    sigma_scale: self.nadir_sigma_scale(t),
                    vertical_sigma_scale: loose,
                    tolerance: Tolerance::sphere(threshold * loose),
                });
            }
        }
        let ground = self
            .altitude
            .ground()
            .has_model()
            .then(|| ElevationGround(self.altitude.ground().clone()));
        crate::final_ba::refine(
            self.slam.map(),
            self.slam.undistorter(),
            &self.config.slam.local_mapping.ba,
            &self.config.final_ba,
            &mut |t| aligner.sim_at(t),
            &ties,
            ground.as_ref().map(|g| g as &dyn GroundModel),
            !self.slam.retired_keyframes().is_empty(),
        )
    }

    /// `slam` in the world frame as known at the end; `frames`: the SLAM's frame trajectory,
    /// whose altimeter readings aid z.
    fn offline_world(
        &self,
        slam: &Referenced<'_>,
        frames: &Referenced<'_>,
        aligner: &mut CentredAligner<'_>,
        refined: Option<&RefinedKeyFrames>,
    ) -> Result<Option<Trajectory>> {
        if self.first_world_timestamp.is_none() {
            return Ok(None);
        }
        let keep: Vec<usize> = (0..slam.trajectory.len())
            .filter(|&i| self.reported_at_end(slam.trajectory.timestamps[i]))
            .collect();
        if keep.is_empty() {
            return Ok(None);
        }
        let mut world =
            |r: &Referenced<'_>, indices: &mut dyn Iterator<Item = usize>| -> Vec<CameraToWorld> {
                let t = r.trajectory;
                indices
                    .map(|i| {
                        let (ts, p) = (t.timestamps[i], &t.poses[i]);
                        let s = aligner.sim_at(ts);
                        match refined {
                            Some(refined) => {
                                let reference = r.keyframes.and_then(|k| k.get(i).copied());
                                refined.world_pose(ts, &s, p, reference)
                            }
                            None => s.transform_pose(p),
                        }
                    })
                    .collect()
            };
        let mut poses = world(slam, &mut keep.iter().copied());
        let frame_poses = world(frames, &mut (0..frames.trajectory.len()));
        let stamps: Vec<f64> = keep
            .iter()
            .map(|&i| slam.trajectory.timestamps[i])
            .collect();
        let frames = frames.trajectory;
        let readings: Vec<Option<f64>> = frames
            .timestamps
            .iter()
            .map(|&ts| {
                self.altimeter
                    .binary_search_by(|(t, _)| t.total_cmp(&ts))
                    .ok()
                    .map(|i| self.altimeter[i].1)
            })
            .collect();
        let shifts = crate::altitude::z_shifts(
            &frames.timestamps,
            &frame_poses,
            &readings,
            self.altitude.ground(),
            self.altitude.scaled(self.config.final_altitude_window_s),
            &stamps,
        );
        for (p, dz) in poses.iter_mut().zip(shifts) {
            if let Some(dz) = dz {
                p.0.translation.vector.z += dz;
            }
        }
        Ok(Some(
            Trajectory::new(stamps, poses).map_err(jointloc_slam::error::SlamError::from)?,
        ))
    }

    /// Alignments over windows of fixes centred in time, with the keyframes' current poses.
    fn centred_aligner(&self) -> CentredAligner<'_> {
        let map = self.slam.map();
        let mut timed: Vec<(f64, Tie)> = self
            .ties
            .iter()
            .map(|tie| {
                let mut tie = tie.clone();
                tie.refresh(map, self.fixes[tie.record].timestamp);
                (self.fixes[tie.record].timestamp, tie)
            })
            .collect();
        timed.sort_by(|x, y| x.0.total_cmp(&y.0));
        let (times, ties): (Vec<f64>, Vec<Tie>) = timed.into_iter().unzip();
        let mut part_ends: Vec<f64> = self.merged_spans.iter().map(|s| s.1).collect();
        part_ends.sort_by(f64::total_cmp);
        CentredAligner {
            system: self,
            times,
            ties,
            window: self.alignment_window_fixes(),
            part_ends,
            fits: BTreeMap::new(),
        }
    }
}

/// The trajectories merged in time; `None` when all are.
fn concat<'a>(parts: impl Iterator<Item = Option<&'a Trajectory>>) -> Result<Option<Trajectory>> {
    let mut timed: Vec<(f64, CameraToWorld)> = Vec::new();
    let mut any = false;
    for t in parts.flatten() {
        any = true;
        timed.extend(t.timestamps.iter().copied().zip(t.poses.iter().copied()));
    }
    if !any {
        return Ok(None);
    }
    // A map merged into the current one holds frames from before a map that was not.
    timed.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (stamps, poses) = timed.into_iter().unzip();
    Ok(Some(
        Trajectory::new(stamps, poses).map_err(jointloc_slam::error::SlamError::from)?,
    ))
}

/// Maps SLAM-frame poses to the world through the alignment of the fixes nearest in time
/// (one fit per window: windows change only between fixes); the latest alignment where a
/// window has no fit. A window stays within one part of a merged map (the time up to the end
/// of a map merged into it, or after the last): the parts are placed relative to each other
/// only by their own alignments, so a window across the seam would fit neither.
struct CentredAligner<'a> {
    system: &'a JointLoc,
    times: Vec<f64>,
    ties: Vec<Tie>,
    /// Fixes per window (0: all of the part).
    window: usize,
    /// Last times of the maps merged into this one, ascending.
    part_ends: Vec<f64>,
    fits: BTreeMap<(usize, usize), Option<Sim3>>,
}

impl CentredAligner<'_> {
    /// The SLAM→world similarity at `timestamp`.
    fn sim_at(&mut self, timestamp: f64) -> Sim3 {
        let latest = self.system.alignment.as_ref().map(|a| a.sim3);
        if self.ties.is_empty() {
            return latest.unwrap_or_else(Sim3::identity);
        }
        // The part of `timestamp` as a range of ties (times ascending).
        let part = self.part_ends.partition_point(|&end| end < timestamp);
        let first = match part {
            0 => 0,
            k => self.times.partition_point(|&x| x <= self.part_ends[k - 1]),
        };
        let last = match self.part_ends.get(part) {
            Some(&end) => self.times.partition_point(|&x| x <= end),
            None => self.times.len(),
        };
        if first >= last {
            return latest.unwrap_or_else(Sim3::identity);
        }
        let window = match self.window {
            0 => last - first,
            w => w.min(last - first),
        };
        let at = self.times.partition_point(|&x| x < timestamp);
        let start = at.saturating_sub(window / 2).clamp(first, last - window);
        let (system, ties) = (self.system, &self.ties);
        let fit = *self
            .fits
            .entry((start, window))
            .or_insert_with(|| system.fit_ties(ties, start..start + window).map(|f| f.sim3));
        fit.or(latest).unwrap_or_else(Sim3::identity)
    }
}
