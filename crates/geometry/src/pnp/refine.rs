//! Pose-only refinement: robust Levenberg-Marquardt on SE(3) minimising reprojection error.
//!
//! The pose `T_cw` is updated by a **left** perturbation, `T ← exp(δ) T` with `δ = [ρ; φ]`
//! (translation first, as in [`crate::pose`]). The camera-frame point `p_c = T p_w` then moves as
//! `∂p_c/∂δ = [I | −[p_c]×]`, which is chained with
//! [`PinholeCamera::project_with_jacobian`] (distortion included) into the analytic 2×6 Jacobian.
//!
//! The cost is `Σ ρ(ωᵢ ‖π(T pᵢ) − uᵢ‖²)` with an optional per-observation information `ωᵢ`
//! (e.g. `1/σ²` of the ORB pyramid level) and a [`RobustKernel`] `ρ` applied to the weighted
//! squared error, as g2o does; the normal equations use the IRLS weights `ρ'(sᵢ) ωᵢ`.
//! SLAM pose-only optimisation reuses this function directly.

use nalgebra::{Matrix2x6, Matrix3x6, Matrix6, Point2, Point3, Vector2, Vector6};
use serde::{Deserialize, Serialize};

use crate::camera::PinholeCamera;
use crate::error::{GeometryError, Result};
use crate::pose::{WorldToCamera, skew};
use crate::robust::RobustKernel;

/// Parameters of [`refine_pose`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RefineConfig {
    /// Robust kernel on the information-weighted squared reprojection error (pixels² when no
    /// information is given).
    pub kernel: RobustKernel,
    /// Maximum number of accepted-or-rejected LM steps.
    pub max_iterations: usize,
    /// Initial Marquardt damping `μ` in `(H + μ diag H) δ = −g`.
    pub initial_damping: f64,
    /// Converged when the update `‖δ‖` (metres and radians mixed) falls below this.
    pub step_tolerance: f64,
    /// Converged when an accepted step lowers the cost by less than this fraction.
    pub cost_tolerance: f64,
}

impl Default for RefineConfig {
    fn default() -> Self {
        Self {
            kernel: RobustKernel::Huber { delta: 2.0 },
            max_iterations: 20,
            initial_damping: 1e-4,
            step_tolerance: 1e-10,
            cost_tolerance: 1e-10,
        }
    }
}

impl RefineConfig {
    /// Checks ranges.
    pub fn validate(&self) -> Result<()> {
        let positive = |field, v: f64| {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err(GeometryError::InvalidConfig {
                    field,
                    value: v.to_string(),
                    reason: "must be finite and >= 0",
                })
            }
        };
        positive("initial_damping", self.initial_damping)?;
        positive("step_tolerance", self.step_tolerance)?;
        positive("cost_tolerance", self.cost_tolerance)?;
        match self.kernel {
            RobustKernel::Huber { delta: s } | RobustKernel::Cauchy { c: s }
                if !(s.is_finite() && s > 0.0) =>
            {
                Err(GeometryError::InvalidConfig {
                    field: "kernel",
                    value: s.to_string(),
                    reason: "kernel scale must be finite and > 0",
                })
            }
            _ => Ok(()),
        }
    }
}

/// The outcome of [`refine_pose`].
#[derive(Debug, Clone, PartialEq)]
pub struct RefinedPose {
    /// The refined world-to-camera pose.
    pub pose: WorldToCamera,
    /// LM iterations performed (each solves the damped normal equations at least once).
    pub iterations: usize,
    /// Robust cost `Σ ρ(ωᵢ eᵢᵀeᵢ)` at the initial pose.
    pub initial_cost: f64,
    /// Robust cost at the returned pose.
    pub final_cost: f64,
    /// True when a tolerance was met before `max_iterations`.
    pub converged: bool,
    /// Unweighted squared reprojection error of every observation at the returned pose, in
    /// pixels²; `f64::INFINITY` for points behind the camera. Lets callers re-classify outliers.
    pub squared_errors: Vec<f64>,
}

/// Projects `p_w` through `pose` and `camera`; also returns `∂(u, v)/∂δ` for the left
/// perturbation `exp(δ) T`, `δ = [ρ; φ]`. `None` behind the camera.
pub fn projection_pose_jacobian(
    camera: &PinholeCamera,
    pose: &WorldToCamera,
    p_w: &Point3<f64>,
) -> Option<(Point2<f64>, Matrix2x6<f64>)> {
    let p_c = pose.transform_point(p_w);
    let (uv, j_proj) = camera.project_with_jacobian(&p_c)?;
    let mut d_point = Matrix3x6::zeros();
    d_point.fixed_view_mut::<3, 3>(0, 0).fill_with_identity();
    d_point
        .fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&(-skew(&p_c.coords)));
    Some((uv, j_proj * d_point))
}

