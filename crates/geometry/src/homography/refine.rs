//! Levenberg–Marquardt refinement of a homography on its inliers.
//!
//! The cost is the symmetric transfer error `Σᵢ ‖π(H sᵢ) − dᵢ‖² + ‖π(H⁻¹ dᵢ) − sᵢ‖²` over the
//! eight free entries of `H` (row-major, `H[2][2] = 1`). The optimisation runs in Hartley-normalised
//! coordinates, where `H̃[2][2] = 1` is safe (the inlier centroid maps to a finite point) and the
//! eight parameters have comparable scales; the residuals are rescaled to pixels so that the cost
//! is exactly the pixel cost.

use nalgebra::{Matrix2x3, Matrix3, Point2, SMatrix, SVector, Vector2, Vector3, Vector4};

use super::dlt::{Normalisation, normalise_scale};

/// Jacobian of a 4-vector residual wrt the 8 homography parameters.
pub type Matrix4x8 = SMatrix<f64, 4, 8>;
type Vector8 = SVector<f64, 8>;
type Matrix8 = SMatrix<f64, 8, 8>;

/// `M · ∂(H v)/∂h` for a 2×3 `M`, where `∂(H v)/∂h = [vᵀ 0 0; 0 vᵀ 0; 0 0 v₁ v₂]` over the eight
/// free entries; written out to skip the structural zeros.
fn times_dhv_dh(m: &Matrix2x3<f64>, v: &Vector3<f64>) -> SMatrix<f64, 2, 8> {
    let mut j = SMatrix::<f64, 2, 8>::zeros();
    for r in 0..2 {
        for c in 0..3 {
            j[(r, c)] = m[(r, 0)] * v[c];
            j[(r, 3 + c)] = m[(r, 1)] * v[c];
        }
        j[(r, 6)] = m[(r, 2)] * v[0];
        j[(r, 7)] = m[(r, 2)] * v[1];
    }
    j
}

/// `π(p)` and `∂π/∂p` for `π(p) = (p₁/p₃, p₂/p₃)`; `None` at infinity.
fn project(p: &Vector3<f64>) -> Option<(Vector2<f64>, Matrix2x3<f64>)> {
    let iw = 1.0 / p.z;
    let (u, v) = (p.x * iw, p.y * iw);
    (iw.is_finite() && u.is_finite() && v.is_finite()).then(|| {
        (
            Vector2::new(u, v),
            Matrix2x3::new(iw, 0.0, -u * iw, 0.0, iw, -v * iw),
        )
    })
}

/// Residual `[π(H s) − d; π(H⁻¹ d) − s]` and its Jacobian wrt the eight parameters, given
/// `h_inv = H⁻¹` exactly (`∂H⁻¹ = −H⁻¹ ∂H H⁻¹`).
fn residual_and_jacobian(
    h: &Matrix3<f64>,
    h_inv: &Matrix3<f64>,
    s: &Vector2<f64>,
    d: &Vector2<f64>,
) -> Option<(Vector4<f64>, Matrix4x8)> {
    let xs = s.push(1.0);
    let xd = d.push(1.0);
    let (fwd, dpf) = project(&(h * xs))?;
    let y = h_inv * xd;
    let (bwd, dpb) = project(&y)?;
    let jf = times_dhv_dh(&dpf, &xs);
    let jb = times_dhv_dh(&-(dpb * h_inv), &y);
    let mut r = Vector4::zeros();
    r.fixed_rows_mut::<2>(0).copy_from(&(fwd - d));
    r.fixed_rows_mut::<2>(2).copy_from(&(bwd - s));
    let mut j = Matrix4x8::zeros();
    j.fixed_rows_mut::<2>(0).copy_from(&jf);
    j.fixed_rows_mut::<2>(2).copy_from(&jb);
    Some((r, j))
}

/// Symmetric transfer residual `[π(H s) − d; π(H⁻¹ d) − s]` (pixels) and its analytic Jacobian
/// wrt `(h₁₁, h₁₂, h₁₃, h₂₁, h₂₂, h₂₃, h₃₁, h₃₂)` with `h₃₃` held fixed. `None` when `H` is
/// singular or a point maps to infinity.
pub fn symmetric_transfer_jacobian(
    h: &Matrix3<f64>,
    src: &Point2<f64>,
    dst: &Point2<f64>,
) -> Option<(Vector4<f64>, Matrix4x8)> {
    residual_and_jacobian(h, &h.try_inverse()?, &src.coords, &dst.coords)
}

