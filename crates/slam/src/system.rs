//! The sequential SLAM driver: frames in (image, timestamp, altitude), per-frame pose and state
//! out. Each frame is extracted and tracked; a new keyframe is mapped (local mapping and local
//! BA) before the next frame is read, which makes runs deterministic. Per-module times are
//! recorded for the timing summary.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Instant;

use jointloc_features::orb::{GrayImageView, OrbConfig, OrbExtractor};
use jointloc_geometry::trajectory::Trajectory;
use jointloc_geometry::{CameraToWorld, PinholeCamera, Sim3, WorldToCamera};
use nalgebra::{Isometry3, Vector3};
use serde::{Deserialize, Serialize};

use crate::cpu_time::{cpu_ms, thread_cpu_ns};
use crate::error::{Result, SlamError};
use crate::frame::{DEFAULT_MAX_OFF_AXIS_DEG, Frame, Undistorter, image_entropy};
use crate::local_mapping::{GroundModel, LocalMapper, LocalMappingConfig};
use crate::loop_closing::{LoopCloser, LoopClosingConfig, LoopClosure};
use crate::map::{GlobalFix, KeyFrameId, Map, RetiredKeyFrame};
use crate::tracking::{Tracker, TrackingConfig, TrackingState};

/// Settings of the whole relative-localisation system.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SystemConfig {
    pub orb: OrbConfig,
    pub tracking: TrackingConfig,
    pub local_mapping: LocalMappingConfig,
    pub loop_closing: LoopClosingConfig,
    /// Sliding-window cap on the keyframes in the map (0: no cap). Once exceeded, the oldest
    /// keyframes outside the newest keyframe's local window are retired with the points only
    /// they observe, so memory stops growing with the flight's length; their poses stay in the
    /// trajectories. Tracking, local BA and relocalisation (the 30 newest) work on the recent
    /// keyframes, but loop closing can only return to keyframes still in the map. Default 200
    /// (≈ 440 m of a straight 10 m-altitude flight), what `jointloc run` uses: it closes no
    /// loop once geo-referenced. `jointloc vo` has no cap unless told (ORB-SLAM2 has none): on
    /// a fresh 1000 m flight that crosses itself, loop closing gives 0.117 m without a cap and
    /// 0.508 m with 200 keyframes, for 342 MB of RSS instead of 139 MB (docs/vo.md §6.1a). The
    /// local window (itself + up to `local_mapping.ba.max_window` covisible keyframes) and the
    /// tracker's reference keyframe are never retired, so a cap below that many is exceeded.
    pub max_keyframes: usize,
    /// Keypoints further off the optical axis than this (degrees) are dropped when a lens
    /// model is undone (`frame::Undistorter`): a fisheye's rays reach 90°, where undistorted
    /// pixels run to infinity. Default 70 (a 133° fisheye keeps its whole width, the corners
    /// pulled in). No effect on a camera without distortion.
    pub max_off_axis_deg: f64,
}

impl Default for SystemConfig {
    fn default() -> Self {
        Self {
            orb: OrbConfig::default(),
            tracking: TrackingConfig::default(),
            local_mapping: LocalMappingConfig::default(),
            loop_closing: LoopClosingConfig::default(),
            max_keyframes: 200,
            max_off_axis_deg: DEFAULT_MAX_OFF_AXIS_DEG,
        }
    }
}

/// The result of one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameResult {
    pub index: usize,
    pub timestamp: f64,
    pub state: TrackingState,
    /// Camera-to-world pose in the SLAM frame as tracked (online), if tracked.
    pub pose: Option<CameraToWorld>,
    pub inliers: usize,
    /// The keyframe this frame became, if any.
    pub keyframe: Option<KeyFrameId>,
    pub relocalised: bool,
    /// The loop this frame's keyframe closed, if any (keyframe poses moved: re-read them).
    pub loop_closed: Option<LoopClosure>,
}

/// Per-module wall times, milliseconds (one entry per frame or per keyframe).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Timing {
    /// ORB extraction, per frame.
    pub orb_ms: Vec<f64>,
    /// Tracking (everything after extraction, before local mapping), per frame.
    pub tracking_ms: Vec<f64>,
    /// Local mapping incl. local BA, per keyframe.
    pub local_mapping_ms: Vec<f64>,
    /// Local BA alone, per keyframe.
    pub lba_ms: Vec<f64>,
    /// Whole frame, per frame.
    pub frame_ms: Vec<f64>,
    /// The same five as thread CPU time (empty where the platform cannot tell): on a shared
    /// machine the wall times above include waiting for a core.
    pub cpu: CpuTiming,
}

