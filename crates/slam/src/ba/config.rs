//! Settings of the bundle adjustment.

use jointloc_geometry::RobustKernel;
use serde::{Deserialize, Serialize};

use crate::{Result, SlamError};

/// χ² of 2 degrees of freedom at 95 %: ORB-SLAM's threshold for monocular observations.
pub const CHI2_2DOF_95: f64 = 5.991;

/// Levenberg–Marquardt settings of [`bundle_adjust`](super::bundle_adjust).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BundleAdjustmentConfig {
    /// Accepted LM steps at most (one linearisation each). ORB-SLAM2's local BA runs 5, drops
    /// outliers, then 10 more.
    pub max_iterations: usize,
    /// Rejected (damping-raising) tries per iteration before giving up, as g2o does.
    pub max_rejected_steps: usize,
    /// Kernel on each observation's χ² = information · ‖e‖². Default: Huber with δ² = 5.991.
    pub reprojection_kernel: RobustKernel,
    /// Observations with χ² above this after the solve are flagged as outliers (5.991: 95 % of
    /// 2-DoF inliers pass).
    pub outlier_chi2: f64,
    /// Initial damping μ, relative to the Hessian diagonal (Marquardt scaling).
    pub initial_damping: f64,
    /// Stop when μ grows beyond this (the model no longer predicts the cost).
    pub max_damping: f64,
    /// Stop when an accepted step lowers the cost by less than this fraction.
    pub function_tolerance: f64,
    /// Stop when the largest gradient entry falls below this.
    pub gradient_tolerance: f64,
    /// Stop when `‖h‖ ≤ step_tolerance · (‖x‖ + step_tolerance)` over free translations and
    /// points.
    pub step_tolerance: f64,
}

impl Default for BundleAdjustmentConfig {
    fn default() -> Self {
        Self {
            max_iterations: 10,
            max_rejected_steps: 10,
            reprojection_kernel: RobustKernel::Huber {
                delta: CHI2_2DOF_95.sqrt(),
            },
            outlier_chi2: CHI2_2DOF_95,
            initial_damping: 1e-4,
            max_damping: 1e16,
            function_tolerance: 1e-9,
            gradient_tolerance: 1e-12,
            step_tolerance: 1e-12,
        }
    }
}

impl BundleAdjustmentConfig {
    /// Rejects values the solver cannot work with.
    pub fn validate(&self) -> Result<()> {
        let positive = [
            ("outlier_chi2", self.outlier_chi2),
            ("initial_damping", self.initial_damping),
            ("max_damping", self.max_damping),
        ];
        for (field, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(SlamError::InvalidConfig {
                    field,
                    value: value.to_string(),
                    reason: "must be finite and > 0",
                });
            }
        }
        let tolerances = [
            ("function_tolerance", self.function_tolerance),
            ("gradient_tolerance", self.gradient_tolerance),
            ("step_tolerance", self.step_tolerance),
        ];
        for (field, value) in tolerances {
            if !(value.is_finite() && value >= 0.0) {
                return Err(SlamError::InvalidConfig {
                    field,
                    value: value.to_string(),
                    reason: "must be finite and >= 0",
                });
            }
        }
        super::problem::check_kernel(&self.reprojection_kernel)
    }
}

/// The ORB-SLAM2 local-BA schedule for [`bundle_adjust_two_stage`](super::bundle_adjust_two_stage):
/// optimise, drop the observations flagged as outliers, optimise again.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TwoStageConfig {
    /// Settings of both stages (their `max_iterations` is overridden by the fields below).
    pub solver: BundleAdjustmentConfig,
    /// Iterations of the first, robust stage (ORB-SLAM2: 5).
    pub first_iterations: usize,
    /// Iterations after the outliers are removed (ORB-SLAM2: 10).
    pub second_iterations: usize,
    /// Keep the robust kernel in the second stage. ORB-SLAM2 drops it (`false`): the remaining
    /// observations are inliers, and plain least squares weights them fully.
    pub robust_second_stage: bool,
}

impl Default for TwoStageConfig {
    fn default() -> Self {
        Self {
            solver: BundleAdjustmentConfig::default(),
            first_iterations: 5,
            second_iterations: 10,
            robust_second_stage: false,
        }
    }
}
