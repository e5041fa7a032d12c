//! Umeyama's closed-form alignment of two point sets (SE(3) or Sim(3)), plain, weighted and
//! robust (iteratively re-weighted).
//!
//! With unit weights this is exactly evo's `geometry.umeyama_alignment`: means, the variance
//! `σ² = 1/n Σ‖x−μx‖²`, the covariance `1/n Σ (y−μy)(x−μx)ᵀ`, the same rank test and the same
//! reflection fix (`det U · det V < 0` flips the last singular direction). Trajectory metrics
//! are only comparable with published numbers when this step is identical.

use nalgebra::{DMatrix, Matrix3, Point3, Rotation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::error::{GeometryError, Result};
use crate::pose::Sim3;
use crate::robust::RobustKernel;

/// Result of an alignment: `dst ≈ sim3 · src`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Alignment {
    /// The transform mapping source points onto destination points (scale 1 for SE(3)).
    pub sim3: Sim3,
    /// Root mean square residual `‖sim3·src − dst‖`, weighted by the weights used.
    pub rms: f64,
}

/// Least-squares `dst ≈ s R src + t` (Umeyama 1991). `weights` (non-negative, not all zero)
/// scale each pair's influence; `None` means unit weights. Without `with_scale`, `s = 1`.
pub fn align(
    src: &[Point3<f64>],
    dst: &[Point3<f64>],
    weights: Option<&[f64]>,
    with_scale: bool,
) -> Result<Alignment> {
    if src.len() != dst.len() {
        return Err(GeometryError::LengthMismatch {
            what: "source vs destination points",
            left: src.len(),
            right: dst.len(),
        });
    }
    if let Some(w) = weights {
        if w.len() != src.len() {
            return Err(GeometryError::LengthMismatch {
                what: "points vs weights",
                left: src.len(),
                right: w.len(),
            });
        }
        if w.iter().any(|v| !v.is_finite() || *v < 0.0) {
            return Err(GeometryError::InvalidConfig {
                field: "weights",
                value: "negative or non-finite".into(),
                reason: "weights must be finite and >= 0",
            });
        }
    }
    if src.len() < 3 {
        return Err(GeometryError::TooFewPoints {
            required: 3,
            found: src.len(),
        });
    }
    if src
        .iter()
        .chain(dst)
        .any(|p| !p.coords.iter().all(|v| v.is_finite()))
    {
        return Err(GeometryError::NonFinite("alignment points"));
    }
    let weight = |i: usize| weights.map_or(1.0, |w| w[i]);
    let total: f64 = (0..src.len()).map(weight).sum();
    if total <= 0.0 {
        return Err(GeometryError::Degenerate(
            "all alignment weights are zero".into(),
        ));
    }

    let mean = |pts: &[Point3<f64>]| -> Vector3<f64> {
        pts.iter()
            .enumerate()
            .fold(Vector3::zeros(), |acc, (i, p)| acc + weight(i) * p.coords)
            / total
    };
    let mean_x = mean(src);
    let mean_y = mean(dst);
    let mut sigma_x = 0.0;
    let mut cov = Matrix3::zeros();
    for (i, (x, y)) in src.iter().zip(dst).enumerate() {
        let dx = x.coords - mean_x;
        let dy = y.coords - mean_y;
        sigma_x += weight(i) * dx.norm_squared();
        cov += weight(i) * dy * dx.transpose();
    }
    sigma_x /= total;
    cov /= total;

    // nalgebra's fixed-size 3×3 SVD goes through the eigenvectors of MᵀM, which squares the
    // condition number (errors ~1e-8 for thin point sets); the general Golub–Kahan SVD used for
    // dynamic matrices is accurate to machine precision, like LAPACK's in numpy.
    let svd = DMatrix::from_column_slice(3, 3, cov.as_slice()).svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Err(GeometryError::Degenerate(
            "SVD of the covariance failed".into(),
        ));
    };
    let u = Matrix3::from_column_slice(u.as_slice());
    let v_t = Matrix3::from_column_slice(v_t.as_slice());
    let d = Vector3::from_column_slice(svd.singular_values.as_slice());
    if d.iter().filter(|&&s| s > f64::EPSILON).count() < 2 {
        return Err(GeometryError::Degenerate(
            "covariance rank < 2 (points coincide or are collinear)".into(),
        ));
    }
    // Umeyama's S = diag(1, 1, det U · det V) on the smallest singular direction keeps R a
    // proper rotation. R = U S Vᵀ equals U' V'ᵀ where the smallest direction of U and V is
    // replaced by the cross product of the other two; that form does not depend on the accuracy
    // of the null vector when the points are coplanar (smallest singular value ≈ 0).
    let smallest = d.imin();
    let mut s_diag = Vector3::new(1.0, 1.0, 1.0);
    if u.determinant() * v_t.determinant() < 0.0 {
        s_diag[smallest] = -1.0;
    }
    let proper = |mut m: Matrix3<f64>| {
        let (a, b) = ((smallest + 1) % 3, (smallest + 2) % 3);
        let c = m.column(a).cross(&m.column(b));
        m.set_column(smallest, &c);
        m
    };
    let r = proper(u) * proper(v_t.transpose()).transpose();
    let scale = if with_scale {
        d.component_mul(&s_diag).sum() / sigma_x
    } else {
        1.0
    };
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let translation = mean_y - scale * (r * mean_x);
    let sim3 = Sim3::new(scale, rotation, translation);
    let sse: f64 = src
        .iter()
        .zip(dst)
        .enumerate()
        .map(|(i, (x, y))| weight(i) * (sim3.transform_point(x) - y).norm_squared())
        .sum();
    Ok(Alignment {
        sim3,
        rms: (sse / total).sqrt(),
    })
}

