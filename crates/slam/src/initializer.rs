//! Monocular initialisation (ORB-SLAM2's `Initializer`, paper §III-C): from matches between a
//! reference frame and the current frame, estimate a homography and an essential matrix in
//! parallel, choose between them by ORB-SLAM's score ratio `R_H = S_H / (S_H + S_F)` (planar or
//! low-parallax scenes favour H, general scenes E), recover the motion, triangulate, and fix the
//! scale — new here — from the altimeter: the height of the first camera above the terrain
//! directly below it, measured in the reconstruction, is set to the altimeter reading. Without
//! an altitude the median depth is set to 1, as ORB-SLAM2 does.
//!
//! Also new: the altimeter referees the motion. Over near-planar ground a downward camera's
//! two-view geometry has a twin solution (translation and plane normal swapped: the camera
//! dives towards a tilted plane instead of gliding over a level one), which the essential
//! matrix cannot tell apart and the homography only by a narrow vote. The twin changes the
//! height above the terrain by the whole baseline; the altimeter says by how much it really
//! changed. A motion whose height ratio `h₂ / h₁` disagrees with the altimeter's is rejected,
//! and when that rejects the preferred model the other one is tried.

use jointloc_geometry::homography::{HomographyConfig, decompose_homography, estimate_homography};
use jointloc_geometry::triangulation::{point_quality, triangulate_linear};
use jointloc_geometry::two_view::{
    EssentialConfig, RecoverPoseConfig, estimate_essential, recover_pose,
};
use jointloc_geometry::{PinholeCamera, WorldToCamera};
use nalgebra::{Matrix3, Point2, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::error::{Result, SlamError};

/// Parameters of [`initialize`]; defaults follow ORB-SLAM2.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct InitializerConfig {
    /// Robust homography estimation (3 px symmetric transfer threshold).
    pub homography: HomographyConfig,
    /// Robust essential-matrix estimation.
    pub essential: EssentialConfig,
    /// Cheirality vote and triangulation of the essential-matrix path.
    pub recover_pose: RecoverPoseConfig,
    /// Choose the homography when `R_H` exceeds this (ORB-SLAM2: 0.40).
    pub homography_ratio: f64,
    /// Fewest triangulated points for a valid initialisation (ORB-SLAM2: 50).
    pub min_points: usize,
    /// Minimum median parallax of the triangulated points, degrees (ORB-SLAM2: 1.0; here
    /// 2.5). Over near-planar ground the planar twin changes the height ratio by about the
    /// parallax in radians, so at 1° (0.2 m of baseline at 10 m) the altimeter's referee
    /// cannot tell the twin from the true motion: on a fresh 60 m crater flight the SLAM took
    /// the twin at 1°, lost tracking after 13 s and never recovered (Sim(3) APE 1.22 m); at
    /// 2.5° it tracked the whole flight (0.040 m). `docs/vo.md` §"Initialisation parallax".
    pub min_parallax_deg: f64,
    /// Largest reprojection error of a triangulated point in either view, pixels
    /// (ORB-SLAM2: √4 at level 0).
    pub max_reprojection_error: f64,
    /// The second-best homography motion must triangulate fewer than this fraction of the
    /// best one's points (ORB-SLAM2: 0.75).
    pub max_ambiguity: f64,
    /// Largest disagreement between the reconstruction's height ratio `h₂ / h₁` (second camera
    /// over first, each above the terrain below it) and the altimeter's; 0 turns the check
    /// off. The altimeter's 0.1 m noise at 10 m makes its ratio good to about 1.5 %; the
    /// planar twin of a 1 m baseline at 10 m is off by 10 %.
    pub max_height_ratio_error: f64,
}

