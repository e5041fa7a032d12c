//! The JointLoc driver (paper §III-A, §III-C). Every frame is tracked by the SLAM; every k-th
//! frame also goes to absolute localisation, whose fix (x, y from the map, z from the altimeter
//! over the map's elevation) is tied to the keyframe that was current at that frame. In the
//! sequential mode the search runs inline (deterministic); in the threaded mode it runs on its
//! own thread and its fix is applied when it arrives, a few frames later. The SLAM→world
//! similarity is re-fitted from the most recent fixes against the keyframes' *current* poses
//! whenever a fix arrives, and each fix becomes a global-position factor `w · ρ(‖S·C − P‖²)`
//! of its keyframe in the local BA, so the map itself is pulled into the world frame. Poses
//! are reported in the world frame once an alignment exists (z aided by every frame's
//! altimeter reading, [`crate::altitude`]), and flagged as not geo-referenced before.

use std::collections::{BTreeMap, BTreeSet};
use std::time::Instant;

use image::GrayImage;
use jointloc_absloc::{AbsLocalizer, Outcome, Prior, heading_from_rotation};
use jointloc_geometry::trajectory::Trajectory;
use jointloc_geometry::{CameraToWorld, PinholeCamera, Sim3};
use jointloc_slam::local_mapping::GroundModel;
use jointloc_slam::map::{GlobalFix, KeyFrameId, MapPointId};
use jointloc_slam::orb::GrayImageView;
use jointloc_slam::system::System;
use jointloc_slam::tracking::TrackingState;
use nalgebra::{Isometry3, Point3, Vector3};
use serde::Serialize;

use crate::alignment::{self, Correspondence, SlamToWorld};
use crate::altitude::AltitudeFilter;
use crate::config::JointLocConfig;
use crate::dead_reckoning::{self, GroundTrack};
use crate::error::Result;
use crate::final_ba::{FinalBaStats, FinalTie, RefinedKeyFrames};
use crate::ground::ElevationGround;
use crate::terrain_shift::{TerrainCorrection, estimate_shift};
use crate::worker::AbsoluteWorker;

/// An absolute fix as the fusion saw it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FixRecord {
    pub frame: usize,
    pub timestamp: f64,
    /// World (x, y) of the map point under the image centre, z the altimeter reading.
    pub position: [f64; 3],
    pub confidence: f64,
    pub ssim: f64,
    pub match_score: f64,
    pub tile: usize,
    pub inliers: usize,
    /// Tiles matched for this fix, and whether the whole map was searched.
    pub searched_tiles: usize,
    pub global: bool,
    /// Whether the fix went into the fusion (confidence high enough and a keyframe to tie it
    /// to) and, after the latest alignment, whether it was an inlier.
    pub used: bool,
    pub inlier: bool,
    /// Replaced by a wrong position by fault injection ([`crate::faults`]).
    pub injected: bool,
    pub ms: f64,
}

/// One processed frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FusedFrame {
    pub index: usize,
    pub timestamp: f64,
    pub state: TrackingState,
    /// Camera-to-world in the SLAM frame, as tracked.
    pub slam_pose: Option<CameraToWorld>,
    /// Camera-to-world in the world frame (S · SLAM pose) with the alignment known at this
    /// frame; `None` while not geo-referenced or not tracked.
    pub world_pose: Option<CameraToWorld>,
    /// Absolute localisation results applied at this frame (the fix or its failure, w = 0),
    /// with the frame each was computed for: this frame in the sequential mode, an earlier
    /// one in the threaded mode.
    pub absolute: Vec<(usize, Outcome)>,
    pub keyframe: Option<KeyFrameId>,
}

/// Per-module wall times, milliseconds.
#[derive(Debug, Clone, Default, Serialize)]
pub struct FusionTiming {
    /// Absolute localisation (feature extraction + matching + homography + confidence), per fix.
    pub absolute_ms: Vec<f64>,
    /// Alignment re-fit and global-factor update, per fix.
    pub alignment_ms: Vec<f64>,
    /// Whole frame (SLAM + fusion), per frame.
    pub frame_ms: Vec<f64>,
    /// Frames due for absolute localisation that the busy thread skipped (threaded mode).
    pub skipped_busy: usize,
    /// Frames due for absolute localisation during an injected outage.
    pub skipped_outage: usize,
    /// Frames due for absolute localisation before the SLAM tracked them (threaded mode).
    pub skipped_untracked: usize,
}

