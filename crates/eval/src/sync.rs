//! Timestamp association, step for step as evo's `sync.associate_trajectories`
//! (nearest-time method), so that the associated pose sets are identical.

use jointloc_geometry::trajectory::Trajectory;
use serde::{Deserialize, Serialize};

use crate::error::{EvalError, Result};

/// Settings of [`associate`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct AssociationConfig {
    /// Largest accepted |t_ref − (t_est + offset)| in seconds (evo's `--t_max_diff`).
    pub max_diff: f64,
    /// Offset added to the estimate's timestamps before matching (evo's `--t_offset`).
    pub offset: f64,
}

impl Default for AssociationConfig {
    fn default() -> Self {
        Self {
            max_diff: 0.01,
            offset: 0.0,
        }
    }
}

/// Two trajectories reduced to their associated poses (same length, pairwise matched).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Associated {
    /// The matched reference poses, with the reference's own timestamps.
    pub reference: Trajectory,
    /// The matched estimate poses, with the estimate's own timestamps.
    pub estimate: Trajectory,
    /// Index of each match in the original reference.
    pub reference_indices: Vec<usize>,
    /// Index of each match in the original estimate.
    pub estimate_indices: Vec<usize>,
}

/// evo's `matching_time_indices`: for each stamp of `stamps_1`, the nearest stamp of
/// `stamps_2 + offset_2` within `max_diff` (ties go to the earlier stamp). A stamp of the second
/// list may be matched more than once, as in evo.
pub fn matching_time_indices(
    stamps_1: &[f64],
    stamps_2: &[f64],
    max_diff: f64,
    offset_2: f64,
) -> (Vec<usize>, Vec<usize>) {
    let mut indices_1 = Vec::new();
    let mut indices_2 = Vec::new();
    if stamps_2.is_empty() {
        return (indices_1, indices_2);
    }
    let stamps_2: Vec<f64> = stamps_2.iter().map(|t| t + offset_2).collect();
    let sorted = stamps_2.windows(2).all(|w| w[1] - w[0] >= 0.0);
    if !sorted {
        // evo's linear fallback: global nearest, first one on ties.
        for (i1, &t1) in stamps_1.iter().enumerate() {
            let mut best = 0;
            for (i2, &t2) in stamps_2.iter().enumerate() {
                if (t2 - t1).abs() < (stamps_2[best] - t1).abs() {
                    best = i2;
                }
            }
            if (stamps_2[best] - t1).abs() <= max_diff {
                indices_1.push(i1);
                indices_2.push(best);
            }
        }
        return (indices_1, indices_2);
    }
    let last = stamps_2.len() - 1;
    for (i1, &t1) in stamps_1.iter().enumerate() {
        if t1 < stamps_2[0] - max_diff || t1 > stamps_2[last] + max_diff {
            continue;
        }
        // numpy.searchsorted(side="right"): first index whose stamp is > t1, clamped.
        let upper = stamps_2.partition_point(|&t| t <= t1).min(last);
        let diff_ub = stamps_2[upper] - t1;
        let diff_lb = if upper > 0 {
            t1 - stamps_2[upper - 1]
        } else {
            f64::INFINITY
        };
        let best = if diff_ub <= max_diff && diff_ub < diff_lb {
            upper
        } else if diff_lb <= max_diff && diff_lb <= diff_ub {
            upper - 1
        } else {
            continue;
        };
        indices_1.push(i1);
        indices_2.push(best);
    }
    (indices_1, indices_2)
}