/// Per-module thread CPU times, milliseconds (same entries as [`Timing`]'s wall times).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct CpuTiming {
    pub orb_ms: Vec<f64>,
    pub tracking_ms: Vec<f64>,
    pub local_mapping_ms: Vec<f64>,
    pub lba_ms: Vec<f64>,
    pub frame_ms: Vec<f64>,
}

/// Median of a list of times (0 when empty).
pub fn median(values: &[f64]) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// What the final trajectory needs of a tracked frame: its pose relative to its reference
/// keyframe, so later keyframe corrections move it too (as ORB-SLAM2 saves trajectories).
#[derive(Debug, Clone, Copy)]
struct FrameRecord {
    timestamp: f64,
    reference: KeyFrameId,
    /// `T_c,ref`.
    relative: Isometry3<f64>,
}

/// A map set aside by [`System::start_new_map`], with what its trajectories need, until it is
/// merged back ([`System::merge_set_aside`]).
#[derive(Debug)]
struct SetAside {
    map: Map,
    records: Vec<FrameRecord>,
    culled: BTreeMap<KeyFrameId, (KeyFrameId, Isometry3<f64>)>,
    retired: BTreeMap<KeyFrameId, RetiredKeyFrame>,
}

/// Monocular SLAM, one frame at a time.
#[derive(Debug)]
pub struct System {
    camera: PinholeCamera,
    /// Keypoints → the tracker's pixels; its `ideal` camera is the one the tracker works
    /// with (no distortion, the undistorted image's bounds).
    undistorter: Undistorter,
    extractor: OrbExtractor,
    map: Map,
    tracker: Tracker,
    mapper: LocalMapper,
    loop_closer: LoopCloser,
    slam_to_world: Option<Sim3>,
    ground: Option<Arc<dyn GroundModel>>,
    records: Vec<FrameRecord>,
    culled: BTreeMap<KeyFrameId, (KeyFrameId, Isometry3<f64>)>,
    /// Keyframes retired by the cap, by id.
    retired: BTreeMap<KeyFrameId, RetiredKeyFrame>,
    max_keyframes: usize,
    timing: Timing,
    next_index: usize,
    last_timestamp: Option<f64>,
    maps_started: usize,
    /// Maps set aside after losses and not merged back, oldest first; `None` once merged.
    set_aside: Vec<Option<SetAside>>,
}

impl System {
    pub fn new(camera: PinholeCamera, config: SystemConfig) -> Result<Self> {
        let k = &camera;
        if ![k.fx, k.fy, k.cx, k.cy].iter().all(|v| v.is_finite()) || k.fx <= 0.0 || k.fy <= 0.0 {
            return Err(SlamError::NonFinite("camera intrinsics"));
        }
        let extractor = OrbExtractor::new(config.orb.clone())?;
        config.tracking.initialization.initializer.validate()?;
        if !(config.max_off_axis_deg > 0.0 && config.max_off_axis_deg < 90.0) {
            return Err(SlamError::InvalidConfig {
                field: "max_off_axis_deg",
                value: config.max_off_axis_deg.to_string(),
                reason: "must be in (0, 90) degrees",
            });
        }
        let map = Map::new(config.orb.scale_factor, config.orb.n_levels);
        Ok(Self {
            camera,
            undistorter: Undistorter::new(&camera, config.max_off_axis_deg),
            extractor,
            map,
            tracker: Tracker::new(config.tracking),
            mapper: LocalMapper::new(config.local_mapping),
            loop_closer: LoopCloser::new(config.loop_closing),
            slam_to_world: None,
            ground: None,
            records: Vec::new(),
            culled: BTreeMap::new(),
            retired: BTreeMap::new(),
            max_keyframes: config.max_keyframes,
            timing: Timing::default(),
            next_index: 0,
            last_timestamp: None,
            maps_started: 0,
            set_aside: Vec::new(),
        })
    }

    /// The camera the map's keypoints are measured in (the intrinsics without distortion:
    /// keypoints are undistorted on extraction; with a lens model, the undistorted image's
    /// bounds, see [`Undistorter`]), as the bundle adjustments use it.
    pub fn ideal_camera(&self) -> &PinholeCamera {
        &self.undistorter.ideal
    }

