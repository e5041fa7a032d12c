//! A generic, seeded RANSAC driver with MSAC scoring and the adaptive stopping criterion.
//!
//! Every estimator in this crate (homography, fundamental, essential, PnP) plugs into
//! [`ransac`] through [`Estimator`]. The random generator is a ChaCha8 seeded from
//! [`RansacConfig::seed`], so the same input and seed always give the same model and inliers.

use rand::SeedableRng;
use rand::seq::index::sample;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::error::{GeometryError, Result};

/// Parameters of a RANSAC run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RansacConfig {
    /// Inlier threshold on the residual (pixels for image-space errors).
    pub threshold: f64,
    /// Probability of having drawn at least one all-inlier sample when stopping early.
    pub confidence: f64,
    /// Hard cap on the number of hypotheses.
    pub max_iterations: usize,
    /// Hypotheses drawn before early stopping is allowed.
    pub min_iterations: usize,
    /// Minimum number of inliers for a model to be accepted.
    pub min_inliers: usize,
    /// Seed of the sampler.
    pub seed: u64,
}

impl Default for RansacConfig {
    fn default() -> Self {
        Self {
            threshold: 3.0,
            confidence: 0.999,
            max_iterations: 2000,
            min_iterations: 10,
            min_inliers: 0,
            seed: 0,
        }
    }
}

impl RansacConfig {
    /// Fails with [`GeometryError::NoConsensus`] when `inliers` is below `min_inliers` (and
    /// never below the minimal sample); estimators call it again after refining on inliers.
    pub fn check_consensus(&self, inliers: usize, sample_size: usize) -> Result<()> {
        let required = self.min_inliers.max(sample_size);
        if inliers < required {
            return Err(GeometryError::NoConsensus { inliers, required });
        }
        Ok(())
    }

    /// Checks ranges; every estimator calls this before sampling.
    pub fn validate(&self) -> Result<()> {
        if !(self.threshold.is_finite() && self.threshold > 0.0) {
            return Err(GeometryError::InvalidConfig {
                field: "threshold",
                value: self.threshold.to_string(),
                reason: "must be finite and > 0",
            });
        }
        if !(self.confidence > 0.0 && self.confidence < 1.0) {
            return Err(GeometryError::InvalidConfig {
                field: "confidence",
                value: self.confidence.to_string(),
                reason: "must be in (0, 1)",
            });
        }
        if self.max_iterations == 0 {
            return Err(GeometryError::InvalidConfig {
                field: "max_iterations",
                value: "0".into(),
                reason: "must be > 0",
            });
        }
        Ok(())
    }
}

/// A model family that RANSAC can fit.
pub trait Estimator {
    /// The fitted model.
    type Model: Clone;
    /// Size of a minimal sample.
    const SAMPLE_SIZE: usize;
    /// Number of data points.
    fn len(&self) -> usize;
    /// True when there is no data.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Models consistent with the minimal sample (zero, one or several solutions).
    fn fit(&self, sample: &[usize]) -> Vec<Self::Model>;
    /// Squared residual of data point `index` under `model`, in squared threshold units.
    fn residual_squared(&self, model: &Self::Model, index: usize) -> f64;
}

/// The outcome of a RANSAC run.
#[derive(Debug, Clone)]
pub struct RansacResult<M> {
    /// The best hypothesis (not yet refined on its inliers).
    pub model: M,
    /// Indices of the inliers of `model`, ascending.
    pub inliers: Vec<usize>,
    /// Number of hypotheses drawn.
    pub iterations: usize,
}

/// Number of samples needed to reach `confidence` with inlier ratio `w` and sample size `m`.
pub fn required_iterations(confidence: f64, inlier_ratio: f64, sample_size: usize) -> usize {
    let p_good = inlier_ratio.powi(sample_size as i32);
    if p_good <= f64::EPSILON {
        return usize::MAX;
    }
    if p_good >= 1.0 - f64::EPSILON {
        return 1;
    }
    let n = (1.0 - confidence).ln() / (1.0 - p_good).ln();
    if n.is_finite() {
        n.ceil().max(1.0) as usize
    } else {
        usize::MAX
    }
}

