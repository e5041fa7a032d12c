//! Monocular map initialisation: matches between a reference frame and the current frame
//! (windowed search around the reference positions, as ORB-SLAM2's
//! `SearchForInitialization`), the two-view reconstruction of [`crate::initializer`], and the
//! first two keyframes with their points, refined by a bundle adjustment.

use jointloc_features::orb::{Match, MatcherConfig, WindowQuery, search_in_window};
use jointloc_geometry::{PinholeCamera, WorldToCamera};
use nalgebra::Point2;
use serde::{Deserialize, Serialize};

use crate::ba::{BaProblem, BundleAdjustmentConfig, Observation, bundle_adjust};
use crate::error::{Result, SlamError};
use crate::frame::Frame;
use crate::initializer::{Altitudes, InitializerConfig, initialize};
use crate::map::{KeyFrame, KeyFrameId, Map};

/// Settings of the initialisation stage.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct InitializationConfig {
    /// Two-view reconstruction.
    pub initializer: InitializerConfig,
    /// Half side of the search window around each reference keypoint, pixels (ORB-SLAM2: 100).
    pub window_px: f64,
    /// Matches needed before trying a reconstruction (ORB-SLAM2: 100).
    pub min_matches: usize,
    /// Points the second keyframe must keep after the bundle adjustment (ORB-SLAM2: 100).
    pub min_map_points: usize,
    /// Frames after which an unsuccessful reference frame is replaced by the current one,
    /// unless the attempt failed only for too little parallax (then the reference is kept
    /// until its matches fall below `min_matches`).
    pub max_reference_age: usize,
    /// Iterations of the two-keyframe bundle adjustment (ORB-SLAM2: 20).
    pub ba_iterations: usize,
}

impl Default for InitializationConfig {
    fn default() -> Self {
        Self {
            initializer: InitializerConfig::default(),
            window_px: 100.0,
            min_matches: 100,
            min_map_points: 100,
            max_reference_age: 30,
            ba_iterations: 20,
        }
    }
}

/// Matches of the reference keypoints (`query`) in the current frame (`train`): same octave
/// ± 1, inside the window, distance ≤ 50, ratio 0.9, one reference keypoint per current
/// keypoint, rotation check.
pub fn match_for_initialization(reference: &Frame, current: &Frame, window_px: f64) -> Vec<Match> {
    let queries: Vec<WindowQuery> = reference
        .features
        .keypoints
        .iter()
        .zip(&reference.features.descriptors)
        .map(|(k, d)| WindowQuery {
            descriptor: *d,
            x: k.x,
            y: k.y,
            radius: window_px,
            octaves: k.octave.saturating_sub(1)..=k.octave + 1,
            angle: Some(k.angle),
        })
        .collect();
    let cfg = MatcherConfig {
        max_distance: 50,
        ratio: 0.9,
        mutual: false,
        check_orientation: true,
        orientation_bins: 30,
    };
    search_in_window(&queries, &current.features, &current.grid, &cfg)
}