/// A used fix tied to a keyframe: the camera centre and the point on the optical axis at the
/// altimeter range, both in the keyframe's camera frame, so they follow the keyframe when the
/// local BA moves it.
#[derive(Debug, Clone)]
struct Tie {
    record: usize,
    keyframe: KeyFrameId,
    centre_in_kf: Point3<f64>,
    ground_in_kf: Point3<f64>,
    world_camera: Point3<f64>,
    world_ground: Point3<f64>,
    weight: f64,
    /// Last known SLAM positions (kept when the keyframe is culled).
    slam_camera: Point3<f64>,
    slam_ground: Point3<f64>,
}

impl Tie {
    /// SLAM positions from the keyframe's current pose (kept when it was culled).
    fn refresh(&mut self, map: &jointloc_slam::map::Map) {
        if let Some(kf) = map.keyframe(self.keyframe) {
            let t_wc = kf.pose.0.inverse();
            self.slam_camera = t_wc.transform_point(&self.centre_in_kf);
            self.slam_ground = t_wc.transform_point(&self.ground_in_kf);
        }
    }
}

/// The state at the frame an absolute search was started for, so its fix can be tied when it
/// arrives: the frame's SLAM pose and the then current keyframe with its pose then.
#[derive(Debug, Clone)]
struct Submitted {
    frame: usize,
    timestamp: f64,
    altitude: f64,
    pose: Option<CameraToWorld>,
    keyframe: Option<(KeyFrameId, Isometry3<f64>)>,
}

/// Where absolute localisation runs.
#[derive(Debug)]
enum Absolute {
    Inline(Box<AbsLocalizer>),
    Thread(AbsoluteWorker),
}

/// The fused system.
#[derive(Debug)]
pub struct JointLoc {
    config: JointLocConfig,
    slam: System,
    absolute: Absolute,
    pending: BTreeMap<usize, Submitted>,
    fixes: Vec<FixRecord>,
    ties: Vec<Tie>,
    alignment: Option<SlamToWorld>,
    /// Before the alignment exists: SLAM→world from the latest fix alone (scale 1, the SLAM is
    /// metric from the altimeter; rotation from the fix's heading and a nadir camera), used
    /// only to predict where to search next, never to report a pose.
    provisional: Option<Sim3>,
    /// Absolute searches failed since the last fix (see
    /// [`JointLocConfig::sweep_after_failures`]).
    failures_in_a_row: usize,
    timing: FusionTiming,
    altitude: AltitudeFilter,
    /// Added to every fix's x, y: the fixes' common bias as the terrain shows it.
    terrain: TerrainCorrection,
    /// Every frame's (timestamp, altimeter reading), for the keyframe trajectory's z
    /// (16 bytes a frame: 290 kB per hour at 5 Hz).
    altimeter: Vec<(f64, f64)>,
    next_index: usize,
    last_world_pose: Option<CameraToWorld>,
    /// The recent world positions, to carry the search prior forward while there is no
    /// world pose.
    ground_track: GroundTrack,
    /// Time of the first frame of the current map reported in the world frame: the outputs
    /// written at the end start there too.
    first_world_timestamp: Option<f64>,
    /// Since when tracking has been lost (see [`JointLocConfig::new_map_after_lost_s`]).
    lost_since: Option<f64>,
    /// The world-frame trajectories of the maps set aside after a loss, as known then.
    earlier_maps: Vec<EarlierMap>,
}

/// A SLAM-frame trajectory with, per pose, the keyframe the SLAM expresses it through
/// (`None`: the poses are keyframes themselves).
struct Referenced<'a> {
    trajectory: &'a Trajectory,
    keyframes: Option<&'a [KeyFrameId]>,
}