/// Settings of [`align_robust`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RobustAlignConfig {
    /// Kernel on the residual distance (same unit as the destination points). Cauchy keeps
    /// gross outliers from dragging the solution; Huber only bounds their pull.
    pub kernel: RobustKernel,
    /// Estimate the scale as well (Sim(3)) instead of SE(3).
    pub with_scale: bool,
    /// Maximum number of re-weighting rounds.
    pub max_iterations: usize,
    /// Stop when the largest weight change of a round is below this.
    pub weight_tolerance: f64,
}

impl Default for RobustAlignConfig {
    fn default() -> Self {
        Self {
            kernel: RobustKernel::Cauchy { c: 1.0 },
            with_scale: false,
            max_iterations: 50,
            weight_tolerance: 1e-8,
        }
    }
}

/// Result of [`align_robust`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RobustAlignment {
    /// The final weighted alignment.
    pub alignment: Alignment,
    /// The final weight of each pair (near 0 for rejected outliers).
    pub weights: Vec<f64>,
    /// Re-weighting rounds performed.
    pub iterations: usize,
}

/// Iteratively re-weighted Umeyama: start from the least-squares fit, weight each pair by the
/// kernel's `ρ'(‖residual‖²)`, re-fit, until the weights settle.
pub fn align_robust(
    src: &[Point3<f64>],
    dst: &[Point3<f64>],
    config: &RobustAlignConfig,
) -> Result<RobustAlignment> {
    if config.max_iterations == 0 {
        return Err(GeometryError::InvalidConfig {
            field: "max_iterations",
            value: "0".into(),
            reason: "at least one iteration is needed",
        });
    }
    let mut alignment = align(src, dst, None, config.with_scale)?;
    let mut weights = vec![1.0; src.len()];
    let mut iterations = 0;
    while iterations < config.max_iterations {
        iterations += 1;
        let mut change: f64 = 0.0;
        for (i, (x, y)) in src.iter().zip(dst).enumerate() {
            let s = (alignment.sim3.transform_point(x) - y).norm_squared();
            let w = config.kernel.weight(s);
            change = change.max((w - weights[i]).abs());
            weights[i] = w;
        }
        alignment = align(src, dst, Some(&weights), config.with_scale)?;
        tracing::trace!(
            iterations,
            change,
            rms = alignment.rms,
            "robust alignment round"
        );
        if change < config.weight_tolerance {
            break;
        }
    }
    Ok(RobustAlignment {
        alignment,
        weights,
        iterations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_sim3(rng: &mut ChaCha8Rng) -> Sim3 {
        let axis = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        Sim3::new(
            rng.random_range(0.2..5.0),
            UnitQuaternion::from_scaled_axis(axis.normalize() * rng.random_range(0.0..3.1)),
            Vector3::new(
                rng.random_range(-50.0..50.0),
                rng.random_range(-50.0..50.0),
                rng.random_range(-50.0..50.0),
            ),
        )
    }

    fn random_points(rng: &mut ChaCha8Rng, n: usize) -> Vec<Point3<f64>> {
        (0..n)
            .map(|_| {
                Point3::new(
                    rng.random_range(-10.0..10.0),
                    rng.random_range(-10.0..10.0),
                    rng.random_range(-3.0..3.0),
                )
            })
            .collect()
    }

    fn assert_close(a: &Sim3, b: &Sim3, tol: f64) {
        assert!(
            (a.scale - b.scale).abs() < tol,
            "{} vs {}",
            a.scale,
            b.scale
        );
        assert!((a.rotation_matrix() - b.rotation_matrix()).norm() < tol);
        assert!((a.translation - b.translation).norm() < tol * 10.0);
    }

    #[test]
    fn recovers_random_sim3_and_se3_exactly() {
        for seed in 0..10 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let truth = random_sim3(&mut rng);
            let src = random_points(&mut rng, 3 + seed as usize * 7);
            let dst: Vec<_> = src.iter().map(|p| truth.transform_point(p)).collect();
            let fit = align(&src, &dst, None, true).unwrap();
            assert_close(&fit.sim3, &truth, 1e-9);
            assert!(fit.rms < 1e-9);

            let rigid = Sim3::new(1.0, truth.rotation, truth.translation);
            let dst: Vec<_> = src.iter().map(|p| rigid.transform_point(p)).collect();
            let fit = align(&src, &dst, None, false).unwrap();
            assert_close(&fit.sim3, &rigid, 1e-9);
        }
    }

    #[test]
    fn planar_points_and_reflection_case_give_proper_rotation() {
        // Coplanar points: one singular value is zero and the SVD may return a reflection.
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for _ in 0..20 {
            let truth = random_sim3(&mut rng);
            let src: Vec<_> = (0..12)
                .map(|_| {
                    Point3::new(
                        rng.random_range(-5.0..5.0),
                        rng.random_range(-5.0..5.0),
                        0.0,
                    )
                })
                .collect();
            let dst: Vec<_> = src.iter().map(|p| truth.transform_point(p)).collect();
            let fit = align(&src, &dst, None, true).unwrap();
            assert!((fit.sim3.rotation_matrix().determinant() - 1.0).abs() < 1e-12);
            assert_close(&fit.sim3, &truth, 1e-9);
        }
        // Mirrored destination: no rotation fits, the result must still be a rotation.
        let src = random_points(&mut rng, 30);
        let dst: Vec<_> = src.iter().map(|p| Point3::new(p.x, p.y, -p.z)).collect();
        let fit = align(&src, &dst, None, false).unwrap();
        assert!((fit.sim3.rotation_matrix().determinant() - 1.0).abs() < 1e-12);
        assert!(fit.rms > 0.1);
    }

    #[test]
    fn zero_weights_ignore_outliers() {
        for seed in 0..5 {
            let mut rng = ChaCha8Rng::seed_from_u64(100 + seed);
            let truth = random_sim3(&mut rng);
            let src = random_points(&mut rng, 40);
            let mut dst: Vec<_> = src.iter().map(|p| truth.transform_point(p)).collect();
            let mut weights = vec![1.0; 40];
            for i in (0..40).step_by(5) {
                dst[i] += Vector3::new(100.0, -80.0, 30.0);
                weights[i] = 0.0;
            }
            let fit = align(&src, &dst, Some(&weights), true).unwrap();
            assert_close(&fit.sim3, &truth, 1e-9);
            let unweighted = align(&src, &dst, None, true).unwrap();
            assert!(unweighted.rms > 1.0);
        }
    }

    #[test]
    fn rejects_bad_input() {
        let p = vec![Point3::origin(); 3];
        assert!(matches!(
            align(&p[..2], &p[..2], None, false),
            Err(GeometryError::TooFewPoints { .. })
        ));
        assert!(matches!(
            align(&p, &p[..2], None, false),
            Err(GeometryError::LengthMismatch { .. })
        ));
        assert!(matches!(
            align(&p, &p, None, false),
            Err(GeometryError::Degenerate(_))
        ));
        let line: Vec<_> = (0..5).map(|i| Point3::new(i as f64, 0.0, 0.0)).collect();
        assert!(matches!(
            align(&line, &line, None, true),
            Err(GeometryError::Degenerate(_))
        ));
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let q = random_points(&mut rng, 4);
        assert!(align(&q, &q, Some(&[1.0, -1.0, 1.0, 1.0]), false).is_err());
        assert!(align(&q, &q, Some(&[0.0; 4]), false).is_err());
    }

    #[test]
    fn robust_variant_rejects_twenty_percent_gross_outliers() {
        for seed in 0..8 {
            let mut rng = ChaCha8Rng::seed_from_u64(200 + seed);
            let truth = random_sim3(&mut rng);
            let src = random_points(&mut rng, 100);
            let mut dst: Vec<_> = src
                .iter()
                .map(|p| {
                    let noise = Vector3::new(
                        rng.random_range(-0.01..0.01),
                        rng.random_range(-0.01..0.01),
                        rng.random_range(-0.01..0.01),
                    );
                    truth.transform_point(p) + noise
                })
                .collect();
            let outliers = rand::seq::index::sample(&mut rng, 100, 20).into_vec();
            for &i in &outliers {
                dst[i] += Vector3::new(
                    rng.random_range(-60.0..60.0),
                    rng.random_range(-60.0..60.0),
                    rng.random_range(-60.0..60.0),
                );
            }
            let plain = align(&src, &dst, None, true).unwrap();
            let config = RobustAlignConfig {
                kernel: RobustKernel::Cauchy { c: 0.1 },
                with_scale: true,
                ..Default::default()
            };
            let robust = align_robust(&src, &dst, &config).unwrap();
            let err = |s: &Sim3| {
                src.iter()
                    .map(|p| (s.transform_point(p) - truth.transform_point(p)).norm())
                    .fold(0.0, f64::max)
            };
            assert!(
                err(&plain.sim3) > 0.5,
                "seed {seed}: plain fit unexpectedly good"
            );
            assert!(
                err(&robust.alignment.sim3) < 0.05,
                "seed {seed}: {}",
                err(&robust.alignment.sim3)
            );
            for &i in &outliers {
                assert!(robust.weights[i] < 1e-3, "seed {seed}: outlier {i} kept");
            }
        }
    }
}
