//! Levenberg–Marquardt over camera poses and points, with Nielsen's damping update.

use jointloc_geometry::WorldToCamera;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::config::BundleAdjustmentConfig;
use super::factors::reprojection_error;
use super::linear::{Layout, Linearization, State, evaluate_cost};
use super::problem::BaProblem;
use crate::Result;

/// Smallest damping μ; `μ · clamp(H_kk) ≥ 1e-18` keeps gauge directions invertible.
const MIN_DAMPING: f64 = 1e-12;

/// Why the optimisation stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Termination {
    /// `max_iterations` accepted steps were taken.
    MaxIterations,
    /// An accepted step lowered the cost by less than `function_tolerance` (relative).
    FunctionTolerance,
    /// The gradient vanished.
    GradientTolerance,
    /// The step became negligible.
    StepTolerance,
    /// μ exceeded `max_damping`, or `max_rejected_steps` tries in a row failed: no further
    /// decrease could be found (usually a minimum reached within numerical precision).
    NoImprovement,
    /// Nothing to optimise (no free camera or point), or a zero iteration budget.
    NothingToDo,
}

/// The optimised window and what the caller needs to clean the map.
#[derive(Debug, Clone, PartialEq)]
pub struct BundleAdjustmentResult {
    /// Optimised camera poses, indexed like [`BaProblem::cameras`] (fixed ones unchanged).
    pub cameras: Vec<WorldToCamera>,
    /// Optimised points, indexed like [`BaProblem::points`].
    pub points: Vec<Vector3<f64>>,
    /// `½ Σ ρ(χ²)` over all factors (observations in front of their camera) at the start.
    pub initial_cost: f64,
    /// The same at the end.
    pub final_cost: f64,
    /// Accepted LM steps.
    pub iterations: usize,
    /// Why it stopped.
    pub termination: Termination,
    /// Per observation, `information · ‖e‖²` at the optimum; `+∞` when the point is not in front
    /// of the camera.
    pub observation_chi2: Vec<f64>,
    /// Per observation, `chi² > outlier_chi2` (ORB-SLAM drops these from the map).
    pub outliers: Vec<bool>,
    /// Per global factor, `‖S · C − P_G‖² / σ²` at the optimum.
    pub global_chi2: Vec<f64>,
}

impl BundleAdjustmentResult {
    /// Number of observations flagged as outliers.
    pub fn outlier_count(&self) -> usize {
        self.outliers.iter().filter(|&&o| o).count()
    }
}

/// Minimises `½ Σ ρ(χ²_reprojection) + ½ Σ w ρ(‖S·C − P_G‖²/σ²) + ½ Σ ‖C − C_prior‖²/σ²` over the
/// free cameras and points (paper §III-C). Invalid input (NaN, bad index) is an error; a
/// problem that cannot improve returns its input with `termination` saying why.
pub fn bundle_adjust(
    problem: &BaProblem,
    config: &BundleAdjustmentConfig,
) -> Result<BundleAdjustmentResult> {
    config.validate()?;
    problem.validate()?;
    let kernel = config.reprojection_kernel;
    let layout = Layout::new(problem);
    let mut state = State {
        poses: problem.cameras.iter().map(|c| c.pose).collect(),
        points: problem.points.iter().map(|p| p.position).collect(),
    };
    let mut lin = Linearization::new(problem, &layout, &kernel, &state);
    let initial_cost = lin.cost;
    let mut iterations = 0;
    let mut mu = config.initial_damping;
    let mut nu = 2.0;
    let termination = if layout.free_cams + layout.free_points == 0 || config.max_iterations == 0 {
        Termination::NothingToDo
    } else {
        'outer: loop {
            if lin.gradient_max_norm() <= config.gradient_tolerance {
                break Termination::GradientTolerance;
            }
            if iterations >= config.max_iterations {
                break Termination::MaxIterations;
            }
            let mut rejected = 0;
            loop {
                if let Some(step) = lin.solve(&layout, mu) {
                    let x_norm = state.free_norm_squared(&layout).sqrt();
                    let tol = config.step_tolerance;
                    if step.norm_squared().sqrt() <= tol * (x_norm + tol) {
                        break 'outer Termination::StepTolerance;
                    }
                    let candidate = state.updated(&layout, &step);
                    let new_cost = evaluate_cost(problem, &kernel, &candidate, &lin.valid);
                    let gain = match new_cost {
                        Some(c) if c.is_finite() && step.predicted_decrease > 0.0 => {
                            (lin.cost - c) / step.predicted_decrease
                        }
                        _ => -1.0,
                    };
                    if gain > 0.0 {
                        let old_cost = lin.cost;
                        let decrease = old_cost - new_cost.unwrap_or(old_cost);
                        // Nielsen: shrink μ by up to 3× after a good step; the floor keeps
                        // `μ · ν` able to grow again from a (near-)pure Gauss–Newton step.
                        mu = (mu * (1.0 - (2.0 * gain - 1.0).powi(3)).max(1.0 / 3.0))
                            .max(MIN_DAMPING);
                        nu = 2.0;
                        state = candidate;
                        lin.relinearize(problem, &layout, &kernel, &state);
                        iterations += 1;
                        tracing::trace!(iterations, cost = lin.cost, mu, gain, "LM step accepted");
                        if decrease <= config.function_tolerance * old_cost {
                            break 'outer Termination::FunctionTolerance;
                        }
                        break;
                    }
                }
                // Rejected (or the damped system was not positive definite): damp harder.
                mu *= nu;
                nu *= 2.0;
                rejected += 1;
                if mu > config.max_damping || rejected >= config.max_rejected_steps {
                    break 'outer Termination::NoImprovement;
                }
            }
        }
    };
    let (observation_chi2, global_chi2) = chi2_at(problem, &state.poses, &state.points);
    let outliers = observation_chi2
        .iter()
        .map(|&c| c > config.outlier_chi2)
        .collect();
    tracing::debug!(
        initial_cost,
        final_cost = lin.cost,
        iterations,
        ?termination,
        "bundle adjustment done"
    );
    Ok(BundleAdjustmentResult {
        cameras: state.poses,
        points: state.points,
        initial_cost,
        final_cost: lin.cost,
        iterations,
        termination,
        observation_chi2,
        outliers,
        global_chi2,
    })
}

/// Per observation `information · ‖e‖²` (`+∞` behind the camera) and per global factor
/// `‖S·C − P_G‖²/σ²`, for the given estimate of the problem's cameras and points.
pub(crate) fn chi2_at(
    problem: &BaProblem,
    poses: &[WorldToCamera],
    points: &[Vector3<f64>],
) -> (Vec<f64>, Vec<f64>) {
    let rot: Vec<_> = poses.iter().map(|p| p.rotation_matrix()).collect();
    let obs = problem
        .observations
        .iter()
        .map(|o| {
            reprojection_error(
                &problem.intrinsics,
                &rot[o.camera],
                &poses[o.camera].translation(),
                &points[o.point],
                &o.pixel,
            )
            .map_or(f64::INFINITY, |e| o.information * e.norm_squared())
        })
        .collect();
    let global = problem
        .global_factors
        .iter()
        .map(|g| {
            let pose = &poses[g.camera];
            let (r, _) = g.whitened_residual(&pose.rotation_matrix(), &pose.translation());
            r.norm_squared() / (g.sigma * g.sigma)
        })
        .collect();
    (obs, global)
}
