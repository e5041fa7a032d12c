//! Observers: code that watches a run as it goes (a progress display, a live viewer, a
//! telemetry link) without owning the frame loop. They are called on the tracking thread, in
//! order, after the fusion has dealt with the frame or fix, so they must be quick.

use crate::system::{FixRecord, FusedFrame};

/// Called by [`crate::JointLoc`] for every frame and every fix.
pub trait Observer: Send {
    /// A frame has been processed.
    fn frame(&mut self, _frame: &FusedFrame) {}
    /// A fix has been recorded (and, if used, the alignment re-fitted).
    fn fix(&mut self, _fix: &FixRecord) {}
}