/// evo's `associate_trajectories` (nearest time): matching starts from the trajectory with fewer
/// poses (the estimate on equal counts), so none of its poses is lost to a coarser partner.
pub fn associate(
    reference: &Trajectory,
    estimate: &Trajectory,
    config: &AssociationConfig,
) -> Result<Associated> {
    if !config.max_diff.is_finite() || config.max_diff < 0.0 {
        return Err(EvalError::InvalidConfig {
            field: "max_diff",
            value: config.max_diff.to_string(),
            reason: "must be finite and >= 0",
        });
    }
    if !config.offset.is_finite() {
        return Err(EvalError::InvalidConfig {
            field: "offset",
            value: config.offset.to_string(),
            reason: "must be finite",
        });
    }
    let estimate_longer = estimate.len() > reference.len();
    let (reference_indices, estimate_indices) = if estimate_longer {
        matching_time_indices(
            &reference.timestamps,
            &estimate.timestamps,
            config.max_diff,
            config.offset,
        )
    } else {
        let (est, reference) = matching_time_indices(
            &estimate.timestamps,
            &reference.timestamps,
            config.max_diff,
            -config.offset,
        );
        (reference, est)
    };
    if reference_indices.is_empty() {
        return Err(EvalError::NoMatchingTimestamps {
            max_diff: config.max_diff,
            offset: config.offset,
        });
    }
    tracing::debug!(
        matches = reference_indices.len(),
        reference = reference.len(),
        estimate = estimate.len(),
        "associated trajectories"
    );
    Ok(Associated {
        reference: reference.select(&reference_indices),
        estimate: estimate.select(&estimate_indices),
        reference_indices,
        estimate_indices,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use jointloc_geometry::CameraToWorld;

    fn traj(stamps: &[f64]) -> Trajectory {
        Trajectory::new(
            stamps.to_vec(),
            vec![CameraToWorld::identity(); stamps.len()],
        )
        .unwrap()
    }

    #[test]
    fn nearest_within_tolerance_with_evo_tie_rules() {
        // Binary-exact stamps so that the tie at 1.0 is a true tie.
        let (a, b) = matching_time_indices(
            &[0.0, 0.5, 1.0, 1.75, 5.0],
            &[0.0078125, 0.5, 0.75, 1.25, 1.5],
            0.3,
            0.0,
        );
        // 1.0 is equidistant from 0.75 and 1.25: the earlier one wins (diff_lb <= diff_ub);
        // 1.75 lies past the last stamp but within max_diff of it.
        assert_eq!(a, vec![0, 1, 2, 3]);
        assert_eq!(b, vec![0, 1, 2, 4]);
        // Offset moves the second list; beyond the ends nothing matches.
        let (a, b) = matching_time_indices(&[1.0, 2.0, 3.0], &[0.0, 1.0], 0.01, 1.0);
        assert_eq!((a, b), (vec![0, 1], vec![0, 1]));
    }

    #[test]
    fn unsorted_second_list_uses_linear_search() {
        let (a, b) = matching_time_indices(&[0.0, 1.0, 2.0], &[2.001, 0.002, 1.5], 0.01, 0.0);
        assert_eq!((a, b), (vec![0, 2], vec![1, 0]));
    }

    #[test]
    fn association_starts_from_the_shorter_trajectory() {
        // Reference at 10 Hz, estimate at 5 Hz shifted by 0.3 s: every estimate pose finds a
        // partner once the offset is given, none without.
        let reference = traj(&(0..50).map(|i| i as f64 * 0.1).collect::<Vec<_>>());
        let estimate = traj(&(0..20).map(|i| 0.3 + i as f64 * 0.2).collect::<Vec<_>>());
        let none = associate(&reference, &estimate, &AssociationConfig::default());
        assert!(none.is_ok(), "matches at equal stamps exist");
        let shifted = associate(
            &reference,
            &estimate,
            &AssociationConfig {
                max_diff: 0.01,
                offset: -0.25,
            },
        );
        assert!(matches!(
            shifted,
            Err(EvalError::NoMatchingTimestamps { .. })
        ));
        let ok = associate(
            &reference,
            &estimate,
            &AssociationConfig {
                max_diff: 0.01,
                offset: -0.3,
            },
        )
        .unwrap();
        assert_eq!(ok.estimate_indices, (0..20).collect::<Vec<_>>());
        assert_eq!(
            ok.reference_indices,
            (0..20).map(|i| 2 * i).collect::<Vec<_>>()
        );
        assert_eq!(ok.reference.len(), ok.estimate.len());
    }
}
