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

use std::collections::BTreeMap;
use std::time::Instant;

use image::GrayImage;
use jointloc_absloc::{Outcome, Prior, heading_from_rotation};
use jointloc_features::orb::GrayImageView;
use jointloc_formats::outputs::{CameraTiltSummary, OnlineFrame, OnlineStatus};
use jointloc_geometry::{CameraToWorld, Sim3};
use jointloc_slam::map::KeyFrameId;
use jointloc_slam::system::System;
use jointloc_slam::tracking::TrackingState;
use nalgebra::{Isometry3, Point3, Vector3};

use crate::alignment::SlamToWorld;
use crate::altimeter_gate::AltimeterGate;
use crate::altitude::AltitudeFilter;
use crate::config::JointLocConfig;
use crate::dead_reckoning::{self, GroundTrack};
use crate::end_outputs::EarlierMap;
use crate::error::Result;
use crate::fix_source::{FixRequest, FixSource, Located};
use crate::map_merge::Mergeable;
use crate::observer::Observer;
pub use crate::records::{FixRecord, FusedFrame, FusionTiming};
use crate::takeoff::TakeOff;
use crate::terrain_shift::TerrainCorrection;
use crate::ties::Tie;
use crate::virtual_frames::VirtualFrames;
use crate::worker::AbsoluteWorker;

/// An elevation model stated this precise (or better) needs no longer z window than the
/// altimeter does.
const DEM_SIGMA_REFERENCE_M: f64 = 0.1;

/// The state at the frame an absolute search was started for, so its fix can be tied when it
/// arrives: the frame's SLAM pose and the then current keyframe with its pose then.
#[derive(Debug, Clone)]
pub(crate) struct Submitted {
    pub(crate) frame: usize,
    pub(crate) timestamp: f64,
    pub(crate) altitude: f64,
    pub(crate) pose: Option<CameraToWorld>,
    pub(crate) keyframe: Option<(KeyFrameId, Isometry3<f64>)>,
}

/// Where absolute localisation runs.
#[derive(Debug)]
pub(crate) enum Absolute {
    Inline(Box<dyn FixSource>),
    Thread(AbsoluteWorker),
}

/// The fused system, built by [`crate::JointLocBuilder`]: feed it frames with
/// [`JointLoc::process`], end with [`JointLoc::finish`].
pub struct JointLoc {
    pub(crate) config: JointLocConfig,
    pub(crate) slam: System,
    absolute: Absolute,
    observers: Vec<Box<dyn Observer>>,
    pending: BTreeMap<usize, Submitted>,
    pub(crate) fixes: Vec<FixRecord>,
    pub(crate) ties: Vec<Tie>,
    pub(crate) alignment: Option<SlamToWorld>,
    /// Before the alignment exists: SLAM→world from the latest fix alone (scale 1, the SLAM is
    /// metric from the altimeter; rotation from the fix's heading and a nadir camera), used
    /// only to predict where to search next, never to report a pose.
    provisional: Option<Sim3>,
    /// Whether the fix that made `provisional` had at least
    /// [`JointLocConfig::strong_fix_confidence`] (see [`Self::moves_provisional`]).
    provisional_strong: bool,
    /// Whether the provisional similarity's heading agrees with the one before it (see
    /// [`JointLocConfig::provisional_turn_deg`]); the search prior leaves it out when not.
    provisional_heading_agrees: bool,
    /// Absolute searches failed since the last fix (see
    /// [`JointLocConfig::sweep_after_failures`]).
    failures_in_a_row: usize,
    /// Frame times of the first and the latest search of the failing streak (see
    /// [`JointLocConfig::sweep_after_failing_s`]).
    failing_since: Option<(f64, f64)>,
    /// The frame rate so far, which turns the windows in seconds into numbers of fixes.
    pub(crate) clock: crate::flight_time::FrameClock,
    timing: FusionTiming,
    pub(crate) altitude: AltitudeFilter,
    /// Drops implausible altimeter readings, counting them.
    pub(crate) altimeter_gate: AltimeterGate,
    /// Added to every fix's x, y: the fixes' common bias as the terrain shows it.
    pub(crate) terrain: TerrainCorrection,
    /// The camera's mean tilt off nadir in its own frame, radians (see
    /// [`crate::camera_tilt`]); a property of the camera, kept across maps.
    pub(crate) camera_tilt: Option<[f64; 2]>,
    /// Every frame's (timestamp, altimeter reading), for the keyframe trajectory's z
    /// (16 bytes a frame: 290 kB per hour at 5 Hz).
    pub(crate) altimeter: Vec<(f64, f64)>,
    /// Every frame as reported online (`trajectory.tum`; 40 bytes a frame).
    online: Vec<OnlineFrame>,
    /// Frames whose tracking was lost.
    lost_frames: usize,
    /// When the first frame arrived and the last one was done (the run's wall time).
    pub(crate) first_frame_at: Option<Instant>,
    pub(crate) last_done_at: Option<Instant>,
    next_index: usize,
    /// Frames given up by the caller ([`JointLoc::skip_frame`]).
    skipped_frames: usize,
    last_world_pose: Option<CameraToWorld>,
    /// The recent world positions, to carry the search prior forward while there is no
    /// world pose.
    ground_track: GroundTrack,
    /// Time of the first frame of the current map reported in the world frame: the outputs
    /// written at the end start there too.
    pub(crate) first_world_timestamp: Option<f64>,
    /// Since when tracking has been lost (see [`JointLocConfig::new_map_after_lost_s`]).
    lost_since: Option<f64>,
    /// The world-frame trajectories of the maps set aside after a loss, as known then.
    pub(crate) earlier_maps: Vec<EarlierMap>,
    /// Loops the SLAM closed, over all its maps.
    loops_closed: usize,
    /// The spans of time (first, last world pose) of the maps merged into the current one.
    pub(crate) merged_spans: Vec<(f64, f64)>,
    /// Maps set aside after a loss and merged back ([`crate::map_merge`]).
    pub(crate) maps_merged: usize,
    /// Recent frames for fixes from more than one frame.
    pub(crate) virtual_frames: VirtualFrames,
    /// With a take-off position: where the first tracked frame of the first map is (see
    /// [`JointLocConfig::start_radius_m`]); gone with that map.
    pub(crate) takeoff: Option<TakeOff>,
}

