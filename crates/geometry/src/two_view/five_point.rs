//! Minimal essential-matrix solver from five calibrated correspondences (Stewénius, Engels &
//! Nistér 2006, "Recent developments on direct relative orientation").
//!
//! The five epipolar constraints leave a 4-D null space `E = x X + y Y + z Z + W`. The cubic
//! constraints `det E = 0` and `E Eᵀ E − ½ tr(E Eᵀ) E = 0` give ten equations in the twenty
//! monomials of degree ≤ 3 in `(x, y, z)`. Gauss-Jordan elimination of the ten cubic monomials
//! leaves each of them as a combination of the ten monomials `x², xy, xz, y², yz, z², x, y, z, 1`,
//! which is enough to write multiplication by `x` as a 10×10 action matrix. Its real
//! eigenvalues are the `x` of the (up to ten) solutions and its eigenvectors hold `y`, `z`.

use nalgebra::{Matrix3, SMatrix, SVector, Vector3, linalg::Schur};

use super::null_space::null_space;

/// Exponents `(x, y, z)` of the twenty monomials, cubic ones first (grevlex); the last ten are
/// the quotient-ring basis, the last four the linear monomials.
const MONOMIALS: [[u8; 3]; 20] = [
    [3, 0, 0],
    [2, 1, 0],
    [2, 0, 1],
    [1, 2, 0],
    [1, 1, 1],
    [1, 0, 2],
    [0, 3, 0],
    [0, 2, 1],
    [0, 1, 2],
    [0, 0, 3],
    [2, 0, 0],
    [1, 1, 0],
    [1, 0, 1],
    [0, 2, 0],
    [0, 1, 1],
    [0, 0, 2],
    [1, 0, 0],
    [0, 1, 0],
    [0, 0, 1],
    [0, 0, 0],
];

const fn monomial_index(e: [u8; 3]) -> usize {
    let mut i = 0;
    while i < 20 {
        let m = MONOMIALS[i];
        if m[0] == e[0] && m[1] == e[1] && m[2] == e[2] {
            return i;
        }
        i += 1;
    }
    // Unreachable for degrees ≤ 3; evaluated at compile time only.
    panic!("monomial of degree > 3")
}

/// `PRODUCT[a][b]`: index of monomial `a` times monomial `b` (for products of degree ≤ 3).
const fn product_table<const A: usize, const B: usize>(
    first_a: usize,
    first_b: usize,
) -> [[usize; B]; A] {
    let mut t = [[0; B]; A];
    let mut a = 0;
    while a < A {
        let mut b = 0;
        while b < B {
            let (ea, eb) = (MONOMIALS[first_a + a], MONOMIALS[first_b + b]);
            t[a][b] = monomial_index([ea[0] + eb[0], ea[1] + eb[1], ea[2] + eb[2]]);
            b += 1;
        }
        a += 1;
    }
    t
}

/// Linear × linear → quadratic, indices into the 20-monomial list.
const MUL_11: [[usize; 4]; 4] = product_table::<4, 4>(16, 16);
/// Quadratic × linear → cubic.
const MUL_21: [[usize; 4]; 10] = product_table::<10, 4>(10, 16);

/// Polynomial of degree ≤ 1: coefficients of `x, y, z, 1`.
type P1 = [f64; 4];
/// Polynomial of degree ≤ 2: coefficients of `x², xy, xz, y², yz, z², x, y, z, 1`.
type P2 = [f64; 10];
/// Polynomial of degree ≤ 3 on all twenty monomials.
type P3 = [f64; 20];

fn mul11(a: &P1, b: &P1) -> P2 {
    let mut out = [0.0; 10];
    for i in 0..4 {
        for j in 0..4 {
            out[MUL_11[i][j] - 10] += a[i] * b[j];
        }
    }
    out
}

fn mul21(a: &P2, b: &P1) -> P3 {
    let mut out = [0.0; 20];
    for i in 0..10 {
        for j in 0..4 {
            out[MUL_21[i][j]] += a[i] * b[j];
        }
    }
    out
}

fn axpy<const N: usize>(acc: &mut [f64; N], alpha: f64, x: &[f64; N]) {
    for (a, b) in acc.iter_mut().zip(x) {
        *a += alpha * b;
    }
}