impl Default for InitializerConfig {
    fn default() -> Self {
        Self {
            homography: HomographyConfig::default(),
            essential: EssentialConfig::default(),
            recover_pose: RecoverPoseConfig {
                min_points: 50,
                ..RecoverPoseConfig::default()
            },
            homography_ratio: 0.40,
            min_points: 50,
            min_parallax_deg: 2.5,
            max_reprojection_error: 2.0,
            max_ambiguity: 0.75,
            max_height_ratio_error: 0.08,
        }
    }
}

impl InitializerConfig {
    /// Checks the ranges of the model choice and the checks (the estimators check their own).
    pub fn validate(&self) -> Result<()> {
        let invalid = |field: &'static str, value: f64, reason: &'static str| {
            Err(SlamError::InvalidConfig {
                field,
                value: value.to_string(),
                reason,
            })
        };
        if !(0.0..=1.0).contains(&self.homography_ratio) {
            return invalid(
                "homography_ratio",
                self.homography_ratio,
                "must be in [0, 1]",
            );
        }
        if !(self.max_ambiguity > 0.0 && self.max_ambiguity <= 1.0) {
            return invalid("max_ambiguity", self.max_ambiguity, "must be in (0, 1]");
        }
        if !(self.max_height_ratio_error.is_finite() && self.max_height_ratio_error >= 0.0) {
            return invalid(
                "max_height_ratio_error",
                self.max_height_ratio_error,
                "must be finite and ≥ 0 (0 turns the check off)",
            );
        }
        Ok(())
    }
}

/// Which two-view model the initialisation used.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TwoViewModel {
    Homography,
    Essential,
}

/// Where the metric scale came from.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ScaleSource {
    /// Height above the terrain below the first camera set to this altimeter reading, metres.
    Altimeter(f64),
    /// Median depth set to 1 (arbitrary units).
    MedianDepth,
}

/// A successful initialisation. The SLAM frame is the first camera's frame (scaled).
#[derive(Debug, Clone, PartialEq)]
pub struct Initialization {
    pub model: TwoViewModel,
    /// `R_H` of the model selection.
    pub homography_ratio: f64,
    /// Pose of the second camera; the first is the identity.
    pub pose2: WorldToCamera,
    /// `(match index, point in the SLAM frame)`, ascending by index.
    pub points: Vec<(usize, Vector3<f64>)>,
    pub median_parallax_deg: f64,
    pub scale: ScaleSource,
    /// Height of the first camera above the terrain below it, in SLAM units after scaling.
    pub height: f64,
}

/// Altimeter readings (height above the terrain directly below) at the two frames.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Altitudes {
    pub reference: Option<f64>,
    pub current: Option<f64>,
}

impl Altitudes {
    /// `current / reference`, when both readings are usable.
    fn ratio(&self) -> Option<f64> {
        let valid = |a: Option<f64>| a.filter(|a| a.is_finite() && *a > 0.0);
        Some(valid(self.current)? / valid(self.reference)?)
    }
}

fn fail(reason: impl Into<String>) -> SlamError {
    SlamError::InitializationFailed {
        reason: reason.into(),
    }
}

