//! Fundamental matrix from pixel correspondences: Hartley's normalised 8-point algorithm with
//! rank-2 enforcement, an MSAC estimator, and refinement on the inliers (linear re-estimate,
//! then Levenberg-Marquardt on the Sampson error over a rank-2 parameterisation).
//!
//! Convention: `x2ᵀ F x1 = 0` for homogeneous pixels `x = (u, v, 1)`.

use nalgebra::{Matrix3, Point2, SMatrix, SVector, Vector3};
use serde::{Deserialize, Serialize};
use tracing::debug;

use super::null_space::null_space;
use super::sampson::{EpipolarManifold, LmSettings, PixelScale, refine_sampson, sampson_squared};
use crate::error::{GeometryError, Result};
use crate::pose::{skew, so3_exp};
use crate::ransac::{Estimator, RansacConfig, inliers_of, ransac};
use crate::robust::RobustKernel;

/// Parameters of [`estimate_fundamental`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct FundamentalConfig {
    /// RANSAC settings; `threshold` is the Sampson distance in pixels (default 2 px, about
    /// 4σ for 0.5 px keypoint noise).
    pub ransac: RansacConfig,
    /// Levenberg-Marquardt iterations on the Sampson error after the linear re-estimate on the
    /// inliers; 0 keeps the linear estimate.
    pub refine_iterations: usize,
    /// Robust kernel of that refinement (residuals in pixels); guards against the few outliers
    /// that happen to lie close to their epipolar line.
    pub refine_kernel: RobustKernel,
}

impl Default for FundamentalConfig {
    fn default() -> Self {
        Self {
            ransac: RansacConfig {
                threshold: 2.0,
                ..RansacConfig::default()
            },
            refine_iterations: 20,
            refine_kernel: RobustKernel::Huber { delta: 1.0 },
        }
    }
}

/// Output of [`estimate_fundamental`].
#[derive(Debug, Clone, PartialEq)]
pub struct FundamentalResult {
    /// Rank-2 fundamental matrix with unit Frobenius norm, `x2ᵀ F x1 = 0`.
    pub f: Matrix3<f64>,
    /// Correspondences whose Sampson distance under `f` is below the threshold, ascending.
    pub inliers: Vec<usize>,
    /// RANSAC hypotheses drawn.
    pub iterations: usize,
}

/// Squared Sampson distance of a pixel correspondence under `f`, in squared pixels.
pub fn sampson_distance_squared(f: &Matrix3<f64>, p1: &Point2<f64>, p2: &Point2<f64>) -> f64 {
    sampson_squared(
        f,
        &p1.to_homogeneous(),
        &p2.to_homogeneous(),
        &PixelScale::PIXELS,
    )
}

/// Similarity `T` of Hartley's normalisation: centroid to the origin, mean distance √2.
/// Returns `(T, s)` with `s` the isotropic scale, or `None` for coincident points.
pub(crate) fn hartley_normalisation(
    points: impl Iterator<Item = Point2<f64>> + Clone,
) -> Option<(Matrix3<f64>, f64)> {
    let (mut cx, mut cy, mut n) = (0.0, 0.0, 0.0);
    for p in points.clone() {
        cx += p.x;
        cy += p.y;
        n += 1.0;
    }
    if n == 0.0 {
        return None;
    }
    cx /= n;
    cy /= n;
    let mean_dist = points.map(|p| (p.x - cx).hypot(p.y - cy)).sum::<f64>() / n;
    if !mean_dist.is_finite() || mean_dist <= 1e-12 * (1.0 + cx.abs() + cy.abs()) {
        return None;
    }
    let s = std::f64::consts::SQRT_2 / mean_dist;
    Some((
        Matrix3::new(s, 0.0, -s * cx, 0.0, s, -s * cy, 0.0, 0.0, 1.0),
        s,
    ))
}

/// The row of the 8-point design matrix: `x2ᵀ F x1 = row · vec(F)` (row-major `vec`).
#[inline]
fn design_row(x1: &Vector3<f64>, x2: &Vector3<f64>) -> SVector<f64, 9> {
    SVector::<f64, 9>::from_fn(|k, _| x2[k / 3] * x1[k % 3])
}

