//! Pose-only optimisation (ORB-SLAM2's `PoseOptimization`): robust refinement of a frame's pose
//! against its matched map points in rounds, re-classifying every match as inlier or outlier
//! by its χ² after each round, so that a match wrongly rejected early can come back.

use jointloc_geometry::pnp::{RefineConfig, refine_pose};
use jointloc_geometry::{PinholeCamera, RobustKernel, WorldToCamera};
use nalgebra::{Point2, Point3};
use serde::{Deserialize, Serialize};

use crate::frame::Frame;
use crate::map::Map;

/// Settings of [`optimize_pose`]; defaults are ORB-SLAM2's.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PoseOptimizationConfig {
    /// Optimise / re-classify rounds (ORB-SLAM2: 4).
    pub rounds: usize,
    /// LM iterations per round (ORB-SLAM2: 10).
    pub iterations: usize,
    /// χ² (information-weighted, px²) above which a match is an outlier: 5.991, the 95 % bound
    /// of 2 DoF.
    pub chi2: f64,
    /// Rounds that use the Huber kernel (δ² = `chi2`); later rounds see inliers only and use
    /// plain least squares (ORB-SLAM2: 2).
    pub robust_rounds: usize,
    /// Stop early when fewer inliers remain.
    pub min_inliers: usize,
}

impl Default for PoseOptimizationConfig {
    fn default() -> Self {
        Self {
            rounds: 4,
            iterations: 10,
            chi2: 5.991,
            robust_rounds: 2,
            min_inliers: 10,
        }
    }
}

/// Refines `frame.pose` (which must be set) against its matched map points and sets
/// `frame.outliers`. Returns the number of inliers; 0 when the pose is unset or fewer than
/// three points are matched (the pose is then left unchanged).
pub fn optimize_pose(
    frame: &mut Frame,
    map: &Map,
    camera: &PinholeCamera,
    config: &PoseOptimizationConfig,
) -> usize {
    let Some(mut pose) = frame.pose else {
        return 0;
    };
    let sf = map.scale_factor();
    let mut index = Vec::new();
    let mut world = Vec::new();
    let mut pixels = Vec::new();
    let mut info = Vec::new();
    for (i, id) in frame.points.iter().enumerate() {
        let Some(p) = id.and_then(|id| map.point(id)) else {
            continue;
        };
        let k = &frame.features.keypoints[i];
        index.push(i);
        world.push(Point3::from(p.position));
        pixels.push(Point2::new(k.x, k.y));
        info.push(1.0 / sf.powi(2 * k.octave as i32));
    }
    if index.len() < 3 {
        return 0;
    }
    let (refined, outlier) = optimize_pose_against(&world, &pixels, &info, camera, pose, config);
    pose = refined;
    let inliers = outlier.iter().filter(|o| !**o).count();
    frame.pose = Some(pose);
    for (j, &i) in index.iter().enumerate() {
        frame.outliers[i] = outlier[j];
    }
    inliers
}

/// The rounds of [`optimize_pose`] on plain correspondences: `world` points seen at `pixels`
/// with information `info` (1/σ² of the keypoint's level), from the starting `pose`. Returns
/// the refined pose and, per correspondence, whether it is an outlier at the end.
pub fn optimize_pose_against(
    world: &[Point3<f64>],
    pixels: &[Point2<f64>],
    info: &[f64],
    camera: &PinholeCamera,
    mut pose: WorldToCamera,
    config: &PoseOptimizationConfig,
) -> (WorldToCamera, Vec<bool>) {
    let n = world.len().min(pixels.len()).min(info.len());
    let mut outlier = vec![false; n];
    for round in 0..config.rounds {
        let keep: Vec<usize> = (0..n).filter(|&j| !outlier[j]).collect();
        if keep.len() < 3 {
            break;
        }
        let w: Vec<_> = keep.iter().map(|&j| world[j]).collect();
        let px: Vec<_> = keep.iter().map(|&j| pixels[j]).collect();
        let inf: Vec<_> = keep.iter().map(|&j| info[j]).collect();
        let refine = RefineConfig {
            kernel: if round < config.robust_rounds {
                RobustKernel::Huber {
                    delta: config.chi2.sqrt(),
                }
            } else {
                RobustKernel::Trivial
            },
            max_iterations: config.iterations,
            ..RefineConfig::default()
        };
        match refine_pose(&w, &px, Some(&inf), camera, pose, &refine) {
            Ok(r) if r.pose.is_finite() => pose = r.pose,
            Ok(_) => break,
            Err(e) => {
                tracing::debug!(error = %e, "pose optimisation round failed");
                break;
            }
        }
        let mut inliers = 0;
        for j in 0..n {
            let chi2 = camera
                .project(&pose.transform_point(&world[j]))
                .map_or(f64::INFINITY, |uv| {
                    info[j] * (uv - pixels[j]).norm_squared()
                });
            outlier[j] = chi2 > config.chi2;
            inliers += usize::from(!outlier[j]);
        }
        if inliers < config.min_inliers {
            break;
        }
    }
    (pose, outlier)
}