impl std::fmt::Debug for JointLoc {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("JointLoc")
            .field("mode", &self.mode())
            .field("frames", &self.next_index)
            .field("fixes", &self.fixes.len())
            .field("geo_referenced", &self.alignment.is_some())
            .field("new_maps", &self.earlier_maps.len())
            .finish_non_exhaustive()
    }
}

/// Sequential (absolute localisation inline, deterministic) or threaded (on its own thread,
/// real time).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Mode {
    #[default]
    Sequential,
    Threaded,
}

impl Mode {
    pub fn name(self) -> &'static str {
        match self {
            Mode::Sequential => "sequential",
            Mode::Threaded => "threaded",
        }
    }
}

impl JointLoc {
    /// The system around `slam` and the fix source (its ground from the map's elevation
    /// model, `ground`); see [`crate::JointLocBuilder`].
    pub(crate) fn assemble(
        mut slam: System,
        source: Box<dyn FixSource>,
        mode: Mode,
        ground: jointloc_absloc::Ground,
        virtual_frames: VirtualFrames,
        observers: Vec<Box<dyn Observer>>,
        config: JointLocConfig,
    ) -> Result<Self> {
        config.validate()?;
        if ground.has_model() {
            slam.set_ground(Some(std::sync::Arc::new(crate::ground::ElevationGround(
                ground.clone(),
            ))));
        }
        let absolute = match mode {
            Mode::Sequential => Absolute::Inline(source),
            Mode::Threaded => Absolute::Thread(AbsoluteWorker::spawn(source)?),
        };
        let altitude = AltitudeFilter::new(config.altitude_window_s, ground).with_plane(
            config.altitude_plane_window_s,
            config.altitude_tilt_sigma_deg.to_radians(),
        );
        let altimeter_gate = AltimeterGate::new(config.max_altitude_rate_mps);
        Ok(Self {
            config,
            slam,
            absolute,
            observers,
            pending: BTreeMap::new(),
            fixes: Vec::new(),
            ties: Vec::new(),
            alignment: None,
            provisional: None,
            provisional_strong: false,
            provisional_heading_agrees: true,
            failures_in_a_row: 0,
            failing_since: None,
            clock: Default::default(),
            timing: FusionTiming::default(),
            altitude,
            altimeter_gate,
            terrain: TerrainCorrection::default(),
            camera_tilt: None,
            altimeter: Vec::new(),
            online: Vec::new(),
            lost_frames: 0,
            first_frame_at: None,
            last_done_at: None,
            next_index: 0,
            skipped_frames: 0,
            last_world_pose: None,
            ground_track: GroundTrack::default(),
            first_world_timestamp: None,
            takeoff: None,
            lost_since: None,
            earlier_maps: Vec::new(),
            loops_closed: 0,
            merged_spans: Vec::new(),
            maps_merged: 0,
            virtual_frames,
        })
    }