/// Runs RANSAC with MSAC scoring (truncated quadratic cost) and adaptive termination.
pub fn ransac<E: Estimator>(
    estimator: &E,
    config: &RansacConfig,
) -> Result<RansacResult<E::Model>> {
    config.validate()?;
    let n = estimator.len();
    if n < E::SAMPLE_SIZE {
        return Err(GeometryError::TooFewPoints {
            required: E::SAMPLE_SIZE,
            found: n,
        });
    }
    let t2 = config.threshold * config.threshold;
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    let mut best: Option<(f64, E::Model, usize)> = None;
    let mut needed = config.max_iterations;
    let mut iterations = 0;
    let mut sample_buf = Vec::with_capacity(E::SAMPLE_SIZE);
    while iterations < needed.max(config.min_iterations).min(config.max_iterations) {
        iterations += 1;
        sample_buf.clear();
        sample_buf.extend(sample(&mut rng, n, E::SAMPLE_SIZE));
        for model in estimator.fit(&sample_buf) {
            let mut cost = 0.0;
            let mut count = 0;
            let best_cost = best.as_ref().map_or(f64::INFINITY, |b| b.0);
            for i in 0..n {
                let r2 = estimator.residual_squared(&model, i);
                if r2 < t2 {
                    cost += r2;
                    count += 1;
                } else {
                    cost += t2;
                }
                if cost >= best_cost {
                    break;
                }
            }
            if cost < best_cost {
                needed =
                    required_iterations(config.confidence, count as f64 / n as f64, E::SAMPLE_SIZE);
                best = Some((cost, model, count));
            }
        }
    }
    let Some((_, model, _)) = best else {
        return Err(GeometryError::NoConsensus {
            inliers: 0,
            required: config.min_inliers.max(E::SAMPLE_SIZE),
        });
    };
    let inliers = inliers_of(estimator, &model, t2);
    config.check_consensus(inliers.len(), E::SAMPLE_SIZE)?;
    Ok(RansacResult {
        model,
        inliers,
        iterations,
    })
}

/// Indices whose squared residual under `model` is below `threshold_squared`, ascending.
pub fn inliers_of<E: Estimator>(
    estimator: &E,
    model: &E::Model,
    threshold_squared: f64,
) -> Vec<usize> {
    (0..estimator.len())
        .filter(|&i| estimator.residual_squared(model, i) < threshold_squared)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::Rng;

    /// A 2-D line `y = a x + b` fitted from two points.
    struct Line<'a>(&'a [(f64, f64)]);

    impl Estimator for Line<'_> {
        type Model = (f64, f64);
        const SAMPLE_SIZE: usize = 2;
        fn len(&self) -> usize {
            self.0.len()
        }
        fn fit(&self, s: &[usize]) -> Vec<(f64, f64)> {
            let ((x0, y0), (x1, y1)) = (self.0[s[0]], self.0[s[1]]);
            if (x1 - x0).abs() < 1e-12 {
                return vec![];
            }
            let a = (y1 - y0) / (x1 - x0);
            vec![(a, y0 - a * x0)]
        }
        fn residual_squared(&self, m: &(f64, f64), i: usize) -> f64 {
            let (x, y) = self.0[i];
            (y - m.0 * x - m.1).powi(2)
        }
    }

    fn data(seed: u64) -> Vec<(f64, f64)> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..200)
            .map(|i| {
                let x = i as f64 * 0.1;
                if i % 3 == 0 {
                    (x, rng.random_range(-50.0..50.0))
                } else {
                    (x, 2.0 * x - 1.0 + rng.random_range(-0.01..0.01))
                }
            })
            .collect()
    }

    #[test]
    fn finds_line_among_outliers_and_is_reproducible() {
        let pts = data(7);
        let cfg = RansacConfig {
            threshold: 0.05,
            seed: 42,
            ..Default::default()
        };
        let a = ransac(&Line(&pts), &cfg).unwrap();
        let b = ransac(&Line(&pts), &cfg).unwrap();
        assert_eq!(a.inliers, b.inliers);
        assert_eq!(a.iterations, b.iterations);
        assert!((a.model.0 - 2.0).abs() < 0.01 && (a.model.1 + 1.0).abs() < 0.1);
        assert!(a.inliers.len() >= 130);
        assert!(
            a.iterations < 100,
            "adaptive stop should kick in, took {}",
            a.iterations
        );
    }

    #[test]
    fn reports_too_few_points_and_bad_config() {
        let pts = [(0.0, 0.0)];
        assert!(matches!(
            ransac(&Line(&pts), &RansacConfig::default()),
            Err(GeometryError::TooFewPoints {
                required: 2,
                found: 1
            })
        ));
        let cfg = RansacConfig {
            confidence: 1.0,
            ..Default::default()
        };
        assert!(matches!(
            ransac(&Line(&data(1)), &cfg),
            Err(GeometryError::InvalidConfig { .. })
        ));
    }

    #[test]
    fn iteration_formula() {
        assert_eq!(required_iterations(0.99, 1.0, 4), 1);
        assert_eq!(required_iterations(0.99, 0.5, 4), 72);
        assert_eq!(required_iterations(0.99, 0.0, 4), usize::MAX);
    }
}