/// Refines `initial` by robust LM on the reprojection errors of `world[i] ↔ pixels[i]`.
///
/// `information`, when given, holds one non-negative weight per observation (`ωᵢ = 1/σᵢ²`);
/// the kernel then acts on `ωᵢ‖eᵢ‖²`. A point that falls behind the camera during the
/// iterations costs `ρ(ωᵢ · diagonal²)` (the image diagonal in pixels) and adds no Jacobian,
/// which keeps costs of different iterates comparable.
pub fn refine_pose(
    world: &[Point3<f64>],
    pixels: &[Point2<f64>],
    information: Option<&[f64]>,
    camera: &PinholeCamera,
    initial: WorldToCamera,
    config: &RefineConfig,
) -> Result<RefinedPose> {
    config.validate()?;
    check_observations(world, pixels, information)?;
    if !initial.is_finite() {
        return Err(GeometryError::NonFinite("initial pose"));
    }
    let problem = Problem {
        world,
        pixels,
        information,
        camera,
        kernel: config.kernel,
        behind_penalty: (camera.width as f64).hypot(camera.height as f64).powi(2),
    };

    let mut pose = initial;
    let mut lin = problem.linearise(&pose);
    if lin.in_front < 3 {
        return Err(GeometryError::Degenerate(format!(
            "only {} of {} points in front of the initial pose",
            lin.in_front,
            world.len()
        )));
    }
    let initial_cost = lin.cost;
    let mut damping = config.initial_damping;
    let mut converged = false;
    let mut iterations = 0;
    'outer: while iterations < config.max_iterations {
        iterations += 1;
        // Inner loop: raise the damping until a step lowers the cost.
        loop {
            let mut a = lin.hessian;
            for k in 0..6 {
                a[(k, k)] += damping * lin.hessian[(k, k)].max(1e-12);
            }
            let Some(chol) = a.cholesky() else {
                damping = damping.max(1e-9) * 10.0;
                if damping > 1e12 {
                    break 'outer;
                }
                continue;
            };
            let delta = -chol.solve(&lin.gradient);
            if delta.norm() < config.step_tolerance {
                converged = true;
                break 'outer;
            }
            let candidate = WorldToCamera(WorldToCamera::exp(&delta).0 * pose.0);
            let cost = problem.cost(&candidate);
            if cost < lin.cost {
                let decrease = lin.cost - cost;
                pose = candidate;
                lin = problem.linearise(&pose);
                damping = (damping / 10.0).max(1e-15);
                if decrease <= config.cost_tolerance * cost.max(f64::MIN_POSITIVE) {
                    converged = true;
                    break 'outer;
                }
                break;
            }
            damping = damping.max(1e-9) * 10.0;
            if damping > 1e12 {
                // No descent direction left: we are at a (numerical) minimum.
                converged = true;
                break 'outer;
            }
        }
    }
    tracing::debug!(
        iterations,
        initial_cost,
        final_cost = lin.cost,
        converged,
        "pose refinement"
    );
    let squared_errors = world
        .iter()
        .zip(pixels)
        .map(|(p, uv)| squared_error(camera, &pose, p, uv))
        .collect();
    Ok(RefinedPose {
        pose,
        iterations,
        initial_cost,
        final_cost: lin.cost,
        converged,
        squared_errors,
    })
}

/// Squared pixel error of one observation; infinite when the point is behind the camera.
pub(crate) fn squared_error(
    camera: &PinholeCamera,
    pose: &WorldToCamera,
    p_w: &Point3<f64>,
    uv: &Point2<f64>,
) -> f64 {
    // Same model and validity test as `PinholeCamera::project`, without its Jacobian: RANSAC
    // scoring calls this for every point and hypothesis.
    let p = pose.transform_point(p_w);
    if p.z <= f64::EPSILON || !p.coords.iter().all(|c| c.is_finite()) {
        return f64::INFINITY;
    }
    let xn = Vector2::new(p.x / p.z, p.y / p.z);
    camera
        .distort_to_pixel(&xn)
        .map_or(f64::INFINITY, |q| (q - uv).norm_squared())
}