    pub fn mode(&self) -> Mode {
        match self.absolute {
            Absolute::Inline(_) => Mode::Sequential,
            Absolute::Thread(_) => Mode::Threaded,
        }
    }

    pub fn config(&self) -> &JointLocConfig {
        &self.config
    }

    /// Frames whose tracking was lost.
    pub fn lost_frames(&self) -> usize {
        self.lost_frames
    }

    /// Frames processed so far.
    pub fn frames(&self) -> usize {
        self.next_index - self.skipped_frames
    }

    /// A frame the camera delivered that the caller could not use (unreadable, wrong size):
    /// it keeps its place in the flight, so the absolute searches stay on every
    /// [`JointLocConfig::fusion_every`]-th frame of the flight (and frame indices in the
    /// outputs on the flight's), as without the loss.
    pub fn skip_frame(&mut self) {
        self.next_index += 1;
        self.skipped_frames += 1;
    }

    /// Every frame as reported online so far.
    pub fn online(&self) -> &[OnlineFrame] {
        &self.online
    }

    /// Loops the SLAM closed, over all its maps.
    pub fn loops_closed(&self) -> usize {
        self.loops_closed
    }

    /// New maps started after tracking losses (see [`JointLocConfig::new_map_after_lost_s`]).
    pub fn new_maps(&self) -> usize {
        self.slam.maps_started()
    }

    /// Maps set aside after a loss and merged back into the current one
    /// ([`JointLocConfig::merge_maps_after_s`]).
    pub fn maps_merged(&self) -> usize {
        self.maps_merged
    }

    /// Maps the outputs written at the end come from: the current one and those set aside
    /// and not merged.
    pub fn maps_at_end(&self) -> usize {
        1 + self.earlier_maps.len()
    }

    pub fn slam(&self) -> &System {
        &self.slam
    }

    pub fn fixes(&self) -> &[FixRecord] {
        &self.fixes
    }

    /// The camera's mean tilt off nadir, `[about image x, about image y]` in degrees, as
    /// estimated from the fused attitudes at the last refit and as used (shrunk by
    /// `camera_tilt_min_deg`); `None` when the estimate is off or nothing was aligned yet.
    pub fn camera_tilt_deg(&self) -> Option<CameraTiltSummary> {
        let raw = self.camera_tilt?;
        let used = self.used_camera_tilt();
        Some(CameraTiltSummary {
            estimated_deg: raw.map(f64::to_degrees),
            used_deg: used.map(f64::to_degrees),
        })
    }

    /// The tilt the nadir pairs use, radians: the estimate shrunk by `camera_tilt_min_deg`.
    pub(crate) fn used_camera_tilt(&self) -> [f64; 2] {
        crate::camera_tilt::shrunk(
            self.camera_tilt.unwrap_or_default(),
            self.config.camera_tilt_min_deg.to_radians(),
        )
    }

    /// The correction added to the fixes' x, y from the terrain (zero when off or without
    /// an elevation model).
    pub fn terrain_correction(&self) -> &TerrainCorrection {
        &self.terrain
    }

    /// A fix's world point with the terrain correction.
    pub(crate) fn corrected(&self, p: &Point3<f64>) -> Point3<f64> {
        p + Vector3::new(self.terrain.offset.x, self.terrain.offset.y, 0.0)
    }

    pub fn alignment(&self) -> Option<&SlamToWorld> {
        self.alignment.as_ref()
    }

    pub fn timing(&self) -> &FusionTiming {
        &self.timing
    }

