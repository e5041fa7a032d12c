//! Decomposition of a plane-induced homography into motion and plane (Ma, Soatto, Košecká &
//! Sastry, "An Invitation to 3-D Vision", §5.3.3), for planar two-view initialisation.
//!
//! Convention: a point `X₁` in the source camera frame lies on the plane `nᵀX₁ = d` (`d > 0`),
//! moves to the destination camera frame as `X₂ = R X₁ + t`, hence
//! `X₂ = (R + t nᵀ/d) X₁` and the pixel homography is `H ∝ K (R + t nᵀ/d) K⁻¹`.

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

use crate::error::{GeometryError, Result};
use crate::rotation::nearest_rotation;

/// One motion/plane interpretation of a homography.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HomographyMotion {
    /// Rotation from the source to the destination camera frame (`X₂ = R X₁ + t`).
    pub rotation: UnitQuaternion<f64>,
    /// Translation divided by the plane distance, `t/d` (the metric scale is unobservable).
    pub translation: Vector3<f64>,
    /// Unit plane normal in the source camera frame, `nᵀX₁ = d`.
    pub normal: Vector3<f64>,
}

impl HomographyMotion {
    /// The Euclidean homography `R + (t/d) nᵀ` this motion induces.
    pub fn euclidean_homography(&self) -> Matrix3<f64> {
        self.rotation.to_rotation_matrix().into_inner() + self.translation * self.normal.transpose()
    }
}

/// Relative gap `σ₁² − σ₃²` below which the homography is a pure rotation (no parallax).
const PURE_ROTATION: f64 = 1e-10;

