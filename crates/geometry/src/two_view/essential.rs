//! Essential matrix from pixel correspondences of one calibrated camera: MSAC over the
//! five-point solver, then Levenberg-Marquardt over the relative motion `(R, t)` (3 + 2 DoF)
//! minimising the Sampson error in pixels on the inliers.
//!
//! Convention: `x2ᵀ E x1 = 0` for normalised rays, `E = [t]× R` with `X₂ = R X₁ + t`.

use nalgebra::{Matrix3, Point2, SVector, Vector3};
use serde::{Deserialize, Serialize};
use tracing::debug;

use super::five_point::essential_five_point;
use super::fundamental::check_correspondences;
use super::relative_pose::decompose_essential;
use super::sampson::{EpipolarManifold, LmSettings, PixelScale, refine_sampson, sampson_squared};
use crate::camera::PinholeCamera;
use crate::error::{GeometryError, Result};
use crate::pose::{skew, so3_exp};
use crate::ransac::{Estimator, RansacConfig, inliers_of, ransac};
use crate::robust::RobustKernel;

/// Parameters of [`estimate_essential`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct EssentialConfig {
    /// RANSAC settings; `threshold` is the Sampson distance in (undistorted) pixels, default
    /// 2 px (about 4σ for 0.5 px keypoint noise).
    pub ransac: RansacConfig,
    /// Levenberg-Marquardt iterations over `(R, t)` after RANSAC; 0 keeps the minimal-sample
    /// hypothesis.
    pub refine_iterations: usize,
    /// Robust kernel of that refinement (residuals in pixels).
    pub refine_kernel: RobustKernel,
}

impl Default for EssentialConfig {
    fn default() -> Self {
        Self {
            ransac: RansacConfig {
                threshold: 2.0,
                ..RansacConfig::default()
            },
            refine_iterations: 20,
            refine_kernel: RobustKernel::Huber { delta: 1.0 },
        }
    }
}

/// Output of [`estimate_essential`].
#[derive(Debug, Clone, PartialEq)]
pub struct EssentialResult {
    /// Essential matrix with unit Frobenius norm (singular values `1/√2, 1/√2, 0`).
    pub e: Matrix3<f64>,
    /// Correspondences whose Sampson distance under `e` is below the threshold, ascending.
    pub inliers: Vec<usize>,
    /// RANSAC hypotheses drawn.
    pub iterations: usize,
}

/// RANSAC model family of the essential matrix: minimal sample of 5 (Stewénius' solver, up to
/// ten models), residual the squared Sampson distance in undistorted pixels².
#[derive(Debug, Clone)]
pub struct EssentialEstimator {
    rays1: Vec<Vector3<f64>>,
    rays2: Vec<Vector3<f64>>,
    scale: PixelScale,
}

impl EssentialEstimator {
    /// Unprojects the pixels of both images with `camera`.
    pub fn new(x1: &[Point2<f64>], x2: &[Point2<f64>], camera: &PinholeCamera) -> Result<Self> {
        check_correspondences(x1, x2, 0)?;
        for (field, v) in [("fx", camera.fx), ("fy", camera.fy)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(GeometryError::InvalidConfig {
                    field,
                    value: v.to_string(),
                    reason: "focal length must be finite and > 0",
                });
            }
        }
        let unproject = |x: &[Point2<f64>]| -> Result<Vec<Vector3<f64>>> {
            x.iter()
                .map(|p| {
                    camera.unproject(p).ok_or_else(|| {
                        GeometryError::Degenerate("pixel cannot be undistorted".into())
                    })
                })
                .collect()
        };
        Ok(Self {
            rays1: unproject(x1)?,
            rays2: unproject(x2)?,
            scale: PixelScale::focal(camera.fx, camera.fy),
        })
    }

    /// Normalised rays (`z = 1`) of image 1 and image 2.
    pub fn rays(&self) -> (&[Vector3<f64>], &[Vector3<f64>]) {
        (&self.rays1, &self.rays2)
    }
}

impl Estimator for EssentialEstimator {
    type Model = Matrix3<f64>;
    const SAMPLE_SIZE: usize = 5;

    fn len(&self) -> usize {
        self.rays1.len()
    }

    fn fit(&self, sample: &[usize]) -> Vec<Matrix3<f64>> {
        let a: [Vector3<f64>; 5] = std::array::from_fn(|k| self.rays1[sample[k]]);
        let b: [Vector3<f64>; 5] = std::array::from_fn(|k| self.rays2[sample[k]]);
        essential_five_point(&a, &b)
    }

    fn residual_squared(&self, e: &Matrix3<f64>, i: usize) -> f64 {
        sampson_squared(e, &self.rays1[i], &self.rays2[i], &self.scale)
    }
}

