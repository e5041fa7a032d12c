//! Global bundle adjustment after a loop (ORB-SLAM2's `RunGlobalBundleAdjustment`): every
//! keyframe and point of the map, the first keyframe fixed, the absolute fixes as global
//! factors when the map is geo-referenced (as in the local BA). The pose graph spreads the
//! loop's error along the path; this lets the images settle it.

use std::collections::{BTreeMap, BTreeSet, VecDeque};

use jointloc_geometry::{PinholeCamera, Sim3, WorldToCamera};
use nalgebra::Point2;

use crate::ba::{
    BaProblem, BundleAdjustmentResult, GlobalPositionFactor, Observation, TwoStageConfig,
    bundle_adjust_two_stage,
};
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
    let job = GlobalBaJob::prepare(map, camera, config, slam_to_world);
    Ok(job.solve()?.apply(map))
}

/// A global BA taken out of the map, to be solved away from it (ORB-SLAM2 runs it on its own
/// thread while tracking and local mapping go on) and applied later with
/// [`GlobalBaSolution::apply`].
#[derive(Debug, Clone)]
pub struct GlobalBaJob {
    problem: BaProblem,
    solver: TwoStageConfig,
    /// Keyframe of each camera of the problem.
    cameras: Vec<KeyFrameId>,
    /// Map point of each point of the problem.
    points: Vec<MapPointId>,
    /// (point, keyframe) of each observation of the problem.
    observations: Vec<(MapPointId, KeyFrameId)>,
}

/// A solved [`GlobalBaJob`].
#[derive(Debug, Clone)]
pub struct GlobalBaSolution {
    job: GlobalBaJob,
    result: BundleAdjustmentResult,
}

impl GlobalBaJob {
    /// Every keyframe and point of `map` as it is now, the first keyframe fixed, with the
    /// keyframes' absolute fixes as global factors when `slam_to_world` is set.
    pub fn prepare(
        map: &Map,
        camera: &PinholeCamera,
        config: &LocalBaConfig,
        slam_to_world: Option<&Sim3>,
    ) -> Self {
        let first = map.keyframes().next().map(|k| k.id);
        let mut problem = BaProblem::new(*camera);
        let mut cam_index: BTreeMap<KeyFrameId, usize> = BTreeMap::new();
        let mut cameras = Vec::new();
        for k in map.keyframes() {
            let is_fixed = Some(k.id) == first;
            let ci = problem.add_camera(k.pose, is_fixed);
            cam_index.insert(k.id, ci);
            cameras.push(k.id);
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
        let sf = map.scale_factor();
        let mut points: Vec<MapPointId> = Vec::new();
        let mut observations: Vec<(MapPointId, KeyFrameId)> = Vec::new();
        for p in map.points() {
            let pi = problem.add_point(p.position, false);
            points.push(p.id);
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
                observations.push((p.id, *k));
            }
        }
        Self {
            problem,
            solver: config.solver,
            cameras,
            points,
            observations,
        }
    }

    /// Keyframes in the problem.
    pub fn n_keyframes(&self) -> usize {
        self.cameras.len()
    }

    /// Solves the problem (the expensive part: it needs no access to the map).
    pub fn solve(self) -> Result<GlobalBaSolution> {
        let result = bundle_adjust_two_stage(&self.problem, &self.solver)?;
        Ok(GlobalBaSolution { job: self, result })
    }
}

