//! One query view (the frame at map scale and orientation, with its features) against one tile:
//! match → robust homography → sanity checks. The homography is estimated between the
//! normalised frame and map pixels (both at the map's GSD, so the RANSAC threshold means the
//! same on both sides) and then expressed from frame pixels to map pixels.

use image::GrayImage;
use jointloc_features::{Detector, Features, Matcher, Matches};
use jointloc_geometry::GeometryError;
use jointloc_geometry::homography::{HomographyConfig, estimate_homography};
use nalgebra::{Matrix2, Matrix3, Point2};
use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::tiles::MapTile;
use crate::warp::{Lens, NormalisedFrame, normalise_lens};

/// Acceptance rules for a tile's homography.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AcceptConfig {
    /// Matches needed before a homography is tried.
    pub min_matches: usize,
    /// RANSAC inliers needed for a tile to count.
    pub min_inliers: usize,
    /// Largest `|ln(measured / expected)|` of the frame-to-map scale at the image centre, where
    /// expected = altitude / (focal length · GSD): 0.3 is ±35 %, room for altimeter noise and
    /// relief, none for a wrong tile that matched at another scale.
    pub max_log_scale_error: f64,
    /// Largest ratio of the singular values of the homography's Jacobian at the image centre:
    /// a nadir camera sees the ground almost by a similarity.
    pub max_anisotropy: f64,
    /// Keypoints closer than this (frame pixels) to the frame border are dropped: after
    /// rotation they sit next to the fill and their descriptors see it.
    pub border_margin_px: f64,
    /// A camera with a lens model (a fisheye) is undistorted into the normalised view up to
    /// this angle off the optical axis, degrees: the undistorted periphery grows as `tan θ`
    /// (a 133° fisheye at 66.5° spans 2.3× its focal length either side) while the map tiles
    /// are cut to a pinhole's footprint. No effect on a camera without distortion.
    pub max_off_axis_deg: f64,
}

impl Default for AcceptConfig {
    fn default() -> Self {
        Self {
            min_matches: 12,
            min_inliers: 15,
            max_log_scale_error: 0.3,
            max_anisotropy: 1.5,
            border_margin_px: 8.0,
            max_off_axis_deg: 50.0,
        }
    }
}

/// The frame prepared for one orientation hypothesis.
#[derive(Debug, Clone)]
pub struct QueryView {
    /// The resampled frame.
    pub normalised: NormalisedFrame,
    /// Its features, in normalised pixels (what the matcher sees).
    pub features: Features,
}

impl QueryView {
    /// Resamples `frame` (scale `scale`, rotation `angle` about `centre`) and detects features,
    /// keeping those well inside the frame.
    pub fn new(
        frame: &GrayImage,
        detector: &dyn Detector,
        centre: (f64, f64),
        scale: f64,
        angle: f64,
        border_margin_px: f64,
    ) -> Result<Self> {
        Self::through(
            frame,
            None,
            detector,
            centre,
            scale,
            angle,
            border_margin_px,
            None,
        )
    }

    /// [`QueryView::new`] for a frame seen through `lens` (see [`crate::warp::Lens`]): the
    /// undistortion is folded into the same resampling, and the view's transform acts on
    /// undistorted pixels. `max_size` crops a view larger than it around the frame's centre
    /// (see [`crate::AbsLocConfig::max_view_over_tile`]).
    #[allow(clippy::too_many_arguments)]
    pub fn through(
        frame: &GrayImage,
        lens: Option<Lens>,
        detector: &dyn Detector,
        centre: (f64, f64),
        scale: f64,
        angle: f64,
        border_margin_px: f64,
        max_size: Option<(usize, usize)>,
    ) -> Result<Self> {
        let normalised = normalise_lens(frame, lens, centre, scale, angle, max_size);
        let all = detector.detect(&normalised.image)?;
        let keep: Vec<usize> = (0..all.len())
            .filter(|&i| {
                let [u, v] = all.keypoints[i];
                normalised.inside(u as f64, v as f64, border_margin_px)
            })
            .collect();
        let features = select(&all, &keep);
        Ok(Self {
            normalised,
            features,
        })
    }
}

/// The features at `keep`, in that order.
pub fn select(f: &Features, keep: &[usize]) -> Features {
    let mut out = Features {
        descriptor_dim: f.descriptor_dim,
        image_size: f.image_size,
        ..Default::default()
    };
    for &i in keep {
        out.keypoints.push(f.keypoints[i]);
        out.scores.push(f.scores.get(i).copied().unwrap_or(0.0));
        out.descriptors.extend_from_slice(f.descriptor(i));
    }
    out
}

