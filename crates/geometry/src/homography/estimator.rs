//! The homography as a RANSAC [`Estimator`], scored by the symmetric transfer error.

use nalgebra::{Matrix3, Point2, Vector2};

use super::dlt::{dlt_indices, minimal_homography};
use crate::error::Result;
use crate::ransac::Estimator;

/// A homography hypothesis with its inverse cached, so that scoring does not invert per point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HomographyModel {
    /// `dst ∝ H src`, scaled as described in the [module docs](super).
    pub h: Matrix3<f64>,
    /// `H⁻¹`.
    pub h_inv: Matrix3<f64>,
}

impl HomographyModel {
    /// Wraps `h`; `None` when it is singular or not finite.
    pub fn new(h: Matrix3<f64>) -> Option<Self> {
        let h_inv = h.try_inverse()?;
        h_inv
            .iter()
            .all(|v| v.is_finite())
            .then_some(Self { h, h_inv })
    }

    /// `½ (‖π(H s) − d‖² + ‖π(H⁻¹ d) − s‖²)` in squared pixels; `+∞` when either point maps to
    /// infinity.
    pub fn symmetric_error_squared(&self, src: &Point2<f64>, dst: &Point2<f64>) -> f64 {
        let f = map(&self.h, src) - dst.coords;
        let b = map(&self.h_inv, dst) - src.coords;
        let e = 0.5 * (f.norm_squared() + b.norm_squared());
        if e.is_finite() { e } else { f64::INFINITY }
    }
}

#[inline]
fn map(h: &Matrix3<f64>, p: &Point2<f64>) -> Vector2<f64> {
    let w = h[(2, 0)] * p.x + h[(2, 1)] * p.y + h[(2, 2)];
    Vector2::new(
        (h[(0, 0)] * p.x + h[(0, 1)] * p.y + h[(0, 2)]) / w,
        (h[(1, 0)] * p.x + h[(1, 1)] * p.y + h[(1, 2)]) / w,
    )
}

/// Homography estimation problem over matched pixels `src[i] ↔ dst[i]`.
///
/// Residual: the mean of the two squared one-way transfer errors,
/// `½ (‖π(H sᵢ) − dᵢ‖² + ‖π(H⁻¹ dᵢ) − sᵢ‖²)`, in squared pixels. Averaging (rather than summing)
/// keeps the RANSAC threshold meaning "pixels of error in one image", while using both
/// directions treats the (equal) noise of both images alike.
#[derive(Debug, Clone, Copy)]
pub struct HomographyEstimator<'a> {
    src: &'a [Point2<f64>],
    dst: &'a [Point2<f64>],
}

impl<'a> HomographyEstimator<'a> {
    /// Checks lengths and finiteness (RANSAC itself checks the count).
    pub fn new(src: &'a [Point2<f64>], dst: &'a [Point2<f64>]) -> Result<Self> {
        super::check_lengths_and_finite(src, dst)?;
        Ok(Self { src, dst })
    }

    /// Normalised DLT on the correspondences `idx` (at least 4).
    pub fn fit_all(&self, idx: &[usize]) -> Result<Matrix3<f64>> {
        dlt_indices(self.src, self.dst, idx)
    }

    pub(crate) fn src(&self) -> &'a [Point2<f64>] {
        self.src
    }

    pub(crate) fn dst(&self) -> &'a [Point2<f64>] {
        self.dst
    }
}

impl Estimator for HomographyEstimator<'_> {
    type Model = HomographyModel;
    const SAMPLE_SIZE: usize = 4;

    fn len(&self) -> usize {
        self.src.len()
    }

    /// Minimal solver for four indices (implausible samples give no model); normalised DLT for
    /// larger samples.
    fn fit(&self, sample: &[usize]) -> Vec<HomographyModel> {
        let h = match *sample {
            [a, b, c, d] => minimal_homography(
                &[self.src[a], self.src[b], self.src[c], self.src[d]],
                &[self.dst[a], self.dst[b], self.dst[c], self.dst[d]],
            ),
            _ => self.fit_all(sample).ok(),
        };
        h.and_then(HomographyModel::new).into_iter().collect()
    }

    fn residual_squared(&self, model: &HomographyModel, index: usize) -> f64 {
        model.symmetric_error_squared(&self.src[index], &self.dst[index])
    }
}