impl GlobalBaSolution {
    /// Writes the solution into `map`, which may have changed since the job was prepared (as
    /// ORB-SLAM2 does when its global BA thread finishes): keyframes and points of the job
    /// take their optimised values; keyframes made since follow their spanning-tree parent's
    /// correction, points made since their reference keyframe's; what was erased since is
    /// skipped. Observations flagged as outliers are erased where they still exist.
    pub fn apply(self, map: &mut Map) -> GlobalBaStats {
        let (job, result) = (self.job, self.result);
        let mut stats = GlobalBaStats {
            keyframes: job.cameras.len(),
            points: job.points.len(),
            observations: job.observations.len(),
            outliers_removed: 0,
            iterations: result.iterations,
        };
        // Current poses, then the corrected ones: the job's keyframes from the solution (the
        // fixed one stays), later keyframes through the spanning tree from them.
        let current: BTreeMap<KeyFrameId, WorldToCamera> =
            map.keyframes().map(|k| (k.id, k.pose)).collect();
        let mut corrected: BTreeMap<KeyFrameId, WorldToCamera> = BTreeMap::new();
        for (ci, id) in job.cameras.iter().enumerate() {
            if let Some(&now) = current.get(id) {
                let pose = if job.problem.cameras[ci].fixed {
                    now
                } else {
                    result.cameras[ci]
                };
                corrected.insert(*id, pose);
            }
        }
        let mut queue: VecDeque<KeyFrameId> = corrected.keys().copied().collect();
        while let Some(k) = queue.pop_front() {
            let children: Vec<KeyFrameId> = map
                .keyframe(k)
                .map(|kf| kf.children().iter().copied().collect())
                .unwrap_or_default();
            for c in children {
                if corrected.contains_key(&c) {
                    continue;
                }
                let (Some(cur_c), Some(cur_k), Some(new_k)) =
                    (current.get(&c), current.get(&k), corrected.get(&k))
                else {
                    continue;
                };
                let pose = WorldToCamera(cur_c.0 * cur_k.0.inverse() * new_k.0);
                corrected.insert(c, pose);
                queue.push_back(c);
            }
        }
        for (id, pose) in &corrected {
            if let Some(kf) = map.keyframe_mut(*id) {
                kf.pose = *pose;
            }
        }
        let in_job: BTreeSet<MapPointId> = job.points.iter().copied().collect();
        for (id, x) in job.points.iter().zip(&result.points) {
            if let Some(p) = map.point_mut(*id) {
                p.position = *x;
            }
        }
        let later: Vec<(MapPointId, KeyFrameId)> = map
            .points()
            .filter(|p| !in_job.contains(&p.id))
            .map(|p| (p.id, p.reference))
            .collect();
        for (id, reference) in later {
            let (Some(cur), Some(new)) = (current.get(&reference), corrected.get(&reference))
            else {
                continue;
            };
            if let Some(p) = map.point_mut(id) {
                let in_camera = cur.0.transform_point(&p.position.into());
                p.position = new.0.inverse().transform_point(&in_camera).coords;
            }
        }
        for (&(id, k), &outlier) in job.observations.iter().zip(&result.outliers) {
            let still = map
                .point(id)
                .is_some_and(|p| p.observations().contains_key(&k));
            if outlier && still {
                map.remove_observation(id, k);
                stats.outliers_removed += 1;
            }
        }
        let all: Vec<MapPointId> = map.points().map(|p| p.id).collect();
        for id in all {
            map.update_normal_and_depth(id);
        }
        tracing::debug!(?stats, "global BA applied");
        stats
    }
}

#[cfg(test)]
mod tests {
    use jointloc_features::orb::{FeatureGrid, KeyPoint, OrbFeatures};
    use nalgebra::{Point3, Vector3};

    use super::*;
    use crate::ba::synthetic::{SyntheticScene, SyntheticSceneConfig, synthetic_scene};
    use crate::map::KeyFrame;

    fn keyframe(index: usize, pose: WorldToCamera, pixels: &[Point2<f64>]) -> KeyFrame {
        let keypoints: Vec<KeyPoint> = pixels
            .iter()
            .map(|p| KeyPoint {
                x: p.x,
                y: p.y,
                octave: 0,
                angle: 0.0,
                response: 1.0,
                size: 31.0,
            })
            .collect();
        let features = OrbFeatures {
            descriptors: vec![[0u8; 32]; keypoints.len()],
            level_scales: (0..8).map(|l| 1.2f64.powi(l)).collect(),
            keypoints,
        };
        let grid = FeatureGrid::new(&features.keypoints, 2000, 2000, 20.0);
        KeyFrame::new(index, index as f64, pose, features, grid)
    }