/// What [`JointLoc::end_outputs`] gives.
#[derive(Debug, Clone, PartialEq)]
pub struct EndOutputs {
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
struct EarlierMap {
    frames: Option<Trajectory>,
    keyframes: Option<Trajectory>,
}

impl JointLoc {
    /// The sequential, deterministic system: absolute localisation runs inline.
    pub fn new(
        camera: PinholeCamera,
        absolute: AbsLocalizer,
        config: JointLocConfig,
    ) -> Result<Self> {
        let ground = absolute.tiles().ground();
        Self::build(camera, Absolute::Inline(Box::new(absolute)), ground, config)
    }

    /// The real-time system: absolute localisation on its own thread; frames due while it is
    /// busy are skipped (counted in [`FusionTiming::skipped_busy`]).
    pub fn threaded(
        camera: PinholeCamera,
        absolute: AbsLocalizer,
        config: JointLocConfig,
    ) -> Result<Self> {
        config.validate()?;
        let ground = absolute.tiles().ground();
        Self::build(
            camera,
            Absolute::Thread(AbsoluteWorker::spawn(absolute)?),
            ground,
            config,
        )
    }

    fn build(
        camera: PinholeCamera,
        absolute: Absolute,
        ground: jointloc_absloc::Ground,
        config: JointLocConfig,
    ) -> Result<Self> {
        config.validate()?;
        let mut slam = System::new(camera, config.slam.clone())?;
        if ground.has_model() {
            slam.set_ground(Some(std::sync::Arc::new(ElevationGround(ground.clone()))));
        }
        let altitude = AltitudeFilter::new(config.altitude_window_s, ground);
        Ok(Self {
            config,
            slam,
            absolute,
            pending: BTreeMap::new(),
            fixes: Vec::new(),
            ties: Vec::new(),
            alignment: None,
            provisional: None,
            failures_in_a_row: 0,
            timing: FusionTiming::default(),
            altitude,
            terrain: TerrainCorrection::default(),
            altimeter: Vec::new(),
            next_index: 0,
            last_world_pose: None,
            ground_track: GroundTrack::default(),
            first_world_timestamp: None,
            lost_since: None,
            earlier_maps: Vec::new(),
        })
    }

    /// New maps started after tracking losses (see [`JointLocConfig::new_map_after_lost_s`]).
    pub fn new_maps(&self) -> usize {
        self.earlier_maps.len()
    }

    pub fn slam(&self) -> &System {
        &self.slam
    }

    pub fn fixes(&self) -> &[FixRecord] {
        &self.fixes
    }

    /// The correction added to the fixes' x, y from the terrain (zero when off or without
    /// an elevation model).
    pub fn terrain_correction(&self) -> &TerrainCorrection {
        &self.terrain
    }

    /// A fix's world point with the terrain correction.
    fn corrected(&self, p: &Point3<f64>) -> Point3<f64> {
        p + Vector3::new(self.terrain.offset.x, self.terrain.offset.y, 0.0)
    }

    pub fn alignment(&self) -> Option<&SlamToWorld> {
        self.alignment.as_ref()
    }

    pub fn timing(&self) -> &FusionTiming {
        &self.timing
    }

