//! Triangulation of one 3-D point from N ≥ 2 calibrated views: a linear (DLT) estimate, a
//! damped Gauss-Newton refinement of the reprojection error, and the quality measures SLAM
//! uses to reject points (parallax, depths, per-view reprojection errors).
//!
//! Views are given as world-to-camera poses with one pixel each, all seen through one camera
//! (with its distortion: rays come from [`PinholeCamera::unproject`]).

use nalgebra::{Matrix2x3, Matrix3, Matrix4, Point2, Point3, RowVector4, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::camera::PinholeCamera;
use crate::error::{GeometryError, Result};
use crate::pose::WorldToCamera;

/// Parameters of [`triangulate`] and [`refine_point`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TriangulationConfig {
    /// Iterations of the reprojection-error refinement; 0 keeps the linear estimate. Two or
    /// three usually suffice, since the DLT start is close.
    pub max_iterations: usize,
    /// Stop once an update moves the point by less than this fraction of its distance to the
    /// mean camera centre.
    pub relative_step_tolerance: f64,
}

impl Default for TriangulationConfig {
    fn default() -> Self {
        Self {
            max_iterations: 10,
            relative_step_tolerance: 1e-10,
        }
    }
}

/// A triangulated point with its fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TriangulatedPoint {
    /// The point in the world frame.
    pub point: Point3<f64>,
    /// Root-mean-square reprojection error over the views, pixels.
    pub rms_error: f64,
    /// Refinement iterations performed.
    pub iterations: usize,
}

/// Geometric quality of a point with respect to its observations.
#[derive(Debug, Clone, PartialEq)]
pub struct PointQuality {
    /// Largest angle between two viewing rays (camera centre to point), degrees. Depth is
    /// ill-conditioned when this is small.
    pub parallax_deg: f64,
    /// Depth (`z` in the camera frame) in each view; negative behind the camera.
    pub depths: Vec<f64>,
    /// Reprojection error in each view, pixels (∞ where the point does not project).
    pub reprojection_errors: Vec<f64>,
}

impl PointQuality {
    /// True when the point lies in front of every camera.
    pub fn in_front(&self) -> bool {
        self.depths.iter().all(|&d| d > 0.0)
    }

    /// The largest per-view reprojection error, pixels.
    pub fn max_reprojection_error(&self) -> f64 {
        self.reprojection_errors.iter().fold(
            0.0,
            |m, &e| if e.is_nan() { f64::INFINITY } else { m.max(e) },
        )
    }

    /// In front of every camera, parallax of at least `min_parallax_deg` and every
    /// reprojection error at most `max_error_px`.
    pub fn is_good(&self, min_parallax_deg: f64, max_error_px: f64) -> bool {
        self.in_front()
            && self.parallax_deg >= min_parallax_deg
            && self.max_reprojection_error() <= max_error_px
    }
}

fn check_views(poses: &[WorldToCamera], pixels: &[Point2<f64>]) -> Result<()> {
    if poses.len() != pixels.len() {
        return Err(GeometryError::LengthMismatch {
            what: "poses vs pixels",
            left: poses.len(),
            right: pixels.len(),
        });
    }
    if poses.len() < 2 {
        return Err(GeometryError::TooFewPoints {
            required: 2,
            found: poses.len(),
        });
    }
    if !poses.iter().all(WorldToCamera::is_finite) {
        return Err(GeometryError::NonFinite("camera poses"));
    }
    if !pixels.iter().all(|p| p.x.is_finite() && p.y.is_finite()) {
        return Err(GeometryError::NonFinite("pixels"));
    }
    Ok(())
}

/// Camera centre of a world-to-camera pose, `−Rᵀ t`.
fn centre(pose: &WorldToCamera) -> Vector3<f64> {
    pose.0.inverse().translation.vector
}

/// Residual `π(R X + t) − u` (pixels) and its Jacobian with respect to the world point `X`;
/// `None` when the point is not in front of the camera.
pub fn reprojection_residual(
    point: &Point3<f64>,
    pose: &WorldToCamera,
    pixel: &Point2<f64>,
    camera: &PinholeCamera,
) -> Option<(Vector2<f64>, Matrix2x3<f64>)> {
    let pc = pose.transform_point(point);
    let (uv, j) = camera.project_with_jacobian(&pc)?;
    Some((uv - pixel, j * pose.rotation_matrix()))
}