    /// Processes the next frame (image, timestamp, altimeter reading). An image of another
    /// size than the camera's, or a timestamp not after the previous frame's, is an error and
    /// leaves the system as it was. An altimeter reading that is not finite, not positive or
    /// jumps implausibly is dropped (the frame is processed without one; see
    /// [`crate::altimeter_gate`]).
    pub fn process(
        &mut self,
        image: &GrayImage,
        timestamp: f64,
        altitude: Option<f64>,
    ) -> Result<FusedFrame> {
        self.slam.check_frame(
            image.width() as usize,
            image.height() as usize,
            timestamp,
            None,
        )?;
        let altitude = self.altimeter_gate.check(timestamp, altitude);
        let start = Instant::now();
        self.first_frame_at.get_or_insert(start);
        let index = self.next_index;
        self.next_index += 1;
        self.clock.tick(index, timestamp);
        let r = self
            .slam
            .process(GrayImageView::from(image), timestamp, altitude)?;
        self.loops_closed += usize::from(r.loop_closed.is_some());
        self.start_new_map_if_lost_for_good(r.state, timestamp)?;
        self.anchor_takeoff(r.pose.as_ref(), timestamp, altitude);
        let mut absolute = Vec::new();
        let (scale, up) = match &self.alignment {
            Some(a) => (a.sim3.scale, Some(a.sim3.rotation.inverse() * Vector3::z())),
            None => (1.0, None),
        };
        self.virtual_frames.push(image, r.pose, altitude, scale);
        if index.is_multiple_of(self.config.fusion_every)
            && let Some(alt) = altitude
        {
            if self.blind_search_waits(timestamp) {
                self.timing.skipped_backoff += 1;
                return self.finish_frame(index, timestamp, altitude, r, absolute, start);
            }
            // A frame too small on the map is searched through a virtual frame: rendered here
            // in the sequential mode, on the thread in the threaded one (only when it is idle).
            // `Err`: none could be made (not tracked, too few frames kept, too little covered).
            let busy = matches!(&self.absolute, Absolute::Thread(w) if w.is_busy());
            let job = match (self.virtual_frames.zoom(alt), r.pose) {
                (None, _) => Ok(None),
                (Some(_), Some(_)) if busy => Ok(None),
                (Some(zoom), Some(pose)) => self
                    .virtual_frames
                    .up(up)
                    .and_then(|up| self.virtual_frames.job(&pose, alt, zoom, scale, up))
                    .map(Some)
                    .ok_or(()),
                (Some(_), None) => Err(()),
            };
            let view = match (&self.absolute, &job) {
                (Absolute::Inline(_), Ok(Some(j))) => j.render().map(Some).ok_or(()),
                (_, Ok(_)) => Ok(None),
                (_, Err(())) => Err(()),
            };
            let (Ok(job), Ok(view)) = (job, view) else {
                self.timing.skipped_no_view += 1;
                return self.finish_frame(index, timestamp, altitude, r, absolute, start);
            };
            if view.is_some() {
                self.timing.virtual_frames += 1;
            }
            let (image, zoom, valid) = match &view {
                Some(m) => (&m.image, m.zoom, Some(m.valid.as_slice())),
                None => (image, 1.0, None),
            };
            let map = self.slam.map();
            let submitted = Submitted {
                frame: index,
                timestamp,
                altitude: alt,
                pose: r.pose,
                keyframe: map.last_keyframe().map(|kf| (kf.id, kf.pose.0)),
            };
            // Threaded, the virtual frame is rendered on the other thread: `job`, no `view`.
            let prior = self.prior(r.pose, timestamp, job.is_some() || view.is_some());
            let request = FixRequest {
                frame: index,
                timestamp,
                image,
                altitude: alt,
                prior: &prior,
                zoom,
                valid,
            };
            match &mut self.absolute {
                Absolute::Inline(source) => {
                    let located = source.localize(&request)?;
                    if let Some(outcome) = self.apply(&submitted, located) {
                        absolute.push((index, outcome));
                    }
                }
                // A fix needs a tracked frame and a keyframe to be tied to: before the map
                // exists a search would only hold the thread for seconds.
                Absolute::Thread(_) if submitted.pose.is_none() || submitted.keyframe.is_none() => {
                    self.timing.skipped_untracked += 1;
                }
                Absolute::Thread(worker) => {
                    let through_virtual_frame = job.is_some();
                    if worker.try_submit(&request, job) {
                        self.timing.virtual_frames += usize::from(through_virtual_frame);
                        self.pending.insert(index, submitted);
                    } else {
                        self.timing.skipped_busy += 1;
                    }
                }
            }
        }
        self.finish_frame(index, timestamp, altitude, r, absolute, start)
    }