    /// The rectification from the camera's pixels to [`Self::ideal_camera`]'s.
    pub fn undistorter(&self) -> &Undistorter {
        &self.undistorter
    }

    pub fn map(&self) -> &Map {
        &self.map
    }

    /// The global-position factors of every keyframe in the map (the fusion's fixes tied to
    /// it, paper §III-C): a keyframe absent from `per_keyframe` gets none; ids not in the
    /// map (culled or retired since) are ignored.
    pub fn set_global_fixes(&mut self, mut per_keyframe: BTreeMap<KeyFrameId, Vec<GlobalFix>>) {
        let ids: Vec<KeyFrameId> = self.map.keyframes().map(|k| k.id).collect();
        for id in ids {
            if let Some(kf) = self.map.keyframe_mut(id) {
                kf.global_fixes = per_keyframe.remove(&id).unwrap_or_default();
            }
        }
    }

    pub fn state(&self) -> TrackingState {
        self.tracker.state()
    }

    pub fn timing(&self) -> &Timing {
        &self.timing
    }

    /// The SLAM→world similarity the local BA uses for global-position factors (`None`: no
    /// global factors).
    pub fn set_slam_to_world(&mut self, s: Option<Sim3>) {
        self.slam_to_world = s;
    }

    /// The terrain the local BA puts map points on once geo-referenced
    /// ([`LocalBaConfig::ground_sigma`](crate::local_mapping::LocalBaConfig::ground_sigma)).
    pub fn set_ground(&mut self, ground: Option<Arc<dyn GroundModel>>) {
        self.ground = ground;
    }

    /// Sets the map aside and starts a new one, which the next frames initialise in a new
    /// SLAM frame: for a loss that relocalisation cannot end (a UAV lost over ground its map
    /// never saw). Keyframe and point ids continue, so no id of the old map names anything in
    /// the new one. The old map's frames and keyframes leave [`Self::trajectory`] and
    /// [`Self::keyframe_trajectory`] until [`Self::merge_set_aside`] brings them back: a
    /// caller that wants them otherwise reads them first. Returns the index of the map set
    /// aside (its order among those set aside).
    pub fn start_new_map(&mut self) -> usize {
        tracing::info!(
            keyframes = self.map.n_keyframes(),
            points = self.map.n_points(),
            frame = self.next_index,
            "new map: the old one is set aside"
        );
        let successor = self.map.successor();
        self.set_aside.push(Some(SetAside {
            map: std::mem::replace(&mut self.map, successor),
            records: std::mem::take(&mut self.records),
            culled: std::mem::take(&mut self.culled),
            retired: std::mem::take(&mut self.retired),
        }));
        self.tracker = Tracker::new(self.tracker.config.clone());
        self.mapper = LocalMapper::new(self.mapper.config);
        self.loop_closer = LoopCloser::new(self.loop_closer.config);
        self.slam_to_world = None;
        self.maps_started += 1;
        self.set_aside.len() - 1
    }

    /// Merges the map set aside as `index` ([`Self::start_new_map`]'s return) into the current
    /// one, `to_current` taking its SLAM frame to the current map's: its keyframes, points,
    /// frames and retired keyframes come back, transformed (see [`Map::absorb`]). `Ok(None)`
    /// when there is no such map or it was merged already.
    pub fn merge_set_aside(
        &mut self,
        index: usize,
        to_current: &Sim3,
    ) -> Result<Option<crate::map::MergeReport>> {
        let Some(slot) = self.set_aside.get_mut(index) else {
            return Ok(None);
        };
        let Some(part) = slot.take() else {
            return Ok(None);
        };
        let s = *to_current;
        if let Err(e) = self.map.check_absorb(&part.map, &s) {
            *slot = Some(part);
            return Err(e);
        }
        let report = self.map.absorb(part.map, &s)?;
        // Rigid offsets in SLAM units scale with the map.
        let scaled = |mut iso: Isometry3<f64>| {
            iso.translation.vector *= s.scale;
            iso
        };
        let mut records: Vec<FrameRecord> = part
            .records
            .into_iter()
            .map(|r| FrameRecord {
                relative: scaled(r.relative),
                ..r
            })
            .chain(self.records.drain(..))
            .collect();
        records.sort_by(|a, b| a.timestamp.total_cmp(&b.timestamp));
        self.records = records;
        for (id, (parent, rel)) in part.culled {
            self.culled.insert(id, (parent, scaled(rel)));
        }
        for (id, mut r) in part.retired {
            r.pose = s.transform_pose(&r.pose.inverse()).inverse();
            self.retired.insert(id, r);
        }
        Ok(Some(report))
    }