/// Initialises from matched pixels `x1[i] ↔ x2[i]` (undistorted) of the reference and current
/// frames; the reference altitude sets the scale, both together check the motion.
pub fn initialize(
    x1: &[Point2<f64>],
    x2: &[Point2<f64>],
    camera: &PinholeCamera,
    altitudes: Altitudes,
    config: &InitializerConfig,
) -> Result<Initialization> {
    if x1.len() != x2.len() {
        return Err(fail(format!("{} vs {} points", x1.len(), x2.len())));
    }
    if x1.len() < config.min_points {
        return Err(fail(format!(
            "{} matches, {} required",
            x1.len(),
            config.min_points
        )));
    }
    let h = estimate_homography(x1, x2, &config.homography).ok();
    let e = estimate_essential(x1, x2, camera, &config.essential).ok();
    let k = camera.k();
    let s_h = h.as_ref().map_or(0.0, |h| score_homography(&h.h, x1, x2));
    let s_f = e.as_ref().map_or(0.0, |e| {
        let k_inv = k.try_inverse().unwrap_or_else(Matrix3::identity);
        score_fundamental(&(k_inv.transpose() * e.e * k_inv), x1, x2)
    });
    if s_h + s_f <= 0.0 {
        return Err(fail("neither a homography nor an essential matrix fits"));
    }
    let ratio = s_h / (s_h + s_f);
    let referee = HeightReferee::new(altitudes, config);
    let from_h = || {
        let h = h
            .as_ref()
            .ok_or_else(|| fail("homography chosen but not estimated"))?;
        from_homography(&h.h, &h.inliers, x1, x2, camera, config, &referee)
            .map(|(pose, points, parallax)| (TwoViewModel::Homography, pose, points, parallax))
    };
    let from_e = || {
        let e = e
            .as_ref()
            .ok_or_else(|| fail("essential matrix chosen but not estimated"))?;
        let rp = recover_pose(&e.e, x1, x2, camera, &e.inliers, &config.recover_pose)?;
        let points: Vec<(usize, Vector3<f64>)> = rp
            .inliers_in_front
            .iter()
            .zip(&rp.points)
            .map(|(&i, p)| (i, p.coords))
            .collect();
        referee.check(&rp.camera2(), &points)?;
        Ok((
            TwoViewModel::Essential,
            rp.camera2(),
            points,
            rp.median_parallax_deg,
        ))
    };
    let prefer_h = ratio > config.homography_ratio;
    let preferred = if prefer_h { from_h() } else { from_e() };
    // Only the altimeter's veto hands over to the other model: any other failure keeps
    // ORB-SLAM2's behaviour (wait for a better frame).
    let (model, pose2, points, parallax) = match preferred {
        Err(Rejected::Height(reason)) => {
            let other = if prefer_h { from_e() } else { from_h() };
            other.map_err(|e| {
                fail(format!(
                    "{reason}; the other model: {}",
                    e.into_error()
                        .to_string()
                        .trim_start_matches("initialisation failed: ")
                ))
            })?
        }
        other => other.map_err(Rejected::into_error)?,
    };
    if points.len() < config.min_points {
        return Err(fail(format!(
            "{} points triangulated, {} required",
            points.len(),
            config.min_points
        )));
    }
    if parallax < config.min_parallax_deg {
        return Err(SlamError::ParallaxTooLow {
            median_deg: parallax,
            required_deg: config.min_parallax_deg,
        });
    }
    let pts: Vec<Vector3<f64>> = points.iter().map(|(_, p)| *p).collect();
    let height = height_below_origin(&pts).ok_or_else(|| fail("no ground plane"))?;
    let (factor, scale) = match altitudes.reference {
        Some(a) if a.is_finite() && a > 0.0 => (a / height, ScaleSource::Altimeter(a)),
        _ => {
            let mut depths: Vec<f64> = pts.iter().map(|p| p.z).collect();
            depths.sort_by(f64::total_cmp);
            (1.0 / depths[depths.len() / 2], ScaleSource::MedianDepth)
        }
    };
    let scaled =
        WorldToCamera::from_rotation_translation(pose2.rotation(), pose2.translation() * factor);
    Ok(Initialization {
        model,
        homography_ratio: ratio,
        pose2: scaled,
        points: points.into_iter().map(|(i, p)| (i, p * factor)).collect(),
        median_parallax_deg: parallax,
        scale,
        height: height * factor,
    })
}

/// ORB-SLAM's model score: Σ over both transfer directions of `Γ − d²/σ²` for errors under the
/// χ² threshold (σ = 1 px, Γ = 5.991).
fn score_homography(h: &Matrix3<f64>, x1: &[Point2<f64>], x2: &[Point2<f64>]) -> f64 {
    let Some(h_inv) = h.try_inverse() else {
        return 0.0;
    };
    let transfer = |m: &Matrix3<f64>, p: &Point2<f64>| {
        let v = m * p.to_homogeneous();
        Point2::new(v.x / v.z, v.y / v.z)
    };
    x1.iter()
        .zip(x2)
        .map(|(a, b)| {
            let d1 = (transfer(h, a) - b).norm_squared();
            let d2 = (transfer(&h_inv, b) - a).norm_squared();
            gain(d1, CHI2_2DOF) + gain(d2, CHI2_2DOF)
        })
        .sum()
}

