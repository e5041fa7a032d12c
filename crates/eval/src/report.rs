//! The whole evaluation of one estimate against ground truth: association, alignment, APE and
//! RPE (translation and rotation), as `evo_ape` / `evo_rpe` would report them.

use jointloc_geometry::Sim3;
use jointloc_geometry::trajectory::Trajectory;
use serde::{Deserialize, Serialize};

use crate::align::{AlignMode, align_estimate};
use crate::error::Result;
use crate::metrics::{PoseRelation, RpeConfig, ape, rpe, rpe_pairs};
use crate::stats::Statistics;
use crate::sync::{AssociationConfig, associate};

/// Settings of [`evaluate`]; the defaults are evo's.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct EvalConfig {
    /// Timestamp association.
    pub association: AssociationConfig,
    /// Alignment of the estimate to the reference.
    pub align: AlignMode,
    /// Fit the alignment on the first poses only (evo's `--n_to_align`); `None` = all.
    pub n_to_align: Option<usize>,
    /// RPE pair selection.
    pub rpe: RpeConfig,
}

/// One error metric: the per-pose (or per-pair) errors and their statistics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MetricResult {
    /// What is measured.
    pub relation: PoseRelation,
    /// Unit of the errors ("m", "deg", ...).
    pub unit: String,
    /// evo's statistics of `errors`.
    pub stats: Statistics,
    /// The errors, in pose (APE) or pair (RPE) order.
    pub errors: Vec<f64>,
    /// Reference timestamp of each error (for RPE the second pose of the pair).
    pub timestamps: Vec<f64>,
}

impl MetricResult {
    fn new(relation: PoseRelation, errors: Vec<f64>, timestamps: Vec<f64>) -> Result<Self> {
        Ok(Self {
            relation,
            unit: relation.unit().to_string(),
            stats: Statistics::from_errors(&errors)?,
            errors,
            timestamps,
        })
    }
}

/// The applied alignment, `aligned = s R p + t`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AlignmentInfo {
    /// Alignment mode used.
    pub mode: AlignMode,
    /// Scale `s` (1 unless Sim(3) or scale-only).
    pub scale: f64,
    /// Rotation `R` as `[qx, qy, qz, qw]`.
    pub rotation_xyzw: [f64; 4],
    /// Translation `t`.
    pub translation: [f64; 3],
}

/// Everything [`evaluate`] computes. The associated trajectories are kept for plotting but not
/// serialised.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    /// Settings used.
    pub config: EvalConfig,
    /// Poses in the reference file.
    pub reference_poses: usize,
    /// Poses in the estimate file.
    pub estimate_poses: usize,
    /// Associated pose pairs (the APE count).
    pub associated_poses: usize,
    /// The alignment applied to the estimate, if any.
    pub alignment: Option<AlignmentInfo>,
    /// APE, translation part (m).
    pub ape_translation: MetricResult,
    /// APE, rotation angle (deg).
    pub ape_rotation: MetricResult,
    /// RPE, translation part (m).
    pub rpe_translation: MetricResult,
    /// RPE, rotation angle (deg).
    pub rpe_rotation: MetricResult,
    /// Associated reference poses.
    #[serde(skip)]
    pub reference: Trajectory,
    /// Associated estimate poses after alignment.
    #[serde(skip)]
    pub aligned_estimate: Trajectory,
}