    /// Processes the next frame (image, timestamp, altimeter reading).
    pub fn process(
        &mut self,
        image: &GrayImage,
        timestamp: f64,
        altitude: Option<f64>,
    ) -> Result<FusedFrame> {
        let start = Instant::now();
        let index = self.next_index;
        self.next_index += 1;
        let grey;
        let image = if self.config.faults.is_blind(timestamp) {
            grey = GrayImage::from_pixel(image.width(), image.height(), image::Luma([128]));
            &grey
        } else {
            image
        };
        let r = self
            .slam
            .process(GrayImageView::from(image), timestamp, altitude)?;
        self.start_new_map_if_lost_for_good(r.state, timestamp)?;
        let mut absolute = Vec::new();
        if index.is_multiple_of(self.config.fusion_every)
            && let Some(alt) = altitude
        {
            if self.config.faults.in_outage(timestamp) {
                self.timing.skipped_outage += 1;
            } else {
                let map = self.slam.map();
                let submitted = Submitted {
                    frame: index,
                    timestamp,
                    altitude: alt,
                    pose: r.pose,
                    keyframe: map.last_keyframe().map(|kf| (kf.id, kf.pose.0)),
                };
                let prior = self.prior(r.pose, timestamp);
                match &mut self.absolute {
                    Absolute::Inline(loc) => {
                        let outcome = loc.localize(image, alt, &prior)?;
                        self.apply(&submitted, &outcome);
                        absolute.push((index, outcome));
                    }
                    // A fix needs a tracked frame and a keyframe to be tied to: before the
                    // map exists a search would only hold the thread for seconds.
                    Absolute::Thread(_)
                        if submitted.pose.is_none() || submitted.keyframe.is_none() =>
                    {
                        self.timing.skipped_untracked += 1;
                    }
                    Absolute::Thread(worker) => {
                        if worker.try_submit(index, image, alt, prior) {
                            self.pending.insert(index, submitted);
                        } else {
                            self.timing.skipped_busy += 1;
                        }
                    }
                }
            }
        }
        while let Some((frame, outcome)) = self.next_finished(false)? {
            absolute.push((frame, outcome));
        }
        if let Some(alt) = altitude.filter(|a| a.is_finite()) {
            self.altimeter.push((timestamp, alt));
        }
        match (r.pose, altitude) {
            (Some(p), Some(alt)) => self.altitude.push(timestamp, p.centre(), alt),
            (None, _) => self.altitude.clear(),
            _ => {}
        }
        let world_pose = match (&self.alignment, r.pose) {
            (Some(a), Some(p)) => {
                let mut pose = a.sim3.transform_pose(&p);
                if let Some(dz) = self.altitude.z_offset(&a.sim3) {
                    pose.0.translation.vector.z += dz;
                }
                Some(pose)
            }
            _ => None,
        };
        if let Some(p) = world_pose {
            self.last_world_pose = world_pose;
            self.ground_track
                .push(timestamp, [p.centre().x, p.centre().y]);
            self.first_world_timestamp.get_or_insert(timestamp);
        }
        self.timing
            .frame_ms
            .push(start.elapsed().as_secs_f64() * 1e3);
        Ok(FusedFrame {
            index,
            timestamp,
            state: r.state,
            slam_pose: r.pose,
            world_pose,
            absolute,
            keyframe: r.keyframe,
        })
    }

    /// Sets the SLAM map aside after [`JointLocConfig::new_map_after_lost_s`] of lost tracking:
    /// its world-frame trajectories are kept as they stand, and the new map starts without
    /// ties, alignment or provisional similarity (their SLAM frame is gone), to be
    /// geo-referenced again by the next fixes. The terrain correction, a bias of the fixes in
    /// the world frame, carries over; so does the last world pose, the best guess of where
    /// to search next.
    fn start_new_map_if_lost_for_good(
        &mut self,
        state: TrackingState,
        timestamp: f64,
    ) -> Result<()> {
        if state != TrackingState::Lost {
            self.lost_since = None;
            return Ok(());
        }
        let since = *self.lost_since.get_or_insert(timestamp);
        let after = self.config.new_map_after_lost_s;
        if after <= 0.0 || timestamp - since < after {
            return Ok(());
        }
        let end = self.map_end_outputs()?;
        self.earlier_maps.push(EarlierMap {
            frames: end.frames,
            keyframes: end.keyframes,
        });
        tracing::warn!(
            lost_s = timestamp - since,
            maps = self.earlier_maps.len() + 1,
            "tracking lost without relocalisation: starting a new map"
        );
        self.slam.start_new_map();
        self.ties.clear();
        self.alignment = None;
        self.provisional = None;
        self.first_world_timestamp = None;
        self.altitude.clear();
        self.lost_since = None;
        Ok(())
    }

