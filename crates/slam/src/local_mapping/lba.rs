//! Local bundle adjustment (ORB-SLAM2's `LocalBundleAdjustment`) over the new keyframe and its
//! covisible neighbours, with the keyframes that see the local points but are outside the
//! window held fixed, plus JointLoc's global-position factors for keyframes that carry an
//! absolute fix (paper §III-C, `f(x)`), given the current SLAM→world similarity.

use std::collections::{BTreeMap, BTreeSet};

use jointloc_geometry::{PinholeCamera, RobustKernel, Sim3};
use nalgebra::Point2;
use serde::{Deserialize, Serialize};

use crate::ba::{
    BaProblem, CHI2_3DOF_95, GlobalPositionFactor, GroundHeightFactor, GroundPlane, Observation,
    TwoStageConfig, bundle_adjust_two_stage,
};
use crate::error::Result;
use crate::map::{KeyFrameId, Map, MapPointId};

/// Settings of [`local_bundle_adjustment`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LocalBaConfig {
    /// The solver schedule (ORB-SLAM2: 5 robust iterations, outliers out, 10 more).
    pub solver: TwoStageConfig,
    /// Covisible keyframes optimised with the new one at most (ORB-SLAM2: all covisible).
    pub max_window: usize,
    /// Fixed keyframes at most (those observing most local points are kept).
    pub max_fixed: usize,
    /// σ_G of a global fix of confidence 1, metres (world frame); a fix of confidence w has
    /// information w / σ_G². JointLoc's fixed ground points are within ~0.07 m of the truth;
    /// 0.15 m measured best of 1 / 0.15 / 0.1 / 0.07 (`docs/jointloc.md` §5): stronger pulls the
    /// map onto the fixes' noise, weaker lets the SLAM drift.
    pub global_sigma: f64,
    /// Kernel of the global-position factors.
    pub global_kernel: RobustKernel,
    /// σ of the terrain height at a map point, metres, for the ground-height factors that put
    /// the window's points onto the elevation model once the map is geo-referenced (they fix the
    /// local map's tilt); 0: off. Only used with a [`GroundModel`]. 0.05 m, the simulated DEM's
    /// stated σ: on 18 fresh flights 1–3 % better than 0.1 online and at the end, on the six
    /// development flights 22 % at the end (`docs/jointloc.md` §"Ground factors"); a coarser
    /// or noisier model (a HiRISE DTM: 1 m posts, decimetres) wants its own vertical
    /// precision: the factors use the larger of this and the model's stated σ
    /// ([`GroundModel::sigma_m`], `map.toml`'s `[elevation] sigma_m`).
    pub ground_sigma: f64,
    /// Kernel of the ground-height factors (rocks and crater rims stand off a smooth model).
    pub ground_kernel: RobustKernel,
}

/// Terrain heights in the world frame (an orbital elevation model).
pub trait GroundModel: Send + Sync + std::fmt::Debug {
    /// The terrain at world `(x, y)` as a plane (height and slope there); `None` outside the
    /// model.
    fn plane_at(&self, x: f64, y: f64) -> Option<GroundPlane>;

    /// The model's stated vertical precision (1 σ), metres; 0 when it states none. A ground
    /// factor is never held tighter than this.
    fn sigma_m(&self) -> f64 {
        0.0
    }
}

/// σ of the ground-height factors: the configured one, never below the model's own precision
/// (a non-finite or negative stated σ counts as none).
pub fn ground_factor_sigma(configured: f64, model: f64) -> f64 {
    if model.is_finite() && model > configured {
        model
    } else {
        configured
    }
}

impl Default for LocalBaConfig {
    fn default() -> Self {
        Self {
            solver: TwoStageConfig::default(),
            max_window: 20,
            max_fixed: 30,
            global_sigma: 0.15,
            global_kernel: RobustKernel::Huber {
                delta: CHI2_3DOF_95.sqrt(),
            },
            ground_sigma: 0.05,
            ground_kernel: RobustKernel::Huber { delta: 1.0 },
        }
    }
}

/// What a local BA did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LbaStats {
    pub free_keyframes: usize,
    pub fixed_keyframes: usize,
    pub points: usize,
    pub observations: usize,
    pub global_factors: usize,
    pub ground_factors: usize,
    pub outliers_removed: usize,
    pub iterations: usize,
}