/// Validates lengths and finiteness of an observation set.
pub(crate) fn check_observations(
    world: &[Point3<f64>],
    pixels: &[Point2<f64>],
    information: Option<&[f64]>,
) -> Result<()> {
    if world.len() != pixels.len() {
        return Err(GeometryError::LengthMismatch {
            what: "world points vs pixels",
            left: world.len(),
            right: pixels.len(),
        });
    }
    if world.len() < 3 {
        return Err(GeometryError::TooFewPoints {
            required: 3,
            found: world.len(),
        });
    }
    if !world.iter().all(|p| p.coords.iter().all(|c| c.is_finite())) {
        return Err(GeometryError::NonFinite("world point"));
    }
    if !pixels
        .iter()
        .all(|p| p.coords.iter().all(|c| c.is_finite()))
    {
        return Err(GeometryError::NonFinite("pixel"));
    }
    if let Some(info) = information {
        if info.len() != world.len() {
            return Err(GeometryError::LengthMismatch {
                what: "information weights vs observations",
                left: info.len(),
                right: world.len(),
            });
        }
        if !info.iter().all(|w| w.is_finite() && *w >= 0.0) {
            return Err(GeometryError::NonFinite(
                "information weight (must be finite, >= 0)",
            ));
        }
    }
    Ok(())
}

struct Problem<'a> {
    world: &'a [Point3<f64>],
    pixels: &'a [Point2<f64>],
    information: Option<&'a [f64]>,
    camera: &'a PinholeCamera,
    kernel: RobustKernel,
    behind_penalty: f64,
}

struct Linearisation {
    cost: f64,
    hessian: Matrix6<f64>,
    gradient: Vector6<f64>,
    in_front: usize,
}