    /// The next search result of the thread (waiting for it when `wait`), applied.
    fn next_finished(&mut self, wait: bool) -> Result<Option<(usize, Outcome)>> {
        let Absolute::Thread(worker) = &mut self.absolute else {
            return Ok(None);
        };
        let next = if wait {
            worker.wait()?
        } else {
            worker.try_next()?
        };
        let Some((frame, outcome)) = next else {
            return Ok(None);
        };
        let outcome = outcome?;
        if let Some(submitted) = self.pending.remove(&frame) {
            self.apply(&submitted, &outcome);
        }
        Ok(Some((frame, outcome)))
    }

    /// Waits for the absolute search in flight (threaded mode) and applies it; for tests and
    /// for a caller that wants every requested fix in the final alignment.
    pub fn flush(&mut self) -> Result<()> {
        while self.next_finished(true)?.is_some() {}
        Ok(())
    }

    /// Records an absolute-localisation outcome and, for a usable fix, ties it to the
    /// keyframe of its frame and re-fits the alignment.
    fn apply(&mut self, submitted: &Submitted, outcome: &Outcome) {
        self.timing.absolute_ms.push(outcome.ms());
        let Outcome::Fix(fix) = outcome else {
            self.failures_in_a_row += 1;
            return;
        };
        self.failures_in_a_row = 0;
        let t0 = Instant::now();
        let mut fix = fix.clone();
        let wrong = self
            .config
            .faults
            .wrong_fix(submitted.frame, self.fixes.len());
        if let Some(w) = wrong {
            fix.position[0] += w.offset[0];
            fix.position[1] += w.offset[1];
            fix.heading = w.heading;
        }
        let used = self.tie_fix(&fix, submitted);
        // Until the alignment exists, the latest usable fix predicts the next search: a wrong
        // first fix must not steer every search after it.
        if used
            && self.alignment.is_none()
            && let Some(pose) = submitted.pose
        {
            let rotation = fix.orientation() * pose.rotation().inverse();
            let centre = nalgebra::Vector3::from(fix.position);
            self.provisional = Some(Sim3 {
                scale: 1.0,
                rotation,
                translation: centre - rotation * pose.centre().coords,
            });
        }
        self.fixes.push(FixRecord {
            frame: submitted.frame,
            timestamp: submitted.timestamp,
            position: fix.position,
            confidence: fix.confidence,
            ssim: fix.ssim,
            match_score: fix.match_score,
            tile: fix.tile,
            inliers: fix.inliers,
            searched_tiles: fix.searched_tiles,
            global: fix.global,
            used,
            inlier: false,
            injected: wrong.is_some(),
            ms: fix.ms,
        });
        if used {
            self.refit();
        }
        self.timing
            .alignment_ms
            .push(t0.elapsed().as_secs_f64() * 1e3);
    }

    /// The search prior from the fused pose: position and heading of the last world pose;
    /// before the alignment, the current SLAM pose through the provisional one-fix similarity
    /// (after a new map, the last world pose of the old one until then). A last world pose
    /// older than [`dead_reckoning::FRESH_S`] is carried forward at the last ground velocity
    /// (see [`JointLocConfig::dead_reckoning_max_s`]) and its heading left out.
    /// Every [`JointLocConfig::sweep_after_failures`]-th search of a failing streak (or
    /// [`JointLocConfig::sweep_after_failures_aligned`]-th once geo-referenced) leaves the
    /// heading out, so the localiser sweeps rotations: the predicted heading may be what is
    /// wrong (a wrong fix or alignment), and with it every search would fail.
    fn prior(&self, slam_pose: Option<CameraToWorld>, timestamp: f64) -> Prior {
        // Before the alignment, the provisional one is fresher than a world pose left from a
        // map set aside after a loss.
        let (predicted, from_last_world_pose) =
            match (&self.alignment, &self.provisional, slam_pose) {
                (None, Some(s), Some(p)) => (Some(s.transform_pose(&p)), false),
                _ => (self.last_world_pose, true),
            };
        let carried = match self.ground_track.last() {
            Some((t, _)) if from_last_world_pose && timestamp - t > dead_reckoning::FRESH_S => self
                .ground_track
                .predict(timestamp, self.config.dead_reckoning_max_s),
            _ => None,
        };
        let every = if self.alignment.is_some() {
            self.config.sweep_after_failures_aligned
        } else {
            self.config.sweep_after_failures
        };
        // A stale heading is a guess: the UAV may have turned while it was not tracked.
        let trust_heading = carried.is_none()
            && every != 0
            && (self.failures_in_a_row == 0 || !self.failures_in_a_row.is_multiple_of(every));
        match predicted {
            Some(p) => Prior {
                position: Some(carried.unwrap_or([p.centre().x, p.centre().y])),
                heading: trust_heading
                    .then(|| heading_from_rotation(&p.rotation().to_rotation_matrix())),
            },
            // Nothing tracked and fixed yet: the take-off position, if the user gave one.
            None => Prior {
                position: self.config.start_position,
                heading: None,
            },
        }
    }

