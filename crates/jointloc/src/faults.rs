//! Fault injection for the robustness evaluation: absolute fixes replaced by wrong
//! positions, an outage during which the absolute localisation is not run, and a blinded
//! camera (frames replaced by a uniform grey: dust, glare, a dropped video link). Off by
//! default; every draw is a pure function of the seed and the frame index, so runs repeat.
//!
//! The faults sit outside the fusion, as wrappers of what feeds it: [`FaultyFixes`] around
//! the fix source (the builder applies it from `[faults]`), [`BlindCamera`] around the frames
//! (applied by whoever reads the camera: the CLI, a test).

use std::borrow::Cow;

use image::GrayImage;
use jointloc_absloc::{AbslocError, Outcome};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::error::{JointLocError, Result};
use crate::fix_source::{FixRequest, FixSource, Located};

/// What to inject.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FaultConfig {
    /// Fraction of fixes whose position is replaced by a wrong one (0: none). The confidence
    /// is kept, so wrong fixes look like real ones; the heading is drawn uniformly, as a
    /// match on the wrong tile gives.
    pub wrong_fix_fraction: f64,
    /// The first this-many fixes found are made wrong as well: a wrong fix at the start, the
    /// case where no alignment exists yet to reject it (a self-similar take-off area).
    pub wrong_first_fixes: usize,
    /// Horizontal offset of a wrong fix, metres: uniform in [min, max], direction uniform.
    pub wrong_fix_min_m: f64,
    pub wrong_fix_max_m: f64,
    /// No absolute localisation for timestamps in [start, start + duration) seconds.
    pub outage_start_s: Option<f64>,
    pub outage_duration_s: f64,
    /// Frames with timestamps in [start, start + duration) seconds are uniform grey.
    pub blind_start_s: Option<f64>,
    pub blind_duration_s: f64,
    pub seed: u64,
}

impl Default for FaultConfig {
    fn default() -> Self {
        Self {
            wrong_fix_fraction: 0.0,
            wrong_first_fixes: 0,
            wrong_fix_min_m: 10.0,
            wrong_fix_max_m: 50.0,
            outage_start_s: None,
            outage_duration_s: 30.0,
            blind_start_s: None,
            blind_duration_s: 10.0,
            seed: 0,
        }
    }
}

impl FaultConfig {
    pub fn validate(&self) -> Result<()> {
        let bad = |field, value: f64, reason| {
            Err(JointLocError::InvalidConfig {
                field,
                value: value.to_string(),
                reason,
            })
        };
        if !(0.0..=1.0).contains(&self.wrong_fix_fraction) {
            return bad(
                "faults.wrong_fix_fraction",
                self.wrong_fix_fraction,
                "must be in [0, 1]",
            );
        }
        if !(self.wrong_fix_min_m >= 0.0 && self.wrong_fix_max_m >= self.wrong_fix_min_m) {
            return bad(
                "faults.wrong_fix_max_m",
                self.wrong_fix_max_m,
                "needs 0 <= wrong_fix_min_m <= wrong_fix_max_m",
            );
        }
        if !(self.outage_duration_s.is_finite() && self.outage_duration_s >= 0.0) {
            return bad(
                "faults.outage_duration_s",
                self.outage_duration_s,
                "must be finite and >= 0",
            );
        }
        if let Some(s) = self.outage_start_s.filter(|s| !s.is_finite()) {
            return bad("faults.outage_start_s", s, "must be finite");
        }
        if !(self.blind_duration_s.is_finite() && self.blind_duration_s >= 0.0) {
            return bad(
                "faults.blind_duration_s",
                self.blind_duration_s,
                "must be finite and >= 0",
            );
        }
        if let Some(s) = self.blind_start_s.filter(|s| !s.is_finite()) {
            return bad("faults.blind_start_s", s, "must be finite");
        }
        Ok(())
    }

    /// Whether the absolute localisation is out at `timestamp`.
    pub fn in_outage(&self, timestamp: f64) -> bool {
        self.outage_start_s
            .is_some_and(|s| timestamp >= s && timestamp < s + self.outage_duration_s)
    }

    /// Whether the fix stream is touched at all (wrong fixes or an outage).
    pub fn affects_fixes(&self) -> bool {
        self.wrong_fix_fraction > 0.0 || self.wrong_first_fixes > 0 || self.outage_start_s.is_some()
    }

    /// Whether the camera is blinded at `timestamp`.
    pub fn is_blind(&self, timestamp: f64) -> bool {
        self.blind_start_s
            .is_some_and(|s| timestamp >= s && timestamp < s + self.blind_duration_s)
    }

