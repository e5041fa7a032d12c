//! Summary statistics of an error array, computed as evo computes them (numpy semantics:
//! population standard deviation, median averaging the two middle values).

use serde::{Deserialize, Serialize};

use crate::error::{EvalError, Result};

/// evo's statistics of one error array.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Statistics {
    /// `sqrt(mean(e²))`.
    pub rmse: f64,
    /// Arithmetic mean.
    pub mean: f64,
    /// Median (mean of the two middle values for an even count).
    pub median: f64,
    /// Population standard deviation (`numpy.std`, ddof = 0).
    pub std: f64,
    /// Smallest error.
    pub min: f64,
    /// Largest error.
    pub max: f64,
    /// Sum of squared errors.
    pub sse: f64,
    /// Number of errors.
    pub count: usize,
}

impl Statistics {
    /// Statistics of `errors`; fails on an empty or non-finite array.
    pub fn from_errors(errors: &[f64]) -> Result<Self> {
        if errors.is_empty() {
            return Err(EvalError::Empty);
        }
        if errors.iter().any(|e| !e.is_finite()) {
            return Err(jointloc_geometry::GeometryError::NonFinite("error array").into());
        }
        let n = errors.len() as f64;
        let sse: f64 = errors.iter().map(|e| e * e).sum();
        let mean = errors.iter().sum::<f64>() / n;
        let var = errors.iter().map(|e| (e - mean) * (e - mean)).sum::<f64>() / n;
        let mut sorted = errors.to_vec();
        sorted.sort_by(f64::total_cmp);
        let mid = sorted.len() / 2;
        let median = if sorted.len() % 2 == 1 {
            sorted[mid]
        } else {
            (sorted[mid - 1] + sorted[mid]) / 2.0
        };
        Ok(Self {
            rmse: (sse / n).sqrt(),
            mean,
            median,
            std: var.sqrt(),
            min: sorted[0],
            max: sorted[sorted.len() - 1],
            sse,
            count: errors.len(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_numpy_definitions() {
        let s = Statistics::from_errors(&[3.0, 1.0, 4.0, 1.0, 5.0, 9.0]).unwrap();
        assert_eq!(s.median, 3.5);
        assert_eq!(s.min, 1.0);
        assert_eq!(s.max, 9.0);
        assert_eq!(s.sse, 133.0);
        assert!((s.mean - 23.0 / 6.0).abs() < 1e-15);
        assert!((s.rmse - (133.0f64 / 6.0).sqrt()).abs() < 1e-15);
        // numpy.std([3,1,4,1,5,9]) = 2.733536577809454
        assert!((s.std - 2.733536577809454).abs() < 1e-15);
        let odd = Statistics::from_errors(&[2.0, 7.0, 1.0]).unwrap();
        assert_eq!(odd.median, 2.0);
        assert_eq!(odd.count, 3);
        assert!(Statistics::from_errors(&[]).is_err());
        assert!(Statistics::from_errors(&[1.0, f64::NAN]).is_err());
    }
}
