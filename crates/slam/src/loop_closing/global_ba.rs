//! Global bundle adjustment after a loop (ORB-SLAM2's `RunGlobalBundleAdjustment`): every
//! keyframe and point of the map, the first keyframe fixed, the absolute fixes as global
//! factors when the map is geo-referenced (as in the local BA). The pose graph spreads the
//! loop's error along the path; this lets the images settle it.

use std::collections::BTreeMap;

use jointloc_geometry::{PinholeCamera, Sim3};
use nalgebra::Point2;

use crate::ba::{BaProblem, GlobalPositionFactor, Observation, bundle_adjust_two_stage};
use crate::error::Result;
use crate::local_mapping::LocalBaConfig;
use crate::map::{KeyFrameId, Map, MapPointId};

/// What the global BA did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct GlobalBaStats {
    pub keyframes: usize,
    pub points: usize,
    pub observations: usize,
    pub outliers_removed: usize,
    pub iterations: usize,
}

/// Optimises the whole map in place; observations flagged as outliers are erased.
pub fn global_bundle_adjustment(
    map: &mut Map,
    camera: &PinholeCamera,
    config: &LocalBaConfig,
    slam_to_world: Option<&Sim3>,
) -> Result<GlobalBaStats> {
    let mut stats = GlobalBaStats::default();
    let first = map.keyframes().next().map(|k| k.id);
    let mut problem = BaProblem::new(*camera);
    let mut cam_index: BTreeMap<KeyFrameId, usize> = BTreeMap::new();
    for k in map.keyframes() {
        let is_fixed = Some(k.id) == first;
        let ci = problem.add_camera(k.pose, is_fixed);
        cam_index.insert(k.id, ci);
        if let (Some(s), false) = (slam_to_world, is_fixed) {
            for fix in k.global_fixes() {
                problem.add_global_factor(GlobalPositionFactor {
                    sigma: config.global_sigma * fix.sigma_scale,
                    kernel: config.global_kernel,
                    point_in_camera: fix.point_in_camera,
                    ..GlobalPositionFactor::new(ci, fix.position, *s, fix.weight)
                });
            }
        }
    }
    stats.keyframes = cam_index.len();
    let sf = map.scale_factor();
    let mut ids: Vec<MapPointId> = Vec::new();
    let mut obs_keys: Vec<(MapPointId, KeyFrameId)> = Vec::new();
    for p in map.points() {
        let pi = problem.add_point(p.position, false);
        ids.push(p.id);
        for (k, &i) in p.observations() {
            let (Some(&ci), Some(kf)) = (cam_index.get(k), map.keyframe(*k)) else {
                continue;
            };
            let kp = &kf.features.keypoints[i];
            problem.observations.push(Observation::at_level(
                ci,
                pi,
                Point2::new(kp.x, kp.y),
                kp.octave,
                sf,
            ));
            obs_keys.push((p.id, *k));
        }
    }
    stats.points = ids.len();
    stats.observations = obs_keys.len();
    let result = bundle_adjust_two_stage(&problem, &config.solver)?;
    stats.iterations = result.iterations;
    for (k, &ci) in &cam_index {
        if !problem.cameras[ci].fixed
            && let Some(kf) = map.keyframe_mut(*k)
        {
            kf.pose = result.cameras[ci];
        }
    }
    for (id, x) in ids.iter().zip(&result.points) {
        if let Some(p) = map.point_mut(*id) {
            p.position = *x;
        }
    }
    for (&(id, k), &outlier) in obs_keys.iter().zip(&result.outliers) {
        if outlier {
            map.remove_observation(id, k);
            stats.outliers_removed += 1;
        }
    }
    let all: Vec<MapPointId> = map.points().map(|p| p.id).collect();
    for id in all {
        map.update_normal_and_depth(id);
    }
    tracing::debug!(?stats, "global BA after a loop");
    Ok(stats)
}