fn params(h: &Matrix3<f64>) -> Vector8 {
    Vector8::from([
        h[(0, 0)],
        h[(0, 1)],
        h[(0, 2)],
        h[(1, 0)],
        h[(1, 1)],
        h[(1, 2)],
        h[(2, 0)],
        h[(2, 1)],
    ])
}

fn from_params(p: &Vector8) -> Matrix3<f64> {
    Matrix3::new(p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], 1.0)
}

/// Normalised correspondences plus the per-direction factor back to pixels.
struct Problem {
    s: Vec<Vector2<f64>>,
    d: Vec<Vector2<f64>>,
    /// Residual block weights `[1/scale_dst², 1/scale_src²]` turning squared normalised errors into
    /// squared pixels.
    w: Vector4<f64>,
    /// Per-correspondence weights (IRLS), parallel to `s` and `d`; empty for all ones.
    k: Vec<f64>,
}

impl Problem {
    /// Cost (squared pixels, summed over both directions) and, optionally, normal equations.
    fn evaluate(&self, p: &Vector8, normal: Option<(&mut Matrix8, &mut Vector8)>) -> Option<f64> {
        let h = from_params(p);
        let h_inv = h.try_inverse()?;
        let mut cost = 0.0;
        match normal {
            None => {
                for (i, (s, d)) in self.s.iter().zip(&self.d).enumerate() {
                    let f = project(&(h * s.push(1.0)))?.0 - d;
                    let b = project(&(h_inv * d.push(1.0)))?.0 - s;
                    cost += self.weight(i)
                        * (self.w[0] * f.norm_squared() + self.w[2] * b.norm_squared());
                }
            }
            Some((jtj, jtr)) => {
                jtj.fill(0.0);
                jtr.fill(0.0);
                for (i, (s, d)) in self.s.iter().zip(&self.d).enumerate() {
                    let (r, j) = residual_and_jacobian(&h, &h_inv, s, d)?;
                    let w = self.w * self.weight(i);
                    let wr = r.component_mul(&w);
                    cost += r.dot(&wr);
                    // Upper triangle of JᵀWJ by hand: nalgebra's generic 8×4·4×8 product
                    // dominated the whole estimation.
                    for k in 0..4 {
                        for a in 0..8 {
                            let wja = w[k] * j[(k, a)];
                            jtr[a] += wja * r[k];
                            for b in a..8 {
                                jtj[(a, b)] += wja * j[(k, b)];
                            }
                        }
                    }
                }
                jtj.fill_lower_triangle_with_upper_triangle();
            }
        }
        cost.is_finite().then_some(cost)
    }

    fn weight(&self, i: usize) -> f64 {
        self.k.get(i).copied().unwrap_or(1.0)
    }
}

/// Outcome of [`refine_homography`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Refinement {
    /// The refined homography in pixels, scaled as in the module docs.
    pub h: Matrix3<f64>,
    /// Summed symmetric cost `Σ ‖e_fwd‖² + ‖e_bwd‖²` of the start, squared pixels.
    pub initial_cost: f64,
    /// The same cost at the returned `h`.
    pub final_cost: f64,
    /// Accepted Levenberg–Marquardt steps.
    pub iterations: usize,
}

/// Minimises the symmetric transfer error of `h` over the correspondences `idx` with
/// Levenberg–Marquardt (Marquardt's diagonal damping). Returns `None` when the problem is
/// degenerate (fewer than 4 points, coincident points, singular `h`); the caller then keeps its
/// unrefined estimate.
pub fn refine_homography(
    h: &Matrix3<f64>,
    src: &[Point2<f64>],
    dst: &[Point2<f64>],
    idx: &[usize],
    max_iterations: usize,
) -> Option<Refinement> {
    refine(h, src, dst, idx, Vec::new(), max_iterations)
}

/// [`refine_homography`] with a weight per correspondence (`weights[k]` for `idx[k]`, finite
/// and ≥ 0): the cost is `Σₖ weights[k] · (‖e_fwd‖² + ‖e_bwd‖²)`, one step of iteratively
/// reweighted least squares. `None` also when the lengths differ, a weight is invalid, or fewer
/// than 4 weights are positive.
pub fn refine_homography_weighted(
    h: &Matrix3<f64>,
    src: &[Point2<f64>],
    dst: &[Point2<f64>],
    idx: &[usize],
    weights: &[f64],
    max_iterations: usize,
) -> Option<Refinement> {
    let valid = weights.len() == idx.len() && weights.iter().all(|w| w.is_finite() && *w >= 0.0);
    if !valid || weights.iter().filter(|w| **w > 0.0).count() < 4 {
        return None;
    }
    refine(h, src, dst, idx, weights.to_vec(), max_iterations)
}

