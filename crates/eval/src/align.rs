//! Aligning an estimated trajectory to the reference before computing errors, as evo's
//! `-a` (SE(3)), `-as` (Sim(3)), `-s` (scale only) and `--align_origin` do.

use jointloc_geometry::trajectory::Trajectory;
use jointloc_geometry::umeyama;
use jointloc_geometry::{CameraToWorld, Sim3};
use serde::{Deserialize, Serialize};

use crate::error::{EvalError, Result};

/// How the estimate is brought into the reference frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AlignMode {
    /// Compare as is.
    #[default]
    None,
    /// Umeyama SE(3) on the positions (evo `-a`).
    Se3,
    /// Umeyama Sim(3) on the positions (evo `-a -s`), for monocular estimates.
    Sim3,
    /// Only the Umeyama scale, applied to the positions (evo `-s` without `-a`).
    Scale,
    /// Rigid transform making the first poses coincide (evo `--align_origin`).
    Origin,
}

/// The aligned estimate and the transform that was applied (`None` for [`AlignMode::None`]).
#[derive(Debug, Clone, PartialEq)]
pub struct AlignedEstimate {
    /// The estimate mapped into the reference frame.
    pub estimate: Trajectory,
    /// The applied transform, `aligned = transform · estimate`.
    pub transform: Option<Sim3>,
}

/// Aligns `estimate` to `reference` (already associated: same length, pose `i` ↔ pose `i`).
/// `n_to_align` restricts the Umeyama fit to the first poses, as evo's `--n_to_align`.
pub fn align_estimate(
    reference: &Trajectory,
    estimate: &Trajectory,
    mode: AlignMode,
    n_to_align: Option<usize>,
) -> Result<AlignedEstimate> {
    if reference.len() != estimate.len() {
        return Err(jointloc_geometry::GeometryError::LengthMismatch {
            what: "associated reference vs estimate",
            left: reference.len(),
            right: estimate.len(),
        }
        .into());
    }
    let transform = match mode {
        AlignMode::None => None,
        AlignMode::Se3 | AlignMode::Sim3 | AlignMode::Scale => {
            let n = match n_to_align {
                Some(0) => {
                    return Err(EvalError::InvalidConfig {
                        field: "n_to_align",
                        value: "0".into(),
                        reason: "must be at least 3",
                    });
                }
                Some(n) => n.min(estimate.len()),
                None => estimate.len(),
            };
            let src = &estimate.positions()[..n];
            let dst = &reference.positions()[..n];
            let fit = umeyama::align(src, dst, None, mode != AlignMode::Se3)?;
            tracing::debug!(
                ?mode,
                scale = fit.sim3.scale,
                rms = fit.rms,
                "Umeyama alignment"
            );
            Some(if mode == AlignMode::Scale {
                Sim3::new(fit.sim3.scale, Default::default(), Default::default())
            } else {
                fit.sim3
            })
        }
        AlignMode::Origin => {
            let to_ref = reference.poses[0].0 * estimate.poses[0].0.inverse();
            Some(Sim3::new(1.0, to_ref.rotation, to_ref.translation.vector))
        }
    };
    let estimate = match &transform {
        None => estimate.clone(),
        Some(t) => Trajectory {
            timestamps: estimate.timestamps.clone(),
            poses: estimate
                .poses
                .iter()
                .map(|p| t.transform_pose(p))
                .collect::<Vec<CameraToWorld>>(),
        },
    };
    Ok(AlignedEstimate {
        estimate,
        transform,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{UnitQuaternion, Vector3};

    fn helix(n: usize) -> Trajectory {
        let poses = (0..n)
            .map(|i| {
                let a = i as f64 * 0.2;
                CameraToWorld::from_rotation_translation(
                    UnitQuaternion::from_euler_angles(0.1 * a, 0.0, a),
                    Vector3::new(5.0 * a.cos(), 5.0 * a.sin(), 0.3 * a),
                )
            })
            .collect();
        Trajectory::new((0..n).map(|i| i as f64).collect(), poses).unwrap()
    }

    #[test]
    fn every_mode_undoes_the_matching_distortion() {
        let reference = helix(40);
        let truth = Sim3::new(
            2.5,
            UnitQuaternion::from_euler_angles(0.3, -0.2, 1.0),
            Vector3::new(1.0, -4.0, 2.0),
        );
        let moved = Trajectory {
            timestamps: reference.timestamps.clone(),
            poses: reference
                .poses
                .iter()
                .map(|p| truth.inverse().transform_pose(p))
                .collect(),
        };
        for mode in [AlignMode::Sim3, AlignMode::Origin] {
            let rigid_only = mode == AlignMode::Origin;
            let input = if rigid_only {
                // Origin alignment cannot undo a scale: use a rigid distortion.
                let rigid = Sim3::new(1.0, truth.rotation, truth.translation);
                Trajectory {
                    timestamps: reference.timestamps.clone(),
                    poses: reference
                        .poses
                        .iter()
                        .map(|p| rigid.inverse().transform_pose(p))
                        .collect(),
                }
            } else {
                moved.clone()
            };
            let aligned = align_estimate(&reference, &input, mode, None).unwrap();
            for (a, b) in aligned.estimate.poses.iter().zip(&reference.poses) {
                assert!(
                    (a.translation() - b.translation()).norm() < 1e-9,
                    "{mode:?}"
                );
                assert!((a.rotation_matrix() - b.rotation_matrix()).norm() < 1e-9);
            }
        }
        let se3 = align_estimate(&reference, &moved, AlignMode::Se3, None).unwrap();
        assert_eq!(se3.transform.unwrap().scale, 1.0);
        let scale = align_estimate(&reference, &moved, AlignMode::Scale, Some(10)).unwrap();
        assert!(scale.transform.unwrap().rotation.angle() == 0.0);
        let none = align_estimate(&reference, &moved, AlignMode::None, None).unwrap();
        assert!(none.transform.is_none());
        assert_eq!(none.estimate, moved);
    }
}