/// The ten cubic constraints on `(x, y, z)` as a 10×20 coefficient matrix.
fn constraint_matrix(basis: &[SVector<f64, 9>; 4]) -> SMatrix<f64, 10, 20> {
    // E_ij(x, y, z) = x X_ij + y Y_ij + z Z_ij + W_ij (row-major vec).
    let e: [[P1; 3]; 3] = std::array::from_fn(|i| {
        std::array::from_fn(|j| {
            let k = 3 * i + j;
            [basis[0][k], basis[1][k], basis[2][k], basis[3][k]]
        })
    });
    let mut eet = [[[0.0; 10]; 3]; 3];
    for i in 0..3 {
        for j in i..3 {
            let mut acc = [0.0; 10];
            for (eik, ejk) in e[i].iter().zip(&e[j]) {
                axpy(&mut acc, 1.0, &mul11(eik, ejk));
            }
            eet[i][j] = acc;
            eet[j][i] = acc;
        }
    }
    let mut half_trace = [0.0; 10];
    for (i, row) in eet.iter().enumerate() {
        axpy(&mut half_trace, 0.5, &row[i]);
    }
    let mut m = SMatrix::<f64, 10, 20>::zeros();
    for i in 0..3 {
        for j in 0..3 {
            // (E Eᵀ E − ½ tr(E Eᵀ) E)_ij
            let mut p: P3 = mul21(&half_trace, &e[i][j]);
            for v in p.iter_mut() {
                *v = -*v;
            }
            for k in 0..3 {
                axpy(&mut p, 1.0, &mul21(&eet[i][k], &e[k][j]));
            }
            for (c, v) in p.iter().enumerate() {
                m[(3 * i + j, c)] = *v;
            }
        }
    }
    // det E by cofactors along the first row.
    let minor = |r1: usize, c1: usize, r2: usize, c2: usize| -> P2 {
        let mut a = mul11(&e[r1][c1], &e[r2][c2]);
        axpy(&mut a, -1.0, &mul11(&e[r1][c2], &e[r2][c1]));
        a
    };
    let mut det = mul21(&minor(1, 1, 2, 2), &e[0][0]);
    axpy(&mut det, -1.0, &mul21(&minor(1, 0, 2, 2), &e[0][1]));
    axpy(&mut det, 1.0, &mul21(&minor(1, 0, 2, 1), &e[0][2]));
    for (c, v) in det.iter().enumerate() {
        m[(9, c)] = *v;
    }
    m
}

/// Gauss-Jordan elimination of the first ten columns with partial pivoting; returns the
/// remaining 10×10 block `C` such that `cubic = −C · basis`, or `None` if singular.
fn eliminate(mut m: SMatrix<f64, 10, 20>) -> Option<SMatrix<f64, 10, 10>> {
    let scale = m.amax();
    if !scale.is_finite() || scale <= 0.0 {
        return None;
    }
    for c in 0..10 {
        let (pr, best) = (c..10)
            .map(|r| (r, m[(r, c)].abs()))
            .fold((c, -1.0), |acc, x| if x.1 > acc.1 { x } else { acc });
        if best <= 1e-12 * scale {
            return None;
        }
        m.swap_rows(c, pr);
        let inv = 1.0 / m[(c, c)];
        m.row_mut(c).scale_mut(inv);
        let pivot = m.row(c).into_owned();
        for r in 0..10 {
            if r != c {
                let f = m[(r, c)];
                if f != 0.0 {
                    for k in 0..20 {
                        m[(r, k)] -= f * pivot[k];
                    }
                }
            }
        }
    }
    Some(m.fixed_columns::<10>(10).into_owned())
}

/// Eigenvector of `a` for the real eigenvalue `lambda` by inverse iteration.
fn eigenvector(a: &SMatrix<f64, 10, 10>, lambda: f64) -> Option<SVector<f64, 10>> {
    let shift = lambda + 1e-10 * (1.0 + lambda.abs());
    let shifted = a - SMatrix::<f64, 10, 10>::identity() * shift;
    let lu = shifted.lu();
    let mut v = SVector::<f64, 10>::repeat(1.0);
    for _ in 0..3 {
        let w = lu.solve(&v)?;
        let n = w.norm();
        if !(n > 0.0 && n.is_finite()) {
            return None;
        }
        v = w / n;
    }
    Some(v)
}

