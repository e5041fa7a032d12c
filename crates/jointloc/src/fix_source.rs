//! Where the absolute fixes come from. The system asks a [`FixSource`] for a fix on every
//! k-th frame; the map localiser of paper §III-B ([`AbsLocalizer`]) is the one a flight uses,
//! and a source can be wrapped (fault injection, [`crate::faults::FaultyFixes`]) or replaced
//! (a test's fixes from ground truth, another localiser) without the fusion knowing.

use image::GrayImage;
use jointloc_absloc::{AbsLocalizer, AbslocError, FrameView, Outcome, Prior};

/// One request: the frame, its altimeter reading and where the fusion expects it.
#[derive(Debug, Clone, Copy)]
pub struct FixRequest<'a> {
    /// Index of the frame in the flight (0-based).
    pub frame: usize,
    pub timestamp: f64,
    pub image: &'a GrayImage,
    /// Altimeter reading, metres above the ground.
    pub altitude: f64,
    pub prior: &'a Prior,
    /// 1 for a camera frame; a virtual frame ([`crate::virtual_frames`]) covers `zoom` times
    /// more ground per side.
    pub zoom: f64,
    /// A virtual frame's covered pixels (row-major); `None`: every pixel.
    pub valid: Option<&'a [bool]>,
}

/// What a source gives for a request.
#[derive(Debug, Clone, PartialEq)]
pub struct Located {
    pub outcome: Outcome,
    /// The fix was made wrong on purpose (fault injection); recorded in `fixes.txt`.
    pub injected: bool,
}

/// A source of absolute fixes. Sources run on the absolute-localisation thread in the
/// threaded mode, hence `Send`.
pub trait FixSource: Send + std::fmt::Debug {
    /// The outcome for `request`, or `None` when the source made no attempt (an outage).
    fn localize(&mut self, request: &FixRequest<'_>) -> Result<Option<Located>, AbslocError>;
}

impl FixSource for AbsLocalizer {
    fn localize(&mut self, request: &FixRequest<'_>) -> Result<Option<Located>, AbslocError> {
        let view = FrameView {
            image: request.image,
            altitude: request.altitude,
            zoom: request.zoom,
            valid: request.valid,
        };
        tracing::debug!(
            frame = request.frame,
            timestamp = request.timestamp,
            prior = ?request.prior.position,
            heading = ?request.prior.heading,
            "absolute localisation request"
        );
        let outcome = self.localize_view(&view, request.prior)?;
        Ok(Some(Located {
            outcome,
            injected: false,
        }))
    }
}

impl FixSource for Box<dyn FixSource> {
    fn localize(&mut self, request: &FixRequest<'_>) -> Result<Option<Located>, AbslocError> {
        (**self).localize(request)
    }
}
