//! Relative pose from an essential matrix: the four `(R, t)` factorisations of `E`, the choice
//! among them by cheirality, and triangulation of the inliers (camera 1 is the world frame,
//! `|t| = 1`).

use nalgebra::{Matrix3, Point2, Point3, Rotation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use tracing::debug;

use super::essential::{EssentialConfig, EssentialResult, estimate_essential};
use super::fundamental::check_correspondences;
use crate::camera::PinholeCamera;
use crate::error::{GeometryError, Result};
use crate::pose::WorldToCamera;
use crate::triangulation::{TriangulationConfig, refine_point};

/// Parameters of [`recover_pose`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RecoverPoseConfig {
    /// Minimum angle between the two viewing rays of a point, degrees. Below it the sign of
    /// the depth is unreliable, so such points neither vote nor are returned.
    pub min_parallax_deg: f64,
    /// Largest reprojection error (pixels, either view) of a returned point.
    pub max_reprojection_error: f64,
    /// Fewest points in front of both cameras for the pose to be accepted.
    pub min_points: usize,
    /// Of the inliers with enough parallax, the fraction the chosen factorisation must place in
    /// front of both cameras. A correct `E` places nearly all of them there; a wrong one (often
    /// the mirror solution of a planar scene) does not.
    pub min_front_ratio: f64,
    /// The runner-up factorisation must have fewer than this fraction of the winner's votes,
    /// otherwise the pose is ambiguous (e.g. almost no translation).
    pub max_ambiguity: f64,
    /// Refinement of each returned point on its reprojection error.
    pub triangulation: TriangulationConfig,
}

impl Default for RecoverPoseConfig {
    fn default() -> Self {
        Self {
            min_parallax_deg: 0.5,
            max_reprojection_error: 4.0,
            min_points: 10,
            min_front_ratio: 0.9,
            max_ambiguity: 0.7,
            triangulation: TriangulationConfig {
                max_iterations: 5,
                ..TriangulationConfig::default()
            },
        }
    }
}

impl RecoverPoseConfig {
    fn validate(&self) -> Result<()> {
        let bad = |field, value: f64, reason| {
            Err(GeometryError::InvalidConfig {
                field,
                value: value.to_string(),
                reason,
            })
        };
        if !(self.min_parallax_deg >= 0.0 && self.min_parallax_deg < 90.0) {
            return bad(
                "min_parallax_deg",
                self.min_parallax_deg,
                "must be in [0, 90)",
            );
        }
        if self.max_reprojection_error.is_nan() || self.max_reprojection_error <= 0.0 {
            return bad(
                "max_reprojection_error",
                self.max_reprojection_error,
                "must be > 0",
            );
        }
        if !(self.min_front_ratio >= 0.0 && self.min_front_ratio <= 1.0) {
            return bad("min_front_ratio", self.min_front_ratio, "must be in [0, 1]");
        }
        if !(self.max_ambiguity > 0.0 && self.max_ambiguity <= 1.0) {
            return bad("max_ambiguity", self.max_ambiguity, "must be in (0, 1]");
        }
        Ok(())
    }
}

/// Relative pose of camera 2 with respect to camera 1 and the points seen in front of both.
#[derive(Debug, Clone, PartialEq)]
pub struct TwoViewPose {
    /// Rotation `R` of `X₂ = R X₁ + t`.
    pub rotation: UnitQuaternion<f64>,
    /// Unit translation `t` of `X₂ = R X₁ + t` (the scale is unobservable).
    pub translation: Vector3<f64>,
    /// Correspondences triangulated in front of both cameras with enough parallax and a small
    /// reprojection error, ascending.
    pub inliers_in_front: Vec<usize>,
    /// Their points in the camera-1 frame, in the units of `|t| = 1`.
    pub points: Vec<Point3<f64>>,
    /// Median parallax of the returned points, degrees (an initialisation-quality cue).
    pub median_parallax_deg: f64,
}

impl TwoViewPose {
    /// World-to-camera pose of camera 2 when camera 1 defines the world frame.
    pub fn camera2(&self) -> WorldToCamera {
        WorldToCamera::from_rotation_translation(self.rotation, self.translation)
    }
}

/// The four factorisations `(R, t)` of `E ≃ [t]× R` with `|t| = 1`: `(R₁, t), (R₁, −t),
/// (R₂, t), (R₂, −t)`. Only one places the scene in front of both cameras.
pub fn decompose_essential(e: &Matrix3<f64>) -> Result<[(Matrix3<f64>, Vector3<f64>); 4]> {
    if !e.iter().all(|v| v.is_finite()) {
        return Err(GeometryError::NonFinite("essential matrix"));
    }
    let svd = e.svd(true, true);
    let (Some(mut u), Some(mut vt)) = (svd.u, svd.v_t) else {
        return Err(GeometryError::Degenerate(
            "essential matrix: SVD failed".into(),
        ));
    };
    if svd.singular_values[1].is_nan() || svd.singular_values[1] <= 0.0 {
        return Err(GeometryError::Degenerate(
            "essential matrix has rank < 2".into(),
        ));
    }
    // E's sign is arbitrary, so U and V can be made proper rotations independently.
    if u.determinant() < 0.0 {
        u = -u;
    }
    if vt.determinant() < 0.0 {
        vt = -vt;
    }
    let w = Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    let r1 = u * w * vt;
    let r2 = u * w.transpose() * vt;
    let t = u.column(2).into_owned();
    Ok([(r1, t), (r1, -t), (r2, t), (r2, -t)])
}