/// Linear triangulation (DLT on normalised rays, smallest eigenvector of `AᵀA`). The world
/// frame is first shifted to the mean camera centre and scaled by the camera spread, so the
/// result does not degrade with large map coordinates.
pub fn triangulate_linear(
    poses: &[WorldToCamera],
    pixels: &[Point2<f64>],
    camera: &PinholeCamera,
) -> Result<Point3<f64>> {
    check_views(poses, pixels)?;
    let n = poses.len() as f64;
    let c = poses.iter().map(centre).sum::<Vector3<f64>>() / n;
    let spread = poses
        .iter()
        .map(|p| (centre(p) - c).norm())
        .fold(0.0, f64::max);
    if spread.is_nan() || spread <= 1e-12 * (1.0 + c.norm()) {
        return Err(GeometryError::Degenerate(
            "triangulation: all views share one camera centre".into(),
        ));
    }
    // World X = c + spread · Y; camera point ∝ R Y + (R c + t) / spread.
    let mut ata = Matrix4::<f64>::zeros();
    for (pose, px) in poses.iter().zip(pixels) {
        let ray = camera.unproject(px).ok_or_else(|| {
            GeometryError::Degenerate("triangulation: pixel cannot be undistorted".into())
        })?;
        let r = pose.rotation_matrix();
        let t = (r * c + pose.translation()) / spread;
        let prow = |k: usize| RowVector4::new(r[(k, 0)], r[(k, 1)], r[(k, 2)], t[k]);
        for row in [ray.x * prow(2) - prow(0), ray.y * prow(2) - prow(1)] {
            ata += row.transpose() * row;
        }
    }
    let eig = ata.symmetric_eigen();
    let k = eig.eigenvalues.imin();
    let y = eig.eigenvectors.column(k);
    if y[3].is_nan() || y[3].abs() <= 1e-12 * y.norm() {
        return Err(GeometryError::Degenerate(
            "triangulation: point at infinity (parallel rays)".into(),
        ));
    }
    let p = c + spread * y.fixed_rows::<3>(0) / y[3];
    if !p.iter().all(|v| v.is_finite()) {
        return Err(GeometryError::Degenerate(
            "triangulation: non-finite solution".into(),
        ));
    }
    Ok(Point3::from(p))
}

fn total_cost(
    point: &Point3<f64>,
    poses: &[WorldToCamera],
    pixels: &[Point2<f64>],
    camera: &PinholeCamera,
) -> f64 {
    poses
        .iter()
        .zip(pixels)
        .map(
            |(pose, px)| match camera.project(&pose.transform_point(point)) {
                Some(uv) => (uv - px).norm_squared(),
                None => f64::INFINITY,
            },
        )
        .sum()
}

/// Refines a point by damped Gauss-Newton (Levenberg-Marquardt) on the squared reprojection
/// error of all views. Fails when the start is not in front of every camera.
pub fn refine_point(
    initial: &Point3<f64>,
    poses: &[WorldToCamera],
    pixels: &[Point2<f64>],
    camera: &PinholeCamera,
    config: &TriangulationConfig,
) -> Result<TriangulatedPoint> {
    check_views(poses, pixels)?;
    let mut point = *initial;
    let mut cost = total_cost(&point, poses, pixels, camera);
    if !cost.is_finite() {
        return Err(GeometryError::Degenerate(
            "triangulation: point is behind a camera".into(),
        ));
    }
    let scale = {
        let n = poses.len() as f64;
        let c = poses.iter().map(centre).sum::<Vector3<f64>>() / n;
        (point.coords - c).norm().max(1e-12)
    };
    // Levenberg-Marquardt with one cost evaluation per iteration: a rejected step only raises
    // the damping. Converged once the proposed step is negligible.
    let mut lambda = 1e-6;
    let mut iterations = 0;
    let mut linearised: Option<(Matrix3<f64>, Vector3<f64>)> = None;
    while iterations < config.max_iterations && cost > 0.0 {
        iterations += 1;
        let (h, g) = *linearised.get_or_insert_with(|| {
            let mut h = Matrix3::<f64>::zeros();
            let mut g = Vector3::<f64>::zeros();
            for (pose, px) in poses.iter().zip(pixels) {
                if let Some((r, j)) = reprojection_residual(&point, pose, px, camera) {
                    h += j.transpose() * j;
                    g += j.transpose() * r;
                }
            }
            (h, g)
        });
        let mut damped = h;
        for k in 0..3 {
            damped[(k, k)] += lambda * h[(k, k)].max(1e-12);
        }
        let Some(step) = damped.cholesky().map(|c| -c.solve(&g)) else {
            lambda *= 10.0;
            continue;
        };
        if step.norm() <= config.relative_step_tolerance * scale {
            break;
        }
        let candidate = point + step;
        let new_cost = total_cost(&candidate, poses, pixels, camera);
        if new_cost < cost {
            point = candidate;
            cost = new_cost;
            lambda = (lambda * 0.1).max(1e-12);
            linearised = None;
        } else {
            lambda *= 10.0;
        }
    }
    Ok(TriangulatedPoint {
        point,
        rms_error: (cost / poses.len() as f64).sqrt(),
        iterations,
    })
}

