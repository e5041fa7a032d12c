//! The Sampson distance (first-order geometric error of an epipolar constraint) and a
//! Levenberg-Marquardt refinement of an epipolar matrix that minimises it.
//!
//! Both the fundamental and the essential pipeline measure errors in pixels; they differ only in
//! the coordinates the matrix acts on (Hartley-normalised pixels, normalised camera rays) and in
//! how the matrix is parameterised. [`PixelScale`] carries the chain rule from those coordinates
//! back to pixels; [`EpipolarManifold`] carries the parameterisation.

use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

use crate::robust::RobustKernel;

/// Squared factors turning gradients in the model's coordinates into pixel units: if a pixel
/// coordinate `u = x / s + c` then `∂/∂u = s ∂/∂x` and the factor is `s²`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct PixelScale {
    /// Factors for the x and y coordinates of image 1.
    pub w1: [f64; 2],
    /// Factors for the x and y coordinates of image 2.
    pub w2: [f64; 2],
}

impl PixelScale {
    /// Coordinates already in pixels.
    pub const PIXELS: Self = Self {
        w1: [1.0, 1.0],
        w2: [1.0, 1.0],
    };

    /// Normalised camera coordinates of a pinhole with focal lengths `fx`, `fy`.
    pub fn focal(fx: f64, fy: f64) -> Self {
        let w = [1.0 / (fx * fx), 1.0 / (fy * fy)];
        Self { w1: w, w2: w }
    }
}

/// Squared Sampson distance of `x2ᵀ M x1 = 0` in squared pixels (∞ when the gradient vanishes
/// but the constraint does not hold).
#[inline]
pub(crate) fn sampson_squared(
    m: &Matrix3<f64>,
    x1: &Vector3<f64>,
    x2: &Vector3<f64>,
    s: &PixelScale,
) -> f64 {
    let a = m * x1; // gradient of the constraint w.r.t. x2
    let b = m.tr_mul(x2); // gradient w.r.t. x1
    let e = x2.dot(&a);
    let d = s.w1[0] * b.x * b.x + s.w1[1] * b.y * b.y + s.w2[0] * a.x * a.x + s.w2[1] * a.y * a.y;
    if d > 0.0 {
        e * e / d
    } else if e == 0.0 {
        0.0
    } else {
        f64::INFINITY
    }
}

/// Signed Sampson residual `r = e / √D` (pixels) and `∂r/∂M`; `None` when `D` vanishes.
pub(crate) fn sampson_residual_gradient(
    m: &Matrix3<f64>,
    x1: &Vector3<f64>,
    x2: &Vector3<f64>,
    s: &PixelScale,
) -> Option<(f64, Matrix3<f64>)> {
    let a = m * x1;
    let b = m.tr_mul(x2);
    let e = x2.dot(&a);
    let d = s.w1[0] * b.x * b.x + s.w1[1] * b.y * b.y + s.w2[0] * a.x * a.x + s.w2[1] * a.y * a.y;
    if d.is_nan() || d <= 1e-300 {
        return None;
    }
    let inv_sqrt_d = 1.0 / d.sqrt();
    let r = e * inv_sqrt_d;
    // ∂D/∂M = 2 (w2∘a) x1ᵀ + 2 x2 (w1∘b)ᵀ, with the third components weighted by zero.
    let wa = Vector3::new(s.w2[0] * a.x, s.w2[1] * a.y, 0.0);
    let wb = Vector3::new(s.w1[0] * b.x, s.w1[1] * b.y, 0.0);
    let d_d = 2.0 * (wa * x1.transpose() + x2 * wb.transpose());
    let grad = x2 * x1.transpose() * inv_sqrt_d - d_d * (0.5 * r / d);
    Some((r, grad))
}

/// A minimal parameterisation of an epipolar matrix, linearised around the current estimate.
pub(crate) trait EpipolarManifold<const K: usize>: Sized {
    /// The 3×3 matrix `M` of `x2ᵀ M x1 = 0`.
    fn matrix(&self) -> Matrix3<f64>;
    /// `∂M/∂δ_k` at `δ = 0` for each tangent direction.
    fn tangents(&self) -> [Matrix3<f64>; K];
    /// The model moved by the tangent step `δ`.
    fn retract(&self, delta: &SVector<f64, K>) -> Self;
}

/// Settings of the Sampson Levenberg-Marquardt refinement.
#[derive(Debug, Clone, Copy)]
pub(crate) struct LmSettings {
    pub max_iterations: usize,
    pub kernel: RobustKernel,
}

/// Outcome of [`refine_sampson`].
#[derive(Debug, Clone, Copy)]
pub(crate) struct LmStats {
    pub initial_cost: f64,
    pub final_cost: f64,
    pub iterations: usize,
}

