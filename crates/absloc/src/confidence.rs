//! The paper's confidence (§III-B, "adaptive subsequent area prediction") and the search
//! radius it sets.
//!
//! `w = SSIM(map under the warped frame, warped frame) × mean matching score of the inliers`.
//! SSIM lies in [−1, 1]; it is clamped to [0, 1] first (an anti-correlated overlap is no
//! evidence at all), so `w ∈ [0, 1]`. The ablation's alternatives (§IV, Table III) are the two
//! factors alone and a fixed value.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::error::AbslocError;

/// How the confidence of a fix is computed. Written `adaptive`, `ssim`, `matching` or
/// `fixed:V` (in TOML and on the command line).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
#[serde(try_from = "String", into = "String")]
pub enum ConfidenceMode {
    /// SSIM × mean matching score (the paper's method).
    #[default]
    Adaptive,
    /// SSIM alone.
    Ssim,
    /// Mean matching score alone.
    Matching,
    /// A constant in [0, 1].
    Fixed(f64),
}

impl ConfidenceMode {
    /// The confidence of a fix with these factors, in [0, 1].
    pub fn confidence(self, ssim: f64, match_score: f64) -> f64 {
        let s = unit(ssim);
        let m = unit(match_score);
        match self {
            Self::Adaptive => s * m,
            Self::Ssim => s,
            Self::Matching => m,
            Self::Fixed(v) => unit(v),
        }
    }
}

/// Clamps to [0, 1]; NaN is 0.
fn unit(v: f64) -> f64 {
    if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) }
}

impl fmt::Display for ConfidenceMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Adaptive => f.write_str("adaptive"),
            Self::Ssim => f.write_str("ssim"),
            Self::Matching => f.write_str("matching"),
            Self::Fixed(v) => write!(f, "fixed:{v}"),
        }
    }
}

impl FromStr for ConfidenceMode {
    type Err = AbslocError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad = |reason: &str| AbslocError::InvalidConfig {
            field: "confidence",
            value: s.to_string(),
            reason: reason.to_string(),
        };
        match s.trim() {
            "adaptive" => Ok(Self::Adaptive),
            "ssim" => Ok(Self::Ssim),
            "matching" => Ok(Self::Matching),
            other => {
                let v = other
                    .strip_prefix("fixed:")
                    .ok_or_else(|| bad("expected adaptive, ssim, matching or fixed:V"))?;
                let v: f64 = v
                    .trim()
                    .parse()
                    .map_err(|_| bad("fixed:V needs a number"))?;
                if !(0.0..=1.0).contains(&v) {
                    return Err(bad("fixed:V needs V in [0, 1]"));
                }
                Ok(Self::Fixed(v))
            }
        }
    }
}

impl TryFrom<String> for ConfidenceMode {
    type Error = AbslocError;
    fn try_from(s: String) -> Result<Self, Self::Error> {
        s.parse()
    }
}

impl From<ConfidenceMode> for String {
    fn from(m: ConfidenceMode) -> String {
        m.to_string()
    }
}

/// Smallest and largest search radius (tile steps), as in the paper.
pub const RADIUS_RANGE: (u32, u32) = (1, 10);

/// Next search radius `r = ⌈10^(1−w)⌉`, clamped to [1, 10] (`w` outside [0, 1] or NaN is
/// clamped first, so a failed fix, w = 0, gives 10). Only `w = 1` gives radius 1; the paper's
/// Fig. 4 caption quotes r = 1 for w = 0.9, which its own formula does not give (⌈1.26⌉ = 2).
pub fn search_radius(w: f64) -> u32 {
    let w = unit(w);
    // 10^(1−w) is exactly 1 at w = 1 and exactly 10 at w = 0; a hair of tolerance keeps
    // rounding noise (e.g. w = 0.3 giving 5.0000000001) from bumping the ceiling.
    let r = (10f64.powf(1.0 - w) - 1e-9).ceil();
    (r as u32).clamp(RADIUS_RANGE.0, RADIUS_RANGE.1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn radius_follows_the_paper() {
        // Figure 4 of the paper: w = 0.7 → r = 2. Its caption also says w = 0.9 gives 1, but
        // the formula gives ⌈10^0.1⌉ = ⌈1.26⌉ = 2; the formula is what we implement.
        assert_eq!(search_radius(0.7), 2);
        assert_eq!(search_radius(0.9), 2);
        assert_eq!(search_radius(1.0), 1);
        assert_eq!(search_radius(0.0), 10);
        assert_eq!(search_radius(0.5), 4); // 3.16
        assert_eq!(search_radius(0.3), 6); // 5.01
        assert_eq!(search_radius(0.2), 7); // 6.31
        assert_eq!(search_radius(1.0 - 2f64.log10()), 2); // exactly 2
        assert_eq!(search_radius(-3.0), 10);
        assert_eq!(search_radius(7.0), 1);
        assert_eq!(search_radius(f64::NAN), 10);
        // Monotone non-increasing in w.
        let mut last = u32::MAX;
        for i in 0..=1000 {
            let r = search_radius(i as f64 / 1000.0);
            assert!(r <= last && (1..=10).contains(&r));
            last = r;
        }
    }

    #[test]
    fn modes_combine_the_factors() {
        assert!((ConfidenceMode::Adaptive.confidence(0.8, 0.5) - 0.4).abs() < 1e-12);
        assert_eq!(ConfidenceMode::Ssim.confidence(0.8, 0.5), 0.8);
        assert_eq!(ConfidenceMode::Matching.confidence(0.8, 0.5), 0.5);
        assert_eq!(ConfidenceMode::Fixed(0.4).confidence(0.8, 0.5), 0.4);
        // Negative SSIM is no evidence; NaN neither.
        assert_eq!(ConfidenceMode::Adaptive.confidence(-0.3, 0.9), 0.0);
        assert_eq!(ConfidenceMode::Adaptive.confidence(f64::NAN, 0.9), 0.0);
    }

    #[test]
    fn modes_parse_and_serialise() {
        for (s, m) in [
            ("adaptive", ConfidenceMode::Adaptive),
            ("ssim", ConfidenceMode::Ssim),
            ("matching", ConfidenceMode::Matching),
            ("fixed:0.4", ConfidenceMode::Fixed(0.4)),
        ] {
            assert_eq!(s.parse::<ConfidenceMode>().unwrap(), m);
            assert_eq!(m.to_string(), s);
            let json = serde_json::to_string(&m).unwrap();
            assert_eq!(json, format!("\"{s}\""));
            assert_eq!(serde_json::from_str::<ConfidenceMode>(&json).unwrap(), m);
        }
        for bad in [
            "",
            "fixed",
            "fixed:x",
            "fixed:1.5",
            "fixed:-0.1",
            "Adaptive",
        ] {
            assert!(bad.parse::<ConfidenceMode>().is_err(), "{bad}");
        }
    }
}