    /// The rest of [`Self::process`] once the absolute search (if any) is made: results of the
    /// thread, z, the world pose, the online record and the observers.
    fn finish_frame(
        &mut self,
        index: usize,
        timestamp: f64,
        altitude: Option<f64>,
        r: jointloc_slam::system::FrameResult,
        mut absolute: Vec<(usize, Outcome)>,
        start: Instant,
    ) -> Result<FusedFrame> {
        while let Some((frame, outcome)) = self.next_finished(false)? {
            absolute.extend(outcome.map(|o| (frame, o)));
        }
        if let Some(alt) = altitude.filter(|a| a.is_finite()) {
            self.altimeter.push((timestamp, alt));
        }
        match (r.pose, altitude) {
            (Some(p), Some(alt)) => {
                // The altimeter's noise is a share of the range: average longer up high; and
                // over a coarse elevation model (z = model + altimeter) average its noise
                // over more ground: ×(stated σ / 0.1 m), 2.5 for a HiRISE-class DTM
                // (`docs/jointloc.md` §"10 m over a 25 cm map").
                let loose = self.config.range_looseness(alt).sqrt();
                let coarse =
                    self.altitude.ground().stated_sigma_m().unwrap_or(0.0) / DEM_SIGMA_REFERENCE_M;
                self.altitude.set_scale(loose.max(coarse));
                self.altitude.push(timestamp, p.centre(), alt)
            }
            (None, _) => self.altitude.clear(),
            _ => {}
        }
        self.drop_unconfirmed_weak_alignment(timestamp);
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
        self.online.push(OnlineFrame {
            timestamp,
            status: match (world_pose, r.pose) {
                (Some(p), _) => OnlineStatus::World(p),
                (None, Some(_)) => OnlineStatus::NotGeoReferenced,
                (None, None) => OnlineStatus::NotTracked,
            },
        });
        if r.state == TrackingState::Lost {
            self.lost_frames += 1;
        }
        let frame = FusedFrame {
            index,
            timestamp,
            state: r.state,
            slam_pose: r.pose,
            world_pose,
            absolute,
            keyframe: r.keyframe,
        };
        for o in &mut self.observers {
            o.frame(&frame);
        }
        let done = Instant::now();
        self.timing
            .frame_ms
            .push(done.duration_since(start).as_secs_f64() * 1e3);
        self.last_done_at = Some(done);
        Ok(frame)
    }

    /// Drops an alignment made of weak fixes only that no fix has confirmed for
    /// [`JointLocConfig::unconfirmed_weak_alignment_s`]: its world poses stop, and its ties,
    /// the search prior and the terrain correction it made go with it.
    fn drop_unconfirmed_weak_alignment(&mut self, timestamp: f64) {
        let limit = self.config.unconfirmed_weak_alignment_s;
        let Some(newest) = self.newest_inlier_if_all_weak() else {
            return;
        };
        if limit <= 0.0 || timestamp - newest <= limit {
            return;
        }
        tracing::warn!(
            unconfirmed_s = timestamp - newest,
            ties = self.ties.len(),
            "an alignment of weak fixes only, unconfirmed: dropped, no world pose until new fixes"
        );
        self.alignment = None;
        self.slam.set_slam_to_world(None);
        self.slam.set_global_fixes(Default::default());
        self.ties.clear();
        for r in &mut self.fixes {
            r.inlier = false;
        }
        self.terrain = TerrainCorrection::default();
        self.forget_provisional();
        self.last_world_pose = None;
        self.ground_track = GroundTrack::default();
        self.first_world_timestamp = None;
        self.altitude.clear();
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
        tracing::warn!(
            lost_s = timestamp - since,
            maps = self.slam.maps_started() + 2,
            "tracking lost without relocalisation: starting a new map"
        );
        let slam_index = self.slam.start_new_map();
        let ties = std::mem::take(&mut self.ties);
        let mut spans = std::mem::take(&mut self.merged_spans);
        let merge = match (&self.alignment, self.first_world_timestamp) {
            (Some(a), Some(first)) => {
                spans.push((first, since));
                Some(Mergeable {
                    slam_index,
                    slam_to_world: a.sim3,
                    ties,
                    spans,
                })
            }
            _ => None,
        };
        self.earlier_maps.push(EarlierMap {
            frames: end.frames,
            keyframes: end.keyframes,
            merge,
        });
        self.alignment = None;
        self.forget_provisional();
        self.takeoff = None;
        self.first_world_timestamp = None;
        self.altitude.clear();
        self.lost_since = None;
        Ok(())
    }

