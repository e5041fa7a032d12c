//! Absolute camera pose from 2D–3D correspondences (PnP).
//!
//! [`solve_pnp_ransac`] runs the crate's MSAC driver with the Lambda Twist P3P minimal solver
//! ([`p3p`]), then polishes the best hypothesis by robust Levenberg-Marquardt on its inliers
//! ([`refine_pose`]) and re-classifies the inliers with the refined pose. This is how an
//! absolute localiser turns satellite-map matches into a camera pose and how SLAM relocalises.

mod p3p;
mod refine;

pub use p3p::{MAX_P3P_SOLUTIONS, p3p};
pub use refine::{RefineConfig, RefinedPose, projection_pose_jacobian, refine_pose};

use nalgebra::{Point2, Point3, Vector3};
use serde::{Deserialize, Serialize};

use crate::camera::PinholeCamera;
use crate::error::{GeometryError, Result};
use crate::pose::WorldToCamera;
use crate::ransac::{Estimator, RansacConfig, inliers_of, ransac};
use crate::robust::RobustKernel;
use refine::{check_observations, squared_error};

/// Parameters of [`solve_pnp_ransac`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PnpConfig {
    /// RANSAC settings; `threshold` is the reprojection error in pixels below which a
    /// correspondence is an inlier. Defaults: 2.5 px, 1000 iterations, 6 inliers (a partially
    /// written `[ransac]` table falls back to [`RansacConfig::default`] for missing keys).
    pub ransac: RansacConfig,
    /// Refine the RANSAC pose on its inliers (recommended: P3P uses only three points).
    pub refine: bool,
    /// Robust kernel of the refinement, on squared pixel errors.
    pub kernel: RobustKernel,
    /// Iteration cap of each refinement round.
    pub max_refine_iterations: usize,
}

impl Default for PnpConfig {
    fn default() -> Self {
        Self {
            ransac: RansacConfig {
                threshold: 2.5,
                max_iterations: 1000,
                // Twice the minimal sample, so a hypothesis is confirmed by independent points.
                min_inliers: 6,
                ..RansacConfig::default()
            },
            refine: true,
            kernel: RobustKernel::Huber { delta: 2.0 },
            max_refine_iterations: 20,
        }
    }
}

/// The outcome of [`solve_pnp_ransac`].
#[derive(Debug, Clone, PartialEq)]
pub struct PnpResult {
    /// World-to-camera pose (refined when [`PnpConfig::refine`] is set).
    pub pose: WorldToCamera,
    /// Indices of correspondences within the threshold under `pose`, ascending.
    pub inliers: Vec<usize>,
    /// RANSAC hypotheses drawn.
    pub iterations: usize,
    /// Root-mean-square reprojection error over `inliers`, in pixels.
    pub rms_reprojection_px: f64,
}

/// P3P hypotheses scored by reprojection error in pixels (distortion included).
#[derive(Debug, Clone)]
pub struct PnpEstimator<'a> {
    world: &'a [Point3<f64>],
    pixels: &'a [Point2<f64>],
    camera: &'a PinholeCamera,
    /// Undistorted viewing rays; `None` where the distortion could not be inverted.
    bearings: Vec<Option<Vector3<f64>>>,
}

impl<'a> PnpEstimator<'a> {
    /// Prepares the bearing of every pixel.
    pub fn new(
        world: &'a [Point3<f64>],
        pixels: &'a [Point2<f64>],
        camera: &'a PinholeCamera,
    ) -> Result<Self> {
        if world.len() != pixels.len() {
            return Err(GeometryError::LengthMismatch {
                what: "world points vs pixels",
                left: world.len(),
                right: pixels.len(),
            });
        }
        let bearings = pixels.iter().map(|uv| camera.unproject(uv)).collect();
        Ok(Self {
            world,
            pixels,
            camera,
            bearings,
        })
    }
}

impl Estimator for PnpEstimator<'_> {
    type Model = WorldToCamera;
    const SAMPLE_SIZE: usize = 3;

    fn len(&self) -> usize {
        self.world.len()
    }

    fn fit(&self, sample: &[usize]) -> Vec<WorldToCamera> {
        let (Some(b0), Some(b1), Some(b2)) = (
            self.bearings[sample[0]],
            self.bearings[sample[1]],
            self.bearings[sample[2]],
        ) else {
            return Vec::new();
        };
        let world = [
            self.world[sample[0]],
            self.world[sample[1]],
            self.world[sample[2]],
        ];
        p3p(&[b0, b1, b2], &world)
    }

    /// Squared reprojection error in pixels²; infinite behind the camera, so such points are
    /// always outliers.
    fn residual_squared(&self, model: &WorldToCamera, index: usize) -> f64 {
        squared_error(self.camera, model, &self.world[index], &self.pixels[index])
    }
}

/// Camera pose from correspondences `world[i] ↔ pixels[i]` with RANSAC + P3P and optional
/// robust refinement (two rounds: refine on the RANSAC inliers, re-classify, and refine again
/// if the inlier set changed).
///
/// Errors on mismatched lengths, fewer than three points, non-finite input, invalid
/// configuration, or when no pose reaches `ransac.min_inliers`.
pub fn solve_pnp_ransac(
    world: &[Point3<f64>],
    pixels: &[Point2<f64>],
    camera: &PinholeCamera,
    config: &PnpConfig,
) -> Result<PnpResult> {
    config.ransac.validate()?;
    check_observations(world, pixels, None)?;
    let estimator = PnpEstimator::new(world, pixels, camera)?;
    let found = ransac(&estimator, &config.ransac)?;
    let t2 = config.ransac.threshold * config.ransac.threshold;
    let required = config.ransac.min_inliers.max(PnpEstimator::SAMPLE_SIZE);

    let mut pose = found.model;
    let mut inliers = found.inliers;
    if config.refine {
        let refine_cfg = RefineConfig {
            kernel: config.kernel,
            max_iterations: config.max_refine_iterations,
            ..RefineConfig::default()
        };
        for round in 0..2 {
            let (w, p): (Vec<_>, Vec<_>) = inliers.iter().map(|&i| (world[i], pixels[i])).unzip();
            let refined = match refine_pose(&w, &p, None, camera, pose, &refine_cfg) {
                Ok(r) => r,
                Err(e) => {
                    tracing::warn!(round, error = %e, "PnP refinement failed; keeping RANSAC pose");
                    break;
                }
            };
            let new_inliers = inliers_of(&estimator, &refined.pose, t2);
            if new_inliers.len() < required {
                tracing::warn!(
                    round,
                    inliers = new_inliers.len(),
                    "refined pose lost its consensus; keeping the previous pose"
                );
                break;
            }
            pose = refined.pose;
            let unchanged = new_inliers == inliers;
            inliers = new_inliers;
            if unchanged {
                break;
            }
        }
    }

    let sum_sq: f64 = inliers
        .iter()
        .map(|&i| estimator.residual_squared(&pose, i))
        .sum();
    let rms_reprojection_px = (sum_sq / inliers.len().max(1) as f64).sqrt();
    tracing::debug!(
        points = world.len(),
        inliers = inliers.len(),
        iterations = found.iterations,
        rms_reprojection_px,
        "PnP RANSAC"
    );
    Ok(PnpResult {
        pose,
        inliers,
        iterations: found.iterations,
        rms_reprojection_px,
    })
}
