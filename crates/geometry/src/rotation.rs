//! The rotation nearest to a 3 × 3 matrix, in closed form.
//!
//! nalgebra's `Rotation3::from_matrix` (and `UnitQuaternion::from_matrix`) iterate towards the
//! nearest rotation from the identity; for a matrix half a turn from the identity they can stop
//! at the identity or at the wrong half turn (a nadir camera's orientation at some headings,
//! `jointloc_absloc::nadir_orientation`). The SVD gives it directly.

use nalgebra::{Matrix3, Rotation3};

/// The rotation nearest to `m` in the Frobenius norm: `U diag(1, 1, det(U Vᵀ)) Vᵀ` of the SVD
/// `m = U Σ Vᵀ`. `None` when `m` has a non-finite entry or the SVD fails.
pub fn nearest_rotation(m: &Matrix3<f64>) -> Option<Rotation3<f64>> {
    if !m.iter().all(|v| v.is_finite()) {
        return None;
    }
    let svd = m.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut d = Matrix3::identity();
    d[(2, 2)] = (u * v_t).determinant().signum();
    Some(Rotation3::from_matrix_unchecked(u * d * v_t))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Unit, Vector3};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn recovers_any_rotation_from_an_exact_or_noisy_matrix() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for i in 0..2000 {
            let axis = Unit::new_normalize(Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            ));
            // Every angle up to and including half a turn, the hard case for iteration.
            let angle = if i % 4 == 0 {
                std::f64::consts::PI
            } else {
                rng.random_range(0.0..std::f64::consts::PI)
            };
            let truth = Rotation3::from_axis_angle(&axis, angle);
            // Exact matrices too: those are where the iteration from the identity stalls.
            let size = if i % 2 == 0 { 0.0 } else { 1e-6 };
            let noise = Matrix3::from_fn(|_, _| size * rng.random_range(-1.0..1.0));
            let r = nearest_rotation(&(truth.matrix() + noise)).unwrap();
            let off = (r.matrix() - truth.matrix()).norm();
            assert!(off < 1e-5, "angle {angle}: off by {off}");
            assert!((r.matrix().determinant() - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn a_nadir_camera_at_any_heading() {
        // Image x along the heading, image y to its right, the optical axis down: the matrix
        // `UnitQuaternion::from_matrix` returned as the identity at −55.7°.
        for i in 0..720 {
            let h = (i as f64 * 0.5 - 180.0).to_radians();
            let (s, c) = h.sin_cos();
            let m = Matrix3::new(c, -s, 0.0, -s, -c, 0.0, 0.0, 0.0, -1.0);
            let r = nearest_rotation(&m).unwrap();
            assert!((r.matrix() - m).norm() < 1e-12, "heading {h}: {r:?}");
        }
    }

    #[test]
    fn a_reflection_becomes_a_proper_rotation_and_nan_gives_none() {
        let reflection = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0));
        let r = nearest_rotation(&reflection).unwrap();
        assert!((r.matrix().determinant() - 1.0).abs() < 1e-12);
        let mut bad = Matrix3::identity();
        bad[(0, 1)] = f64::NAN;
        assert!(nearest_rotation(&bad).is_none());
    }
}
