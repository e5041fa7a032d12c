//! Where to search while there is no world pose: the last one carried forward at the UAV's
//! last ground velocity.
//!
//! After a tracking loss the search prior used to be the last world pose, which falls behind
//! by the distance flown during the loss (12 m after 5 s lost and the new map's
//! initialisation at 1 m/s: more than a tile, so the first searches of the new map fail).

use std::collections::VecDeque;

/// The recent world positions (x, y) and their times, over a short window.
#[derive(Debug, Clone, Default)]
pub struct GroundTrack {
    recent: VecDeque<(f64, [f64; 2])>,
}

/// Span of the positions the velocity is taken over (s): long enough to average out the
/// frame-to-frame jitter of the fused poses, short enough to follow a turn.
const WINDOW_S: f64 = 2.0;
/// Shortest span that gives a velocity (s).
const MIN_SPAN_S: f64 = 0.5;
/// A prior younger than this (s) is used as it is: the UAV has moved less than a tile's
/// fraction since, and the searches of an uninterrupted flight stay as they were.
pub const FRESH_S: f64 = 1.0;

impl GroundTrack {
    /// Records the world position at `t`. Times must increase; an older one is ignored.
    pub fn push(&mut self, t: f64, xy: [f64; 2]) {
        if !(t.is_finite() && xy.iter().all(|v| v.is_finite())) {
            return;
        }
        if self.recent.back().is_some_and(|&(last, _)| t <= last) {
            return;
        }
        self.recent.push_back((t, xy));
        while self
            .recent
            .front()
            .is_some_and(|&(first, _)| t - first > WINDOW_S)
        {
            self.recent.pop_front();
        }
    }

    /// Time and position of the newest record.
    pub fn last(&self) -> Option<(f64, [f64; 2])> {
        self.recent.back().copied()
    }

    /// Ground velocity (m/s) over the window; `None` before it spans half a second.
    pub fn velocity(&self) -> Option<[f64; 2]> {
        let (&(t0, a), &(t1, b)) = (self.recent.front()?, self.recent.back()?);
        let dt = t1 - t0;
        (dt >= MIN_SPAN_S).then(|| [(b[0] - a[0]) / dt, (b[1] - a[1]) / dt])
    }

    /// The newest position carried forward to `now` at the velocity, for at most `max_s`
    /// seconds (0: not at all); `None` without a record.
    pub fn predict(&self, now: f64, max_s: f64) -> Option<[f64; 2]> {
        let (t, xy) = self.last()?;
        let dt = (now - t).clamp(0.0, max_s.max(0.0));
        Some(match self.velocity() {
            Some(v) if dt > 0.0 => [xy[0] + v[0] * dt, xy[1] + v[1] * dt],
            _ => xy,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn carries_the_last_position_at_the_last_velocity_up_to_the_cap() {
        let mut track = GroundTrack::default();
        assert_eq!(track.predict(3.0, 10.0), None);
        // 1 m/s along x, 0.5 m/s along y, at 5 Hz, with a glitch in time ignored.
        for i in 0..=20 {
            let t = f64::from(i) * 0.2;
            track.push(t, [t, 0.5 * t]);
        }
        track.push(1.0, [100.0, 100.0]);
        track.push(f64::NAN, [0.0, 0.0]);
        let v = track.velocity().unwrap();
        assert!(
            (v[0] - 1.0).abs() < 1e-12 && (v[1] - 0.5).abs() < 1e-12,
            "{v:?}"
        );
        let p = track.predict(10.0, 15.0).unwrap();
        assert!(
            (p[0] - 10.0).abs() < 1e-9 && (p[1] - 5.0).abs() < 1e-9,
            "{p:?}"
        );
        // Capped at 3 s past the last record, not carried at all with a cap of 0.
        let p = track.predict(10.0, 3.0).unwrap();
        assert!((p[0] - 7.0).abs() < 1e-9, "{p:?}");
        assert_eq!(track.predict(10.0, 0.0), Some([4.0, 2.0]));
        // Only the last WINDOW_S seconds count: a turn shows within them.
        for i in 1..=15 {
            let t = 4.0 + f64::from(i) * 0.2;
            track.push(t, [4.0, 2.0 + (t - 4.0)]);
        }
        let v = track.velocity().unwrap();
        assert!(v[0].abs() < 1e-12 && (v[1] - 1.0).abs() < 1e-12, "{v:?}");
    }

    #[test]
    fn no_velocity_from_a_single_instant() {
        let mut track = GroundTrack::default();
        track.push(1.0, [2.0, 3.0]);
        track.push(1.2, [2.2, 3.0]);
        assert_eq!(track.velocity(), None);
        assert_eq!(track.predict(5.0, 10.0), Some([2.2, 3.0]));
    }
}