/// Normalised 8-point algorithm on the pairs yielded by `pairs` (at least 8). `None` when the
/// points do not determine `F` (coincident, collinear, or a null space of dimension > 1).
fn eight_point_iter(
    pairs: impl Iterator<Item = (Point2<f64>, Point2<f64>)> + Clone,
) -> Option<Matrix3<f64>> {
    let (t1, _) = hartley_normalisation(pairs.clone().map(|p| p.0))?;
    let (t2, _) = hartley_normalisation(pairs.clone().map(|p| p.1))?;
    let count = pairs.clone().count();
    if count < 8 {
        return None;
    }
    let rows =
        pairs.map(|(p1, p2)| design_row(&(t1 * p1.to_homogeneous()), &(t2 * p2.to_homogeneous())));
    let v = if count == 8 {
        // Minimal sample: the exact null vector by elimination, much cheaper than an eigen-
        // decomposition inside RANSAC.
        let mut a = [[0.0; 9]; 8];
        for (dst, row) in a.iter_mut().zip(rows) {
            dst.copy_from_slice(row.as_slice());
        }
        let [v] = null_space::<8, 1>(&a)?;
        v
    } else {
        let mut ata = SMatrix::<f64, 9, 9>::zeros();
        for row in rows {
            ata.ger(1.0, &row, &row, 1.0);
        }
        let eig = ata.symmetric_eigen();
        let mut order: [usize; 9] = std::array::from_fn(|i| i);
        order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
        let largest = eig.eigenvalues[order[8]];
        // A second (near-)null direction means a family of solutions: degenerate data.
        if largest.is_nan() || largest <= 0.0 || eig.eigenvalues[order[1]] <= 1e-12 * largest {
            return None;
        }
        eig.eigenvectors.column(order[0]).into_owned()
    };
    let fn_ = Matrix3::from_fn(|i, j| v[3 * i + j]);
    let svd = fn_.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut sv = svd.singular_values;
    sv[2] = 0.0;
    let rank2 = u * Matrix3::from_diagonal(&sv) * vt;
    let f = t2.transpose() * rank2 * t1;
    let norm = f.norm();
    (norm > 0.0 && norm.is_finite()).then(|| f / norm)
}

/// Normalised 8-point estimate of `F` from at least 8 pixel correspondences (least squares for
/// more), rank 2 enforced, unit Frobenius norm.
pub fn eight_point(x1: &[Point2<f64>], x2: &[Point2<f64>]) -> Result<Matrix3<f64>> {
    check_correspondences(x1, x2, 8)?;
    eight_point_iter(x1.iter().copied().zip(x2.iter().copied())).ok_or_else(|| {
        GeometryError::Degenerate("8-point: correspondences do not determine F".into())
    })
}

pub(crate) fn check_correspondences(
    x1: &[Point2<f64>],
    x2: &[Point2<f64>],
    required: usize,
) -> Result<()> {
    if x1.len() != x2.len() {
        return Err(GeometryError::LengthMismatch {
            what: "x1 vs x2",
            left: x1.len(),
            right: x2.len(),
        });
    }
    if x1.len() < required {
        return Err(GeometryError::TooFewPoints {
            required,
            found: x1.len(),
        });
    }
    if !x1
        .iter()
        .chain(x2)
        .all(|p| p.x.is_finite() && p.y.is_finite())
    {
        return Err(GeometryError::NonFinite("pixel correspondences"));
    }
    Ok(())
}

/// RANSAC model family of the fundamental matrix: minimal sample of 8, residual the squared
/// Sampson distance in pixels² (first-order approximation of the squared distance of the
/// correspondence, as a point of ℝ⁴, to the epipolar variety).
#[derive(Debug, Clone)]
pub struct FundamentalEstimator<'a> {
    x1: &'a [Point2<f64>],
    x2: &'a [Point2<f64>],
}

impl<'a> FundamentalEstimator<'a> {
    /// Wraps pixel correspondences; checks lengths and finiteness.
    pub fn new(x1: &'a [Point2<f64>], x2: &'a [Point2<f64>]) -> Result<Self> {
        check_correspondences(x1, x2, 0)?;
        Ok(Self { x1, x2 })
    }
}

impl Estimator for FundamentalEstimator<'_> {
    type Model = Matrix3<f64>;
    const SAMPLE_SIZE: usize = 8;

    fn len(&self) -> usize {
        self.x1.len()
    }

    fn fit(&self, sample: &[usize]) -> Vec<Matrix3<f64>> {
        eight_point_iter(sample.iter().map(|&i| (self.x1[i], self.x2[i])))
            .into_iter()
            .collect()
    }

    fn residual_squared(&self, f: &Matrix3<f64>, i: usize) -> f64 {
        sampson_distance_squared(f, &self.x1[i], &self.x2[i])
    }
}

/// `F = U diag(1, σ, 0) Vᵀ` with `U, V ∈ SO(3)`: 7 parameters, rank 2 by construction.
#[derive(Debug, Clone, Copy)]
struct RankTwo {
    u: Matrix3<f64>,
    v: Matrix3<f64>,
    sigma: f64,
}

impl RankTwo {
    fn from_matrix(f: &Matrix3<f64>) -> Option<Self> {
        let svd = f.svd(true, true);
        let (mut u, vt) = (svd.u?, svd.v_t?);
        let mut v = vt.transpose();
        // Flipping a factor's sign flips F's sign, which the epipolar constraint ignores.
        if u.determinant() < 0.0 {
            u = -u;
        }
        if v.determinant() < 0.0 {
            v = -v;
        }
        let sv = svd.singular_values;
        (sv[0] > 0.0).then(|| Self {
            u,
            v,
            sigma: sv[1] / sv[0],
        })
    }

    fn diag(&self) -> Matrix3<f64> {
        Matrix3::from_diagonal(&Vector3::new(1.0, self.sigma, 0.0))
    }
}