    /// Ties a fix to the keyframe that was current at its frame; false when it cannot be used
    /// (low confidence, frame not tracked, or that keyframe culled since).
    fn tie_fix(&mut self, fix: &jointloc_absloc::Fix, at: &Submitted) -> bool {
        if fix.confidence < self.config.min_confidence {
            return false;
        }
        let (Some(pose), Some((kf_id, t_cw))) = (at.pose, at.keyframe) else {
            return false;
        };
        if self.slam.map().keyframe(kf_id).is_none() {
            return false;
        }
        let altitude = at.altitude;
        // SLAM units per metre: the current alignment's inverse scale, else 1 (the SLAM map is
        // metric from the altimeter at initialisation).
        let per_metre = self.alignment.as_ref().map_or(1.0, |a| 1.0 / a.sim3.scale);
        let centre = pose.centre();
        let ground = pose
            .0
            .transform_point(&Point3::new(0.0, 0.0, altitude * per_metre));
        let [x, y, z] = fix.position;
        self.ties.push(Tie {
            record: self.fixes.len(),
            keyframe: kf_id,
            centre_in_kf: t_cw.transform_point(&centre),
            ground_in_kf: t_cw.transform_point(&ground),
            world_camera: Point3::new(x, y, z),
            world_ground: Point3::new(x, y, z - altitude),
            weight: fix.confidence,
            slam_camera: centre,
            slam_ground: ground,
        });
        true
    }

    /// Refreshes the tie points from the keyframes' current poses, re-fits the alignment and
    /// updates every keyframe's global-position factor.
    fn refit(&mut self) {
        let map = self.slam.map();
        for t in &mut self.ties {
            t.refresh(map);
        }
        let first = match self.config.alignment_window {
            0 => 0,
            w => self.ties.len().saturating_sub(w),
        };
        let fitted = self.fit_ties(&self.ties, first..self.ties.len());
        let Some(fitted) = fitted else {
            return;
        };
        for r in &mut self.fixes {
            r.inlier = false;
        }
        let s = fitted.sim3;
        // Global factors per keyframe, one pair per inlier fix tied to it: the fix's ground
        // point as the point on the tied frame's optical axis (what a map fix measures), and
        // the camera above it (a nadir view, `nadir_sigma_scale`). The SLAM's tilt is its
        // weakest direction (a tilt and a sideways shift look alike over flat ground), so the
        // lever arm from the ground point to the camera must not be taken from it alone.
        let mut per_kf: BTreeMap<KeyFrameId, Vec<GlobalFix>> = BTreeMap::new();
        for &i in &fitted.inlier_fixes {
            let t = &self.ties[i];
            self.fixes[t.record].inlier = true;
            let fixes = per_kf.entry(t.keyframe).or_default();
            fixes.push(GlobalFix {
                point_in_camera: t.ground_in_kf.coords,
                position: self.corrected(&t.world_ground).coords,
                weight: t.weight,
                sigma_scale: 1.0,
            });
            if self.config.nadir_sigma_scale > 0.0 {
                fixes.push(GlobalFix {
                    point_in_camera: t.centre_in_kf.coords,
                    position: self.corrected(&t.world_camera).coords,
                    weight: t.weight,
                    sigma_scale: self.config.nadir_sigma_scale,
                });
            }
        }
        let map = self.slam.map_mut();
        let ids: Vec<KeyFrameId> = map.keyframes().map(|k| k.id).collect();
        for id in ids {
            if let Some(kf) = map.keyframe_mut(id) {
                kf.global_fixes = per_kf.remove(&id).unwrap_or_default();
            }
        }
        self.slam.set_slam_to_world(Some(s));
        self.alignment = Some(fitted);
        self.correct_by_terrain(first);
    }