/// Point-to-epipolar-line distances in both images, scored like [`score_homography`] with the
/// 1-DoF threshold (3.841) but the same Γ, as ORB-SLAM does to compare the models fairly.
fn score_fundamental(f: &Matrix3<f64>, x1: &[Point2<f64>], x2: &[Point2<f64>]) -> f64 {
    x1.iter()
        .zip(x2)
        .map(|(a, b)| {
            let (ha, hb) = (a.to_homogeneous(), b.to_homogeneous());
            let l2 = f * ha;
            let l1 = f.transpose() * hb;
            let num = hb.dot(&l2).powi(2);
            let d2 = num / (l2.x * l2.x + l2.y * l2.y);
            let d1 = num / (l1.x * l1.x + l1.y * l1.y);
            let g = |d: f64| {
                if d.is_finite() && d < CHI2_1DOF {
                    CHI2_2DOF - d
                } else {
                    0.0
                }
            };
            g(d1) + g(d2)
        })
        .sum()
}

const CHI2_1DOF: f64 = 3.841;
const CHI2_2DOF: f64 = 5.991;

fn gain(d2: f64, threshold: f64) -> f64 {
    if d2.is_finite() && d2 < threshold {
        CHI2_2DOF - d2
    } else {
        0.0
    }
}

type Reconstruction = (WorldToCamera, Vec<(usize, Vector3<f64>)>, f64);

/// Why a model gave no motion: the altimeter vetoed it, or anything else.
enum Rejected {
    Height(String),
    Other(SlamError),
}

impl<E: Into<SlamError>> From<E> for Rejected {
    fn from(e: E) -> Self {
        Self::Other(e.into())
    }
}

impl Rejected {
    fn into_error(self) -> SlamError {
        match self {
            Self::Height(reason) => fail(reason),
            Self::Other(e) => e,
        }
    }
}

/// Compares a motion's height ratio with the altimeter's (inactive without both readings or
/// with `max_height_ratio_error = 0`).
struct HeightReferee {
    expected: Option<f64>,
    tolerance: f64,
}

impl HeightReferee {
    fn new(altitudes: Altitudes, config: &InitializerConfig) -> Self {
        let tolerance = config.max_height_ratio_error;
        Self {
            expected: altitudes.ratio().filter(|_| tolerance > 0.0),
            tolerance,
        }
    }

    /// Ok when the reconstruction's `h₂ / h₁` is within the tolerance of the altimeter's.
    fn check(
        &self,
        pose2: &WorldToCamera,
        points: &[(usize, Vector3<f64>)],
    ) -> std::result::Result<(), Rejected> {
        let Some(expected) = self.expected else {
            return Ok(());
        };
        // Along each camera's optical axis, not the fitted plane's normal: the camera looks
        // down, and a twin's plane can be a wall beside the path, whose distance the dive
        // does not change.
        let in1: Vec<Vector3<f64>> = points.iter().map(|(_, p)| *p).collect();
        let in2: Vec<Vector3<f64>> = in1
            .iter()
            .map(|p| pose2.transform_point(&(*p).into()).coords)
            .collect();
        let ratio = height_along(&in1, &Vector3::z())
            .zip(height_along(&in2, &Vector3::z()))
            .map(|(h1, h2)| h2 / h1);
        tracing::debug!(
            ?ratio,
            expected,
            points = points.len(),
            "initialisation height check"
        );
        match ratio {
            Some(r) if (r - expected).abs() <= self.tolerance => Ok(()),
            Some(r) => Err(Rejected::Height(format!(
                "height ratio {r:.3} against the altimeter's {expected:.3}"
            ))),
            None => Err(Rejected::Height(
                "no ground plane to check the height on".into(),
            )),
        }
    }
}

