//! Tracking (ORB-SLAM2's `Tracking`, paper §III-C): initialisation, then per frame a pose from
//! the constant-velocity motion model (reference-keyframe fallback, PnP relocalisation when
//! lost), refined against the local map, and the keyframe decision.

pub mod initialization;
pub mod keyframe_decision;
pub mod local_map;
pub mod pose_optimization;
pub mod projection;
pub mod reference;

use std::sync::Arc;

use jointloc_features::orb::MatcherConfig;
use jointloc_geometry::{PinholeCamera, WorldToCamera};
use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

use crate::error::SlamError;
use crate::frame::Frame;
use crate::loop_closing::appearance::BowCache;
use crate::map::{KeyFrameId, Map};
use crate::place::Vocabulary;
use crate::relocalisation::{RelocalisationConfig, relocalise};

pub use initialization::{InitializationConfig, try_initialize};
pub use keyframe_decision::{KeyframeContext, KeyframeDecisionConfig, need_keyframe};
pub use local_map::{LocalMap, build_local_map};
pub use pose_optimization::{PoseOptimizationConfig, optimize_pose};

/// The isometry with its quaternion re-normalised: products of unit quaternions drift off the
/// unit sphere, and the motion model would compound the drift frame after frame.
pub fn renormalized(mut iso: Isometry3<f64>) -> Isometry3<f64> {
    iso.rotation.renormalize();
    iso
}

/// Settings of the tracker; defaults are ORB-SLAM2's unless noted.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrackingConfig {
    pub initialization: InitializationConfig,
    pub pose_optimization: PoseOptimizationConfig,
    pub keyframe: KeyframeDecisionConfig,
    pub relocalisation: RelocalisationConfig,
    /// Motion-model search window at level 0, pixels (ORB-SLAM2 monocular: 15; doubled when
    /// too few matches are found).
    pub motion_window_px: f64,
    /// Matches the motion-model search must find (ORB-SLAM2: 20).
    pub min_motion_matches: usize,
    /// Inliers the motion-model or reference-keyframe pose must keep (ORB-SLAM2: 10).
    pub min_pose_inliers: usize,
    /// Local-map search window factor (ORB-SLAM2: 1; 3 right after a relocalisation).
    pub local_map_th: f64,
    /// Local keyframes at most (ORB-SLAM2: 80).
    pub max_local_keyframes: usize,
    /// Inliers after the local-map optimisation for tracking to count as good (ORB-SLAM2: 30,
    /// and `min_inliers_after_relocalisation` within `relocalisation_grace` frames of one).
    pub min_local_map_inliers: usize,
    pub min_inliers_after_relocalisation: usize,
    pub relocalisation_grace: usize,
}

impl Default for TrackingConfig {
    fn default() -> Self {
        Self {
            initialization: InitializationConfig::default(),
            pose_optimization: PoseOptimizationConfig::default(),
            keyframe: KeyframeDecisionConfig::default(),
            relocalisation: RelocalisationConfig::default(),
            motion_window_px: 15.0,
            min_motion_matches: 20,
            min_pose_inliers: 10,
            local_map_th: 1.0,
            max_local_keyframes: 80,
            min_local_map_inliers: 30,
            min_inliers_after_relocalisation: 50,
            relocalisation_grace: 10,
        }
    }
}

/// Where the tracker stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrackingState {
    /// No map yet.
    NotInitialized,
    /// The frame was tracked.
    Ok,
    /// The frame could not be tracked (relocalisation is tried on the next ones).
    Lost,
}

/// What happened to one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackOutcome {
    pub state: TrackingState,
    /// Inlier map-point matches of the frame.
    pub inliers: usize,
    /// The map was initialised with this frame (it is the second keyframe).
    pub initialised: bool,
    /// The frame was relocalised.
    pub relocalised: bool,
    /// The frame should become a keyframe.
    pub keyframe_needed: bool,
}

/// The tracker's state between frames.
#[derive(Debug, Clone)]
pub struct Tracker {
    pub config: TrackingConfig,
    state: TrackingState,
    init_reference: Option<Frame>,
    last_frame: Option<Frame>,
    /// `T_cw(k) · T_cw(k−1)⁻¹` of the last two tracked frames.
    velocity: Option<Isometry3<f64>>,
    reference_kf: Option<KeyFrameId>,
    last_keyframe_frame: usize,
    last_relocalisation: Option<usize>,
    /// The vocabulary of relocalisation by appearance, when it is on.
    vocabulary: Option<Arc<Vocabulary>>,
    bows: BowCache,
}

impl Tracker {
    pub fn new(config: TrackingConfig) -> Self {
        let vocabulary = (config.relocalisation.appearance_candidates > 0).then(Vocabulary::shared);
        Self {
            config,
            state: TrackingState::NotInitialized,
            init_reference: None,
            last_frame: None,
            velocity: None,
            reference_kf: None,
            last_keyframe_frame: 0,
            last_relocalisation: None,
            vocabulary,
            bows: BowCache::default(),
        }
    }

    pub fn state(&self) -> TrackingState {
        self.state
    }