/// An accepted tile.
#[derive(Debug, Clone)]
pub struct Candidate {
    /// Position in [`crate::MapTiles::tiles`].
    pub tile: usize,
    /// Which query view matched.
    pub view: usize,
    /// Frame pixels → map pixels (undistorted frame pixels for a camera with a lens model:
    /// those of [`jointloc_geometry::PinholeCamera::without_distortion`]).
    pub h_map_from_frame: Matrix3<f64>,
    /// All matches (query index in the view's features, index in the tile's features).
    pub matches: Matches,
    /// Indices into `matches` of the RANSAC inliers.
    pub inliers: Vec<usize>,
    /// RMS symmetric transfer error of the inliers, map pixels.
    pub rms_error: f64,
    /// Frame-to-map scale at the image centre and its rotation (radians, image axes).
    pub scale: f64,
    pub heading: f64,
}

impl Candidate {
    /// Map pixel of frame pixel `(x, y)` (the principal point: the ground point the fix
    /// measures).
    pub fn map_pixel(&self, (x, y): (f64, f64)) -> (f64, f64) {
        let q = self.h_map_from_frame * Point2::new(x, y).to_homogeneous();
        (q.x / q.z, q.y / q.z)
    }
}

/// Why a tile was not accepted.
#[derive(Debug, Clone, PartialEq)]
pub enum Rejection {
    TooFewMatches { matches: usize },
    NoConsensus { inliers: usize },
    TooFewInliers { inliers: usize },
    Scale { measured: f64, expected: f64 },
    Anisotropy { ratio: f64 },
    Folded,
}

/// The Jacobian of `h` at `(x, y)`.
pub fn jacobian(h: &Matrix3<f64>, x: f64, y: f64) -> Option<Matrix2<f64>> {
    let w = h[(2, 0)] * x + h[(2, 1)] * y + h[(2, 2)];
    if w.abs() < 1e-12 {
        return None;
    }
    let u = (h[(0, 0)] * x + h[(0, 1)] * y + h[(0, 2)]) / w;
    let v = (h[(1, 0)] * x + h[(1, 1)] * y + h[(1, 2)]) / w;
    Some(
        Matrix2::new(
            h[(0, 0)] - u * h[(2, 0)],
            h[(0, 1)] - u * h[(2, 1)],
            h[(1, 0)] - v * h[(2, 0)],
            h[(1, 1)] - v * h[(2, 1)],
        ) / w,
    )
}

/// Rotation angle of the best similarity fitting the 2 × 2 map `j` (image axes).
pub fn rotation_of(j: &Matrix2<f64>) -> f64 {
    (j[(1, 0)] - j[(0, 1)]).atan2(j[(0, 0)] + j[(1, 1)])
}

/// Whether `h` maps the frame's corners to a convex quadrilateral of the same orientation.
fn keeps_the_frame_convex(h: &Matrix3<f64>, w: f64, hgt: f64) -> bool {
    let c: Vec<Point2<f64>> = [
        (0.0, 0.0),
        (w - 1.0, 0.0),
        (w - 1.0, hgt - 1.0),
        (0.0, hgt - 1.0),
    ]
    .iter()
    .filter_map(|&(x, y)| {
        let q = h * Point2::new(x, y).to_homogeneous();
        (q.z > 1e-12).then(|| Point2::new(q.x / q.z, q.y / q.z))
    })
    .collect();
    if c.len() != 4 {
        return false;
    }
    (0..4).all(|i| {
        let (a, b, d) = (c[i], c[(i + 1) % 4], c[(i + 2) % 4]);
        let cross = (b - a).perp(&(d - b));
        cross > 0.0
    })
}

/// Inputs shared by every tile of one search.
#[derive(Debug, Clone, Copy)]
pub struct MatchContext<'a> {
    pub matcher: &'a dyn Matcher,
    pub homography: &'a HomographyConfig,
    pub accept: &'a AcceptConfig,
    /// Frame principal point (the image centre mapped to the map is the UAV's position).
    pub principal: (f64, f64),
    /// Expected frame-to-map scale from the altimeter; `None` skips the scale check.
    pub expected_scale: Option<f64>,
}

/// The pixels of `matches`: query keypoints (in the normalised view) and tile keypoints moved
/// into map pixels by the tile's offset.
pub fn matched_points(
    query: &Features,
    tile_features: &Features,
    matches: &Matches,
    tile: &MapTile,
) -> (Vec<Point2<f64>>, Vec<Point2<f64>>) {
    let (ox, oy) = (tile.x as f64, tile.y as f64);
    matches
        .pairs
        .iter()
        .map(|&(i, j)| {
            let (a, b) = (query.keypoints[i], tile_features.keypoints[j]);
            (
                Point2::new(a[0] as f64, a[1] as f64),
                Point2::new(b[0] as f64 + ox, b[1] as f64 + oy),
            )
        })
        .unzip()
}

