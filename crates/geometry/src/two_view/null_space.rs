//! Null space of a small full-rank `R×9` epipolar design matrix (`R` = 5 for the five-point
//! solver, 8 for the minimal 8-point sample), by Gauss-Jordan elimination with full pivoting:
//! several times cheaper than an SVD or eigen-decomposition for these sizes.

use nalgebra::SVector;

/// Orthonormal basis of the `N = 9 − R` dimensional null space of the rows; `None` when the
/// rank is below `R` (degenerate sample) or the sizes do not add up to 9.
pub(crate) fn null_space<const R: usize, const N: usize>(
    rows: &[[f64; 9]; R],
) -> Option<[SVector<f64, 9>; N]> {
    if R + N != 9 {
        return None;
    }
    let mut a = *rows;
    let mut cols: [usize; 9] = std::array::from_fn(|i| i);
    let scale = a.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    if !scale.is_finite() || scale <= 0.0 {
        return None;
    }
    for r in 0..R {
        let (mut pr, mut pc, mut best) = (r, r, 0.0);
        for (i, row) in a.iter().enumerate().skip(r) {
            for (j, v) in row.iter().enumerate().skip(r) {
                if v.abs() > best {
                    (pr, pc, best) = (i, j, v.abs());
                }
            }
        }
        if best <= 1e-10 * scale {
            return None;
        }
        a.swap(r, pr);
        for row in a.iter_mut() {
            row.swap(r, pc);
        }
        cols.swap(r, pc);
        let inv = 1.0 / a[r][r];
        for v in a[r].iter_mut() {
            *v *= inv;
        }
        let pivot_row = a[r];
        for (i, row) in a.iter_mut().enumerate() {
            if i != r && row[r] != 0.0 {
                let f = row[r];
                for (v, p) in row.iter_mut().zip(pivot_row.iter()) {
                    *v -= f * p;
                }
            }
        }
    }
    // The last N (permuted) columns are free: v[cols[R + k]] = 1, v[cols[i]] = −a[i][R + k].
    let mut basis: [SVector<f64, 9>; N] = std::array::from_fn(|k| {
        let mut v = SVector::<f64, 9>::zeros();
        v[cols[R + k]] = 1.0;
        for (i, row) in a.iter().enumerate() {
            v[cols[i]] = -row[R + k];
        }
        v
    });
    // Gram-Schmidt: an orthonormal basis keeps downstream coefficients well scaled.
    for k in 0..N {
        for j in 0..k {
            let bj = basis[j];
            let d = basis[k].dot(&bj);
            basis[k] -= d * bj;
        }
        let n = basis[k].norm();
        if n.is_nan() || n <= 1e-12 {
            return None;
        }
        basis[k] /= n;
    }
    Some(basis)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn basis_is_orthonormal_and_annihilated() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        for _ in 0..20 {
            let rows: [[f64; 9]; 5] =
                std::array::from_fn(|_| std::array::from_fn(|_| rng.random_range(-1.0..1.0)));
            let basis = null_space::<5, 4>(&rows).unwrap();
            for (k, b) in basis.iter().enumerate() {
                for row in &rows {
                    let dot: f64 = row.iter().zip(b.iter()).map(|(x, y)| x * y).sum();
                    assert!(dot.abs() < 1e-12);
                }
                for (j, c) in basis.iter().enumerate() {
                    let expected = if j == k { 1.0 } else { 0.0 };
                    assert!((b.dot(c) - expected).abs() < 1e-12);
                }
            }
        }
    }

    #[test]
    fn rank_deficiency_and_bad_sizes_are_rejected() {
        let mut rows = [[0.0; 9]; 8];
        for (i, row) in rows.iter_mut().enumerate() {
            row[i % 4] = 1.0 + i as f64;
        }
        assert!(null_space::<8, 1>(&rows).is_none());
        assert!(null_space::<8, 2>(&rows).is_none());
        assert!(null_space::<5, 4>(&[[f64::NAN; 9]; 5]).is_none());
    }
}
