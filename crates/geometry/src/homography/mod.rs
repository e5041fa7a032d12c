//! Plane homographies between two images: robust estimation, accuracy metric and decomposition.
//!
//! A homography `H` maps source pixels to destination pixels, `dst ∝ H src`, with pixel centres
//! at integer coordinates. Every `H` returned here is scaled so that `H[2][2] = 1`; only when
//! that entry vanishes (the pixel origin maps to the line at infinity) is it scaled to unit
//! Frobenius norm instead, with `H[2][2] ≥ 0`.
//!
//! Pipeline of [`estimate_homography`]: MSAC with a 4-point minimal solver (degenerate and
//! orientation-inconsistent samples rejected before solving) → normalised DLT on the inliers →
//! Levenberg–Marquardt on the symmetric transfer error → inliers recomputed with the refined `H`
//! (and one more refinement pass if they changed).

mod decompose;
mod dlt;
mod estimator;
mod footprint;
mod refine;

use nalgebra::{Matrix3, Point2};
use serde::{Deserialize, Serialize};

pub use decompose::{HomographyMotion, decompose_homography};
pub use dlt::{dlt, minimal_homography};
pub use estimator::{HomographyEstimator, HomographyModel};
pub use footprint::{FootprintFit, FootprintKernel, refit_over_footprint, refit_with_kernel};
pub use refine::{
    Matrix4x8, Refinement, refine_homography, refine_homography_weighted,
    symmetric_transfer_jacobian,
};

use crate::error::{GeometryError, Result};
use crate::ransac::{Estimator, RansacConfig, inliers_of, ransac};

/// Parameters of [`estimate_homography`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HomographyConfig {
    /// RANSAC parameters; `threshold` is in pixels of symmetric transfer error (see
    /// [`HomographyEstimator`]), 3 px by default.
    pub ransac: RansacConfig,
    /// Refine by Levenberg–Marquardt after the inlier DLT. Costs well under a millisecond for a
    /// thousand inliers and removes the DLT's algebraic-error bias.
    pub refine: bool,
    /// Maximum accepted Levenberg–Marquardt steps per refinement pass (it usually converges in
    /// fewer than five).
    pub refine_iterations: usize,
}

impl Default for HomographyConfig {
    fn default() -> Self {
        Self {
            ransac: RansacConfig {
                threshold: 3.0,
                ..RansacConfig::default()
            },
            refine: true,
            refine_iterations: 20,
        }
    }
}

/// Outcome of [`estimate_homography`].
#[derive(Debug, Clone, PartialEq)]
pub struct HomographyResult {
    /// `dst ∝ H src`, scaled as described in the module docs.
    pub h: Matrix3<f64>,
    /// Indices of the correspondences within the threshold of the final `H`, ascending.
    pub inliers: Vec<usize>,
    /// RANSAC hypotheses drawn.
    pub iterations: usize,
    /// Root mean square of the symmetric transfer error over `inliers`, pixels.
    pub rms_error: f64,
}

/// Maps a pixel through `h`; the result is non-finite when the point maps to infinity.
pub fn transfer_point(h: &Matrix3<f64>, p: &Point2<f64>) -> Point2<f64> {
    let q = h * p.to_homogeneous();
    Point2::new(q.x / q.z, q.y / q.z)
}

/// Mean distance between the four image corners mapped by `h_est` and by `h_true`, the accuracy
/// metric of SuperPoint's HPatches evaluation (and of the paper's @N px table). Corners are the
/// outer pixel centres `(0, 0)`, `(w−1, 0)`, `(w−1, h−1)`, `(0, h−1)`. `+∞` when either matrix
/// sends a corner to infinity.
pub fn corner_error(h_est: &Matrix3<f64>, h_true: &Matrix3<f64>, width: u32, height: u32) -> f64 {
    let (w, h) = (f64::from(width) - 1.0, f64::from(height) - 1.0);
    let total: f64 = [(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)]
        .iter()
        .map(|&(x, y)| {
            let c = Point2::new(x, y);
            (transfer_point(h_est, &c) - transfer_point(h_true, &c)).norm()
        })
        .sum();
    let mean = total / 4.0;
    if mean.is_finite() {
        mean
    } else {
        f64::INFINITY
    }
}

