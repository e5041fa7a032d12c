//! Monocular initialisation (ORB-SLAM2's `Initializer`, paper §III-C): from matches between a
//! reference frame and the current frame, estimate a homography and an essential matrix in
//! parallel, choose between them by ORB-SLAM's score ratio `R_H = S_H / (S_H + S_F)` (planar or
//! low-parallax scenes favour H, general scenes E), recover the motion, triangulate, and fix the
//! scale — new here — from the altimeter: the height of the first camera above the terrain
//! directly below it, measured in the reconstruction, is set to the altimeter reading. Without
//! an altitude the median depth is set to 1, as ORB-SLAM2 does.

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
    /// Minimum median parallax of the triangulated points, degrees (ORB-SLAM2: 1.0).
    pub min_parallax_deg: f64,
    /// Largest reprojection error of a triangulated point in either view, pixels
    /// (ORB-SLAM2: √4 at level 0).
    pub max_reprojection_error: f64,
    /// The second-best homography motion must triangulate fewer than this fraction of the
    /// best one's points (ORB-SLAM2: 0.75).
    pub max_ambiguity: f64,
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
            min_parallax_deg: 1.0,
            max_reprojection_error: 2.0,
            max_ambiguity: 0.75,
        }
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

fn fail(reason: impl Into<String>) -> SlamError {
    SlamError::InitializationFailed {
        reason: reason.into(),
    }
}

/// Initialises from matched pixels `x1[i] ↔ x2[i]` (undistorted) of the reference and current
/// frames; `altitude` is the altimeter reading at the reference frame.
pub fn initialize(
    x1: &[Point2<f64>],
    x2: &[Point2<f64>],
    camera: &PinholeCamera,
    altitude: Option<f64>,
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
    let (model, pose2, points, parallax) = if ratio > config.homography_ratio {
        let h = h.ok_or_else(|| fail("homography chosen but not estimated"))?;
        let (pose, points, parallax) = from_homography(&h.h, &h.inliers, x1, x2, camera, config)?;
        (TwoViewModel::Homography, pose, points, parallax)
    } else {
        let e = e.ok_or_else(|| fail("essential matrix chosen but not estimated"))?;
        let rp = recover_pose(&e.e, x1, x2, camera, &e.inliers, &config.recover_pose)?;
        let points = rp
            .inliers_in_front
            .iter()
            .zip(&rp.points)
            .map(|(&i, p)| (i, p.coords))
            .collect();
        (
            TwoViewModel::Essential,
            rp.camera2(),
            points,
            rp.median_parallax_deg,
        )
    };
    if points.len() < config.min_points {
        return Err(fail(format!(
            "{} points triangulated, {} required",
            points.len(),
            config.min_points
        )));
    }
    if parallax < config.min_parallax_deg {
        return Err(fail(format!(
            "median parallax {parallax:.2}° below {:.2}°",
            config.min_parallax_deg
        )));
    }
    let pts: Vec<Vector3<f64>> = points.iter().map(|(_, p)| *p).collect();
    let height = height_below_origin(&pts).ok_or_else(|| fail("no ground plane"))?;
    let (factor, scale) = match altitude {
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

/// Tries the motions of the homography's decomposition and keeps the one that triangulates
/// the most inliers in front of both cameras, if it clearly wins.
fn from_homography(
    h: &Matrix3<f64>,
    inliers: &[usize],
    x1: &[Point2<f64>],
    x2: &[Point2<f64>],
    camera: &PinholeCamera,
    config: &InitializerConfig,
) -> Result<Reconstruction> {
    let motions = decompose_homography(h, &camera.k())?;
    let mut results: Vec<Reconstruction> = motions
        .iter()
        .map(|m| {
            let pose = WorldToCamera::from_rotation_translation(m.rotation, m.translation);
            triangulate_all(&pose, inliers, x1, x2, camera, config)
        })
        .collect();
    results.sort_by_key(|r| std::cmp::Reverse(r.1.len()));
    let best = results
        .first()
        .ok_or_else(|| fail("no homography motion"))?;
    let second = results.get(1).map_or(0, |r| r.1.len());
    if second as f64 > config.max_ambiguity * best.1.len() as f64 {
        return Err(fail(format!(
            "ambiguous homography decomposition: {} vs {} points",
            best.1.len(),
            second
        )));
    }
    // Half the RANSAC inliers: those use a 3 px transfer threshold, triangulation a tighter
    // reprojection bound, so a correct motion keeps well over half of them.
    if 2 * best.1.len() < inliers.len() {
        return Err(fail(format!(
            "homography motion explains only {} of {} inliers",
            best.1.len(),
            inliers.len()
        )));
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
    // Local linear fit of the height over the plane around the vertical through the camera:
    // the altimeter measures the terrain right below, which relief can put far from the
    // plane's mean.
    let e1 = normal
        .cross(&Vector3::x())
        .try_normalize(1e-9)
        .unwrap_or_else(|| {
            normal
                .cross(&Vector3::y())
                .try_normalize(1e-9)
                .unwrap_or(Vector3::z())
        });
    let e2 = normal.cross(&e1);
    let mut local: Vec<(f64, f64, f64)> = points
        .iter()
        .map(|p| (p.dot(&e1), p.dot(&e2), p.dot(&normal)))
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