/// Associates, aligns, and computes APE and RPE (translation and rotation angle).
pub fn evaluate(
    reference: &Trajectory,
    estimate: &Trajectory,
    config: &EvalConfig,
) -> Result<EvalReport> {
    let associated = associate(reference, estimate, &config.association)?;
    let aligned = align_estimate(
        &associated.reference,
        &associated.estimate,
        config.align,
        config.n_to_align,
    )?;
    let reference_sync = associated.reference;
    let est = aligned.estimate;

    let stamps = reference_sync.timestamps.clone();
    let ape_translation = MetricResult::new(
        PoseRelation::TranslationPart,
        ape(&reference_sync, &est, PoseRelation::TranslationPart)?,
        stamps.clone(),
    )?;
    let ape_rotation = MetricResult::new(
        PoseRelation::RotationAngleDeg,
        ape(&reference_sync, &est, PoseRelation::RotationAngleDeg)?,
        stamps,
    )?;

    let pair_source = if config.rpe.pairs_from_reference {
        &reference_sync
    } else {
        &est
    };
    let pairs = rpe_pairs(&pair_source.poses, &config.rpe)?;
    let pair_stamps: Vec<f64> = pairs
        .iter()
        .map(|&(_, j)| reference_sync.timestamps[j])
        .collect();
    let rpe_translation = MetricResult::new(
        PoseRelation::TranslationPart,
        rpe(&reference_sync, &est, &pairs, PoseRelation::TranslationPart)?,
        pair_stamps.clone(),
    )?;
    let rpe_rotation = MetricResult::new(
        PoseRelation::RotationAngleDeg,
        rpe(
            &reference_sync,
            &est,
            &pairs,
            PoseRelation::RotationAngleDeg,
        )?,
        pair_stamps,
    )?;

    Ok(EvalReport {
        config: *config,
        reference_poses: reference.len(),
        estimate_poses: estimate.len(),
        associated_poses: reference_sync.len(),
        alignment: aligned.transform.map(|t| alignment_info(config.align, &t)),
        ape_translation,
        ape_rotation,
        rpe_translation,
        rpe_rotation,
        reference: reference_sync,
        aligned_estimate: est,
    })
}

fn alignment_info(mode: AlignMode, t: &Sim3) -> AlignmentInfo {
    let q = t.rotation.quaternion();
    AlignmentInfo {
        mode,
        scale: t.scale,
        rotation_xyzw: [q.i, q.j, q.k, q.w],
        translation: [t.translation.x, t.translation.y, t.translation.z],
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use jointloc_geometry::CameraToWorld;
    use nalgebra::{UnitQuaternion, Vector3};

    #[test]
    fn perfect_estimate_up_to_similarity_has_zero_error_after_sim3() {
        let n = 60;
        let reference = Trajectory::new(
            (0..n).map(|i| i as f64 * 0.1).collect(),
            (0..n)
                .map(|i| {
                    let a = i as f64 * 0.1;
                    CameraToWorld::from_rotation_translation(
                        UnitQuaternion::from_euler_angles(0.0, 0.2 * a.sin(), a),
                        Vector3::new(10.0 * a.cos(), 10.0 * a.sin(), a),
                    )
                })
                .collect(),
        )
        .unwrap();
        let g = Sim3::new(
            0.25,
            UnitQuaternion::from_euler_angles(0.5, 0.1, -2.0),
            Vector3::new(3.0, 1.0, -7.0),
        );
        let estimate = Trajectory::new(
            reference.timestamps.iter().map(|t| t + 0.002).collect(),
            reference
                .poses
                .iter()
                .map(|p| g.transform_pose(p))
                .collect(),
        )
        .unwrap();
        let config = EvalConfig {
            align: AlignMode::Sim3,
            ..Default::default()
        };
        let report = evaluate(&reference, &estimate, &config).unwrap();
        assert_eq!(report.associated_poses, n);
        assert!(report.ape_translation.stats.max < 1e-9);
        assert!(report.ape_rotation.stats.max < 1e-6);
        assert!(report.rpe_translation.stats.max < 1e-9);
        assert!((report.alignment.unwrap().scale - 4.0).abs() < 1e-9);
        assert_eq!(report.rpe_translation.errors.len(), n - 1);
        let unaligned = evaluate(&reference, &estimate, &EvalConfig::default()).unwrap();
        assert!(unaligned.ape_translation.stats.rmse > 1.0);
        let json = serde_json::to_string(&report).unwrap();
        assert!(json.contains("\"rmse\""));
    }
}
