//! Absolute and relative pose errors with evo's definitions (`metrics.APE`, `metrics.RPE`).
//!
//! APE of pose i: `E = P_i⁻¹ Q_i` (estimate P, reference Q). RPE of the pair (i, j):
//! `E = (Q_i⁻¹ Q_j)⁻¹ (P_i⁻¹ P_j)`. A pose relation turns `E` into one number.

use jointloc_geometry::CameraToWorld;
use jointloc_geometry::trajectory::Trajectory;
use nalgebra::{Isometry3, Matrix3, Matrix4, UnitQuaternion};
use serde::{Deserialize, Serialize};

use crate::error::{EvalError, Result};

/// Which part of the error pose is measured (evo's `PoseRelation`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PoseRelation {
    /// ‖translation of E‖ in metres (for APE simply the distance between positions).
    TranslationPart,
    /// Rotation angle of E in degrees.
    RotationAngleDeg,
    /// Rotation angle of E in radians.
    RotationAngleRad,
    /// ‖R_E − I‖_F (dimensionless).
    RotationPart,
    /// ‖E − I‖_F of the 4×4 matrix (dimensionless).
    FullTransformation,
}

impl PoseRelation {
    /// The unit label evo uses for this relation.
    pub fn unit(&self) -> &'static str {
        match self {
            PoseRelation::TranslationPart => "m",
            PoseRelation::RotationAngleDeg => "deg",
            PoseRelation::RotationAngleRad => "rad",
            PoseRelation::RotationPart | PoseRelation::FullTransformation => "none",
        }
    }

    /// The number this relation extracts from an error pose.
    pub fn apply(&self, e: &Isometry3<f64>) -> f64 {
        match self {
            PoseRelation::TranslationPart => e.translation.vector.norm(),
            PoseRelation::RotationAngleDeg => rotation_angle(&e.rotation).to_degrees(),
            PoseRelation::RotationAngleRad => rotation_angle(&e.rotation),
            PoseRelation::RotationPart => {
                (e.rotation.to_rotation_matrix().into_inner() - Matrix3::identity()).norm()
            }
            PoseRelation::FullTransformation => (e.to_homogeneous() - Matrix4::identity()).norm(),
        }
    }
}

/// Rotation angle in `[0, π]`, accurate for small angles (unlike `acos(w)`).
fn rotation_angle(q: &UnitQuaternion<f64>) -> f64 {
    2.0 * q.imag().norm().atan2(q.w.abs())
}

/// Per-pose absolute errors of an associated, already aligned pair of trajectories.
pub fn ape(
    reference: &Trajectory,
    estimate: &Trajectory,
    relation: PoseRelation,
) -> Result<Vec<f64>> {
    check_same_length(reference, estimate)?;
    Ok(reference
        .poses
        .iter()
        .zip(&estimate.poses)
        .map(|(q, p)| match relation {
            PoseRelation::TranslationPart => (p.translation() - q.translation()).norm(),
            _ => relation.apply(&(p.0.inverse() * q.0)),
        })
        .collect())
}

/// Unit of the RPE step (evo's `--delta_unit f|m`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DeltaUnit {
    /// Index distance.
    #[default]
    Frames,
    /// Travelled path length in metres.
    Meters,
}

impl DeltaUnit {
    /// Unit label as evo prints it.
    pub fn label(&self) -> &'static str {
        match self {
            DeltaUnit::Frames => "frames",
            DeltaUnit::Meters => "m",
        }
    }
}

/// How RPE pose pairs are chosen (evo's `RPE` constructor arguments).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RpeConfig {
    /// Step between the two poses of a pair, in `unit` (an integer for frames).
    pub delta: f64,
    /// Unit of `delta`.
    pub unit: DeltaUnit,
    /// Use every pose as a pair start instead of consecutive, non-overlapping pairs.
    pub all_pairs: bool,
    /// Relative tolerance on the path length of all-pairs metre pairs (evo's `--delta_tol`).
    pub rel_delta_tol: f64,
    /// Choose pairs on the reference instead of on the (aligned) estimate.
    pub pairs_from_reference: bool,
}