/// Tries to initialise the map from `reference` and `current`. On success the map holds two
/// keyframes (the reference at the identity) and `current` is tracked against the second.
pub fn try_initialize(
    map: &mut Map,
    reference: &Frame,
    current: &mut Frame,
    camera: &PinholeCamera,
    config: &InitializationConfig,
) -> Result<(KeyFrameId, KeyFrameId)> {
    let matches = match_for_initialization(reference, current, config.window_px);
    if matches.len() < config.min_matches {
        return Err(SlamError::InitializationFailed {
            reason: format!("{} matches, {} required", matches.len(), config.min_matches),
        });
    }
    let x1: Vec<Point2<f64>> = matches.iter().map(|m| reference.pixel(m.query)).collect();
    let x2: Vec<Point2<f64>> = matches.iter().map(|m| current.pixel(m.train)).collect();
    let altitudes = Altitudes {
        reference: reference.altitude,
        current: current.altitude,
    };
    let init = initialize(&x1, &x2, camera, altitudes, &config.initializer)?;

    let mut kf0 = KeyFrame::new(
        reference.index,
        reference.timestamp,
        WorldToCamera::identity(),
        reference.features.clone(),
        reference.grid.clone(),
    );
    kf0.altitude = reference.altitude;
    let mut kf1 = KeyFrame::new(
        current.index,
        current.timestamp,
        init.pose2,
        current.features.clone(),
        current.grid.clone(),
    );
    kf1.altitude = current.altitude;
    let mut fresh = map.successor();
    let k0 = fresh.insert_keyframe(kf0);
    let k1 = fresh.insert_keyframe(kf1);
    let mut points = Vec::new();
    for (mi, x) in &init.points {
        let m = matches[*mi];
        if let Some(id) = fresh.insert_point(*x, k0, m.query) {
            fresh.add_observation(id, k1, m.train);
            points.push(id);
        }
    }
    for &id in &points {
        fresh.update_descriptor(id);
        fresh.update_normal_and_depth(id);
    }
    fresh.update_connections(k0);
    fresh.update_connections(k1);
    refine_two_view(&mut fresh, camera, config.ba_iterations)?;
    let kept = fresh.keyframe(k1).map_or(0, KeyFrame::n_points);
    if kept < config.min_map_points {
        return Err(SlamError::InitializationFailed {
            reason: format!(
                "{kept} map points after BA, {} required",
                config.min_map_points
            ),
        });
    }
    let kf1 = fresh.keyframe(k1).expect("inserted above");
    current.clear_matches();
    current.points.clone_from(&kf1.points);
    current.pose = Some(kf1.pose);
    current.reference = Some(k1);
    tracing::info!(
        model = ?init.model,
        points = kept,
        scale = ?init.scale,
        reference = reference.index,
        current = current.index,
        "map initialised"
    );
    *map = fresh;
    Ok((k0, k1))
}

/// Bundle adjustment of every keyframe and point with the first keyframe fixed; erases the
/// observations it flags as outliers.
fn refine_two_view(map: &mut Map, camera: &PinholeCamera, iterations: usize) -> Result<()> {
    let mut problem = BaProblem::new(*camera);
    let kfs: Vec<KeyFrameId> = map.keyframes().map(|k| k.id).collect();
    for (i, k) in kfs.iter().enumerate() {
        let kf = map.keyframe(*k).expect("listed");
        problem.add_camera(kf.pose, i == 0);
    }
    let ids: Vec<_> = map.points().map(|p| p.id).collect();
    let mut obs_keys = Vec::new();
    for (pi, id) in ids.iter().enumerate() {
        let p = map.point(*id).expect("listed");
        problem.add_point(p.position, false);
        for (kf, &idx) in p.observations() {
            let ci = kfs.iter().position(|k| k == kf).expect("listed");
            let k = &map.keyframe(*kf).expect("listed").features.keypoints[idx];
            problem.observations.push(Observation::at_level(
                ci,
                pi,
                Point2::new(k.x, k.y),
                k.octave,
                map.scale_factor(),
            ));
            obs_keys.push((*id, *kf));
        }
    }
    let cfg = BundleAdjustmentConfig {
        max_iterations: iterations,
        ..BundleAdjustmentConfig::default()
    };
    let result = bundle_adjust(&problem, &cfg)?;
    for (k, pose) in kfs.iter().zip(&result.cameras) {
        if let Some(kf) = map.keyframe_mut(*k) {
            kf.pose = *pose;
        }
    }
    for (id, x) in ids.iter().zip(&result.points) {
        if let Some(p) = map.point_mut(*id) {
            p.position = *x;
        }
    }
    for (&(id, kf), &outlier) in obs_keys.iter().zip(&result.outliers) {
        if outlier {
            map.remove_observation(id, kf);
        }
    }
    for id in ids {
        map.update_normal_and_depth(id);
    }
    Ok(())
}