    /// How to make the fix of `frame` wrong, if it is to be: `ordinal` counts the fixes found
    /// before it (for [`Self::wrong_first_fixes`]).
    pub fn wrong_fix(&self, frame: usize, ordinal: usize) -> Option<WrongFix> {
        let mut rng = ChaCha8Rng::seed_from_u64(
            self.seed ^ (frame as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
        );
        let drawn = rng.random::<f64>() < self.wrong_fix_fraction;
        if !(drawn || ordinal < self.wrong_first_fixes) {
            return None;
        }
        let d = if self.wrong_fix_max_m > self.wrong_fix_min_m {
            rng.random_range(self.wrong_fix_min_m..self.wrong_fix_max_m)
        } else {
            self.wrong_fix_min_m
        };
        let a = rng.random_range(0.0..std::f64::consts::TAU);
        Some(WrongFix {
            offset: [d * a.cos(), d * a.sin()],
            heading: rng.random_range(0.0..std::f64::consts::TAU),
        })
    }
}

/// What replaces a fix's position and heading.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WrongFix {
    /// Added to the fix's (x, y), metres.
    pub offset: [f64; 2],
    /// Replaces the fix's heading, radians.
    pub heading: f64,
}

/// A fix source with the configured wrong fixes and outage.
#[derive(Debug)]
pub struct FaultyFixes<S> {
    inner: S,
    faults: FaultConfig,
    /// Fixes the inner source has found so far (for [`FaultConfig::wrong_first_fixes`]).
    found: usize,
}

impl<S: FixSource> FaultyFixes<S> {
    pub fn new(inner: S, faults: FaultConfig) -> Self {
        Self {
            inner,
            faults,
            found: 0,
        }
    }
}

impl<S: FixSource> FixSource for FaultyFixes<S> {
    fn localize(
        &mut self,
        request: &FixRequest<'_>,
    ) -> std::result::Result<Option<Located>, AbslocError> {
        if self.faults.in_outage(request.timestamp) {
            return Ok(None);
        }
        let Some(mut located) = self.inner.localize(request)? else {
            return Ok(None);
        };
        if let Outcome::Fix(fix) = &mut located.outcome {
            if let Some(w) = self.faults.wrong_fix(request.frame, self.found) {
                fix.position[0] += w.offset[0];
                fix.position[1] += w.offset[1];
                fix.heading = w.heading;
                located.injected = true;
            }
            self.found += 1;
        }
        Ok(Some(located))
    }
}

/// The camera as the fault configuration blinds it: frames in the blind window become
/// uniform grey, of the same size.
#[derive(Debug, Clone)]
pub struct BlindCamera {
    faults: FaultConfig,
}

impl BlindCamera {
    pub fn new(faults: FaultConfig) -> Self {
        Self { faults }
    }

    /// The frame the system sees at `timestamp`.
    pub fn frame<'a>(&self, image: &'a GrayImage, timestamp: f64) -> Cow<'a, GrayImage> {
        if self.faults.is_blind(timestamp) {
            Cow::Owned(GrayImage::from_pixel(
                image.width(),
                image.height(),
                image::Luma([128]),
            ))
        } else {
            Cow::Borrowed(image)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrong_fixes_have_the_requested_rate_and_distance() {
        for seed in [1, 2, 3] {
            let f = FaultConfig {
                wrong_fix_fraction: 0.2,
                seed,
                ..Default::default()
            };
            let offsets: Vec<[f64; 2]> = (0..2000)
                .filter_map(|i| f.wrong_fix(i, 100).map(|w| w.offset))
                .collect();
            let rate = offsets.len() as f64 / 2000.0;
            assert!((rate - 0.2).abs() < 0.03, "seed {seed}: rate {rate}");
            for o in &offsets {
                let d = o[0].hypot(o[1]);
                assert!((10.0..=50.0).contains(&d), "{d}");
            }
            // Repeatable per frame.
            assert_eq!(f.wrong_fix(17, 100), f.wrong_fix(17, 100));
        }
        assert_eq!(FaultConfig::default().wrong_fix(3, 0), None);
        // The first fixes, whatever the draw.
        let first = FaultConfig {
            wrong_first_fixes: 2,
            ..Default::default()
        };
        assert!(first.wrong_fix(3, 0).is_some() && first.wrong_fix(40, 1).is_some());
        assert_eq!(first.wrong_fix(50, 2), None);
    }

    #[test]
    fn outage_and_blindness_cover_their_windows_only() {
        let f = FaultConfig {
            outage_start_s: Some(40.0),
            ..Default::default()
        };
        assert!(!f.in_outage(39.99) && f.in_outage(40.0) && f.in_outage(69.9));
        assert!(!f.in_outage(70.0));
        assert!(!FaultConfig::default().in_outage(50.0));
        let blind = FaultConfig {
            blind_start_s: Some(10.0),
            blind_duration_s: 5.0,
            ..Default::default()
        };
        assert!(!blind.is_blind(9.9) && blind.is_blind(10.0) && blind.is_blind(14.9));
        assert!(!blind.is_blind(15.0) && !blind.in_outage(12.0));
        assert!(!FaultConfig::default().is_blind(12.0));
        let bad_blind = FaultConfig {
            blind_duration_s: f64::NAN,
            ..Default::default()
        };
        assert!(bad_blind.validate().is_err());
        let bad = FaultConfig {
            wrong_fix_fraction: 1.5,
            ..Default::default()
        };
        assert!(bad.validate().is_err());
    }
}