/// Two-view triangulation by the midpoint of the common perpendicular, in camera-1
/// coordinates, with the depths along both rays; `None` for (nearly) parallel rays.
fn midpoint(
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    x1: &Vector3<f64>,
    x2: &Vector3<f64>,
) -> Option<(Point3<f64>, f64, f64)> {
    let c = -r.tr_mul(t);
    let b = r.tr_mul(x2);
    let (aa, bb, ab) = (x1.dot(x1), b.dot(&b), x1.dot(&b));
    let det = aa * bb - ab * ab;
    if det.is_nan() || det <= 1e-14 * aa * bb {
        return None;
    }
    let (ac, bc) = (x1.dot(&c), b.dot(&c));
    let l1 = (bb * ac - ab * bc) / det;
    let l2 = (ab * ac - aa * bc) / det;
    Some((Point3::from(0.5 * (l1 * x1 + c + l2 * b)), l1, l2))
}

/// Picks the factorisation of `e` that puts the most inliers in front of both cameras (with
/// parallax above [`RecoverPoseConfig::min_parallax_deg`]), then triangulates and refines
/// those inliers. Fails when too few points vote or the vote is ambiguous.
pub fn recover_pose(
    e: &Matrix3<f64>,
    x1: &[Point2<f64>],
    x2: &[Point2<f64>],
    camera: &PinholeCamera,
    inliers: &[usize],
    config: &RecoverPoseConfig,
) -> Result<TwoViewPose> {
    config.validate()?;
    check_correspondences(x1, x2, 0)?;
    if let Some(&bad) = inliers.iter().find(|&&i| i >= x1.len()) {
        return Err(GeometryError::InvalidConfig {
            field: "inliers",
            value: bad.to_string(),
            reason: "index out of range of the correspondences",
        });
    }
    let required = config.min_points.max(1);
    if inliers.len() < required {
        return Err(GeometryError::TooFewPoints {
            required,
            found: inliers.len(),
        });
    }
    let mut rays = Vec::with_capacity(inliers.len());
    for &i in inliers {
        match (camera.unproject(&x1[i]), camera.unproject(&x2[i])) {
            (Some(a), Some(b)) => rays.push((i, a, b)),
            _ => {
                return Err(GeometryError::Degenerate(
                    "pixel cannot be undistorted".into(),
                ));
            }
        }
    }
    let candidates = decompose_essential(e)?;
    let cos_min = config.min_parallax_deg.to_radians().cos();
    // Per factorisation: (points in front of both cameras, points with enough parallax); only
    // the latter can vote, since the depth sign of a low-parallax point is noise.
    let votes = candidates.map(|(r, t)| {
        rays.iter()
            .fold((0usize, 0usize), |(front, usable), (_, a, b)| {
                let d2 = r.tr_mul(b);
                if a.dot(&d2) / (a.norm() * d2.norm()) >= cos_min {
                    return (front, usable);
                }
                let ok = midpoint(&r, &t, a, b).is_some_and(|(_, l1, l2)| l1 > 0.0 && l2 > 0.0);
                (front + usize::from(ok), usable + 1)
            })
    });
    let best = (0..4).max_by_key(|&k| votes[k].0).unwrap_or(0);
    let runner_up = (0..4)
        .filter(|&k| k != best)
        .map(|k| votes[k].0)
        .max()
        .unwrap_or(0);
    let (front, usable) = votes[best];
    debug!(?votes, "cheirality votes (in front, with parallax)");
    if front < required {
        return Err(GeometryError::Degenerate(format!(
            "only {front} of {} inliers in front of both cameras with parallax ≥ {}°",
            inliers.len(),
            config.min_parallax_deg
        )));
    }
    if (front as f64) < config.min_front_ratio * usable as f64 {
        return Err(GeometryError::Degenerate(format!(
            "only {front} of {usable} inliers with parallax are in front of both cameras \
             (wrong or ambiguous essential matrix, e.g. a planar scene)"
        )));
    }
    if runner_up as f64 > config.max_ambiguity * front as f64 {
        return Err(GeometryError::Degenerate(format!(
            "ambiguous cheirality: {front} vs {runner_up} votes"
        )));
    }
    let (r, t) = candidates[best];
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let poses = [
        WorldToCamera::identity(),
        WorldToCamera::from_rotation_translation(rotation, t),
    ];
    let c2 = -r.tr_mul(&t);
    let max_err2 = config.max_reprojection_error.powi(2);
    let mut inliers_in_front = Vec::with_capacity(rays.len());
    let mut points = Vec::with_capacity(rays.len());
    let mut parallaxes = Vec::with_capacity(rays.len());
    for (i, a, b) in &rays {
        let Some((start, l1, l2)) = midpoint(&r, &t, a, b) else {
            continue;
        };
        if !(l1 > 0.0 && l2 > 0.0) {
            continue;
        }
        let pixels = [x1[*i], x2[*i]];
        let Ok(refined) = refine_point(&start, &poses, &pixels, camera, &config.triangulation)
        else {
            continue;
        };
        let p = refined.point;
        let in_view = |pose: &WorldToCamera, px: &Point2<f64>| {
            let pc = pose.transform_point(&p);
            pc.z > 0.0
                && camera
                    .project(&pc)
                    .is_some_and(|uv| (uv - px).norm_squared() <= max_err2)
        };
        if !(in_view(&poses[0], &x1[*i]) && in_view(&poses[1], &x2[*i])) {
            continue;
        }
        let (ray1, ray2) = (p.coords, p.coords - c2);
        let cos = ray1.dot(&ray2) / (ray1.norm() * ray2.norm());
        if cos.is_nan() || cos >= cos_min {
            continue;
        }
        inliers_in_front.push(*i);
        points.push(p);
        parallaxes.push(cos.clamp(-1.0, 1.0).acos().to_degrees());
    }
    if inliers_in_front.len() < required {
        return Err(GeometryError::Degenerate(format!(
            "only {} triangulated points pass the depth, parallax and reprojection checks",
            inliers_in_front.len()
        )));
    }
    parallaxes.sort_by(f64::total_cmp);
    let median_parallax_deg = parallaxes[parallaxes.len() / 2];
    debug!(
        points = points.len(),
        inliers = inliers.len(),
        median_parallax_deg,
        "two-view pose recovered"
    );
    Ok(TwoViewPose {
        rotation,
        translation: t,
        inliers_in_front,
        points,
        median_parallax_deg,
    })
}

