//! Repeatability and matching precision under a known homography, computed the same way for
#![allow(dead_code)]
//! our keypoints and OpenCV's.

use jointloc_features::orb::{KeyPoint, MatcherConfig, OrbFeatures, match_mutual};
use nalgebra::Matrix3;

use super::sim_frames::apply;

/// Keypoints of A count only where H maps them at least this far inside B (px), so that
/// neither extractor's own border decides the figure.
pub const MARGIN: f64 = 40.0;
/// A keypoint is repeated when one of the other image lies within this distance (px)…
pub const REPEAT_PX: f64 = 2.5;
/// …with a size within this factor of the expected one (one pyramid level of 1.2 plus the
/// rounding to the nearest level).
pub const SCALE_TOL: f64 = 1.315;
/// A match is correct when H maps the query within this distance (px) of the train point.
pub const CORRECT_PX: f64 = 3.0;

/// Local scale of H at (x, y): √|det J|.
fn local_scale(h: &Matrix3<f64>, x: f64, y: f64) -> f64 {
    let e = 0.5;
    let (x0, y0) = apply(h, x - e, y);
    let (x1, y1) = apply(h, x + e, y);
    let (x2, y2) = apply(h, x, y - e);
    let (x3, y3) = apply(h, x, y + e);
    let j = [
        [(x1 - x0) / (2.0 * e), (x3 - x2) / (2.0 * e)],
        [(y1 - y0) / (2.0 * e), (y3 - y2) / (2.0 * e)],
    ];
    (j[0][0] * j[1][1] - j[0][1] * j[1][0]).abs().sqrt()
}

/// Fraction of A's keypoints (mapped inside B by the margin) repeated in B.
fn one_way(a: &[KeyPoint], b: &[KeyPoint], h: &Matrix3<f64>, size: f64) -> (usize, usize) {
    let (mut seen, mut hit) = (0, 0);
    for k in a {
        let (x, y) = apply(h, k.x, k.y);
        if x < MARGIN || y < MARGIN || x > size - 1.0 - MARGIN || y > size - 1.0 - MARGIN {
            continue;
        }
        seen += 1;
        let want = k.size * local_scale(h, k.x, k.y);
        if b.iter().any(|o| {
            let d2 = (o.x - x).powi(2) + (o.y - y).powi(2);
            let r = o.size / want;
            d2 <= REPEAT_PX * REPEAT_PX && (1.0 / SCALE_TOL..=SCALE_TOL).contains(&r)
        }) {
            hit += 1;
        }
    }
    (seen, hit)
}

/// Symmetric repeatability: repeated keypoints of A in B plus of B in A, over all counted.
pub fn repeatability(a: &[KeyPoint], b: &[KeyPoint], h: &Matrix3<f64>, size: usize) -> f64 {
    let hinv = h.try_inverse().expect("invertible");
    let (s1, h1) = one_way(a, b, h, size as f64);
    let (s2, h2) = one_way(b, a, &hinv, size as f64);
    (h1 + h2) as f64 / (s1 + s2).max(1) as f64
}

/// Mutual nearest neighbours by Hamming distance (no ratio test, no cap) and the fraction of
/// them that H confirms within `CORRECT_PX`.
pub fn precision(a: &OrbFeatures, b: &OrbFeatures, h: &Matrix3<f64>) -> (usize, f64) {
    let cfg = MatcherConfig {
        max_distance: 256,
        ratio: 1.0,
        mutual: true,
        check_orientation: false,
        ..MatcherConfig::default()
    };
    let m = match_mutual(a, b, &cfg);
    let good = m
        .iter()
        .filter(|m| {
            let (ka, kb) = (&a.keypoints[m.query], &b.keypoints[m.train]);
            let (x, y) = apply(h, ka.x, ka.y);
            (kb.x - x).powi(2) + (kb.y - y).powi(2) <= CORRECT_PX * CORRECT_PX
        })
        .count();
    (m.len(), good as f64 / m.len().max(1) as f64)
}