impl Default for RpeConfig {
    fn default() -> Self {
        Self {
            delta: 1.0,
            unit: DeltaUnit::Frames,
            all_pairs: false,
            rel_delta_tol: 0.1,
            pairs_from_reference: false,
        }
    }
}

/// Index pairs `(i, j)` for the RPE, as evo's `id_pairs_from_delta`.
pub fn rpe_pairs(poses: &[CameraToWorld], config: &RpeConfig) -> Result<Vec<(usize, usize)>> {
    if !config.delta.is_finite() || config.delta <= 0.0 {
        return Err(EvalError::InvalidConfig {
            field: "rpe delta",
            value: config.delta.to_string(),
            reason: "must be positive",
        });
    }
    let pairs = match config.unit {
        DeltaUnit::Frames => {
            if config.delta.fract() != 0.0 {
                return Err(EvalError::InvalidConfig {
                    field: "rpe delta",
                    value: config.delta.to_string(),
                    reason: "must be an integer for delta unit frames",
                });
            }
            pairs_by_index(poses.len(), config.delta as usize, config.all_pairs)
        }
        DeltaUnit::Meters => pairs_by_path(
            poses,
            config.delta,
            config.delta * config.rel_delta_tol,
            config.all_pairs,
        ),
    };
    if pairs.is_empty() {
        return Err(EvalError::NoRpePairs {
            delta: config.delta,
            unit: config.unit.label(),
        });
    }
    Ok(pairs)
}

/// evo's `filter_pairs_by_index`.
fn pairs_by_index(n: usize, delta: usize, all_pairs: bool) -> Vec<(usize, usize)> {
    if all_pairs {
        (0..n)
            .filter(|i| i + delta < n)
            .map(|i| (i, i + delta))
            .collect()
    } else {
        let ids: Vec<usize> = (0..n).step_by(delta).collect();
        ids.windows(2).map(|w| (w[0], w[1])).collect()
    }
}

/// evo's `filter_pairs_by_path`: consecutive mode cuts the path every time the travelled
/// distance since the last cut reaches `delta`; all-pairs mode pairs each pose with the later
/// pose whose path distance is closest to `delta`, if within `tol`.
fn pairs_by_path(
    poses: &[CameraToWorld],
    delta: f64,
    tol: f64,
    all_pairs: bool,
) -> Vec<(usize, usize)> {
    if poses.is_empty() {
        return Vec::new();
    }
    let step = |i: usize| (poses[i].translation() - poses[i - 1].translation()).norm();
    if all_pairs {
        let mut acc = vec![0.0; poses.len()];
        for i in 1..poses.len() {
            acc[i] = acc[i - 1] + step(i);
        }
        let mut pairs = Vec::new();
        for i in 0..poses.len().saturating_sub(1) {
            let mut best = i + 1;
            let mut best_diff = f64::INFINITY;
            for (j, d) in acc.iter().enumerate().skip(i + 1) {
                let diff = ((d - acc[i]) - delta).abs();
                if diff < best_diff {
                    best = j;
                    best_diff = diff;
                }
            }
            if best_diff <= tol {
                pairs.push((i, best));
            }
        }
        pairs
    } else {
        let mut ids = vec![0];
        let mut path = 0.0;
        for i in 1..poses.len() {
            path += step(i);
            if path >= delta {
                ids.push(i);
                path = 0.0;
            }
        }
        ids.windows(2).map(|w| (w[0], w[1])).collect()
    }
}

/// Relative errors for the given pairs.
pub fn rpe(
    reference: &Trajectory,
    estimate: &Trajectory,
    pairs: &[(usize, usize)],
    relation: PoseRelation,
) -> Result<Vec<f64>> {
    check_same_length(reference, estimate)?;
    if let Some(&(i, j)) = pairs.iter().find(|(i, j)| *i.max(j) >= reference.len()) {
        return Err(EvalError::InvalidConfig {
            field: "rpe pair",
            value: format!("({i}, {j})"),
            reason: "index beyond the trajectory",
        });
    }
    Ok(pairs
        .iter()
        .map(|&(i, j)| {
            let q_rel = reference.poses[i].relative_to(&reference.poses[j]);
            let p_rel = estimate.poses[i].relative_to(&estimate.poses[j]);
            relation.apply(&(q_rel.inverse() * p_rel))
        })
        .collect())
}