/// Linear triangulation followed by [`refine_point`].
pub fn triangulate(
    poses: &[WorldToCamera],
    pixels: &[Point2<f64>],
    camera: &PinholeCamera,
    config: &TriangulationConfig,
) -> Result<TriangulatedPoint> {
    let linear = triangulate_linear(poses, pixels, camera)?;
    refine_point(&linear, poses, pixels, camera, config)
}

/// Parallax, depths and reprojection errors of `point` in each view.
pub fn point_quality(
    point: &Point3<f64>,
    poses: &[WorldToCamera],
    pixels: &[Point2<f64>],
    camera: &PinholeCamera,
) -> Result<PointQuality> {
    check_views(poses, pixels)?;
    if !point.iter().all(|v| v.is_finite()) {
        return Err(GeometryError::NonFinite("point"));
    }
    let mut depths = Vec::with_capacity(poses.len());
    let mut reprojection_errors = Vec::with_capacity(poses.len());
    for (pose, px) in poses.iter().zip(pixels) {
        let pc = pose.transform_point(point);
        depths.push(pc.z);
        reprojection_errors.push(
            camera
                .project(&pc)
                .map_or(f64::INFINITY, |uv| (uv - px).norm()),
        );
    }
    let rays: Vec<Vector3<f64>> = poses.iter().map(|p| point.coords - centre(p)).collect();
    let mut min_cos = 1.0f64;
    for (i, a) in rays.iter().enumerate() {
        for b in &rays[i + 1..] {
            let denom = a.norm() * b.norm();
            if denom > 0.0 {
                min_cos = min_cos.min(a.dot(b) / denom);
            }
        }
    }
    Ok(PointQuality {
        parallax_deg: min_cos.clamp(-1.0, 1.0).acos().to_degrees(),
        depths,
        reprojection_errors,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::RadTan;
    use nalgebra::{UnitQuaternion, Vector6};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    fn camera() -> PinholeCamera {
        PinholeCamera::ideal(500.0, 500, 500)
    }

    /// Cameras on a rough arc looking at the origin region, far from the world origin.
    fn views(seed: u64, n: usize) -> Vec<WorldToCamera> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|_| {
                let xi = Vector6::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-0.3..0.3),
                    rng.random_range(-0.1..0.1),
                    rng.random_range(-0.1..0.1),
                    rng.random_range(-0.1..0.1),
                );
                let local = WorldToCamera::exp(&xi);
                // Shift the world by a large offset (map coordinates are hundreds of metres).
                let offset = Vector3::new(1500.0, -800.0, 120.0);
                WorldToCamera(local.0 * nalgebra::Translation3::from(-offset))
            })
            .collect()
    }

    fn observe(p: &Point3<f64>, poses: &[WorldToCamera], cam: &PinholeCamera) -> Vec<Point2<f64>> {
        poses
            .iter()
            .map(|pose| cam.project(&pose.transform_point(p)).unwrap())
            .collect()
    }

    #[test]
    fn linear_is_exact_without_noise() {
        let cam = camera();
        for seed in 0..10 {
            let poses = views(seed, 2 + seed as usize % 4);
            let p = Point3::new(1500.3, -800.2, 128.0);
            let px = observe(&p, &poses, &cam);
            let est = triangulate_linear(&poses, &px, &cam).unwrap();
            assert!((est - p).norm() < 1e-7, "seed {seed}: {}", (est - p).norm());
        }
    }

    #[test]
    fn refinement_reduces_reprojection_error_under_noise() {
        let cam = camera();
        let noise = Normal::new(0.0, 1.0).unwrap();
        for seed in 0..10 {
            let mut rng = ChaCha8Rng::seed_from_u64(100 + seed);
            let poses = views(seed, 4);
            let p = Point3::new(1500.0, -800.5, 126.0);
            let px: Vec<Point2<f64>> = observe(&p, &poses, &cam)
                .into_iter()
                .map(|u| u + Vector2::new(noise.sample(&mut rng), noise.sample(&mut rng)))
                .collect();
            let linear = triangulate_linear(&poses, &px, &cam).unwrap();
            let refined = refine_point(&linear, &poses, &px, &cam, &Default::default()).unwrap();
            let lin_cost = total_cost(&linear, &poses, &px, &cam);
            assert!(refined.rms_error.powi(2) * 4.0 <= lin_cost + 1e-12);
            // At the optimum the Gauss-Newton step vanishes (to round-off of map coordinates).
            let (mut h, mut g) = (Matrix3::zeros(), Vector3::zeros());
            for (pose, u) in poses.iter().zip(&px) {
                let (r, j) = reprojection_residual(&refined.point, pose, u, &cam).unwrap();
                h += j.transpose() * j;
                g += j.transpose() * r;
            }
            let step = h.cholesky().unwrap().solve(&g).norm();
            assert!(step < 1e-6, "seed {seed}: remaining step {step} m");
            assert!((refined.point - p).norm() < 0.5);
        }
    }

    #[test]
    fn reprojection_jacobian_matches_central_differences() {
        let distorted = PinholeCamera {
            distortion: Some(
                RadTan {
                    k1: -0.2,
                    k2: 0.05,
                    p1: 1e-3,
                    p2: -5e-4,
                    k3: 0.0,
                }
                .into(),
            ),
            ..camera()
        };
        for cam in [camera(), distorted] {
            for (seed, pose) in views(7, 5).iter().enumerate() {
                let p = Point3::new(1500.2, -799.7, 127.0 + seed as f64);
                let px = Point2::new(250.0, 240.0);
                let (_, j) = reprojection_residual(&p, pose, &px, &cam).unwrap();
                for k in 0..3 {
                    let h = 1e-5;
                    let (mut pp, mut pm) = (p, p);
                    pp[k] += h;
                    pm[k] -= h;
                    let num = (reprojection_residual(&pp, pose, &px, &cam).unwrap().0
                        - reprojection_residual(&pm, pose, &px, &cam).unwrap().0)
                        / (2.0 * h);
                    let rel = (num - j.column(k)).norm() / j.norm();
                    assert!(rel < 1e-6, "column {k}: {num} vs {}", j.column(k));
                }
            }
        }
    }

    #[test]
    fn quality_reports_parallax_depth_and_error() {
        let cam = camera();
        let poses = [
            WorldToCamera::identity(),
            WorldToCamera::from_rotation_translation(
                UnitQuaternion::identity(),
                Vector3::new(-1.0, 0.0, 0.0),
            ),
        ];
        let p = Point3::new(0.5, 0.0, 10.0);
        let px = observe(&p, &poses, &cam);
        let q = point_quality(&p, &poses, &px, &cam).unwrap();
        let expected = 2.0 * (0.5f64 / 10.0).atan().to_degrees();
        assert!((q.parallax_deg - expected).abs() < 1e-9);
        assert!(q.in_front() && q.max_reprojection_error() < 1e-9);
        assert!((q.depths[0] - 10.0).abs() < 1e-12 && (q.depths[1] - 10.0).abs() < 1e-12);
        assert!(q.is_good(1.0, 0.5) && !q.is_good(10.0, 0.5));
        let behind = point_quality(&Point3::new(0.0, 0.0, -5.0), &poses, &px, &cam).unwrap();
        assert!(!behind.in_front() && behind.max_reprojection_error().is_infinite());
    }

    #[test]
    fn bad_input_gives_errors() {
        let cam = camera();
        let poses = views(1, 3);
        let p = Point3::new(1500.0, -800.0, 127.0);
        let px = observe(&p, &poses, &cam);
        let cfg = TriangulationConfig::default();
        assert!(matches!(
            triangulate(&poses[..1], &px[..1], &cam, &cfg),
            Err(GeometryError::TooFewPoints { .. })
        ));
        assert!(matches!(
            triangulate(&poses, &px[..2], &cam, &cfg),
            Err(GeometryError::LengthMismatch { .. })
        ));
        let mut nan = px.clone();
        nan[1].x = f64::NAN;
        assert!(matches!(
            triangulate(&poses, &nan, &cam, &cfg),
            Err(GeometryError::NonFinite(_))
        ));
        let same = [poses[0], poses[0]];
        assert!(matches!(
            triangulate(&same, &px[..2], &cam, &cfg),
            Err(GeometryError::Degenerate(_))
        ));
        // Parallel rays from two centres: the point is at infinity.
        let shifted = [
            WorldToCamera::identity(),
            WorldToCamera::from_rotation_translation(
                UnitQuaternion::identity(),
                Vector3::new(-1.0, 0.0, 0.0),
            ),
        ];
        let c = Point2::new(cam.cx, cam.cy);
        assert!(triangulate(&shifted, &[c, c], &cam, &cfg).is_err());
        // Start behind the cameras.
        assert!(matches!(
            refine_point(&Point3::new(0.0, 0.0, -3.0), &shifted, &[c, c], &cam, &cfg),
            Err(GeometryError::Degenerate(_))
        ));
    }
}