/// Matches `view` against tile `tile` (features in tile pixels) and checks the homography.
pub fn evaluate(
    ctx: &MatchContext<'_>,
    view_index: usize,
    view: &QueryView,
    tile_index: usize,
    tile: &MapTile,
    tile_features: &Features,
) -> Result<std::result::Result<Candidate, Rejection>> {
    let q = &view.features;
    if q.len() < ctx.accept.min_matches || tile_features.len() < ctx.accept.min_matches {
        return Ok(Err(Rejection::TooFewMatches { matches: 0 }));
    }
    let matches = ctx.matcher.match_features(q, tile_features)?;
    if matches.pairs.len() < ctx.accept.min_matches.max(4) {
        return Ok(Err(Rejection::TooFewMatches {
            matches: matches.pairs.len(),
        }));
    }
    let (src, dst) = matched_points(q, tile_features, &matches, tile);
    let mut cfg = *ctx.homography;
    cfg.ransac.min_inliers = cfg.ransac.min_inliers.max(ctx.accept.min_inliers);
    let est = match estimate_homography(&src, &dst, &cfg) {
        Ok(e) => e,
        Err(GeometryError::NoConsensus { inliers, .. }) => {
            return Ok(Err(Rejection::NoConsensus { inliers }));
        }
        Err(GeometryError::Degenerate(_)) | Err(GeometryError::TooFewPoints { .. }) => {
            return Ok(Err(Rejection::NoConsensus { inliers: 0 }));
        }
        Err(e) => return Err(e.into()),
    };
    if est.inliers.len() < ctx.accept.min_inliers {
        return Ok(Err(Rejection::TooFewInliers {
            inliers: est.inliers.len(),
        }));
    }
    let h = est.h * view.normalised.transform.matrix();
    let (fw, fh) = (
        view.normalised.frame_size.0 as f64,
        view.normalised.frame_size.1 as f64,
    );
    if !keeps_the_frame_convex(&h, fw, fh) {
        return Ok(Err(Rejection::Folded));
    }
    let Some(j) = jacobian(&h, ctx.principal.0, ctx.principal.1) else {
        return Ok(Err(Rejection::Folded));
    };
    let det = j.determinant();
    if det.is_nan() || det <= 0.0 {
        return Ok(Err(Rejection::Folded));
    }
    let sv = j.singular_values();
    let ratio = sv.max() / sv.min().max(1e-300);
    if ratio > ctx.accept.max_anisotropy {
        return Ok(Err(Rejection::Anisotropy { ratio }));
    }
    let scale = det.sqrt();
    if let Some(expected) = ctx.expected_scale
        && (scale / expected).ln().abs() > ctx.accept.max_log_scale_error
    {
        return Ok(Err(Rejection::Scale {
            measured: scale,
            expected,
        }));
    }
    Ok(Ok(Candidate {
        tile: tile_index,
        view: view_index,
        h_map_from_frame: h / h[(2, 2)],
        matches,
        inliers: est.inliers,
        rms_error: est.rms_error,
        scale,
        heading: rotation_of(&j),
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jacobian_and_rotation_of_a_similarity() {
        let (s, a) = (0.4f64, 0.9f64);
        let h = Matrix3::new(
            s * a.cos(),
            -s * a.sin(),
            10.0,
            s * a.sin(),
            s * a.cos(),
            -3.0,
            0.0,
            0.0,
            1.0,
        );
        let j = jacobian(&h, 100.0, 50.0).unwrap();
        assert!((j.determinant().sqrt() - s).abs() < 1e-12);
        assert!((rotation_of(&j) - a).abs() < 1e-12);
        assert!(keeps_the_frame_convex(&h, 500.0, 500.0));
        // A mirror image flips the corner order.
        let m = Matrix3::new(-1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0);
        assert!(!keeps_the_frame_convex(&m, 500.0, 500.0));
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        let h = Matrix3::new(0.41, -0.05, 300.0, 0.03, 0.39, 120.0, 1e-4, -2e-4, 1.0);
        let f = |x: f64, y: f64| {
            let q = h * Point2::new(x, y).to_homogeneous();
            (q.x / q.z, q.y / q.z)
        };
        let j = jacobian(&h, 250.0, 240.0).unwrap();
        let e = 1e-5;
        let (a, b) = (f(250.0 + e, 240.0), f(250.0 - e, 240.0));
        assert!(((a.0 - b.0) / (2.0 * e) - j[(0, 0)]).abs() < 1e-7);
        assert!(((a.1 - b.1) / (2.0 * e) - j[(1, 0)]).abs() < 1e-7);
        let (c, d) = (f(250.0, 240.0 + e), f(250.0, 240.0 - e));
        assert!(((c.0 - d.0) / (2.0 * e) - j[(0, 1)]).abs() < 1e-7);
        assert!(((c.1 - d.1) / (2.0 * e) - j[(1, 1)]).abs() < 1e-7);
    }
}