fn check_same_length(reference: &Trajectory, estimate: &Trajectory) -> Result<()> {
    if reference.len() != estimate.len() {
        return Err(jointloc_geometry::GeometryError::LengthMismatch {
            what: "reference vs estimate poses",
            left: reference.len(),
            right: estimate.len(),
        }
        .into());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn line(xs: &[f64]) -> Vec<CameraToWorld> {
        xs.iter()
            .map(|&x| {
                CameraToWorld::from_rotation_translation(
                    UnitQuaternion::identity(),
                    Vector3::new(x, 0.0, 0.0),
                )
            })
            .collect()
    }

    #[test]
    fn frame_pairs_follow_evo() {
        assert_eq!(pairs_by_index(7, 3, false), vec![(0, 3), (3, 6)]);
        assert_eq!(pairs_by_index(5, 3, true), vec![(0, 3), (1, 4)]);
        assert_eq!(pairs_by_index(2, 3, false), vec![]);
        let cfg = RpeConfig {
            delta: 1.5,
            ..Default::default()
        };
        assert!(rpe_pairs(&line(&[0.0, 1.0]), &cfg).is_err());
    }

    #[test]
    fn metre_pairs_follow_evo() {
        let poses = line(&[0.0, 0.4, 0.8, 1.2, 1.6, 2.0, 2.4, 2.8]);
        // Path reaches >= 1 m at index 3 (1.2), then 1.2 m more at 6.
        assert_eq!(pairs_by_path(&poses, 1.0, 0.0, false), vec![(0, 3), (3, 6)]);
        // All pairs: the path distance closest to 1.0 is 0.8 (1.2 is a hair further in f64).
        let all = pairs_by_path(&poses, 1.0, 0.25, true);
        assert_eq!(all[0], (0, 2));
        assert_eq!(all.len(), 6);
        assert!(pairs_by_path(&poses, 1.0, 0.1, true).is_empty());
    }

    #[test]
    fn ape_and_rpe_relations() {
        let reference = Trajectory::new(vec![0.0, 1.0, 2.0], line(&[0.0, 1.0, 2.0])).unwrap();
        let rot = UnitQuaternion::from_euler_angles(0.0, 0.0, 0.1);
        let estimate = Trajectory::new(
            vec![0.0, 1.0, 2.0],
            reference
                .poses
                .iter()
                .map(|p| {
                    CameraToWorld::from_rotation_translation(
                        rot,
                        p.translation() + Vector3::new(0.0, 0.5, 0.0),
                    )
                })
                .collect(),
        )
        .unwrap();
        let t = ape(&reference, &estimate, PoseRelation::TranslationPart).unwrap();
        assert!(t.iter().all(|e| (e - 0.5).abs() < 1e-15));
        let r = ape(&reference, &estimate, PoseRelation::RotationAngleDeg).unwrap();
        assert!(r.iter().all(|e| (e - 0.1f64.to_degrees()).abs() < 1e-12));
        let rp = ape(&reference, &estimate, PoseRelation::RotationPart).unwrap();
        assert!((rp[0] - (2.0 * (2.0 - 2.0 * 0.1f64.cos())).sqrt()).abs() < 1e-12);
        // Relative motion of the estimate is 1 m along its rotated x axis: the error
        // translation is (cos 0.1 − 1, sin 0.1, 0).
        let pairs = [(0, 1), (1, 2)];
        let e = rpe(&reference, &estimate, &pairs, PoseRelation::TranslationPart).unwrap();
        let expected = ((0.1f64.cos() - 1.0).powi(2) + 0.1f64.sin().powi(2)).sqrt();
        assert!(e.iter().all(|v| (v - expected).abs() < 1e-12), "{e:?}");
        let e = rpe(
            &reference,
            &estimate,
            &pairs,
            PoseRelation::RotationAngleRad,
        )
        .unwrap();
        assert!(e.iter().all(|v| v.abs() < 1e-12));
        assert!(
            rpe(
                &reference,
                &estimate,
                &[(0, 3)],
                PoseRelation::TranslationPart
            )
            .is_err()
        );
    }
}