/// Decomposes the pixel homography `h` (`dst ∝ H src`, any scale and sign) of two views with the
/// same intrinsics `k`.
///
/// Returns the four solutions consistent with both cameras on the same side of the plane
/// (`det(R + t nᵀ/d) > 0`, which fixes the sign of `H`), in two pairs `(R, t/d, n)` and
/// `(R, −t/d, −n)`; the solutions whose normal faces the source camera (`n_z > 0`, the plane
/// visible along its optical axis) come first. The caller picks one by triangulating inliers
/// (cheirality) — usually only one survives. A pure rotation gives one solution with zero
/// translation and the (arbitrary) normal `(0, 0, 1)`.
pub fn decompose_homography(h: &Matrix3<f64>, k: &Matrix3<f64>) -> Result<Vec<HomographyMotion>> {
    if !h.iter().chain(k.iter()).all(|v| v.is_finite()) {
        return Err(GeometryError::NonFinite("homography or intrinsics"));
    }
    let k_inv = k
        .try_inverse()
        .ok_or_else(|| GeometryError::Degenerate("singular intrinsic matrix".into()))?;
    let he = k_inv * h * k;
    let svd = he.svd(false, true);
    let v_t = svd
        .v_t
        .ok_or_else(|| GeometryError::Degenerate("homography SVD failed".into()))?;
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| svd.singular_values[b].total_cmp(&svd.singular_values[a]));
    let sv = order.map(|i| svd.singular_values[i]);
    // Inputs are finite, so the singular values are too.
    if sv[1] <= 1e-12 * sv[0] {
        return Err(GeometryError::Degenerate(
            "homography has rank below 2".into(),
        ));
    }
    // Scale to σ₂ = 1 and the sign with positive determinant.
    let mut he = he / sv[1];
    if he.determinant() < 0.0 {
        he = -he;
    }
    let s1 = (sv[0] / sv[1]).powi(2);
    let s3 = (sv[2] / sv[1]).powi(2);
    if s1 - s3 < PURE_ROTATION {
        let r = nearest_rotation(&he).ok_or_else(|| {
            GeometryError::Degenerate("homography has no nearest rotation".into())
        })?;
        return Ok(vec![HomographyMotion {
            rotation: UnitQuaternion::from_rotation_matrix(&r),
            translation: Vector3::zeros(),
            normal: Vector3::z(),
        }]);
    }
    let v = order.map(|i| v_t.row(i).transpose().into_owned());
    let (a, b, c) = (
        (1.0 - s3).max(0.0).sqrt(),
        (s1 - 1.0).max(0.0).sqrt(),
        (s1 - s3).sqrt(),
    );
    let mut out = Vec::with_capacity(4);
    for u in [(a * v[0] + b * v[2]) / c, (a * v[0] - b * v[2]) / c] {
        let n = v[1].cross(&u);
        let (hv2, hu) = (he * v[1], he * u);
        let basis = Matrix3::from_columns(&[v[1], u, n]);
        let image = Matrix3::from_columns(&[hv2, hu, hv2.cross(&hu)]);
        let r = image * basis.transpose();
        let t = (he - r) * n;
        let Some(rotation) = nearest_rotation(&r) else {
            continue;
        };
        let rotation = UnitQuaternion::from_rotation_matrix(&rotation);
        for sign in [1.0, -1.0] {
            out.push(HomographyMotion {
                rotation,
                translation: sign * t,
                normal: sign * n,
            });
        }
    }
    // Stable: keeps the (R₁, R₂) order within each visibility class.
    out.sort_by_key(|m| m.normal.z <= 0.0);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn k() -> Matrix3<f64> {
        Matrix3::new(500.0, 0.0, 249.5, 0.0, 480.0, 251.0, 0.0, 0.0, 1.0)
    }

    fn unit(rng: &mut ChaCha8Rng) -> Vector3<f64> {
        loop {
            let v = Vector3::from_fn(|_, _| rng.random_range(-1.0..1.0));
            if v.norm() > 0.1 && v.norm() < 1.0 {
                return v.normalize();
            }
        }
    }

    #[test]
    fn recovers_motion_and_plane() {
        for seed in 0..50 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let (r, t, n, d) = loop {
                let r =
                    UnitQuaternion::from_scaled_axis(unit(&mut rng) * rng.random_range(0.0..0.8));
                let mut n = unit(&mut rng);
                n.z = n.z.abs() + 0.3;
                let n = n.normalize();
                let t = unit(&mut rng) * rng.random_range(0.2..2.0);
                let d = rng.random_range(1.0..10.0);
                // Both cameras on the visible side of the plane.
                if 1.0 + n.dot(&(r.inverse() * t)) / d > 0.2 {
                    break (r, t, n, d);
                }
            };
            let he = r.to_rotation_matrix().into_inner() + t * n.transpose() / d;
            let scale = rng.random_range(0.1..10.0) * if seed % 2 == 0 { 1.0 } else { -1.0 };
            let h = scale * k() * he * k().try_inverse().unwrap();
            let sols = decompose_homography(&h, &k()).unwrap();
            assert_eq!(sols.len(), 4);
            for s in &sols {
                // Every solution explains H.
                let e = s.euclidean_homography();
                assert!(
                    (e - he).norm() < 1e-9 * he.norm(),
                    "seed {seed}: {e} vs {he}"
                );
            }
            let rm = r.to_rotation_matrix().into_inner();
            let hit = sols.iter().any(|s| {
                (s.rotation.to_rotation_matrix().into_inner() - rm).norm() < 1e-9
                    && (s.translation - t / d).norm() < 1e-9
                    && (s.normal - n).norm() < 1e-9
            });
            assert!(hit, "seed {seed}: no solution matches\n{sols:#?}");
            // The true plane faces the source camera, so it is among the first two.
            assert!(sols[..2].iter().any(|s| (s.normal - n).norm() < 1e-9));
        }
    }

    #[test]
    fn pure_rotation_and_bad_input() {
        let r = UnitQuaternion::from_euler_angles(0.1, -0.2, 0.3);
        let h = k() * r.to_rotation_matrix().into_inner() * k().try_inverse().unwrap() * 2.0;
        let sols = decompose_homography(&h, &k()).unwrap();
        assert_eq!(sols.len(), 1);
        assert!(sols[0].rotation.angle_to(&r) < 1e-9);
        assert_eq!(sols[0].translation, Vector3::zeros());
        assert!(decompose_homography(&Matrix3::zeros(), &k()).is_err());
        let mut bad = h;
        bad[(0, 0)] = f64::NAN;
        assert!(matches!(
            decompose_homography(&bad, &k()),
            Err(GeometryError::NonFinite(_))
        ));
    }
}