pub(crate) fn check_lengths_and_finite(src: &[Point2<f64>], dst: &[Point2<f64>]) -> Result<()> {
    if src.len() != dst.len() {
        return Err(GeometryError::LengthMismatch {
            what: "homography source vs target points",
            left: src.len(),
            right: dst.len(),
        });
    }
    if !src
        .iter()
        .chain(dst)
        .all(|p| p.x.is_finite() && p.y.is_finite())
    {
        return Err(GeometryError::NonFinite("homography correspondences"));
    }
    Ok(())
}

/// Lengths, count (at least 4) and finiteness.
pub(crate) fn check_input(src: &[Point2<f64>], dst: &[Point2<f64>]) -> Result<()> {
    if src.len() == dst.len() && src.len() < 4 {
        return Err(GeometryError::TooFewPoints {
            required: 4,
            found: src.len(),
        });
    }
    check_lengths_and_finite(src, dst)
}

/// Robust homography `dst ∝ H src` from matched pixels (see the module docs for the pipeline).
///
/// Errors: [`GeometryError::TooFewPoints`] below 4 pairs, [`GeometryError::LengthMismatch`],
/// [`GeometryError::NonFinite`] for NaN/∞ coordinates, [`GeometryError::InvalidConfig`],
/// [`GeometryError::NoConsensus`] when no hypothesis reaches `ransac.min_inliers` (at least 4),
/// [`GeometryError::Degenerate`] when the inliers do not determine `H`.
pub fn estimate_homography(
    src: &[Point2<f64>],
    dst: &[Point2<f64>],
    cfg: &HomographyConfig,
) -> Result<HomographyResult> {
    check_input(src, dst)?;
    let est = HomographyEstimator::new(src, dst)?;
    let found = ransac(&est, &cfg.ransac)?;
    let t2 = cfg.ransac.threshold * cfg.ransac.threshold;

    let mut h = est.fit_all(&found.inliers).unwrap_or(found.model.h);
    let mut inliers = model_inliers(&est, &h, t2).unwrap_or_else(|| found.inliers.clone());
    if cfg.refine {
        let mut fit_set = found.inliers.clone();
        // Second pass only when the refined H changed the inlier set.
        for pass in 0..2 {
            let Some(r) =
                refine_homography(&h, est.src(), est.dst(), &fit_set, cfg.refine_iterations)
            else {
                tracing::debug!(pass, "homography refinement skipped: degenerate inlier set");
                break;
            };
            let Some(new_inliers) = model_inliers(&est, &r.h, t2) else {
                break;
            };
            tracing::trace!(
                pass,
                steps = r.iterations,
                initial_cost = r.initial_cost,
                final_cost = r.final_cost,
                "homography refined"
            );
            h = r.h;
            let changed = new_inliers != fit_set;
            inliers = new_inliers;
            if !changed {
                break;
            }
            fit_set = inliers.clone();
        }
    }
    cfg.ransac
        .check_consensus(inliers.len(), HomographyEstimator::SAMPLE_SIZE)?;
    let model = HomographyModel::new(h)
        .ok_or_else(|| GeometryError::Degenerate("estimated homography is singular".into()))?;
    let rms_error = (inliers
        .iter()
        .map(|&i| est.residual_squared(&model, i))
        .sum::<f64>()
        / inliers.len() as f64)
        .sqrt();
    tracing::debug!(
        matches = src.len(),
        inliers = inliers.len(),
        iterations = found.iterations,
        rms_error,
        "homography estimated"
    );
    Ok(HomographyResult {
        h,
        inliers,
        iterations: found.iterations,
        rms_error,
    })
}

/// Inliers of `h` under the estimator's residual; `None` when `h` is singular.
fn model_inliers(est: &HomographyEstimator<'_>, h: &Matrix3<f64>, t2: f64) -> Option<Vec<usize>> {
    HomographyModel::new(*h).map(|m| inliers_of(est, &m, t2))
}