/// Parameters of [`estimate_relative_pose`].
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct RelativePoseConfig {
    /// Robust essential-matrix estimation.
    pub essential: EssentialConfig,
    /// Choice of the factorisation and triangulation.
    pub pose: RecoverPoseConfig,
}

/// Output of [`estimate_relative_pose`].
#[derive(Debug, Clone, PartialEq)]
pub struct RelativePose {
    /// The essential matrix and its inliers.
    pub essential: EssentialResult,
    /// Pose and triangulated points.
    pub pose: TwoViewPose,
}

/// [`estimate_essential`] followed by [`recover_pose`] on its inliers.
pub fn estimate_relative_pose(
    x1: &[Point2<f64>],
    x2: &[Point2<f64>],
    camera: &PinholeCamera,
    config: &RelativePoseConfig,
) -> Result<RelativePose> {
    let essential = estimate_essential(x1, x2, camera, &config.essential)?;
    let pose = recover_pose(
        &essential.e,
        x1,
        x2,
        camera,
        &essential.inliers,
        &config.pose,
    )?;
    Ok(RelativePose { essential, pose })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pose::{skew, so3_exp};

    #[test]
    fn one_factorisation_is_the_truth() {
        let r = so3_exp(&Vector3::new(0.05, -0.15, 0.1))
            .to_rotation_matrix()
            .into_inner();
        let t = Vector3::new(0.8, 0.1, -0.3).normalize();
        for sign in [1.0, -1.0] {
            let e = sign * skew(&t) * r * 3.0;
            let cands = decompose_essential(&e).unwrap();
            let hits = cands
                .iter()
                .filter(|(rc, tc)| (rc - r).norm() < 1e-12 && (tc - t).norm() < 1e-12)
                .count();
            assert_eq!(hits, 1);
            for (rc, tc) in &cands {
                assert!((rc.determinant() - 1.0).abs() < 1e-12);
                let ec = skew(tc) * rc;
                let en = e / e.norm();
                let ec = ec / ec.norm();
                assert!((ec - en).norm() < 1e-12 || (ec + en).norm() < 1e-12);
            }
        }
        assert!(decompose_essential(&Matrix3::zeros()).is_err());
        assert!(decompose_essential(&Matrix3::from_element(f64::NAN)).is_err());
    }

    #[test]
    fn midpoint_is_exact_for_intersecting_rays() {
        let r = so3_exp(&Vector3::new(0.0, 0.2, 0.0))
            .to_rotation_matrix()
            .into_inner();
        let t = Vector3::new(-1.0, 0.0, 0.1);
        let p = Vector3::new(0.4, -0.3, 7.0);
        let q = r * p + t;
        let (m, l1, l2) = midpoint(&r, &t, &(p / p.z), &(q / q.z)).unwrap();
        assert!((m.coords - p).norm() < 1e-12);
        assert!((l1 - p.z).abs() < 1e-12 && (l2 - q.z).abs() < 1e-12);
        let a = Vector3::new(0.1, 0.0, 1.0);
        assert!(midpoint(&Matrix3::identity(), &Vector3::x(), &a, &a).is_none());
    }
}
