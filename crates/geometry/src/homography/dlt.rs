//! Normalised direct linear transform (Hartley & Zisserman, Alg. 4.2).
//!
//! Both point sets are moved to their centroid and scaled to a mean distance of √2 before the
//! linear system is built; without this the system's condition number grows with the square of
//! the pixel coordinates and the estimate degrades badly in the presence of noise.

use nalgebra::{Matrix3, Point2, SMatrix, SVector, SymmetricEigen, Vector2};

use crate::error::{GeometryError, Result};

/// Twice the area of a normalised triangle below which a triple counts as collinear.
///
/// In normalised coordinates (mean distance √2) a well-spread quadruple has twice-areas of order
/// 1–4; samples this flat determine no useful homography and only waste RANSAC hypotheses.
const COLLINEAR_TWICE_AREA: f64 = 1e-3;

/// Ratio of the second-smallest to the largest eigenvalue of `AᵀA` below which the null space of
/// the DLT system is more than one-dimensional (collinear or coincident points).
const RANK_DEFICIENT: f64 = 1e-12;

/// Similarity `x ↦ s (x − c)` moving a point set to centroid 0 and mean distance √2.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Normalisation {
    pub(crate) centroid: Vector2<f64>,
    pub(crate) scale: f64,
}

impl Normalisation {
    /// The normalisation of `points[idx]`; `None` when all points coincide.
    pub(crate) fn of(points: &[Point2<f64>], idx: &[usize]) -> Option<Self> {
        let n = idx.len() as f64;
        let centroid = idx
            .iter()
            .fold(Vector2::zeros(), |acc, &i| acc + points[i].coords)
            / n;
        let mean_dist = idx
            .iter()
            .map(|&i| (points[i].coords - centroid).norm())
            .sum::<f64>()
            / n;
        (mean_dist.is_finite() && mean_dist > 0.0).then(|| Self {
            centroid,
            scale: std::f64::consts::SQRT_2 / mean_dist,
        })
    }

    pub(crate) fn apply(&self, p: &Point2<f64>) -> Vector2<f64> {
        (p.coords - self.centroid) * self.scale
    }

    /// The similarity as a homogeneous matrix `T`.
    pub(crate) fn matrix(&self) -> Matrix3<f64> {
        let s = self.scale;
        let c = self.centroid;
        Matrix3::new(s, 0.0, -s * c.x, 0.0, s, -s * c.y, 0.0, 0.0, 1.0)
    }

    /// `T⁻¹` in closed form.
    pub(crate) fn inverse_matrix(&self) -> Matrix3<f64> {
        let is = 1.0 / self.scale;
        let c = self.centroid;
        Matrix3::new(is, 0.0, c.x, 0.0, is, c.y, 0.0, 0.0, 1.0)
    }
}

/// Scales `h` so that `H[2][2] = 1`; when that entry vanishes (the pixel origin maps to the line
/// at infinity) falls back to unit Frobenius norm with `H[2][2] ≥ 0`. `None` for a zero or
/// non-finite matrix.
pub(crate) fn normalise_scale(h: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    let f = h.norm();
    if !(f.is_finite() && f > 0.0) {
        return None;
    }
    let h22 = h[(2, 2)];
    if h22.abs() > 1e-12 * f {
        Some(h / h22)
    } else if h22 < 0.0 {
        Some(-h / f)
    } else {
        Some(h / f)
    }
}

/// True when `h` (any scale) is far from rank-deficient.
fn well_conditioned(h: &Matrix3<f64>) -> bool {
    let f = h.norm();
    let det = h.determinant();
    det.is_finite() && f > 0.0 && det.abs() > 1e-10 * f * f * f
}

fn cross2(a: &Vector2<f64>, b: &Vector2<f64>, c: &Vector2<f64>) -> f64 {
    (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x)
}