    /// The next search result of the thread (waiting for it when `wait`), applied; its
    /// outcome is `None` when the source made no attempt (an outage).
    fn next_finished(&mut self, wait: bool) -> Result<Option<(usize, Option<Outcome>)>> {
        let Absolute::Thread(worker) = &mut self.absolute else {
            return Ok(None);
        };
        let next = if wait {
            worker.wait()?
        } else {
            worker.try_next()?
        };
        let Some((frame, located)) = next else {
            return Ok(None);
        };
        let located = located?;
        let outcome = match self.pending.remove(&frame) {
            Some(submitted) => self.apply(&submitted, located),
            None => located.map(|l| l.outcome),
        };
        Ok(Some((frame, outcome)))
    }

    /// Waits for the absolute search in flight (threaded mode) and applies it.
    pub(crate) fn flush(&mut self) -> Result<()> {
        while self.next_finished(true)?.is_some() {}
        Ok(())
    }

    /// Records an absolute-localisation outcome and, for a usable fix, ties it to the
    /// keyframe of its frame and re-fits the alignment.
    /// `None` (the source made no attempt: an outage) is counted and gives no outcome.
    fn apply(&mut self, submitted: &Submitted, located: Option<Located>) -> Option<Outcome> {
        let Some(Located { outcome, injected }) = located else {
            self.timing.skipped_outage += 1;
            return None;
        };
        self.timing.absolute_ms.push(outcome.ms());
        let Outcome::Fix(fix) = &outcome else {
            self.failures_in_a_row += 1;
            let first = self.failing_since.map_or(submitted.timestamp, |(t0, _)| t0);
            self.failing_since = Some((first, submitted.timestamp));
            return Some(outcome);
        };
        self.failures_in_a_row = 0;
        self.failing_since = None;
        let t0 = Instant::now();
        let used = self.tie_fix(fix, submitted);
        // Until the alignment exists, the latest usable fix predicts the next search: a wrong
        // first fix must not steer every search after it.
        if used
            && self.alignment.is_none()
            && let Some(pose) = submitted.pose
            && self.moves_provisional(fix, &pose, submitted.altitude)
        {
            let rotation = fix.orientation() * pose.rotation().inverse();
            let centre = nalgebra::Vector3::from(fix.position);
            let one_fix = Sim3 {
                scale: 1.0,
                rotation,
                translation: centre - rotation * pose.centre().coords,
            };
            self.refresh_takeoff();
            if self.takeoff_agrees(&one_fix, &[pose.centre()]) {
                tracing::debug!(
                    frame = submitted.frame,
                    fix_heading = fix.heading,
                    slam_rotation = ?pose.rotation().euler_angles(),
                    "provisional similarity from a fix"
                );
                self.provisional_heading_agrees = self.heading_agrees(&rotation);
                self.provisional = Some(one_fix);
                self.provisional_strong = fix.confidence >= self.config.strong_fix_confidence;
            } else {
                tracing::debug!(
                    frame = submitted.frame,
                    confidence = fix.confidence,
                    "a fix that puts the take-off too far from the given position leaves the search prior"
                );
            }
        }
        self.fixes.push(FixRecord {
            frame: submitted.frame,
            timestamp: submitted.timestamp,
            position: fix.position,
            heading: fix.heading,
            confidence: fix.confidence,
            ssim: fix.ssim,
            match_score: fix.match_score,
            tile: fix.tile,
            inliers: fix.inliers,
            searched_tiles: fix.searched_tiles,
            global: fix.global,
            used,
            inlier: false,
            injected,
            ms: fix.ms,
        });
        if used {
            self.refit();
        }
        for o in &mut self.observers {
            o.fix(&self.fixes[self.fixes.len() - 1]);
        }
        self.timing
            .alignment_ms
            .push(t0.elapsed().as_secs_f64() * 1e3);
        Some(outcome)
    }