fn refine(
    h: &Matrix3<f64>,
    src: &[Point2<f64>],
    dst: &[Point2<f64>],
    idx: &[usize],
    k: Vec<f64>,
    max_iterations: usize,
) -> Option<Refinement> {
    if idx.len() < 4 {
        return None;
    }
    let ns = Normalisation::of(src, idx)?;
    let nd = Normalisation::of(dst, idx)?;
    let hn = nd.matrix() * h * ns.inverse_matrix();
    let hn22 = hn[(2, 2)];
    let representable = hn.iter().all(|v| v.is_finite()) && hn22.abs() > 1e-12 * hn.norm();
    if !representable {
        return None;
    }
    let problem = Problem {
        s: idx.iter().map(|&i| ns.apply(&src[i])).collect(),
        d: idx.iter().map(|&i| nd.apply(&dst[i])).collect(),
        w: {
            let (a, b) = (1.0 / (nd.scale * nd.scale), 1.0 / (ns.scale * ns.scale));
            Vector4::new(a, a, b, b)
        },
        k,
    };
    let mut p = params(&(hn / hn22));
    let mut jtj = Matrix8::zeros();
    let mut jtr = Vector8::zeros();
    let initial_cost = problem.evaluate(&p, Some((&mut jtj, &mut jtr)))?;
    let mut cost = initial_cost;
    let mut lambda = 1e-4;
    let mut iterations = 0;
    // Stops on a relative cost decrease or step below `TOL`: once the cost is at its rounding
    // floor, further trials would only raise the damping through a string of rejected steps.
    const TOL: f64 = 1e-10;
    'outer: while iterations < max_iterations {
        loop {
            let mut a = jtj;
            for k in 0..8 {
                a[(k, k)] += lambda * jtj[(k, k)].max(1e-12);
            }
            let step = a.cholesky().map(|c| c.solve(&-jtr));
            let Some(step) = step.filter(|s| s.iter().all(|v| v.is_finite())) else {
                lambda *= 10.0;
                if lambda > 1e10 {
                    break 'outer;
                }
                continue;
            };
            if step.norm() <= TOL * p.norm() {
                break 'outer;
            }
            let candidate = p + step;
            match problem.evaluate(&candidate, None) {
                Some(c) if c < cost => {
                    let converged = cost - c <= TOL * cost;
                    p = candidate;
                    iterations += 1;
                    lambda = (lambda * 0.1).max(1e-12);
                    cost = problem.evaluate(&p, Some((&mut jtj, &mut jtr)))?;
                    if converged {
                        break 'outer;
                    }
                    break;
                }
                _ => {
                    lambda *= 10.0;
                    if lambda > 1e10 {
                        break 'outer;
                    }
                }
            }
        }
    }
    let h = normalise_scale(&(nd.inverse_matrix() * from_params(&p) * ns.matrix()))?;
    Some(Refinement {
        h,
        initial_cost,
        final_cost: cost,
        iterations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn analytic_jacobian_matches_central_differences() {
        for seed in 0..20 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let mut r = || rng.random_range(-1.0..1.0);
            let h = Matrix3::new(
                1.0 + 0.2 * r(),
                0.2 * r(),
                30.0 * r(),
                0.2 * r(),
                1.0 + 0.2 * r(),
                30.0 * r(),
                4e-4 * r(),
                4e-4 * r(),
                1.0,
            );
            let s = Point2::new(rng.random_range(0.0..500.0), rng.random_range(0.0..500.0));
            let d = Point2::new(rng.random_range(0.0..500.0), rng.random_range(0.0..500.0));
            let (_, j) = symmetric_transfer_jacobian(&h, &s, &d).unwrap();
            let p0 = params(&h);
            for k in 0..8 {
                let eps = 1e-6 * p0[k].abs().max(1e-4);
                let mut pp = p0;
                let mut pm = p0;
                pp[k] += eps;
                pm[k] -= eps;
                let (rp, _) = symmetric_transfer_jacobian(&from_params(&pp), &s, &d).unwrap();
                let (rm, _) = symmetric_transfer_jacobian(&from_params(&pm), &s, &d).unwrap();
                let numeric = (rp - rm) / (2.0 * eps);
                let analytic = j.column(k);
                let err = (numeric - analytic).norm();
                assert!(
                    err <= 1e-6 * analytic.norm().max(1e-12),
                    "seed {seed} param {k}: analytic {analytic} numeric {numeric}"
                );
            }
        }
    }

    #[test]
    fn weights_scale_each_correspondence_and_zero_drops_it() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let h = Matrix3::new(0.9, 0.1, 20.0, -0.05, 1.1, -10.0, 1e-4, -2e-4, 1.0);
        let src: Vec<Point2<f64>> = (0..60)
            .map(|_| Point2::new(rng.random_range(0.0..500.0), rng.random_range(0.0..500.0)))
            .collect();
        let mut dst: Vec<Point2<f64>> = src
            .iter()
            .map(|p| {
                let q = crate::homography::transfer_point(&h, p);
                Point2::new(
                    q.x + rng.random_range(-0.5..0.5),
                    q.y + rng.random_range(-0.5..0.5),
                )
            })
            .collect();
        // Ten gross outliers: weight 0 must give the fit of the other fifty alone.
        for q in dst.iter_mut().take(10) {
            q.x += 40.0;
        }
        let all: Vec<usize> = (0..60).collect();
        let clean: Vec<usize> = (10..60).collect();
        let weights: Vec<f64> = all
            .iter()
            .map(|&i| if i < 10 { 0.0 } else { 1.0 })
            .collect();
        let weighted = refine_homography_weighted(&h, &src, &dst, &all, &weights, 50).unwrap();
        let alone = refine_homography(&h, &src, &dst, &clean, 50).unwrap();
        assert!((weighted.h - alone.h).norm() / alone.h.norm() < 1e-8);
        // Uniform weights of 2: the same optimum at twice the cost.
        let twos = vec![2.0; 60];
        let doubled = refine_homography_weighted(&h, &src, &dst, &all, &twos, 50).unwrap();
        let plain = refine_homography(&h, &src, &dst, &all, 50).unwrap();
        assert!((doubled.h - plain.h).norm() / plain.h.norm() < 1e-8);
        assert!((doubled.final_cost - 2.0 * plain.final_cost).abs() < 1e-6 * plain.final_cost);
        // Invalid weights or too few positive ones: no refinement.
        let mut bad = weights.clone();
        bad[20] = f64::NAN;
        assert!(refine_homography_weighted(&h, &src, &dst, &all, &bad, 50).is_none());
        bad[20] = -1.0;
        assert!(refine_homography_weighted(&h, &src, &dst, &all, &bad, 50).is_none());
        assert!(refine_homography_weighted(&h, &src, &dst, &all, &weights[1..], 50).is_none());
        let three: Vec<f64> = (0..60).map(|i| if i < 3 { 1.0 } else { 0.0 }).collect();
        assert!(refine_homography_weighted(&h, &src, &dst, &all, &three, 50).is_none());
    }

    #[test]
    fn refinement_lowers_the_cost_and_keeps_an_exact_fit() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let h = Matrix3::new(0.9, 0.1, 20.0, -0.05, 1.1, -10.0, 1e-4, -2e-4, 1.0);
        let src: Vec<Point2<f64>> = (0..100)
            .map(|_| Point2::new(rng.random_range(0.0..500.0), rng.random_range(0.0..500.0)))
            .collect();
        let dst: Vec<Point2<f64>> = src
            .iter()
            .map(|p| crate::homography::transfer_point(&h, p))
            .collect();
        let idx: Vec<usize> = (0..100).collect();
        // Exact data: the optimum is H itself, and the refinement must stay there.
        let r = refine_homography(&h, &src, &dst, &idx, 20).unwrap();
        assert!((r.h - h).norm() / h.norm() < 1e-12);
        // Perturbed start: the cost must fall to (nearly) zero.
        let mut h0 = h;
        h0[(0, 2)] += 3.0;
        h0[(2, 0)] += 2e-5;
        let r = refine_homography(&h0, &src, &dst, &idx, 50).unwrap();
        assert!(r.initial_cost > 100.0 && r.final_cost < 1e-12, "{r:?}");
        assert!((r.h - h).norm() / h.norm() < 1e-9);
    }
}
