//! Local bundle adjustment with JointLoc's global-position factors (paper §III-C).
//!
//! The cost over free keyframe poses `T_i` and map points `X_j` is
//! ```text
//! f(x) = ½ Σ_ij ρ(e_ijᵀ Ω_ij e_ij) + ½ Σ_i w_G,i ρ_G(‖S · C_i − P_G,i‖² / σ_G²)
//!        [+ ½ Σ_j ρ_h(h_j² / σ_h²)] [+ ½ Σ priors]
//! ```
//! with `h_j` the height of `S · X_j` above the elevation model (the ground-height factors).
//! with `e_ij = π(T_i X_j) − z_ij`, `Ω_ij = 1/σ²` of the keypoint's pyramid level, `C_i` the
//! keyframe centre in the SLAM frame and `S` the SLAM→world similarity, held fixed. It is
//! minimised by Levenberg–Marquardt (Nielsen's damping update, Marquardt diagonal scaling) with
//! the points eliminated by the Schur complement and the reduced camera system solved by a
//! dense Cholesky: a local window has at most a few dozen free keyframes, so the reduced system
//! is at most ~180×180 while the thousands of points only need their own 3×3 inverses, and the
//! cost stays linear in the number of observations. Poses are updated by left-multiplied SE(3)
//! exponentials (see [`factors`]).
//!
//! Why not a library: `kornia-3d`'s Schur BA is f32 (centimetres at tens of metres need more)
//! and pulls `rand 0.10`, `faer` and its image crates; `apex-solver` needs Rust 1.93 (workspace
//! MSRV 1.89), `nalgebra 0.33` and `faer`. This module is about a thousand lines on nalgebra alone, takes
//! the global factor as a first-class term, and meets the speed target (see the `ba` bench).

mod config;
pub mod factors;
mod linear;
mod problem;
mod solver;
pub mod synthetic;
mod two_stage;

pub use config::{BundleAdjustmentConfig, CHI2_2DOF_95, TwoStageConfig};
pub use problem::{
    BaCamera, BaPoint, BaProblem, CHI2_3DOF_95, GlobalPositionFactor, GroundHeightFactor,
    GroundPlane, Observation, PositionPrior,
};
pub use solver::{BundleAdjustmentResult, Termination, bundle_adjust};
pub use two_stage::bundle_adjust_two_stage;

#[cfg(test)]
mod tests;