/// Optimises the local window of `kf` and writes poses and points back; observations flagged
/// as outliers are erased from the map. `slam_to_world` enables the global-position factors of
/// the window keyframes' `global_fixes` and, with `ground`, the ground-height factors of the
/// free points.
pub fn local_bundle_adjustment(
    map: &mut Map,
    kf: KeyFrameId,
    camera: &PinholeCamera,
    config: &LocalBaConfig,
    slam_to_world: Option<&Sim3>,
    ground: Option<&dyn GroundModel>,
) -> Result<LbaStats> {
    let first = map.keyframes().next().map(|k| k.id);
    let window: Vec<KeyFrameId> = map.local_window(kf, config.max_window);
    if window.len() < 2 {
        return Ok(LbaStats::default());
    }
    let window_set: BTreeSet<KeyFrameId> = window.iter().copied().collect();
    let mut points: BTreeSet<MapPointId> = BTreeSet::new();
    for k in &window {
        if let Some(k) = map.keyframe(*k) {
            points.extend(k.points.iter().flatten().copied());
        }
    }
    let points: Vec<MapPointId> = points.into_iter().collect();
    let mut fixed_counts: BTreeMap<KeyFrameId, usize> = BTreeMap::new();
    for id in &points {
        if let Some(p) = map.point(*id) {
            for o in p.observations().keys().filter(|o| !window_set.contains(o)) {
                *fixed_counts.entry(*o).or_default() += 1;
            }
        }
    }
    let mut fixed: Vec<(KeyFrameId, usize)> = fixed_counts.into_iter().collect();
    fixed.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    fixed.truncate(config.max_fixed);
    let mut problem = BaProblem::new(*camera);
    let mut cam_index: BTreeMap<KeyFrameId, usize> = BTreeMap::new();
    let mut stats = LbaStats::default();
    for k in &window {
        let kfr = map.keyframe(*k).expect("window keyframes exist");
        let is_fixed = Some(*k) == first;
        let ci = problem.add_camera(kfr.pose, is_fixed);
        cam_index.insert(*k, ci);
        if is_fixed {
            stats.fixed_keyframes += 1;
        } else {
            stats.free_keyframes += 1;
            if let Some(s) = slam_to_world {
                for fix in &kfr.global_fixes {
                    problem.add_global_factor(GlobalPositionFactor {
                        sigma: config.global_sigma * fix.sigma_scale,
                        kernel: config.global_kernel,
                        point_in_camera: fix.point_in_camera,
                        ..GlobalPositionFactor::new(ci, fix.position, *s, fix.weight)
                    });
                    stats.global_factors += 1;
                }
            }
        }
    }
    for (k, _) in &fixed {
        let kfr = map.keyframe(*k).expect("observing keyframes exist");
        cam_index.insert(*k, problem.add_camera(kfr.pose, true));
        stats.fixed_keyframes += 1;
    }
    let sf = map.scale_factor();
    let mut obs_keys: Vec<(MapPointId, KeyFrameId)> = Vec::new();
    for (pi, id) in points.iter().enumerate() {
        let p = map.point(*id).expect("collected above");
        problem.add_point(p.position, false);
        if let (Some(s), Some(g)) = (slam_to_world, ground)
            && config.ground_sigma > 0.0
        {
            let w = s.transform_point(&nalgebra::Point3::from(p.position));
            if let Some(plane) = g.plane_at(w.x, w.y) {
                problem.add_ground_factor(GroundHeightFactor {
                    point: pi,
                    slam_to_world: *s,
                    ground: plane,
                    sigma: ground_factor_sigma(config.ground_sigma, g.sigma_m()),
                    kernel: config.ground_kernel,
                });
                stats.ground_factors += 1;
            }
        }
        for (k, &i) in p.observations() {
            let Some(&ci) = cam_index.get(k) else {
                continue;
            };
            let kp = &map
                .keyframe(*k)
                .expect("observing keyframes exist")
                .features
                .keypoints[i];
            problem.observations.push(Observation::at_level(
                ci,
                pi,
                Point2::new(kp.x, kp.y),
                kp.octave,
                sf,
            ));
            obs_keys.push((*id, *k));
        }
    }
    stats.points = points.len();
    stats.observations = obs_keys.len();
    let result = bundle_adjust_two_stage(&problem, &config.solver)?;
    stats.iterations = result.iterations;
    for (k, &ci) in &cam_index {
        if !problem.cameras[ci].fixed
            && let Some(kfr) = map.keyframe_mut(*k)
        {
            kfr.pose = result.cameras[ci];
        }
    }
    for (id, x) in points.iter().zip(&result.points) {
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
    for id in &points {
        map.update_normal_and_depth(*id);
    }
    tracing::debug!(?stats, "local BA");
    Ok(stats)
}

#[cfg(test)]
mod tests {
    use super::ground_factor_sigma;

    #[test]
    fn ground_factors_are_never_tighter_than_the_model() {
        // The simulated DEM (5 cm) keeps the configured 0.1 m; a HiRISE-like DTM (0.3 m) wins.
        assert_eq!(ground_factor_sigma(0.1, 0.05), 0.1);
        assert_eq!(ground_factor_sigma(0.1, 0.3), 0.3);
        assert_eq!(ground_factor_sigma(0.1, 0.0), 0.1);
        assert_eq!(ground_factor_sigma(0.1, f64::NAN), 0.1);
        assert_eq!(ground_factor_sigma(0.1, -1.0), 0.1);
    }
}