    /// Whether `fix` (of a frame tracked at SLAM `pose`, `altitude` above ground) replaces the
    /// provisional similarity: always, unless it is weak (below
    /// [`JointLocConfig::strong_fix_confidence`]) while a strong fix made the provisional one
    /// and it lies farther from where that one puts the frame than twice the alignment's
    /// inlier bound (scaled with the altitude). A weak fix far off is most likely a wrong
    /// place (at 100 m over gravel under another sun: 15 inliers, 138 m off, after two fixes
    /// of 255 inliers); had it moved the prior, every later search would have looked around
    /// the wrong place, and fixes found there move with the UAV as right ones do. It is still
    /// tied: the alignment's consensus decides on it.
    fn moves_provisional(
        &self,
        fix: &jointloc_absloc::Fix,
        pose: &CameraToWorld,
        altitude: f64,
    ) -> bool {
        let Some(provisional) = &self.provisional else {
            return true;
        };
        if !self.provisional_strong || fix.confidence >= self.config.strong_fix_confidence {
            return true;
        }
        let predicted = provisional.transform_pose(pose).centre();
        let off = (predicted.x - fix.position[0]).hypot(predicted.y - fix.position[1]);
        let bound = 2.0 * self.config.inlier_threshold_m * self.config.range_looseness(altitude);
        if off > bound {
            tracing::debug!(
                off_m = off,
                bound_m = bound,
                confidence = fix.confidence,
                "a weak fix far from the provisional prediction leaves the search prior"
            );
        }
        off <= bound
    }

    /// Anchors the take-off at the first tracked frame of the flight's first map, when a
    /// take-off position is given (see [`JointLocConfig::start_radius_m`]), and then the
    /// frame a second later that gives the velocity to carry it back to the first frame.
    fn anchor_takeoff(
        &mut self,
        pose: Option<&CameraToWorld>,
        timestamp: f64,
        altitude: Option<f64>,
    ) {
        if self.config.start_position.is_none()
            || self.config.start_radius_m <= 0.0
            || self.slam.maps_started() > 0
        {
            return;
        }
        let (Some(pose), Some(kf), Some(first_frame_s)) = (
            pose,
            self.slam.map().last_keyframe(),
            self.clock.first_timestamp(),
        ) else {
            return;
        };
        match &mut self.takeoff {
            None if self.alignment.is_none() => {
                self.takeoff = Some(TakeOff::new(
                    first_frame_s,
                    timestamp,
                    altitude.unwrap_or(0.0),
                    kf.id,
                    &kf.pose.0,
                    pose.centre(),
                ));
            }
            Some(t) if t.needs_later() => t.observe(timestamp, kf.id, &kf.pose.0, pose.centre()),
            _ => {}
        }
    }

    /// The take-off anchor from its keyframes' current poses.
    pub(crate) fn refresh_takeoff(&mut self) {
        if let Some(t) = &mut self.takeoff {
            t.refresh(self.slam.map());
        }
    }

    /// Whether `s` (SLAM → world) puts the take-off within [`JointLocConfig::start_radius_m`]
    /// (and the allowances of [`crate::takeoff::tolerance_m`], the distance taken to the
    /// farthest of the fixes' SLAM camera centres `fix_cameras`) of the take-off position;
    /// true without a take-off or before it is known.
    pub(crate) fn takeoff_agrees(&self, s: &Sim3, fix_cameras: &[Point3<f64>]) -> bool {
        let (Some(takeoff), Some(start)) = (&self.takeoff, self.config.start_position) else {
            return true;
        };
        let Some((at, carried)) = takeoff.slam() else {
            return true;
        };
        let distance = fix_cameras
            .iter()
            .map(|p| (p - at).norm() * s.scale)
            .fold(0.0, f64::max);
        let miss = crate::takeoff::miss_m(s, &at, start);
        let tolerance = crate::takeoff::tolerance_m(
            self.config.start_radius_m,
            carried * s.scale,
            takeoff.range_m(),
            self.config.start_drift,
            distance,
        );
        miss <= tolerance
    }

    /// No provisional similarity: the next searches before the alignment start from the
    /// last world pose or the take-off position.
    pub(crate) fn forget_provisional(&mut self) {
        self.provisional = None;
        self.provisional_strong = false;
        self.provisional_heading_agrees = true;
    }