/// Relative motion with unit translation: `E = [t]× R`, 5 DoF (`R ← R exp(δφ)`, `t` moved in
/// its tangent plane and renormalised).
#[derive(Debug, Clone, Copy)]
struct Motion {
    r: Matrix3<f64>,
    t: Vector3<f64>,
}

impl Motion {
    /// Orthonormal basis of the plane orthogonal to `t`.
    fn tangent_plane(&self) -> (Vector3<f64>, Vector3<f64>) {
        let a = self.t.iamin();
        let b1 = self.t.cross(&Vector3::ith(a, 1.0)).normalize();
        (b1, self.t.cross(&b1))
    }
}

impl EpipolarManifold<5> for Motion {
    fn matrix(&self) -> Matrix3<f64> {
        skew(&self.t) * self.r
    }

    fn tangents(&self) -> [Matrix3<f64>; 5] {
        let tx = skew(&self.t);
        let (b1, b2) = self.tangent_plane();
        std::array::from_fn(|k| match k {
            0..3 => tx * self.r * skew(&Vector3::ith(k, 1.0)),
            3 => skew(&b1) * self.r,
            _ => skew(&b2) * self.r,
        })
    }

    fn retract(&self, d: &SVector<f64, 5>) -> Self {
        let (b1, b2) = self.tangent_plane();
        let phi = Vector3::new(d[0], d[1], d[2]);
        Self {
            r: self.r * so3_exp(&phi).to_rotation_matrix().into_inner(),
            t: (self.t + d[3] * b1 + d[4] * b2).normalize(),
        }
    }
}

fn msac_cost(est: &EssentialEstimator, e: &Matrix3<f64>, t2: f64) -> f64 {
    (0..est.len())
        .map(|i| est.residual_squared(e, i).min(t2))
        .sum()
}

/// Robust essential matrix: MSAC over five-point samples, then LM over `(R, t)` on the inliers
/// (kept only when it lowers the MSAC cost over all correspondences) and re-classification.
pub fn estimate_essential(
    x1: &[Point2<f64>],
    x2: &[Point2<f64>],
    camera: &PinholeCamera,
    config: &EssentialConfig,
) -> Result<EssentialResult> {
    let est = EssentialEstimator::new(x1, x2, camera)?;
    let found = ransac(&est, &config.ransac)?;
    let t2 = config.ransac.threshold * config.ransac.threshold;
    let mut e = found.model;
    let mut inliers = found.inliers;
    let mut cost = msac_cost(&est, &e, t2);
    if config.refine_iterations > 0 {
        let settings = LmSettings {
            max_iterations: config.refine_iterations,
            kernel: config.refine_kernel,
        };
        for _ in 0..2 {
            // Any of the four decompositions gives ±E, so the Sampson cost is the same.
            let Ok([(r, t), ..]) = decompose_essential(&e) else {
                break;
            };
            let (motion, stats) = refine_sampson(
                Motion { r, t },
                &est.rays1,
                &est.rays2,
                &inliers,
                &est.scale,
                &settings,
            );
            debug!(
                initial = stats.initial_cost,
                last = stats.final_cost,
                iterations = stats.iterations,
                "essential LM"
            );
            let candidate = motion.matrix();
            let candidate = candidate / candidate.norm();
            let candidate_cost = msac_cost(&est, &candidate, t2);
            if candidate_cost.is_nan() || candidate_cost >= cost {
                break;
            }
            let new_inliers = inliers_of(&est, &candidate, t2);
            let unchanged = new_inliers == inliers;
            e = candidate;
            cost = candidate_cost;
            inliers = new_inliers;
            if unchanged {
                break;
            }
        }
    }
    config
        .ransac
        .check_consensus(inliers.len(), EssentialEstimator::SAMPLE_SIZE)?;
    debug!(
        inliers = inliers.len(),
        total = x1.len(),
        iterations = found.iterations,
        "essential estimated"
    );
    Ok(EssentialResult {
        e,
        inliers,
        iterations: found.iterations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pose::so3_exp;

    #[test]
    fn motion_tangents_match_retraction() {
        let m = Motion {
            r: so3_exp(&Vector3::new(0.1, -0.2, 0.05))
                .to_rotation_matrix()
                .into_inner(),
            t: Vector3::new(0.3, -0.5, 0.8).normalize(),
        };
        let tangents = m.tangents();
        for (k, tangent) in tangents.iter().enumerate() {
            let h = 1e-6;
            let step = SVector::<f64, 5>::ith(k, h);
            let num = (m.retract(&step).matrix() - m.retract(&-step).matrix()) / (2.0 * h);
            let rel = (num - tangent).norm() / tangent.norm();
            assert!(rel < 1e-6, "tangent {k}: rel {rel}");
        }
    }
}