fn robust_cost<const K: usize, M: EpipolarManifold<K>>(
    model: &M,
    x1: &[Vector3<f64>],
    x2: &[Vector3<f64>],
    idx: &[usize],
    s: &PixelScale,
    kernel: &RobustKernel,
) -> f64 {
    let m = model.matrix();
    idx.iter()
        .map(|&i| kernel.rho(sampson_squared(&m, &x1[i], &x2[i], s)))
        .sum()
}

/// Minimises `Σ ρ(r_i²)` over the points `idx` with Levenberg-Marquardt (IRLS weights for the
/// robust kernel). Never returns a model with a higher cost than the input.
pub(crate) fn refine_sampson<const K: usize, M: EpipolarManifold<K>>(
    model: M,
    x1: &[Vector3<f64>],
    x2: &[Vector3<f64>],
    idx: &[usize],
    s: &PixelScale,
    settings: &LmSettings,
) -> (M, LmStats) {
    let kernel = &settings.kernel;
    let mut model = model;
    let mut cost = robust_cost(&model, x1, x2, idx, s, kernel);
    let initial_cost = cost;
    // One cost evaluation per iteration: a rejected step only raises the damping.
    let mut lambda = 1e-4;
    let mut iterations = 0;
    let mut linearised: Option<(SMatrix<f64, K, K>, SVector<f64, K>)> = None;
    while iterations < settings.max_iterations && cost.is_finite() && cost > 0.0 {
        iterations += 1;
        let (h, g) = *linearised.get_or_insert_with(|| {
            let m = model.matrix();
            let tangents = model.tangents();
            let mut h = SMatrix::<f64, K, K>::zeros();
            let mut g = SVector::<f64, K>::zeros();
            for &i in idx {
                if let Some((r, grad)) = sampson_residual_gradient(&m, &x1[i], &x2[i], s) {
                    let w = kernel.weight(r * r);
                    let j = SVector::<f64, K>::from_fn(|k, _| grad.dot(&tangents[k]));
                    h += (w * j) * j.transpose();
                    g += (w * r) * j;
                }
            }
            (h, g)
        });
        let mut damped = h;
        for k in 0..K {
            damped[(k, k)] += lambda * h[(k, k)].max(1e-12);
        }
        let Some(step) = damped.cholesky().map(|c| -c.solve(&g)) else {
            lambda *= 10.0;
            continue;
        };
        if step.norm() <= 1e-12 {
            break;
        }
        let candidate = model.retract(&step);
        let new_cost = robust_cost(&candidate, x1, x2, idx, s, kernel);
        if new_cost < cost {
            let decrease = cost - new_cost;
            model = candidate;
            cost = new_cost;
            lambda = (lambda * 0.1).max(1e-12);
            linearised = None;
            if decrease <= 1e-12 * cost {
                break;
            }
        } else if lambda > 1e12 {
            break;
        } else {
            lambda *= 10.0;
        }
    }
    (
        model,
        LmStats {
            initial_cost,
            final_cost: cost,
            iterations,
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gradient_matches_central_differences() {
        let m = Matrix3::new(0.1, -0.7, 0.3, 0.5, 0.05, -0.9, -0.2, 0.8, 0.02);
        let x1 = Vector3::new(0.12, -0.3, 1.0);
        let x2 = Vector3::new(-0.2, 0.25, 1.0);
        for s in [PixelScale::PIXELS, PixelScale::focal(500.0, 450.0)] {
            let (r, grad) = sampson_residual_gradient(&m, &x1, &x2, &s).unwrap();
            assert!((r * r - sampson_squared(&m, &x1, &x2, &s)).abs() < 1e-12 * (1.0 + r * r));
            for i in 0..3 {
                for j in 0..3 {
                    let h = 1e-6;
                    let (mut mp, mut mm) = (m, m);
                    mp[(i, j)] += h;
                    mm[(i, j)] -= h;
                    let num = (sampson_residual_gradient(&mp, &x1, &x2, &s).unwrap().0
                        - sampson_residual_gradient(&mm, &x1, &x2, &s).unwrap().0)
                        / (2.0 * h);
                    let rel = (num - grad[(i, j)]).abs() / grad.norm().max(1e-12);
                    assert!(rel < 1e-6, "({i},{j}): {num} vs {}", grad[(i, j)]);
                }
            }
        }
    }

    #[test]
    fn vanishing_gradient_is_handled() {
        let z = Matrix3::zeros();
        let x = Vector3::new(0.0, 0.0, 1.0);
        assert_eq!(sampson_squared(&z, &x, &x, &PixelScale::PIXELS), 0.0);
        assert!(sampson_residual_gradient(&z, &x, &x, &PixelScale::PIXELS).is_none());
    }
}