    /// Maps set aside by [`Self::start_new_map`] and not merged back.
    pub fn maps_set_aside(&self) -> usize {
        self.set_aside.iter().flatten().count()
    }

    /// Loops closed in the current map, in order.
    pub fn loops_closed(&self) -> &[LoopClosure] {
        self.loop_closer.closed()
    }

    /// Maps started by [`Self::start_new_map`] since the first one.
    pub fn maps_started(&self) -> usize {
        self.maps_started
    }

    /// Declares tracking lost, forgetting the motion model (see [`Tracker::force_lost`]).
    pub fn force_lost(&mut self) {
        self.tracker.force_lost();
    }

    /// The error [`System::process`] would return for a frame of this size, timestamp and
    /// altitude before touching any state (wrong size, timestamp not finite or not after the
    /// previous frame's, altitude not finite and positive), or `Ok` when it would take it.
    pub fn check_frame(
        &self,
        width: usize,
        height: usize,
        timestamp: f64,
        altitude: Option<f64>,
    ) -> Result<()> {
        let bad = |reason: String| {
            Err(SlamError::InvalidFrame {
                index: self.next_index,
                reason,
            })
        };
        if width != self.camera.width as usize || height != self.camera.height as usize {
            return bad(format!(
                "image is {width}x{height} px, the camera {}x{}",
                self.camera.width, self.camera.height
            ));
        }
        if !timestamp.is_finite() || self.last_timestamp.is_some_and(|t| timestamp <= t) {
            return bad(format!(
                "timestamp {timestamp} is not finite or not increasing"
            ));
        }
        if let Some(a) = altitude
            && !(a.is_finite() && a > 0.0)
        {
            return bad(format!("altitude {a} is not a positive finite number"));
        }
        Ok(())
    }

    /// Processes the next frame. Errors on an image of the wrong size, a non-finite or
    /// non-increasing timestamp, or a non-finite / non-positive altitude.
    pub fn process(
        &mut self,
        image: GrayImageView<'_>,
        timestamp: f64,
        altitude: Option<f64>,
    ) -> Result<FrameResult> {
        let index = self.next_index;
        self.check_frame(image.width(), image.height(), timestamp, altitude)?;
        self.apply_background(false)?;
        self.next_index += 1;
        self.last_timestamp = Some(timestamp);
        let t0 = Instant::now();
        let c0 = thread_cpu_ns();
        let features = self.extractor.extract(image)?;
        let entropy = image_entropy(&image);
        let mut frame = Frame::rectified(
            index,
            timestamp,
            features,
            &self.undistorter,
            altitude,
            entropy,
        );
        let t1 = Instant::now();
        let c1 = thread_cpu_ns();
        let outcome = self
            .tracker
            .track(&mut frame, &mut self.map, &self.undistorter.ideal);
        let t2 = Instant::now();
        let c2 = thread_cpu_ns();
        let mut keyframe = None;
        let mut record = None;
        let mut loop_closed = None;
        if outcome.initialised {
            self.mapper.add_recent(&self.map);
            keyframe = self.map.last_keyframe().map(|k| k.id);
        } else if outcome.keyframe_needed
            // While a loop correction is solved on its thread the map must stay as it was
            // (ORB-SLAM2 stops local mapping for it); tracking goes on without new keyframes.
            && !self.loop_closer.correcting()
            && let Some(kf) = self.mapper.insert_keyframe(&mut self.map, &frame)
        {
            self.tracker.keyframe_inserted(&frame, kf);
            frame.reference = Some(kf);
            // Against its new keyframe as tracked, before the local BA moves that keyframe
            // (ORB-SLAM2 records the relative pose in tracking): the frame *is* the keyframe,
            // and its saved pose must be the keyframe's final one.
            record = self.frame_record(&frame, timestamp);
            let report = self.mapper.process(
                &mut self.map,
                kf,
                &self.undistorter.ideal,
                self.slam_to_world.as_ref(),
                self.ground.as_deref(),
            )?;
            for c in &report.culled_keyframes {
                self.culled.insert(c.id, (c.parent, c.relative));
            }
            self.timing.local_mapping_ms.push(report.total_ms);
            self.timing.lba_ms.push(report.lba_ms);
            let cpu = &mut self.timing.cpu;
            cpu.local_mapping_ms.extend(report.total_cpu_ms);
            cpu.lba_ms.extend(report.lba_cpu_ms);
            let before = self.map.keyframe(kf).map(|k| k.pose);
            loop_closed = self.loop_closer.process(
                &mut self.map,
                kf,
                &self.undistorter.ideal,
                &self.mapper.config.ba,
                self.slam_to_world.as_ref(),
            )?;
            if let (Some(_), Some(before)) = (loop_closed, before) {
                self.tracker.keyframes_moved(&self.map, &before, kf);
            }
            self.retire_old_keyframes(kf);
            keyframe = Some(kf);
        }
        let t3 = Instant::now();
        let c3 = thread_cpu_ns();
        self.timing.orb_ms.push(ms(t1 - t0));
        let cpu = &mut self.timing.cpu;
        cpu.orb_ms.extend(cpu_ms(c0, c1));
        cpu.tracking_ms.extend(cpu_ms(c1, c2));
        cpu.frame_ms.extend(cpu_ms(c0, c3));
        self.timing.tracking_ms.push(ms(t2 - t1));
        self.timing.frame_ms.push(ms(t3 - t0));
        if let Some(r) = record.or_else(|| self.frame_record(&frame, timestamp)) {
            self.records.push(r);
        }
        Ok(FrameResult {
            index,
            timestamp,
            state: outcome.state,
            pose: frame.pose.map(|p| p.inverse()),
            inliers: outcome.inliers,
            keyframe,
            relocalised: outcome.relocalised,
            loop_closed,
        })
    }