    /// The keyframe the current frame is tracked against.
    pub fn reference_keyframe(&self) -> Option<KeyFrameId> {
        self.reference_kf
    }

    /// Forgets the motion and the last frame and declares tracking lost (tests, or a caller
    /// that knows the frames are discontinuous); the next frames relocalise.
    pub fn force_lost(&mut self) {
        if self.state != TrackingState::NotInitialized {
            self.state = TrackingState::Lost;
        }
        self.velocity = None;
        self.last_frame = None;
    }

    /// Records that `frame` became keyframe `kf`.
    pub fn keyframe_inserted(&mut self, frame: &Frame, kf: KeyFrameId) {
        self.reference_kf = Some(kf);
        self.last_keyframe_frame = frame.index;
        if let Some(last) = self.last_frame.as_mut()
            && last.index == frame.index
        {
            last.reference = Some(kf);
        }
    }

    /// Keyframe poses were changed under the tracker (a loop correction): the last frame
    /// follows its reference keyframe, keeping its pose relative to it as tracked. The motion
    /// model is relative and stays.
    pub fn keyframes_moved(&mut self, map: &Map, before: &WorldToCamera, kf: KeyFrameId) {
        let Some(last) = self.last_frame.as_mut() else {
            return;
        };
        let (Some(pose), Some(k)) = (last.pose, map.keyframe(kf)) else {
            return;
        };
        let relative = pose.0 * before.0.inverse();
        last.pose = Some(WorldToCamera(renormalized(relative * k.pose.0)));
    }

    /// Tracks `frame` (features extracted, pose unset) against `map`.
    pub fn track(
        &mut self,
        frame: &mut Frame,
        map: &mut Map,
        camera: &PinholeCamera,
    ) -> TrackOutcome {
        let mut outcome = TrackOutcome {
            state: self.state,
            inliers: 0,
            initialised: false,
            relocalised: false,
            keyframe_needed: false,
        };
        if self.state == TrackingState::NotInitialized {
            outcome.initialised = self.initialise(frame, map, camera);
            if !outcome.initialised {
                return outcome;
            }
            outcome.state = TrackingState::Ok;
            outcome.inliers = frame.n_inliers();
            self.finish(frame, true);
            return outcome;
        }
        let mut ok = self.state == TrackingState::Ok
            && (self.track_motion_model(frame, map, camera)
                || self.track_reference_keyframe(frame, map, camera));
        if !ok {
            // Lost, or the motion and reference searches just failed: relocalise right away.
            frame.clear_matches();
            let cfg = &self.config.relocalisation;
            let place = self.vocabulary.as_deref().map(|v| (v, &mut self.bows));
            if let Some(kf) = relocalise(
                frame,
                map,
                camera,
                cfg,
                &self.config.pose_optimization,
                place,
            ) {
                self.reference_kf = Some(kf);
                self.last_relocalisation = Some(frame.index);
                outcome.relocalised = true;
                ok = true;
            }
        }
        if ok {
            outcome.inliers = self.track_local_map(frame, map, camera);
            let recent = self
                .last_relocalisation
                .is_some_and(|r| frame.index < r + self.config.relocalisation_grace);
            let needed = if recent {
                self.config.min_inliers_after_relocalisation
            } else {
                self.config.min_local_map_inliers
            };
            ok = outcome.inliers >= needed;
        }
        if !ok {
            tracing::debug!(
                frame = frame.index,
                inliers = outcome.inliers,
                "tracking lost"
            );
            frame.pose = None;
            frame.clear_matches();
            self.state = TrackingState::Lost;
            self.velocity = None;
            self.last_frame = None;
            outcome.state = TrackingState::Lost;
            return outcome;
        }
        tracing::trace!(frame = frame.index, inliers = outcome.inliers, "tracked");
        self.state = TrackingState::Ok;
        outcome.state = TrackingState::Ok;
        frame.reference = self.reference_kf;
        outcome.keyframe_needed = self.decide_keyframe(frame, map, outcome.inliers);
        self.finish(frame, false);
        outcome
    }

    fn initialise(&mut self, frame: &mut Frame, map: &mut Map, camera: &PinholeCamera) -> bool {
        let cfg = &self.config.initialization;
        let Some(reference) = self.init_reference.as_ref() else {
            if frame.features.len() > cfg.min_matches {
                self.init_reference = Some(frame.clone());
            }
            return false;
        };
        match try_initialize(map, reference, frame, camera, cfg) {
            Ok((_, k1)) => {
                self.init_reference = None;
                self.reference_kf = Some(k1);
                self.last_keyframe_frame = frame.index;
                self.state = TrackingState::Ok;
                true
            }
            Err(e) => {
                tracing::debug!(frame = frame.index, error = %e, "initialisation attempt failed");
                // Too little parallax with enough matches: the baseline is still growing (at
                // 200 m, 2.5° takes 9 m), so the reference is kept, as ORB-SLAM2 keeps its
                // own while it has matches.
                let waiting = matches!(e, SlamError::ParallaxTooLow { .. });
                if !waiting
                    && frame.index >= reference.index + cfg.max_reference_age
                    && frame.features.len() > cfg.min_matches
                {
                    self.init_reference = Some(frame.clone());
                }
                false
            }
        }
    }

