//! Robust kernels shared by every optimiser (PnP refinement, bundle adjustment, alignment).
//!
//! A kernel maps a squared residual `s = ‖e‖²` to `ρ(s)`; iteratively re-weighted least squares
//! uses the weight `ρ'(s)`. Conventions follow Ceres/g2o: `ρ(s) ≈ s` for small `s`.

use serde::{Deserialize, Serialize};

/// A robust loss on squared residuals.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum RobustKernel {
    /// Plain least squares, `ρ(s) = s`.
    #[default]
    Trivial,
    /// Huber with threshold `delta` on the residual norm: quadratic inside, linear outside.
    Huber { delta: f64 },
    /// Cauchy (Lorentzian) with scale `c`: `ρ(s) = c² ln(1 + s/c²)`.
    Cauchy { c: f64 },
}

impl RobustKernel {
    /// `ρ(s)` for the squared residual `s`.
    pub fn rho(&self, s: f64) -> f64 {
        match *self {
            RobustKernel::Trivial => s,
            RobustKernel::Huber { delta } => {
                let d2 = delta * delta;
                if s <= d2 {
                    s
                } else {
                    2.0 * delta * s.sqrt() - d2
                }
            }
            RobustKernel::Cauchy { c } => {
                let c2 = c * c;
                c2 * (s / c2).ln_1p()
            }
        }
    }

    /// `ρ'(s)`: the IRLS weight of a residual with squared norm `s`, in `(0, 1]`.
    pub fn weight(&self, s: f64) -> f64 {
        match *self {
            RobustKernel::Trivial => 1.0,
            RobustKernel::Huber { delta } => {
                if s <= delta * delta {
                    1.0
                } else {
                    delta / s.sqrt()
                }
            }
            RobustKernel::Cauchy { c } => 1.0 / (1.0 + s / (c * c)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_are_derivatives_of_rho() {
        for k in [
            RobustKernel::Trivial,
            RobustKernel::Huber { delta: 1.5 },
            RobustKernel::Cauchy { c: 0.7 },
        ] {
            for s in [0.01, 0.5, 1.0, 2.0, 9.0, 100.0] {
                let h = 1e-6 * s;
                let numeric = (k.rho(s + h) - k.rho(s - h)) / (2.0 * h);
                assert!(
                    (numeric - k.weight(s)).abs() < 1e-6 * numeric.abs().max(1.0),
                    "{k:?} {s}"
                );
            }
            assert!((k.rho(1e-6) - 1e-6).abs() < 1e-9);
        }
    }

    #[test]
    fn huber_is_continuous_at_threshold() {
        let k = RobustKernel::Huber { delta: 2.0 };
        assert!((k.rho(4.0 - 1e-12) - k.rho(4.0 + 1e-12)).abs() < 1e-9);
    }
}