    /// Where the window's map points sit on the elevation model through the new alignment:
    /// the residual of the fixes' common bias, taken into the correction that the next refits
    /// add to every fix (see [`crate::terrain_shift`]).
    fn correct_by_terrain(&mut self, first: usize) {
        let config = &self.config.terrain;
        let (Some(a), true) = (&self.alignment, config.gain > 0.0) else {
            return;
        };
        if !self.altitude.ground().has_model() {
            return;
        }
        let map = self.slam.map();
        let first = match config.window {
            0 => first,
            w => self.ties.len().saturating_sub(w),
        };
        // The window keyframes' points, in id order.
        let ids: BTreeSet<MapPointId> = self.ties[first..]
            .iter()
            .filter_map(|t| map.keyframe(t.keyframe))
            .flat_map(|kf| kf.points.iter().flatten().copied())
            .collect();
        // Points seen from at least 3 keyframes: triangulated, not fresh two-view guesses.
        let points: Vec<Point3<f64>> = ids
            .into_iter()
            .filter_map(|id| map.point(id))
            .filter(|p| p.n_observations() >= 3)
            .map(|p| a.sim3.transform_point(&Point3::from(p.position)))
            .collect();
        if let Some(estimate) = estimate_shift(&points, self.altitude.ground(), config) {
            self.terrain.update(&estimate, config);
            tracing::debug!(
                shift = ?estimate.shift.as_slice(),
                points = estimate.points,
                offset = ?self.terrain.offset.as_slice(),
                "terrain shift"
            );
        }
    }

    /// The alignment fitted to the ties `range`: the ground point carries the fix's x, y
    /// exactly (the map point under the image centre); the camera centre adds the altimeter's
    /// z with a lower weight (its x, y assume a nadir view).
    fn fit_ties(&self, ties: &[Tie], range: std::ops::Range<usize>) -> Option<SlamToWorld> {
        let mut pairs = Vec::with_capacity(2 * range.len());
        for i in range {
            let t = &ties[i];
            pairs.push(Correspondence {
                slam: t.slam_ground,
                world: self.corrected(&t.world_ground),
                weight: t.weight,
                fix: i,
            });
            pairs.push(Correspondence {
                slam: t.slam_camera,
                world: self.corrected(&t.world_camera),
                weight: t.weight * self.config.nadir_weight,
                fix: i,
            });
        }
        alignment::fit(
            &pairs,
            self.config.inlier_threshold_m,
            self.config.ransac_iterations,
            self.config.min_fixes,
            self.config.seed,
        )
    }

