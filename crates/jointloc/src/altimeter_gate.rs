//! The gate on the altimeter readings given to [`crate::JointLoc::process`]: a reading that is
//! not finite, not positive, or that jumps from the last accepted one faster than the UAV can
//! climb or sink ([`crate::JointLocConfig::max_altitude_rate_mps`]) is dropped, as if the frame
//! had none, with a warning and a count by kind (`summary.json`'s `input_faults`). One bad
//! sample must not stop a flight nor scale a fix wrongly.

use std::collections::BTreeMap;

use jointloc_formats::InputFaultKind;

/// Added to `max_altitude_rate_mps × dt`: the altimeter's own noise, so that a high frame
/// rate (dt small) does not turn noise into jumps. 0.5 m is 5σ of the simulator's 0.1 m and
/// well above a laser altimeter's few centimetres. Far from the ground the noise grows with
/// the range: see [`JUMP_NOISE_FRACTION`].
pub const JUMP_NOISE_ALLOWANCE_M: f64 = 0.5;

/// The allowance as a fraction of the last accepted reading, when that is larger: 5σ of the
/// difference of two readings whose σ is 0.5 % of the range (the simulator's above 20 m, a
/// laser altimeter's at long range). A fixed 0.5 m dropped 9 of 751 sound readings at 200 m.
pub const JUMP_NOISE_FRACTION: f64 = 0.035;

/// Consecutive jumps that agree with each other after which the reference itself is taken
/// to be the outlier (a spike as the first reading) and the gate re-anchors on them.
pub const REANCHOR_AFTER: usize = 3;

/// The gate's state: the last accepted reading and the counts of dropped ones.
#[derive(Debug, Clone, Default)]
pub struct AltimeterGate {
    max_rate_mps: f64,
    last: Option<(f64, f64)>,
    /// The latest run of dropped jumps consistent with each other: (last of them, how many).
    run: Option<((f64, f64), usize)>,
    invalid: usize,
    jumps: usize,
}

impl AltimeterGate {
    pub fn new(max_rate_mps: f64) -> Self {
        Self {
            max_rate_mps,
            ..Self::default()
        }
    }

    /// The reading at `timestamp` if it passes (it becomes the reference of the next), `None`
    /// if there is none or it is dropped. Timestamps must increase (the caller checks).
    pub fn check(&mut self, timestamp: f64, altitude: Option<f64>) -> Option<f64> {
        let a = altitude?;
        if !(a.is_finite() && a > 0.0) {
            self.invalid += 1;
            tracing::warn!(
                timestamp,
                altitude = a,
                "altimeter reading not finite and positive: dropped"
            );
            return None;
        }
        if let Some((t0, a0)) = self.last
            && !self.consistent((t0, a0), (timestamp, a))
        {
            // A run of jumps that agree with each other: the reference was the outlier.
            let run = match self.run {
                Some((prev, n)) if self.consistent(prev, (timestamp, a)) => n + 1,
                _ => 1,
            };
            if run >= REANCHOR_AFTER {
                tracing::warn!(
                    timestamp,
                    altitude = a,
                    last = a0,
                    "altimeter: {run} consistent readings disagree with the reference; re-anchored on them"
                );
            } else {
                self.run = Some(((timestamp, a), run));
                self.jumps += 1;
                let limit = self.max_rate_mps * (timestamp - t0) + allowance(a0);
                tracing::warn!(
                    timestamp,
                    altitude = a,
                    last = a0,
                    limit_m = limit,
                    "altimeter reading jumps faster than the UAV can climb or sink: dropped"
                );
                return None;
            }
        }
        self.run = None;
        self.last = Some((timestamp, a));
        Some(a)
    }

    /// Whether reading `b` can follow reading `a` at the UAV's climb rate.
    fn consistent(&self, a: (f64, f64), b: (f64, f64)) -> bool {
        (b.1 - a.1).abs() <= self.max_rate_mps * (b.0 - a.0) + allowance(a.1)
    }