/// Rejects minimal samples that cannot come from a homography of a plane seen by two cameras:
/// any (nearly) collinear triple in either image, or triple orientations that disagree.
///
/// For `x'ᵢ ∝ H xᵢ` with depths `wᵢ = (H xᵢ)₃`, `det[x'ᵢ x'ⱼ x'ₖ] = det H · det[xᵢ xⱼ xₖ] / (wᵢ wⱼ wₖ)`.
/// Points seen in front of both cameras all have `wᵢ` of one sign, so the orientation ratio of
/// all four triples must agree; a mixed sign means an outlier (or a fold-over) and the sample is
/// dropped before solving.
fn sample_is_plausible(s: &[Vector2<f64>; 4], d: &[Vector2<f64>; 4]) -> bool {
    const TRIPLES: [(usize, usize, usize); 4] = [(0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3)];
    let mut sign = 0.0;
    for (i, j, k) in TRIPLES {
        let a = cross2(&s[i], &s[j], &s[k]);
        let b = cross2(&d[i], &d[j], &d[k]);
        if a.abs() < COLLINEAR_TWICE_AREA || b.abs() < COLLINEAR_TWICE_AREA {
            return false;
        }
        let r = (a * b).signum();
        if sign == 0.0 {
            sign = r;
        } else if r != sign {
            return false;
        }
    }
    true
}

/// The homography of exactly four correspondences (`dst ∝ H src`), or `None` for a degenerate
/// or implausible sample: a (nearly) collinear triple in either image, or triple orientations
/// that disagree between the images (the points cannot all lie in front of both cameras).
///
/// Solves the 8×8 system with `H̃[2][2] = 1` in normalised coordinates; the orientation test
/// guarantees that the centroid maps to a finite point, so that entry cannot vanish there.
pub fn minimal_homography(src: &[Point2<f64>; 4], dst: &[Point2<f64>; 4]) -> Option<Matrix3<f64>> {
    let idx = [0, 1, 2, 3];
    let ns = Normalisation::of(src, &idx)?;
    let nd = Normalisation::of(dst, &idx)?;
    let s = src.map(|p| ns.apply(&p));
    let d = dst.map(|p| nd.apply(&p));
    if !sample_is_plausible(&s, &d) {
        return None;
    }
    let mut a = SMatrix::<f64, 8, 8>::zeros();
    let mut b = SVector::<f64, 8>::zeros();
    for k in 0..4 {
        let (x, y, u, v) = (s[k].x, s[k].y, d[k].x, d[k].y);
        let r = 2 * k;
        a.row_mut(r)
            .copy_from_slice(&[x, y, 1.0, 0.0, 0.0, 0.0, -u * x, -u * y]);
        a.row_mut(r + 1)
            .copy_from_slice(&[0.0, 0.0, 0.0, x, y, 1.0, -v * x, -v * y]);
        b[r] = u;
        b[r + 1] = v;
    }
    let h = a.lu().solve(&b)?;
    let hn = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], 1.0);
    if !well_conditioned(&hn) {
        return None;
    }
    normalise_scale(&(nd.inverse_matrix() * hn * ns.matrix()))
}

/// Normalised DLT over the correspondences `idx` (at least 4).
///
/// Accumulates the 9×9 normal matrix `AᵀA` of the 2N×9 system and takes the eigenvector of its
/// smallest eigenvalue. In normalised coordinates `AᵀA` is well conditioned, so squaring the
/// condition number costs no useful precision, and the work stays O(N) without a 2N×9 buffer.
pub(crate) fn dlt_indices(
    src: &[Point2<f64>],
    dst: &[Point2<f64>],
    idx: &[usize],
) -> Result<Matrix3<f64>> {
    if idx.len() < 4 {
        return Err(GeometryError::TooFewPoints {
            required: 4,
            found: idx.len(),
        });
    }
    let degenerate = |why: &str| GeometryError::Degenerate(format!("homography DLT: {why}"));
    let ns = Normalisation::of(src, idx).ok_or_else(|| degenerate("source points coincide"))?;
    let nd = Normalisation::of(dst, idx).ok_or_else(|| degenerate("target points coincide"))?;
    let mut m = SMatrix::<f64, 9, 9>::zeros();
    for &i in idx {
        let s = ns.apply(&src[i]);
        let d = nd.apply(&dst[i]);
        let (x, y, u, v) = (s.x, s.y, d.x, d.y);
        let r1 = SVector::<f64, 9>::from([-x, -y, -1.0, 0.0, 0.0, 0.0, u * x, u * y, u]);
        let r2 = SVector::<f64, 9>::from([0.0, 0.0, 0.0, -x, -y, -1.0, v * x, v * y, v]);
        m.ger(1.0, &r1, &r1, 1.0);
        m.ger(1.0, &r2, &r2, 1.0);
    }
    let eig = SymmetricEigen::new(m);
    let mut order: [usize; 9] = std::array::from_fn(|i| i);
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let largest = eig.eigenvalues[order[8]];
    if !(largest.is_finite() && eig.eigenvalues[order[1]] > RANK_DEFICIENT * largest) {
        return Err(degenerate("points are collinear or rank-deficient"));
    }
    let h = eig.eigenvectors.column(order[0]);
    let hn = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    if !well_conditioned(&hn) {
        return Err(degenerate("estimated homography is singular"));
    }
    normalise_scale(&(nd.inverse_matrix() * hn * ns.matrix()))
        .ok_or_else(|| degenerate("estimated homography is not finite"))
}