    /// Whether a new one-fix similarity with `rotation` (SLAM → world) turns the map by no
    /// more than [`JointLocConfig::provisional_turn_deg`] from the provisional one it replaces
    /// (true when there is none or the rule is off).
    fn heading_agrees(&self, rotation: &nalgebra::UnitQuaternion<f64>) -> bool {
        let max = self.config.provisional_turn_deg;
        let Some(previous) = &self.provisional else {
            return true;
        };
        let turn = rotation.angle_to(&previous.rotation).to_degrees();
        if max > 0.0 && turn > max {
            tracing::debug!(
                turn_deg = turn,
                max_deg = max,
                "two fixes disagree on the heading: the next search sweeps the headings"
            );
            return false;
        }
        true
    }

    /// Whether the latest fix that went into the fusion has at least
    /// [`JointLocConfig::strong_fix_confidence`]: before the first world pose, the next
    /// virtual frame is then searched around it (a confirmation must be as strong, see
    /// `first_fix_span_m`) instead of over the whole map.
    fn latest_fix_strong(&self) -> bool {
        self.fixes
            .iter()
            .rev()
            .find(|r| r.used)
            .is_some_and(|r| r.confidence >= self.config.strong_fix_confidence)
    }

    /// No world pose yet, no alignment and no take-off position: nothing but the fixes says
    /// where the flight is.
    pub(crate) fn unanchored(&self) -> bool {
        self.alignment.is_none()
            && self.last_world_pose.is_none()
            && self.config.start_position.is_none()
    }

    /// Sequential mode, before the first fix: whether the due search waits, backing off
    /// after failures (see [`JointLocConfig::blind_retry_max_s`]). Threaded, a search that
    /// outlasts the interval already skips the frames due meanwhile.
    fn blind_search_waits(&self, timestamp: f64) -> bool {
        let blind = self.alignment.is_none()
            && self.provisional.is_none()
            && self.last_world_pose.is_none();
        let (Absolute::Inline(_), true, Some((_, latest))) =
            (&self.absolute, blind, self.failing_since)
        else {
            return false;
        };
        crate::flight_time::blind_search_waits(
            self.failures_in_a_row,
            latest,
            timestamp,
            self.search_interval_s(),
            self.config.blind_retry_max_s,
        )
    }

    /// The search prior from the fused pose: position and heading of the last world pose;
    /// before the alignment, the current SLAM pose through the provisional one-fix similarity
    /// (after a new map, the last world pose of the old one until then). A last world pose
    /// older than [`dead_reckoning::FRESH_S`] is carried forward at the last ground velocity
    /// (see [`JointLocConfig::dead_reckoning_max_s`]) and its heading left out.
    /// Every [`JointLocConfig::sweep_after_failures`]-th search of a failing streak (once
    /// geo-referenced, the search each time the streak has lasted another
    /// [`JointLocConfig::sweep_after_failing_s`]) leaves the heading out, so the localiser
    /// sweeps rotations: the predicted heading may be what is wrong (a wrong fix or
    /// alignment), and with it every search would fail.
    ///
    /// A virtual frame with no take-off position, before any world pose
    /// ([`Self::unanchored`]), gets no prior: each fix the first alignment needs then comes
    /// from its own whole-map search. A search around the first fix would only confirm it: a
    /// wrong one, over gravel under another sun, was followed by 7 local fixes moving with the
    /// UAV and made an alignment 630 m off (`docs/absloc.md` §"With no prior: the whole map").
    fn prior(
        &self,
        slam_pose: Option<CameraToWorld>,
        timestamp: f64,
        virtual_frame: bool,
    ) -> Prior {
        if virtual_frame && self.unanchored() && !self.latest_fix_strong() {
            return Prior::default();
        }
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
        let sweep = if self.alignment.is_some() {
            crate::flight_time::sweep_due(
                self.failing_since,
                timestamp,
                self.config.sweep_after_failing_s,
            )
        } else {
            let every = self.config.sweep_after_failures;
            every == 0
                || (self.failures_in_a_row != 0 && self.failures_in_a_row.is_multiple_of(every))
        };
        // A stale heading is a guess: the UAV may have turned while it was not tracked.
        let trust_heading = carried.is_none()
            && (from_last_world_pose || self.provisional_heading_agrees)
            && !sweep;
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
}