    /// Applies what loop closing finished on its threads (`wait`: waits for all of it; see
    /// [`LoopClosingConfig::global_ba_thread`](crate::loop_closing::LoopClosingConfig)), and
    /// moves the tracker's last frame with its reference keyframe.
    fn apply_background(&mut self, wait: bool) -> Result<()> {
        if !self.loop_closer.background_running() {
            return Ok(());
        }
        let reference = self.tracker.reference_keyframe();
        let before = reference.and_then(|r| self.map.keyframe(r)).map(|k| k.pose);
        let applied = self.loop_closer.poll_background(
            &mut self.map,
            &self.undistorter.ideal,
            &self.mapper.config.ba,
            self.slam_to_world.as_ref(),
            wait,
        )?;
        if applied.moved() {
            tracing::info!(
                ?applied,
                frame = self.next_index,
                "loop closing from its threads applied"
            );
            if let (Some(r), Some(b)) = (reference, before) {
                self.tracker.keyframes_moved(&self.map, &b, r);
            }
        }
        Ok(())
    }

    /// Waits for loop closing's background work and applies it: call before reading the
    /// final trajectories. Nothing to do without
    /// [`LoopClosingConfig::global_ba_thread`](crate::loop_closing::LoopClosingConfig).
    pub fn finish_background_work(&mut self) -> Result<()> {
        self.apply_background(true)
    }

    /// The frame's pose relative to its reference keyframe as that keyframe is now.
    fn frame_record(&self, frame: &Frame, timestamp: f64) -> Option<FrameRecord> {
        let (pose, reference) = (frame.pose?, frame.reference?);
        let ref_pose = self.keyframe_pose(reference)?;
        Some(FrameRecord {
            timestamp,
            reference,
            relative: pose.0 * ref_pose.0.inverse(),
        })
    }

    /// Keyframes retired by the sliding-window cap so far, by id.
    pub fn retired_keyframes(&self) -> &BTreeMap<KeyFrameId, RetiredKeyFrame> {
        &self.retired
    }

