//! `jointloc run --realtime`: frames released at their timestamps, as the camera delivers
//! them, and how far behind the camera their processing finished.

use std::time::Instant;

use jointloc_slam::system::median;
use jointloc_system::{RealtimeSummary, Summary};

/// Frames released at their timestamps (scaled by `speed`) from the start of the run, and how
/// far behind the camera the processing of each one finished.
pub(super) struct Replay {
    speed: f64,
    first_timestamp: f64,
    started: Instant,
    lags_ms: Vec<f64>,
    /// Frames that were due before the previous one was done (the loop fell behind).
    late: usize,
}

impl Replay {
    pub(super) fn new(speed: f64, first_timestamp: f64) -> Self {
        Self {
            speed,
            first_timestamp,
            started: Instant::now(),
            lags_ms: Vec::new(),
            late: 0,
        }
    }

    /// Seconds after the start at which the camera delivers the frame stamped `timestamp`.
    fn due_s(&self, timestamp: f64) -> f64 {
        ((timestamp - self.first_timestamp) / self.speed).max(0.0)
    }

    pub(super) fn wait_for(&mut self, timestamp: f64) {
        let due = self.due_s(timestamp);
        let now = self.started.elapsed().as_secs_f64();
        if due > now {
            std::thread::sleep(std::time::Duration::from_secs_f64(due - now));
        } else if !self.lags_ms.is_empty() {
            self.late += 1;
        }
    }

    pub(super) fn record_done(&mut self, timestamp: f64) {
        let lag = self.started.elapsed().as_secs_f64() - self.due_s(timestamp);
        self.lags_ms.push(lag * 1e3);
    }

    pub(super) fn lag_median_ms(&self) -> f64 {
        median(&self.lags_ms)
    }

    pub(super) fn lag_max_ms(&self) -> f64 {
        self.lags_ms.iter().copied().fold(0.0, f64::max)
    }
}

impl Replay {
    /// Records the replay in the run's summary.
    pub(super) fn record_in(&self, summary: &mut Summary) {
        summary.mode = "threaded, real-time replay".to_string();
        summary.realtime = Some(RealtimeSummary {
            speed: self.speed,
            lag_median_ms: self.lag_median_ms(),
            lag_max_ms: self.lag_max_ms(),
            frames_late: self.late,
        });
    }
}