    /// Updates the motion model and keeps the frame as the last one.
    fn finish(&mut self, frame: &mut Frame, reset_velocity: bool) {
        frame.pose = frame.pose.map(|p| WorldToCamera(renormalized(p.0)));
        self.velocity = match (&self.last_frame, frame.pose, reset_velocity) {
            (Some(last), Some(pose), false) if last.index + 1 == frame.index => {
                last.pose.map(|lp| renormalized(pose.0 * lp.0.inverse()))
            }
            _ => None,
        };
        self.last_frame = Some(frame.clone());
    }

    fn track_motion_model(&mut self, frame: &mut Frame, map: &Map, camera: &PinholeCamera) -> bool {
        let (Some(v), Some(last)) = (self.velocity, self.last_frame.as_ref()) else {
            return false;
        };
        let Some(last_pose) = last.pose else {
            return false;
        };
        frame.pose = Some(WorldToCamera(renormalized(v * last_pose.0)));
        frame.clear_matches();
        let matcher = MatcherConfig {
            max_distance: 100,
            ratio: 1.0,
            mutual: false,
            check_orientation: true,
            orientation_bins: 30,
        };
        let th = self.config.motion_window_px;
        let mut n = projection::search_last_frame(frame, last, map, camera, th, &matcher);
        if n < self.config.min_motion_matches {
            frame.clear_matches();
            n = projection::search_last_frame(frame, last, map, camera, 2.0 * th, &matcher);
        }
        if n < self.config.min_motion_matches {
            frame.clear_matches();
            return false;
        }
        self.optimise_and_check(frame, map, camera)
    }

    fn track_reference_keyframe(
        &mut self,
        frame: &mut Frame,
        map: &Map,
        camera: &PinholeCamera,
    ) -> bool {
        let Some(kf) = self.reference_kf.and_then(|k| map.keyframe(k)) else {
            return false;
        };
        let matches = reference::match_keyframe(frame, kf, map, &reference::keyframe_matcher(0.7));
        if matches.len() < 15 {
            return false;
        }
        frame.clear_matches();
        for (i, id) in matches {
            frame.points[i] = Some(id);
        }
        frame.pose = self
            .last_frame
            .as_ref()
            .and_then(|l| l.pose)
            .or(Some(kf.pose));
        self.optimise_and_check(frame, map, camera)
    }

    fn optimise_and_check(&self, frame: &mut Frame, map: &Map, camera: &PinholeCamera) -> bool {
        let n = optimize_pose(frame, map, camera, &self.config.pose_optimization);
        frame.drop_outliers();
        n >= self.config.min_pose_inliers
    }

    /// Projects the local map into the frame, re-optimises, updates the points' found counters;
    /// returns the inliers.
    fn track_local_map(
        &mut self,
        frame: &mut Frame,
        map: &mut Map,
        camera: &PinholeCamera,
    ) -> usize {
        let local = build_local_map(frame, map, self.config.max_local_keyframes);
        if let Some(r) = local.reference {
            self.reference_kf = Some(r);
        }
        let matched: std::collections::BTreeSet<_> =
            frame.points.iter().flatten().copied().collect();
        for id in &matched {
            if let Some(p) = map.point_mut(*id) {
                p.visible += 1;
            }
        }
        let candidates: Vec<_> = local
            .points
            .iter()
            .filter(|p| !matched.contains(p))
            .copied()
            .collect();
        let just_relocalised = self
            .last_relocalisation
            .is_some_and(|r| frame.index < r + 2);
        let th = if just_relocalised {
            3.0
        } else {
            self.config.local_map_th
        };
        let matcher = MatcherConfig {
            max_distance: 100,
            ratio: 0.8,
            mutual: false,
            check_orientation: false,
            orientation_bins: 30,
        };
        projection::search_local_points(frame, map, &candidates, camera, th, &matcher);
        let inliers = optimize_pose(frame, map, camera, &self.config.pose_optimization);
        for (id, outlier) in frame.points.iter().zip(&frame.outliers) {
            if let (Some(id), false) = (id, outlier)
                && let Some(p) = map.point_mut(*id)
            {
                p.found += 1;
            }
        }
        frame.drop_outliers();
        inliers
    }

    fn decide_keyframe(&self, frame: &Frame, map: &Map, inliers: usize) -> bool {
        let min_obs = if map.n_keyframes() <= 2 { 2 } else { 3 };
        let reference_points = self
            .reference_kf
            .and_then(|k| map.keyframe(k))
            .map_or(0, |kf| {
                kf.points
                    .iter()
                    .flatten()
                    .filter(|p| {
                        map.point(**p)
                            .is_some_and(|p| p.n_observations() >= min_obs)
                    })
                    .count()
            });
        let ctx = KeyframeContext {
            frames_since_keyframe: frame.index.saturating_sub(self.last_keyframe_frame),
            inliers,
            reference_points,
            entropy_bits: frame.entropy,
        };
        need_keyframe(&ctx, &self.config.keyframe)
    }
}