/// Normalised DLT homography `dst ∝ H src` from all correspondences (at least 4), scaled as
/// described in the [module docs](super).
pub fn dlt(src: &[Point2<f64>], dst: &[Point2<f64>]) -> Result<Matrix3<f64>> {
    super::check_input(src, dst)?;
    let idx: Vec<usize> = (0..src.len()).collect();
    dlt_indices(src, dst, &idx)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::homography::transfer_point;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_h(rng: &mut ChaCha8Rng) -> Matrix3<f64> {
        // Corner-perturbation homography of a 500×500 image (as in SuperPoint's benchmarks).
        let c = [(0.0, 0.0), (499.0, 0.0), (499.0, 499.0), (0.0, 499.0)];
        let src = c.map(|(x, y)| Point2::new(x, y));
        let dst = c.map(|(x, y)| {
            Point2::new(
                x + rng.random_range(-100.0..100.0),
                y + rng.random_range(-100.0..100.0),
            )
        });
        minimal_homography(&src, &dst).expect("perturbed corners are a valid sample")
    }

    fn rel_diff(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
        (a / a.norm() - b / b.norm()).norm()
    }

    #[test]
    fn minimal_and_dlt_recover_exact_homography() {
        for seed in 0..10 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let h = random_h(&mut rng);
            let src: Vec<Point2<f64>> = (0..50)
                .map(|_| Point2::new(rng.random_range(0.0..500.0), rng.random_range(0.0..500.0)))
                .collect();
            let dst: Vec<Point2<f64>> = src.iter().map(|p| transfer_point(&h, p)).collect();
            let est = dlt(&src, &dst).unwrap();
            assert!(rel_diff(&est, &h) < 1e-10, "seed {seed}: {est} vs {h}");
            assert!((est[(2, 2)] - 1.0).abs() < 1e-15);
            let s4 = [src[0], src[1], src[2], src[3]];
            let d4 = [dst[0], dst[1], dst[2], dst[3]];
            if let Some(m) = minimal_homography(&s4, &d4) {
                assert!(rel_diff(&m, &h) < 1e-9, "seed {seed}: minimal {m} vs {h}");
            }
        }
    }

    #[test]
    fn rejects_collinear_and_folded_samples() {
        let sq = [(0.0, 0.0), (100.0, 0.0), (100.0, 100.0), (0.0, 100.0)]
            .map(|(x, y)| Point2::new(x, y));
        assert!(minimal_homography(&sq, &sq).is_some());
        // Three collinear source points.
        let col =
            [(0.0, 0.0), (50.0, 0.0), (100.0, 0.0), (0.0, 100.0)].map(|(x, y)| Point2::new(x, y));
        assert!(minimal_homography(&col, &sq).is_none());
        assert!(minimal_homography(&sq, &col).is_none());
        // Swapping two target points folds the quadrilateral: orientations disagree.
        let folded = [sq[1], sq[0], sq[2], sq[3]];
        assert!(minimal_homography(&sq, &folded).is_none());
        // A fully collinear set is rank-deficient for the general DLT.
        let line: Vec<_> = (0..10)
            .map(|i| Point2::new(i as f64, 2.0 * i as f64))
            .collect();
        assert!(matches!(
            dlt(&line, &line),
            Err(GeometryError::Degenerate(_))
        ));
    }
}