impl EpipolarManifold<7> for RankTwo {
    fn matrix(&self) -> Matrix3<f64> {
        self.u * self.diag() * self.v.transpose()
    }

    fn tangents(&self) -> [Matrix3<f64>; 7] {
        let d = self.diag();
        let vt = self.v.transpose();
        std::array::from_fn(|k| match k {
            0..3 => self.u * skew(&Vector3::ith(k, 1.0)) * d * vt,
            3..6 => -(self.u * d * skew(&Vector3::ith(k - 3, 1.0)) * vt),
            _ => self.u * Matrix3::from_diagonal(&Vector3::new(0.0, 1.0, 0.0)) * vt,
        })
    }

    fn retract(&self, delta: &SVector<f64, 7>) -> Self {
        let a = Vector3::new(delta[0], delta[1], delta[2]);
        let b = Vector3::new(delta[3], delta[4], delta[5]);
        Self {
            u: self.u * so3_exp(&a).to_rotation_matrix().into_inner(),
            v: self.v * so3_exp(&b).to_rotation_matrix().into_inner(),
            sigma: self.sigma + delta[6],
        }
    }
}

/// MSAC cost (sum of truncated squared residuals) of `f` over all correspondences.
fn msac_cost(est: &FundamentalEstimator<'_>, f: &Matrix3<f64>, t2: f64) -> f64 {
    (0..est.len())
        .map(|i| est.residual_squared(f, i).min(t2))
        .sum()
}

/// Refines `f` on `inliers`: linear re-estimate, then LM in Hartley-normalised coordinates.
fn refine(
    x1: &[Point2<f64>],
    x2: &[Point2<f64>],
    f: &Matrix3<f64>,
    inliers: &[usize],
    config: &FundamentalConfig,
) -> Option<Matrix3<f64>> {
    let linear = eight_point_iter(inliers.iter().map(|&i| (x1[i], x2[i]))).unwrap_or(*f);
    if config.refine_iterations == 0 {
        return Some(linear);
    }
    let (t1, s1) = hartley_normalisation(inliers.iter().map(|&i| x1[i]))?;
    let (t2, s2) = hartley_normalisation(inliers.iter().map(|&i| x2[i]))?;
    let n1: Vec<Vector3<f64>> = x1.iter().map(|p| t1 * p.to_homogeneous()).collect();
    let n2: Vec<Vector3<f64>> = x2.iter().map(|p| t2 * p.to_homogeneous()).collect();
    let scale = PixelScale {
        w1: [s1 * s1, s1 * s1],
        w2: [s2 * s2, s2 * s2],
    };
    // F = T2ᵀ Fn T1  ⇔  Fn = T2⁻ᵀ F T1⁻¹.
    let fn0 = t2.try_inverse()?.transpose() * linear * t1.try_inverse()?;
    let start = RankTwo::from_matrix(&fn0)?;
    let settings = LmSettings {
        max_iterations: config.refine_iterations,
        kernel: config.refine_kernel,
    };
    let (model, stats) = refine_sampson(start, &n1, &n2, inliers, &scale, &settings);
    debug!(
        initial = stats.initial_cost,
        last = stats.final_cost,
        iterations = stats.iterations,
        "fundamental LM"
    );
    let f = t2.transpose() * model.matrix() * t1;
    let norm = f.norm();
    (norm > 0.0 && norm.is_finite()).then(|| f / norm)
}

/// Robust fundamental matrix: MSAC over 8-point samples, then refinement on the inliers (kept
/// only when it lowers the MSAC cost) and re-classification of the inliers.
pub fn estimate_fundamental(
    x1: &[Point2<f64>],
    x2: &[Point2<f64>],
    config: &FundamentalConfig,
) -> Result<FundamentalResult> {
    let est = FundamentalEstimator::new(x1, x2)?;
    let found = ransac(&est, &config.ransac)?;
    let t2 = config.ransac.threshold * config.ransac.threshold;
    let mut f = found.model;
    let mut inliers = found.inliers;
    let mut cost = msac_cost(&est, &f, t2);
    // Two rounds: the refined model may re-admit inliers the hypothesis was too rough for.
    for _ in 0..2 {
        let Some(candidate) = refine(x1, x2, &f, &inliers, config) else {
            break;
        };
        let candidate_cost = msac_cost(&est, &candidate, t2);
        if candidate_cost >= cost {
            break;
        }
        let new_inliers = inliers_of(&est, &candidate, t2);
        let unchanged = new_inliers == inliers;
        f = candidate;
        cost = candidate_cost;
        inliers = new_inliers;
        if unchanged {
            break;
        }
    }
    config
        .ransac
        .check_consensus(inliers.len(), FundamentalEstimator::SAMPLE_SIZE)?;
    debug!(
        inliers = inliers.len(),
        total = x1.len(),
        iterations = found.iterations,
        "fundamental estimated"
    );
    Ok(FundamentalResult {
        f,
        inliers,
        iterations: found.iterations,
    })
}