/// Tries the motions of the homography's decomposition and keeps the one that triangulates
/// the most inliers in front of both cameras, if it clearly wins among those the altimeter
/// accepts.
fn from_homography(
    h: &Matrix3<f64>,
    inliers: &[usize],
    x1: &[Point2<f64>],
    x2: &[Point2<f64>],
    camera: &PinholeCamera,
    config: &InitializerConfig,
    referee: &HeightReferee,
) -> std::result::Result<Reconstruction, Rejected> {
    let motions = decompose_homography(h, &camera.k())?;
    let mut results: Vec<Reconstruction> = motions
        .iter()
        .map(|m| {
            let pose = WorldToCamera::from_rotation_translation(m.rotation, m.translation);
            triangulate_all(&pose, inliers, x1, x2, camera, config)
        })
        .collect();
    results.sort_by_key(|r| std::cmp::Reverse(r.1.len()));
    let mut veto = None;
    results.retain(|r| match referee.check(&r.0, &r.1) {
        Ok(()) => true,
        Err(e) => {
            veto.get_or_insert(e);
            false
        }
    });
    let Some(best) = results.first() else {
        return Err(veto.unwrap_or_else(|| fail("no homography motion").into()));
    };
    let second = results.get(1).map_or(0, |r| r.1.len());
    if second as f64 > config.max_ambiguity * best.1.len() as f64 {
        return Err(fail(format!(
            "ambiguous homography decomposition: {} vs {} points",
            best.1.len(),
            second
        ))
        .into());
    }
    // Half the RANSAC inliers: those use a 3 px transfer threshold, triangulation a tighter
    // reprojection bound, so a correct motion keeps well over half of them.
    if 2 * best.1.len() < inliers.len() {
        return Err(fail(format!(
            "homography motion explains only {} of {} inliers",
            best.1.len(),
            inliers.len()
        ))
        .into());
    }
    Ok(results.swap_remove(0))
}

fn triangulate_all(
    pose2: &WorldToCamera,
    inliers: &[usize],
    x1: &[Point2<f64>],
    x2: &[Point2<f64>],
    camera: &PinholeCamera,
    config: &InitializerConfig,
) -> Reconstruction {
    let poses = [WorldToCamera::identity(), *pose2];
    let mut points = Vec::new();
    let mut parallaxes = Vec::new();
    for &i in inliers {
        let pixels = [x1[i], x2[i]];
        let Ok(p) = triangulate_linear(&poses, &pixels, camera) else {
            continue;
        };
        let Ok(q) = point_quality(&p, &poses, &pixels, camera) else {
            continue;
        };
        if q.in_front() && q.max_reprojection_error() <= config.max_reprojection_error {
            points.push((i, p.coords));
            parallaxes.push(q.parallax_deg);
        }
    }
    parallaxes.sort_by(f64::total_cmp);
    let median = parallaxes.get(parallaxes.len() / 2).copied().unwrap_or(0.0);
    (*pose2, points, median)
}

/// Height of the origin (the first camera) above the terrain directly below it: fit a plane to
/// the points (least squares after trimming outliers) for the vertical direction, then take the
/// median distance along it of the points closest to the vertical through the camera.
fn height_below_origin(points: &[Vector3<f64>]) -> Option<f64> {
    if points.len() < 3 {
        return None;
    }
    let mut keep: Vec<Vector3<f64>> = points.to_vec();
    let mut normal = Vector3::z();
    for _ in 0..3 {
        let n = keep.len() as f64;
        let c = keep.iter().sum::<Vector3<f64>>() / n;
        let cov = keep
            .iter()
            .map(|p| (p - c) * (p - c).transpose())
            .sum::<Matrix3<f64>>();
        let eig = cov.symmetric_eigen();
        let (imin, _) = eig
            .eigenvalues
            .iter()
            .enumerate()
            .min_by(|a, b| a.1.total_cmp(b.1))?;
        normal = eig.eigenvectors.column(imin).into_owned();
        if normal.dot(&c) < 0.0 {
            normal = -normal;
        }
        let mut res: Vec<f64> = points.iter().map(|p| (p - c).dot(&normal).abs()).collect();
        res.sort_by(f64::total_cmp);
        let mad = res[res.len() / 2].max(1e-12);
        keep = points
            .iter()
            .filter(|p| (*p - c).dot(&normal).abs() <= 3.0 * 1.4826 * mad)
            .copied()
            .collect();
        if keep.len() < 3 {
            return None;
        }
    }
    height_along(points, &normal)
}