impl Problem<'_> {
    fn info(&self, i: usize) -> f64 {
        self.information.map_or(1.0, |w| w[i])
    }

    fn cost(&self, pose: &WorldToCamera) -> f64 {
        (0..self.world.len())
            .map(|i| {
                let w = self.info(i);
                let e2 = squared_error(self.camera, pose, &self.world[i], &self.pixels[i]);
                self.kernel.rho(w * e2.min(self.behind_penalty))
            })
            .sum()
    }

    fn linearise(&self, pose: &WorldToCamera) -> Linearisation {
        let mut lin = Linearisation {
            cost: 0.0,
            hessian: Matrix6::zeros(),
            gradient: Vector6::zeros(),
            in_front: 0,
        };
        for i in 0..self.world.len() {
            let w = self.info(i);
            let Some((uv, j)) = projection_pose_jacobian(self.camera, pose, &self.world[i]) else {
                lin.cost += self.kernel.rho(w * self.behind_penalty);
                continue;
            };
            lin.in_front += 1;
            let e = uv - self.pixels[i];
            let s = w * e.norm_squared().min(self.behind_penalty);
            lin.cost += self.kernel.rho(s);
            let irls = self.kernel.weight(s) * w;
            let jt = j.transpose();
            lin.hessian += irls * jt * j;
            lin.gradient += irls * jt * e;
        }
        lin
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::RadTan;
    use nalgebra::{UnitQuaternion, Vector3};

    fn cameras() -> [PinholeCamera; 2] {
        let ideal = PinholeCamera::ideal(500.0, 500, 500);
        let distorted = PinholeCamera {
            distortion: Some(
                RadTan {
                    k1: -0.28,
                    k2: 0.07,
                    p1: 2e-4,
                    p2: -1.5e-4,
                    k3: 0.01,
                }
                .into(),
            ),
            ..ideal
        };
        [ideal, distorted]
    }

    #[test]
    fn pose_jacobian_matches_central_differences() {
        let pose = WorldToCamera::from_rotation_translation(
            UnitQuaternion::from_scaled_axis(Vector3::new(0.3, -0.5, 0.2)),
            Vector3::new(0.4, -1.0, 6.0),
        );
        let points = [
            Point3::new(0.5, 0.3, 2.0),
            Point3::new(-2.0, 1.0, 4.0),
            Point3::new(1.5, -1.2, 0.5),
        ];
        for camera in cameras() {
            for p in &points {
                let (_, j) = projection_pose_jacobian(&camera, &pose, p).unwrap();
                for k in 0..6 {
                    let h = 1e-6;
                    let mut d = Vector6::zeros();
                    d[k] = h;
                    let plus = WorldToCamera(WorldToCamera::exp(&d).0 * pose.0);
                    let minus = WorldToCamera(WorldToCamera::exp(&(-d)).0 * pose.0);
                    let up = camera.project(&plus.transform_point(p)).unwrap();
                    let um = camera.project(&minus.transform_point(p)).unwrap();
                    let num = (up - um) / (2.0 * h);
                    let ana = j.column(k);
                    let rel = (num - ana).norm() / ana.norm().max(1.0);
                    assert!(rel < 1e-6, "column {k}: numeric {num} vs analytic {ana}");
                }
            }
        }
    }

    #[test]
    fn squared_error_matches_camera_projection() {
        let pose = WorldToCamera::from_rotation_translation(
            UnitQuaternion::from_scaled_axis(Vector3::new(0.3, -0.5, 0.2)),
            Vector3::new(0.4, -1.0, 6.0),
        );
        let uv = Point2::new(240.0, 260.0);
        for camera in cameras() {
            for p in [Point3::new(0.5, 0.3, 2.0), Point3::new(-2.0, 1.0, 4.0)] {
                let expected =
                    (camera.project(&pose.transform_point(&p)).unwrap() - uv).norm_squared();
                let got = squared_error(&camera, &pose, &p, &uv);
                assert!(
                    (got - expected).abs() <= 1e-9 * expected,
                    "{got} vs {expected}"
                );
            }
            let behind = pose.inverse().transform_point(&Point3::new(0.1, 0.2, -3.0));
            assert_eq!(squared_error(&camera, &pose, &behind, &uv), f64::INFINITY);
        }
    }

    #[test]
    fn converges_from_perturbed_pose_to_exact_solution() {
        let truth = WorldToCamera::from_rotation_translation(
            UnitQuaternion::from_scaled_axis(Vector3::new(0.1, 0.2, -0.3)),
            Vector3::new(1.0, -0.5, 8.0),
        );
        let world: Vec<Point3<f64>> = (0..30)
            .map(|i| {
                let f = i as f64;
                Point3::new(
                    (f * 0.7).sin() * 3.0,
                    (f * 1.3).cos() * 3.0,
                    (f * 0.37).sin(),
                )
            })
            .collect();
        for camera in cameras() {
            let pixels: Vec<Point2<f64>> = world
                .iter()
                .map(|p| camera.project(&truth.transform_point(p)).unwrap())
                .collect();
            let start = WorldToCamera(
                WorldToCamera::exp(&Vector6::new(0.2, -0.1, 0.3, 0.03, -0.02, 0.04)).0 * truth.0,
            );
            let cfg = RefineConfig {
                kernel: RobustKernel::Cauchy { c: 2.0 },
                ..Default::default()
            };
            let info: Vec<f64> = (0..world.len()).map(|i| 1.0 / (1 + i % 3) as f64).collect();
            let out = refine_pose(&world, &pixels, Some(&info), &camera, start, &cfg).unwrap();
            assert!(out.final_cost < 1e-12 && out.final_cost < out.initial_cost);
            let err = (out.pose.0.inverse() * truth.0).translation.vector.norm();
            assert!(err < 1e-8, "translation error {err}");
            assert!(out.squared_errors.iter().all(|&e| e < 1e-12));
        }
    }

    #[test]
    fn rejects_bad_input() {
        let camera = PinholeCamera::ideal(500.0, 500, 500);
        let world = [Point3::new(0.0, 0.0, 5.0); 4];
        let pixels = [Point2::new(250.0, 250.0); 4];
        let cfg = RefineConfig::default();
        let id = WorldToCamera::identity();
        assert!(matches!(
            refine_pose(&world[..2], &pixels[..2], None, &camera, id, &cfg),
            Err(GeometryError::TooFewPoints { .. })
        ));
        assert!(matches!(
            refine_pose(&world, &pixels[..3], None, &camera, id, &cfg),
            Err(GeometryError::LengthMismatch { .. })
        ));
        let mut nan = pixels;
        nan[2].y = f64::NAN;
        assert!(matches!(
            refine_pose(&world, &nan, None, &camera, id, &cfg),
            Err(GeometryError::NonFinite(_))
        ));
        assert!(matches!(
            refine_pose(
                &world,
                &pixels,
                Some(&[1.0, -1.0, 1.0, 1.0]),
                &camera,
                id,
                &cfg
            ),
            Err(GeometryError::NonFinite(_))
        ));
        let behind = [Point3::new(0.0, 0.0, -5.0); 4];
        assert!(matches!(
            refine_pose(&behind, &pixels, None, &camera, id, &cfg),
            Err(GeometryError::Degenerate(_))
        ));
    }
}
