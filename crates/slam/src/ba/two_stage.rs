//! ORB-SLAM2's local-BA schedule: a short robust solve, removal of the observations it flags,
//! and a second solve on the inliers only.

use jointloc_geometry::RobustKernel;

use super::config::{BundleAdjustmentConfig, TwoStageConfig};
use super::problem::BaProblem;
use super::solver::{BundleAdjustmentResult, bundle_adjust, chi2_at};
use crate::Result;

/// Runs [`bundle_adjust`] twice as ORB-SLAM2's `LocalBundleAdjustment` does. The result is
/// indexed like the input problem: `observation_chi2` is evaluated for every observation at the
/// final estimate, and `outliers` marks those dropped after the first stage or still above
/// `outlier_chi2` after the second (the caller erases these from the map). `initial_cost` is the
/// first stage's, `final_cost` the second stage's (over the kept observations only),
/// `iterations` the sum and `termination` the second stage's.
pub fn bundle_adjust_two_stage(
    problem: &BaProblem,
    config: &TwoStageConfig,
) -> Result<BundleAdjustmentResult> {
    let first_config = BundleAdjustmentConfig {
        max_iterations: config.first_iterations,
        ..config.solver
    };
    let first = bundle_adjust(problem, &first_config)?;
    let mut second_problem = BaProblem {
        observations: Vec::with_capacity(problem.observations.len()),
        ..problem.clone()
    };
    for (cam, pose) in second_problem.cameras.iter_mut().zip(&first.cameras) {
        cam.pose = *pose;
    }
    for (point, x) in second_problem.points.iter_mut().zip(&first.points) {
        point.position = *x;
    }
    let kept: Vec<usize> = (0..problem.observations.len())
        .filter(|&i| !first.outliers[i])
        .collect();
    second_problem
        .observations
        .extend(kept.iter().map(|&i| problem.observations[i]));
    tracing::debug!(
        dropped = problem.observations.len() - kept.len(),
        "local BA: outliers removed after the first stage"
    );
    let second_config = BundleAdjustmentConfig {
        max_iterations: config.second_iterations,
        reprojection_kernel: if config.robust_second_stage {
            config.solver.reprojection_kernel
        } else {
            RobustKernel::Trivial
        },
        ..config.solver
    };
    let second = bundle_adjust(&second_problem, &second_config)?;
    // Re-evaluate every original observation at the final estimate.
    let (observation_chi2, _) = chi2_at(problem, &second.cameras, &second.points);
    let outliers = observation_chi2
        .iter()
        .zip(&first.outliers)
        .map(|(&c, &dropped)| dropped || c > config.solver.outlier_chi2)
        .collect();
    Ok(BundleAdjustmentResult {
        cameras: second.cameras,
        points: second.points,
        initial_cost: first.initial_cost,
        final_cost: second.final_cost,
        iterations: first.iterations + second.iterations,
        termination: second.termination,
        observation_chi2,
        outliers,
        global_chi2: second.global_chi2,
    })
}