/// Distance from the origin to the terrain along the unit `axis`: a local linear fit of the
/// points' height along it over the perpendicular plane, around the axis — the altimeter
/// measures the terrain right below, which relief can put far from the plane's mean.
fn height_along(points: &[Vector3<f64>], axis: &Vector3<f64>) -> Option<f64> {
    let e1 = axis
        .cross(&Vector3::x())
        .try_normalize(1e-9)
        .unwrap_or_else(|| {
            axis.cross(&Vector3::y())
                .try_normalize(1e-9)
                .unwrap_or(Vector3::z())
        });
    let e2 = axis.cross(&e1);
    let mut local: Vec<(f64, f64, f64)> = points
        .iter()
        .map(|p| (p.dot(&e1), p.dot(&e2), p.dot(axis)))
        .filter(|&(_, _, h)| h > 0.0)
        .collect();
    local.sort_by(|a, b| (a.0.hypot(a.1)).total_cmp(&b.0.hypot(b.1)));
    let take = (local.len() / 10).clamp(12, 60).min(local.len());
    let near = &local[..take];
    let mut ata = Matrix3::zeros();
    let mut atb = Vector3::zeros();
    for &(u, v, h) in near {
        let row = Vector3::new(1.0, u, v);
        ata += row * row.transpose();
        atb += row * h;
    }
    let fit = ata.cholesky().map(|c| c.solve(&atb)[0]);
    let mut heights: Vec<f64> = near.iter().map(|x| x.2).collect();
    heights.sort_by(f64::total_cmp);
    let median = heights.get(heights.len() / 2).copied()?;
    // Fall back to the median when the fit is degenerate or far outside the local heights.
    Some(match fit {
        Some(a) if a.is_finite() && a > 0.5 * median && a < 2.0 * median => a,
        _ => median,
    })
}