    /// The scene's cameras and points as a map (noisy starts, as the scene gives them).
    fn map_of(scene: &SyntheticScene) -> (Map, Vec<KeyFrameId>) {
        let p = &scene.problem;
        let mut per_camera: Vec<Vec<(usize, Point2<f64>)>> = vec![Vec::new(); p.cameras.len()];
        for o in &p.observations {
            per_camera[o.camera].push((o.point, o.pixel));
        }
        let mut map = Map::new(1.2, 8);
        let ids: Vec<KeyFrameId> = per_camera
            .iter()
            .enumerate()
            .map(|(ci, obs)| {
                let pixels: Vec<Point2<f64>> = obs.iter().map(|o| o.1).collect();
                map.insert_keyframe(keyframe(ci, p.cameras[ci].pose, &pixels))
            })
            .collect();
        let mut point_ids: Vec<Option<MapPointId>> = vec![None; p.points.len()];
        for (ci, obs) in per_camera.iter().enumerate() {
            for (j, &(pi, _)) in obs.iter().enumerate() {
                match point_ids[pi] {
                    None => point_ids[pi] = map.insert_point(p.points[pi].position, ids[ci], j),
                    Some(id) => {
                        map.add_observation(id, ids[ci], j);
                    }
                }
            }
        }
        for &k in &ids {
            map.update_connections(k);
        }
        (map, ids)
    }

    #[test]
    fn a_global_ba_applied_late_carries_what_was_mapped_meanwhile() {
        let scene = synthetic_scene(&SyntheticSceneConfig {
            outlier_fraction: 0.0,
            seed: 11,
            ..Default::default()
        })
        .unwrap();
        let camera = scene.problem.intrinsics;
        let (mut map, ids) = map_of(&scene);
        let inline = {
            let mut m = map.clone();
            global_bundle_adjustment(&mut m, &camera, &LocalBaConfig::default(), None).unwrap();
            m
        };
        let job = GlobalBaJob::prepare(&map, &camera, &LocalBaConfig::default(), None);
        // Meanwhile: a keyframe next to the last one, seeing its points and one new point.
        let last = *ids.last().unwrap();
        let (pose, mut pixels, seen) = {
            let k = map.keyframe(last).unwrap();
            let seen: Vec<(usize, MapPointId)> = k
                .points
                .iter()
                .enumerate()
                .filter_map(|(i, p)| p.map(|p| (i, p)))
                .collect();
            let pixels: Vec<Point2<f64>> = k
                .features
                .keypoints
                .iter()
                .map(|kp| Point2::new(kp.x, kp.y))
                .collect();
            (k.pose, pixels, seen)
        };
        pixels.push(Point2::new(100.0, 100.0));
        let late = map.insert_keyframe(keyframe(999, pose, &pixels));
        for &(i, p) in &seen {
            assert!(map.add_observation(p, late, i));
        }
        let fresh = map
            .insert_point(Vector3::new(1.0, 2.0, 0.5), late, pixels.len() - 1)
            .unwrap();
        map.update_connections(late);
        let parent = map.keyframe(late).unwrap().parent().unwrap();
        let pose_of = |m: &Map, k: KeyFrameId| m.keyframe(k).unwrap().pose;
        let relative_before = pose_of(&map, late).0 * pose_of(&map, parent).0.inverse();
        let fresh_in_late = pose_of(&map, late)
            .0
            .transform_point(&Point3::from(map.point(fresh).unwrap().position));
        let parent_before = pose_of(&map, parent);

        job.solve().unwrap().apply(&mut map);

        // The job's keyframes take the solution, as inline.
        for &k in &ids {
            let (a, b) = (pose_of(&map, k), pose_of(&inline, k));
            assert!((a.0.translation.vector - b.0.translation.vector).norm() < 1e-9);
        }
        let moved = (pose_of(&map, parent).0.translation.vector
            - parent_before.0.translation.vector)
            .norm();
        assert!(moved > 1e-4, "the parent did not move ({moved})");
        // The late keyframe and its point follow their parent's correction.
        let relative_after = pose_of(&map, late).0 * pose_of(&map, parent).0.inverse();
        assert!(
            (relative_after.translation.vector - relative_before.translation.vector).norm() < 1e-9
        );
        assert!(relative_after.rotation.angle_to(&relative_before.rotation) < 1e-9);
        let fresh_after = pose_of(&map, late)
            .0
            .transform_point(&Point3::from(map.point(fresh).unwrap().position));
        assert!((fresh_after - fresh_in_late).norm() < 1e-9);
    }
}