    /// The outputs known as a whole at the end: every tracked frame and every keyframe in the
    /// world frame (empty before the first alignment), from the first frame reported in the
    /// world frame on, as ORB-SLAM2 saves trajectories (through the keyframes' final poses;
    /// `trajectory.tum` is what was known online). The frames of the two-view initialisation
    /// before it are left out (up to 1 m off after the map settled, on crater-easy-s103), so
    /// the online and end files cover the same frames.
    ///
    /// Each pose goes through the alignment fitted to the `alignment_window` fixes nearest
    /// to it in time (the latest alignment alone fits the recent fixes, and SLAM drift since
    /// an early frame would carry into it); then, with [`JointLocConfig::final_ba`], the
    /// whole map is bundle-adjusted once more in the world frame with every fix
    /// ([`crate::final_ba`]). z is altimeter-aided as online, over a window centred on the
    /// pose, from every frame's reading. Maps set aside after a loss come first, each as it
    /// was at the loss.
    pub fn end_outputs(&self) -> Result<EndOutputs> {
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
    fn map_end_outputs(&self) -> Result<EndOutputs> {
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
        for t in &self.ties {
            ties.push(FinalTie {
                keyframe: t.keyframe,
                point_in_camera: t.ground_in_kf,
                world: self.corrected(&t.world_ground),
                weight: t.weight,
                sigma_scale: 1.0,
            });
            if self.config.nadir_sigma_scale > 0.0 {
                ties.push(FinalTie {
                    keyframe: t.keyframe,
                    point_in_camera: t.centre_in_kf,
                    world: self.corrected(&t.world_camera),
                    weight: t.weight,
                    sigma_scale: self.config.nadir_sigma_scale,
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
            self.slam.ideal_camera(),
            &self.config.slam.local_mapping.ba,
            &self.config.final_ba,
            &mut |t| aligner.sim_at(t),
            &ties,
            self.config.inlier_threshold_m,
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
        let Some(t0) = self.first_world_timestamp else {
            return Ok(None);
        };
        let keep = slam.trajectory.timestamps.partition_point(|&t| t < t0);
        if keep == slam.trajectory.len() {
            return Ok(None);
        }
        let mut world = |r: &Referenced<'_>, from: usize| -> Vec<CameraToWorld> {
            let t = r.trajectory;
            (from..t.len())
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
        let mut poses = world(slam, keep);
        let frame_poses = world(frames, 0);
        let (stamps, frames) = (&slam.trajectory.timestamps[keep..], frames.trajectory);
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
            self.altitude.window_s(),
            stamps,
        );
        for (p, dz) in poses.iter_mut().zip(shifts) {
            if let Some(dz) = dz {
                p.0.translation.vector.z += dz;
            }
        }
        Ok(Some(
            Trajectory::new(stamps.to_vec(), poses)
                .map_err(jointloc_slam::error::SlamError::from)?,
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
                tie.refresh(map);
                (self.fixes[tie.record].timestamp, tie)
            })
            .collect();
        timed.sort_by(|x, y| x.0.total_cmp(&y.0));
        let (times, ties): (Vec<f64>, Vec<Tie>) = timed.into_iter().unzip();
        let window = match self.config.alignment_window {
            0 => ties.len(),
            w => w.min(ties.len()),
        };
        CentredAligner {
            system: self,
            times,
            ties,
            window,
            fits: BTreeMap::new(),
        }
    }
}

/// The trajectories one after the other (each later than the one before); `None` when all
/// are.
fn concat<'a>(parts: impl Iterator<Item = Option<&'a Trajectory>>) -> Result<Option<Trajectory>> {
    let (mut stamps, mut poses) = (Vec::new(), Vec::new());
    let mut any = false;
    for t in parts.flatten() {
        any = true;
        stamps.extend_from_slice(&t.timestamps);
        poses.extend_from_slice(&t.poses);
    }
    if !any {
        return Ok(None);
    }
    Ok(Some(
        Trajectory::new(stamps, poses).map_err(jointloc_slam::error::SlamError::from)?,
    ))
}

/// Maps SLAM-frame poses to the world through the alignment of the fixes nearest in time
/// (one fit per window start: windows change only between fixes); the latest alignment where
/// a window has no fit.
struct CentredAligner<'a> {
    system: &'a JointLoc,
    times: Vec<f64>,
    ties: Vec<Tie>,
    window: usize,
    fits: BTreeMap<usize, Option<Sim3>>,
}

impl CentredAligner<'_> {
    /// The SLAM→world similarity at `timestamp`.
    fn sim_at(&mut self, timestamp: f64) -> Sim3 {
        let latest = self.system.alignment.as_ref().map(|a| a.sim3);
        if self.ties.is_empty() {
            return latest.unwrap_or_else(Sim3::identity);
        }
        let at = self.times.partition_point(|&x| x < timestamp);
        let start = at
            .saturating_sub(self.window / 2)
            .min(self.ties.len() - self.window);
        let (system, ties, window) = (self.system, &self.ties, self.window);
        let fit = *self
            .fits
            .entry(start)
            .or_insert_with(|| system.fit_ties(ties, start..start + window).map(|f| f.sim3));
        fit.or(latest).unwrap_or_else(Sim3::identity)
    }
}
