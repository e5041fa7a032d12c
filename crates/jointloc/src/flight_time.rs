//! The fusion's windows in seconds of flight. The alignment's window, the terrain
//! correction's, the wait before merging a map set aside and the cadence of heading sweeps in
//! a failing streak are set in seconds, so that the fusion frequency
//! ([`crate::JointLocConfig::fusion_every`]) changes how many fixes a window holds and not how
//! far back it reaches. A window holds the fixes its span holds at the search rate when none
//! fails; failed searches make it reach further back (fewer fixes would leave more of their
//! noise in the alignment: on the development flights a window of 40 s of fixes instead of
//! 40 fixes was 3 % worse online, 15 % on the flight with the most failures).

/// Frame times closer than this are the same instant (timestamps are sums of floats).
const SAME_INSTANT_S: f64 = 1e-6;

/// The flight's frame period, from the first and the latest frame seen (frames given up by
/// the caller count: they were due).
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct FrameClock {
    first: Option<(usize, f64)>,
    latest: Option<(usize, f64)>,
}

impl FrameClock {
    /// Time of the flight's first frame (with a finite timestamp).
    pub(crate) fn first_timestamp(&self) -> Option<f64> {
        self.first.map(|(_, t)| t)
    }

    /// Frame `index` (counted from the flight's first) was taken at `timestamp`.
    pub(crate) fn tick(&mut self, index: usize, timestamp: f64) {
        if !timestamp.is_finite() {
            return;
        }
        self.first.get_or_insert((index, timestamp));
        self.latest = Some((index, timestamp));
    }

    /// Seconds per frame; `None` before two frames with distinct times.
    pub(crate) fn frame_period_s(&self) -> Option<f64> {
        let ((i0, t0), (i1, t1)) = (self.first?, self.latest?);
        let period = (t1 - t0) / i1.checked_sub(i0).filter(|&n| n > 0)? as f64;
        (period.is_finite() && period > 0.0).then_some(period)
    }
}

/// How many fixes a span of `span_s` seconds holds at one search per `search_interval_s`, at
/// least `min` (also while the interval is not known yet); 0 (all) when `span_s` is 0.
pub(crate) fn fixes_in(span_s: f64, search_interval_s: Option<f64>, min: usize) -> usize {
    if span_s <= 0.0 {
        return 0;
    }
    let held = search_interval_s.map_or(0, |dt| (span_s / dt + SAME_INSTANT_S).round() as usize);
    held.max(min).max(1)
}

/// Whether the search at frame time `now` is due to sweep the headings: once the failing
/// streak `(first, latest)` (frame times of its first and latest failed search) has crossed
/// another multiple of `every_s` since its first search; always when `every_s` is 0 (never
/// a heading), never without a streak.
pub(crate) fn sweep_due(streak: Option<(f64, f64)>, now: f64, every_s: f64) -> bool {
    if every_s <= 0.0 {
        return true;
    }
    let Some((first, latest)) = streak else {
        return false;
    };
    let periods = |t: f64| ((t - first + SAME_INSTANT_S) / every_s).floor();
    periods(now) > periods(latest)
}

/// Whether a search with nothing to search around yet (no fix, no alignment, no world pose)
/// waits at frame time `now`: after `failures` such searches failed in a row, the latest at
/// `latest`, the next is made once `interval_s × 2^(failures − 1)` has passed, at most
/// `max_s` (0: never waits; nor while the interval is not known yet). Each covers the whole
/// map (seconds, on a map of 60 m) and the ground that made it fail is still under the
/// camera for the next few.
pub(crate) fn blind_search_waits(
    failures: usize,
    latest: f64,
    now: f64,
    interval_s: Option<f64>,
    max_s: f64,
) -> bool {
    let Some(interval_s) = interval_s.filter(|&dt| dt > 0.0) else {
        return false;
    };
    if failures == 0 || max_s <= 0.0 {
        return false;
    }
    let doublings = (failures - 1).min(30) as i32;
    let wait = (interval_s * 2f64.powi(doublings)).min(max_s);
    now - latest + SAME_INSTANT_S < wait
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blind_searches_back_off_by_doubling_up_to_the_cap() {
        // A search a second; the times at which a streak of failures searches.
        let searches = |max_s: f64| {
            let (mut failures, mut latest, mut made) = (0, 0.0, Vec::new());
            for k in 0..40 {
                let now = k as f64 * 0.2 * 5.0;
                if !blind_search_waits(failures, latest, now, Some(1.0), max_s) {
                    made.push(now);
                    failures += 1;
                    latest = now;
                }
            }
            made.iter()
                .map(|t: &f64| t.round() as i64)
                .collect::<Vec<_>>()
        };
        assert_eq!(searches(8.0), [0, 1, 3, 7, 15, 23, 31, 39]);
        assert_eq!(searches(5.0), [0, 1, 3, 7, 12, 17, 22, 27, 32, 37]);
        assert_eq!(searches(0.0).len(), 40, "0: no backoff");
        assert_eq!(
            searches(1.0).len(),
            40,
            "capped at the interval: no backoff"
        );
        // No failure yet, or no interval known yet: search.
        assert!(!blind_search_waits(0, 0.0, 0.0, Some(1.0), 8.0));
        assert!(!blind_search_waits(3, 0.0, 0.5, None, 8.0));
    }

    #[test]
    fn the_clock_gives_the_frame_period() {
        let mut clock = FrameClock::default();
        assert_eq!(clock.frame_period_s(), None);
        // 5 Hz as a flight's timestamps give it (sums of 0.2), one frame given up (index 3).
        let mut t = 0.0;
        for i in 0..100 {
            if i != 3 {
                clock.tick(i, t);
            }
            t += 0.2;
        }
        assert!((clock.frame_period_s().unwrap() - 0.2).abs() < 1e-12);
        clock.tick(100, f64::NAN);
        assert!((clock.frame_period_s().unwrap() - 0.2).abs() < 1e-12);
    }

    #[test]
    fn a_span_holds_the_fixes_of_the_search_rate() {
        // A fix every 5th frame of 5 Hz: 40 s hold 40; every 10th, 20; every 100th, 2, and
        // the floor keeps 10.
        let interval = |every: f64| Some((0..5).fold(0.0, |t, _| t + 0.2) * every / 5.0);
        assert_eq!(fixes_in(40.0, interval(5.0), 10), 40);
        assert_eq!(fixes_in(40.0, interval(10.0), 10), 20);
        assert_eq!(fixes_in(40.0, interval(100.0), 10), 10);
        assert_eq!(fixes_in(10.0, interval(10.0), 1), 5);
        assert_eq!(fixes_in(0.0, interval(5.0), 10), 0);
        assert_eq!(fixes_in(40.0, None, 10), 10);
        assert_eq!(fixes_in(40.0, None, 0), 1);
    }

    #[test]
    fn sweeps_come_once_per_period_of_a_failing_streak() {
        // Searches a second apart failing from t = 7: the 21st search (t = 27) sweeps, as
        // every 20th failure did at a fix a second, then the 41st.
        let mut streak: Option<(f64, f64)> = None;
        let mut sweeps = Vec::new();
        for k in 0..45 {
            let now = 7.0 + k as f64;
            if sweep_due(streak, now, 20.0) {
                sweeps.push(k);
            }
            let first = streak.map_or(now, |s| s.0);
            streak = Some((first, now));
        }
        assert_eq!(sweeps, vec![20, 40]);
        assert!(!sweep_due(None, 100.0, 20.0));
        assert!(sweep_due(None, 100.0, 0.0));
    }
}