/// All essential matrices (unit Frobenius norm, up to ten) consistent with five
/// correspondences of normalised camera rays `x2ᵀ E x1 = 0`. Empty when the slices do not
/// hold exactly five finite rays or the configuration is degenerate.
pub fn essential_five_point(x1: &[Vector3<f64>], x2: &[Vector3<f64>]) -> Vec<Matrix3<f64>> {
    if x1.len() != 5 || x2.len() != 5 {
        return Vec::new();
    }
    let mut rows = [[0.0; 9]; 5];
    for (row, (a, b)) in rows.iter_mut().zip(x1.iter().zip(x2)) {
        let (na, nb) = (a.norm(), b.norm());
        if !(na > 0.0 && nb > 0.0 && na.is_finite() && nb.is_finite()) {
            return Vec::new();
        }
        let (a, b) = (a / na, b / nb);
        for (k, v) in row.iter_mut().enumerate() {
            *v = b[k / 3] * a[k % 3];
        }
    }
    let Some(basis) = null_space::<5, 4>(&rows) else {
        return Vec::new();
    };
    let Some(c) = eliminate(constraint_matrix(&basis)) else {
        return Vec::new();
    };
    // Action matrix of multiplication by x on the basis (x², xy, xz, y², yz, z², x, y, z, 1).
    let mut action = SMatrix::<f64, 10, 10>::zeros();
    for k in 0..6 {
        action.set_row(k, &(-c.row(k)));
    }
    action[(6, 0)] = 1.0;
    action[(7, 1)] = 1.0;
    action[(8, 2)] = 1.0;
    action[(9, 6)] = 1.0;
    let Some(schur) = Schur::try_new(action, 1e-14, 500) else {
        return Vec::new();
    };
    let mut out = Vec::with_capacity(10);
    for ev in schur.complex_eigenvalues().iter() {
        if ev.im.abs() > 1e-8 * (1.0 + ev.re.abs()) {
            continue;
        }
        let Some(v) = eigenvector(&action, ev.re) else {
            continue;
        };
        if v[9].abs() < 1e-12 {
            continue;
        }
        let (x, y, z) = (ev.re, v[7] / v[9], v[8] / v[9]);
        let e = basis[0] * x + basis[1] * y + basis[2] * z + basis[3];
        let n = e.norm();
        if n > 0.0 && n.is_finite() {
            out.push(Matrix3::from_fn(|i, j| e[3 * i + j] / n));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pose::{skew, so3_exp};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Five random correspondences seen by two random cameras; returns rays and the true E.
    fn problem(seed: u64) -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>, Matrix3<f64>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let axis = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        let r = so3_exp(&(axis.normalize() * rng.random_range(0.05..0.5)))
            .to_rotation_matrix()
            .into_inner();
        let t = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-0.5..0.5),
        )
        .normalize();
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for _ in 0..5 {
            let p = Vector3::new(
                rng.random_range(-3.0..3.0),
                rng.random_range(-3.0..3.0),
                rng.random_range(4.0..10.0),
            );
            let q = r * p + t;
            a.push(p / p.z);
            b.push(q / q.z);
        }
        let e = skew(&t) * r;
        (a, b, e / e.norm())
    }

    #[test]
    fn recovers_the_true_essential_matrix() {
        for seed in 0..20 {
            let (a, b, truth) = problem(seed);
            let sols = essential_five_point(&a, &b);
            assert!(!sols.is_empty(), "seed {seed}: no solution");
            let best = sols
                .iter()
                .map(|e| (e - truth).norm().min((e + truth).norm()))
                .fold(f64::INFINITY, f64::min);
            assert!(best < 1e-8, "seed {seed}: closest solution {best}");
            for e in &sols {
                // Every solution satisfies the constraints and is essential.
                for (p, q) in a.iter().zip(&b) {
                    assert!((q.transpose() * e * p)[0].abs() < 1e-9);
                }
                let sv = e.singular_values();
                let mut s = [sv[0], sv[1], sv[2]];
                s.sort_by(f64::total_cmp);
                assert!(s[0] < 1e-8 && (s[2] - s[1]).abs() < 1e-8, "{s:?}");
            }
        }
    }

    #[test]
    fn degenerate_samples_give_no_solution() {
        let (a, b, _) = problem(3);
        let mut same = a.clone();
        same[1] = same[0];
        let mut same2 = b.clone();
        same2[1] = same2[0];
        assert!(essential_five_point(&same, &same2).is_empty());
        assert!(essential_five_point(&a[..4], &b[..4]).is_empty());
        let mut nan = a.clone();
        nan[2].x = f64::NAN;
        assert!(essential_five_point(&nan, &b).is_empty());
    }
}