    /// Dropped readings by kind (`altimeter_invalid`, `altimeter_jump`), the kinds with none
    /// left out.
    pub fn counts(&self) -> BTreeMap<String, usize> {
        [
            (InputFaultKind::AltimeterInvalid, self.invalid),
            (InputFaultKind::AltimeterJump, self.jumps),
        ]
        .into_iter()
        .filter(|&(_, n)| n > 0)
        .map(|(k, n)| (k.name().to_string(), n))
        .collect()
    }
}

/// The noise allowance after a reading of `altitude` metres.
fn allowance(altitude: f64) -> f64 {
    JUMP_NOISE_ALLOWANCE_M.max(JUMP_NOISE_FRACTION * altitude.abs())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_readings_are_dropped_and_counted_by_kind() {
        let mut gate = AltimeterGate::new(15.0);
        assert_eq!(gate.check(0.0, Some(10.0)), Some(10.0));
        assert_eq!(gate.check(0.2, None), None);
        assert_eq!(gate.check(0.4, Some(f64::NAN)), None);
        assert_eq!(gate.check(0.6, Some(f64::INFINITY)), None);
        assert_eq!(gate.check(0.8, Some(-3.0)), None);
        assert_eq!(gate.check(1.0, Some(0.0)), None);
        // 1.2 s after the last accepted reading: 18.5 m allowed.
        assert_eq!(gate.check(1.2, Some(40.0)), None);
        assert_eq!(gate.check(1.4, Some(10.3)), Some(10.3));
        // 0.2 s: 3.5 m allowed.
        assert_eq!(gate.check(1.6, Some(13.9)), None);
        assert_eq!(gate.check(1.8, Some(13.5)), Some(13.5));
        let counts = gate.counts();
        assert_eq!(counts.len(), 2, "{counts:?}");
        assert_eq!(counts["altimeter_invalid"], 4);
        assert_eq!(counts["altimeter_jump"], 2);
        assert!(AltimeterGate::new(15.0).counts().is_empty());
    }

    #[test]
    fn a_step_in_the_terrain_is_accepted_once_time_allows_it() {
        // Flying off a 6 m ledge: the reading steps and stays; the gate takes it after
        // (6 − 0.5) / 15 s.
        let mut gate = AltimeterGate::new(15.0);
        gate.check(0.0, Some(10.0));
        assert_eq!(gate.check(0.2, Some(16.0)), None);
        assert_eq!(gate.check(0.4, Some(16.0)), Some(16.0));
    }

    #[test]
    fn a_spike_as_the_first_reading_does_not_lock_the_gate() {
        let mut gate = AltimeterGate::new(15.0);
        assert_eq!(gate.check(0.0, Some(1000.0)), Some(1000.0));
        assert_eq!(gate.check(0.2, Some(10.0)), None);
        assert_eq!(gate.check(0.4, Some(10.1)), None);
        // The third consistent reading re-anchors the gate; the next ones pass.
        assert_eq!(gate.check(0.6, Some(10.0)), Some(10.0));
        assert_eq!(gate.check(0.8, Some(10.1)), Some(10.1));
        assert_eq!(gate.counts()["altimeter_jump"], 2);
        // Scattered outliers that disagree with each other never re-anchor it.
        let mut gate = AltimeterGate::new(15.0);
        gate.check(0.0, Some(10.0));
        for (i, spike) in [300.0, 50.0, 900.0, 4.0e3].into_iter().enumerate() {
            assert_eq!(
                gate.check(0.2 * (i + 1) as f64, Some(spike)),
                None,
                "{spike}"
            );
        }
        assert_eq!(gate.check(1.0, Some(10.2)), Some(10.2));
    }

    #[test]
    fn far_from_the_ground_the_allowance_follows_the_range() {
        // At 200 m the readings' σ is 1 m: 5 m between two frames is noise, 20 m is not.
        let mut gate = AltimeterGate::new(15.0);
        gate.check(0.0, Some(200.0));
        assert_eq!(gate.check(0.2, Some(204.0)), Some(204.0));
        assert_eq!(gate.check(0.4, Some(199.5)), Some(199.5));
        assert_eq!(gate.check(0.6, Some(220.0)), None);
        assert_eq!(gate.check(0.8, Some(201.0)), Some(201.0));
        assert_eq!(gate.counts()["altimeter_jump"], 1);
    }
}