    /// Enforces `max_keyframes` after keyframe `newest` was mapped: retires the oldest
    /// keyframes outside its local window and the tracker's reference keyframe.
    fn retire_old_keyframes(&mut self, newest: KeyFrameId) {
        let cap = self.max_keyframes;
        if cap == 0 || self.map.n_keyframes() <= cap {
            return;
        }
        let mut keep: Vec<KeyFrameId> = self
            .map
            .local_window(newest, self.mapper.config.ba.max_window);
        keep.extend(self.tracker.reference_keyframe());
        let excess = self.map.n_keyframes() - cap;
        let old: Vec<KeyFrameId> = self
            .map
            .keyframes()
            .map(|k| k.id)
            .filter(|id| !keep.contains(id))
            .take(excess)
            .collect();
        for id in old {
            if let Some(r) = self.map.retire_keyframe(id) {
                self.retired.insert(id, r);
            }
        }
        tracing::debug!(
            retired = self.retired.len(),
            keyframes = self.map.n_keyframes(),
            points = self.map.n_points(),
            "keyframe cap"
        );
    }

    /// Current `T_cw` of a keyframe, following culled keyframes to their parents; retired
    /// keyframes keep their pose at retirement.
    fn keyframe_pose(&self, mut id: KeyFrameId) -> Option<WorldToCamera> {
        let mut chain = Isometry3::identity();
        for _ in 0..10_000 {
            if let Some(kf) = self.map.keyframe(id) {
                return Some(WorldToCamera(chain * kf.pose.0));
            }
            if let Some(r) = self.retired.get(&id) {
                return Some(WorldToCamera(chain * r.pose.0));
            }
            let (parent, rel) = self.culled.get(&id)?;
            chain *= rel;
            id = *parent;
        }
        None
    }

    /// Every tracked frame's camera-to-world pose in the SLAM frame, each expressed through its
    /// reference keyframe's current (optimised) pose, as ORB-SLAM2 saves trajectories. Frames
    /// that were lost, or processed before the initialisation, are absent.
    pub fn trajectory(&self) -> Result<Trajectory> {
        let mut stamps = Vec::new();
        let mut poses = Vec::new();
        for r in &self.records {
            if let Some(kf) = self.keyframe_pose(r.reference) {
                stamps.push(r.timestamp);
                poses.push(CameraToWorld((r.relative * kf.0).inverse()));
            }
        }
        Ok(Trajectory::new(stamps, poses)?)
    }

    /// The optical axes (unit, SLAM frame) of the tracked frames from `since` on (timestamp
    /// ≥ `since`), as [`System::trajectory`] poses them, oldest first. Reads the records from
    /// the newest back, so a short span of a long flight costs only its own frames.
    pub fn optical_axes_since(&self, since: f64) -> Vec<(f64, Vector3<f64>)> {
        let mut axes: Vec<(f64, Vector3<f64>)> = self
            .records
            .iter()
            .rev()
            .take_while(|r| r.timestamp >= since)
            .filter_map(|r| {
                let kf = self.keyframe_pose(r.reference)?;
                let t_cw = r.relative * kf.0;
                Some((r.timestamp, t_cw.rotation.inverse() * Vector3::z()))
            })
            .collect();
        axes.reverse();
        axes
    }

    /// For each pose of [`System::trajectory`], the keyframe it is expressed through: its
    /// reference keyframe, or, when that was culled, the keyframe the culling chain ends at
    /// (in the map, or retired by the cap).
    pub fn trajectory_keyframes(&self) -> Vec<KeyFrameId> {
        self.records
            .iter()
            .filter_map(|r| self.keyframe_root(r.reference))
            .collect()
    }

    /// The keyframe at the end of `id`'s culling chain (itself when not culled).
    fn keyframe_root(&self, mut id: KeyFrameId) -> Option<KeyFrameId> {
        for _ in 0..10_000 {
            if self.map.keyframe(id).is_some() || self.retired.contains_key(&id) {
                return Some(id);
            }
            id = self.culled.get(&id)?.0;
        }
        None
    }

    /// Camera-to-world poses of the keyframes in the map and of those retired by the cap
    /// (culled keyframes are absent).
    pub fn keyframe_trajectory(&self) -> Result<Trajectory> {
        let mut kfs: Vec<_> = self
            .map
            .keyframes()
            .map(|k| (k.timestamp, k.pose.inverse()))
            .chain(
                self.retired
                    .values()
                    .map(|r| (r.timestamp, r.pose.inverse())),
            )
            .collect();
        kfs.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (stamps, poses) = kfs.into_iter().unzip();
        Ok(Trajectory::new(stamps, poses)?)
    }
}

fn ms(d: std::time::Duration) -> f64 {
    d.as_secs_f64() * 1e3
}