/// Rotation between two unit quaternions, degrees (used by tests and diagnostics).
pub fn rotation_error_deg(a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>) -> f64 {
    a.angle_to(b).to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Point3, Translation3};

    /// Ground points on a level plane 10 m below camera 1 (a 12 × 12 grid over the image),
    /// seen again after 1.5 m sideways and 5 cm down with a small rotation.
    fn level_pair() -> (Vec<Point2<f64>>, Vec<Point2<f64>>, WorldToCamera, f64) {
        let camera = PinholeCamera::ideal(500.0, 500, 500);
        let r = UnitQuaternion::from_euler_angles(0.01, -0.005, 0.02);
        let c2 = Vector3::new(1.5, 0.2, 0.05);
        let pose2 = WorldToCamera(Isometry3::from_parts(Translation3::from(-(r * c2)), r));
        let (mut x1, mut x2) = (Vec::new(), Vec::new());
        for i in 0..12 {
            for j in 0..12 {
                let p = Point3::new(-4.0 + 0.7 * i as f64, -4.0 + 0.7 * j as f64, 10.0);
                if let (Some(a), Some(b)) = (camera.project(&p), camera.project(&(pose2.0 * p))) {
                    x1.push(a);
                    x2.push(b);
                }
            }
        }
        (x1, x2, pose2, 10.0 - c2.z)
    }

    /// Every motion of the exact homography that triangulates the scene: the altimeter (10 m,
    /// then 9.95 m) accepts the true one and rejects the others, its planar twin among them.
    #[test]
    fn the_height_check_accepts_the_true_motion_and_rejects_its_planar_twin() {
        let camera = PinholeCamera::ideal(500.0, 500, 500);
        let (x1, x2, truth, altitude2) = level_pair();
        let config = InitializerConfig::default();
        let rt = truth.rotation().to_rotation_matrix().into_inner();
        let h = camera.k()
            * (rt + truth.translation() / 10.0 * Vector3::z().transpose())
            * camera.k().try_inverse().unwrap();
        let referee = HeightReferee::new(
            Altitudes {
                reference: Some(10.0),
                current: Some(altitude2),
            },
            &config,
        );
        let all: Vec<usize> = (0..x1.len()).collect();
        let (mut true_ones, mut twins) = (0, 0);
        for m in decompose_homography(&h, &camera.k()).unwrap() {
            let pose = WorldToCamera::from_rotation_translation(m.rotation, m.translation);
            let (pose, points, _) = triangulate_all(&pose, &all, &x1, &x2, &camera, &config);
            if points.len() < x1.len() / 2 {
                continue;
            }
            let is_true = pose.rotation().angle_to(&truth.rotation()) < 1e-6;
            let accepted = referee.check(&pose, &points).is_ok();
            assert_eq!(
                accepted,
                is_true,
                "motion {m:?} with {} points",
                points.len()
            );
            if is_true {
                true_ones += 1;
            } else {
                twins += 1;
            }
        }
        assert_eq!((true_ones, twins), (1, 1));
    }

    #[test]
    fn out_of_range_settings_are_rejected_with_their_field() {
        for (config, field) in [
            (
                InitializerConfig {
                    max_height_ratio_error: -0.1,
                    ..InitializerConfig::default()
                },
                "max_height_ratio_error",
            ),
            (
                InitializerConfig {
                    max_height_ratio_error: f64::NAN,
                    ..InitializerConfig::default()
                },
                "max_height_ratio_error",
            ),
            (
                InitializerConfig {
                    homography_ratio: 1.5,
                    ..InitializerConfig::default()
                },
                "homography_ratio",
            ),
            (
                InitializerConfig {
                    max_ambiguity: 0.0,
                    ..InitializerConfig::default()
                },
                "max_ambiguity",
            ),
        ] {
            let e = config.validate().unwrap_err();
            assert!(
                matches!(e, SlamError::InvalidConfig { field: f, .. } if f == field),
                "{e}"
            );
        }
        assert!(InitializerConfig::default().validate().is_ok());
    }

    /// Without both readings, or with the tolerance at 0, the check accepts anything.
    #[test]
    fn the_height_check_is_off_without_two_readings_or_tolerance() {
        let (x1, x2, truth, _) = level_pair();
        let camera = PinholeCamera::ideal(500.0, 500, 500);
        let config = InitializerConfig::default();
        let all: Vec<usize> = (0..x1.len()).collect();
        // A wrong motion: the translation along the optical axis.
        let wrong = WorldToCamera::from_rotation_translation(
            truth.rotation(),
            Vector3::new(0.0, 0.0, -truth.translation().norm()),
        );
        let (_, points, _) = triangulate_all(&wrong, &all, &x1, &x2, &camera, &config);
        let both = Altitudes {
            reference: Some(10.0),
            current: Some(10.0),
        };
        let off = InitializerConfig {
            max_height_ratio_error: 0.0,
            ..config.clone()
        };
        assert!(
            HeightReferee::new(both, &off)
                .check(&wrong, &points)
                .is_ok()
        );
        let one = Altitudes {
            reference: Some(10.0),
            current: None,
        };
        assert!(
            HeightReferee::new(one, &config)
                .check(&wrong, &points)
                .is_ok()
        );
    }
}
