//! The absolute-localisation thread of the real-time mode (paper §III-A: absolute and relative
//! localisation run in parallel). Requests go through a channel of capacity one: when the
//! thread is still busy with the previous frame, the new request is refused and the frame is
//! simply not localised (the only frames the real-time mode may skip); tracking never waits.

use std::sync::mpsc::{Receiver, SyncSender, TryRecvError, TrySendError, sync_channel};
use std::thread::JoinHandle;

use image::GrayImage;
use jointloc_absloc::correlate::NoPeak;
use jointloc_absloc::{Failure, FailureReason, Outcome, Prior, search_radius};

use crate::error::{JointLocError, Result};
use crate::fix_source::{FixRequest, FixSource, Located};
use crate::virtual_frames::MosaicJob;

struct Request {
    frame: usize,
    timestamp: f64,
    image: GrayImage,
    altitude: f64,
    prior: Prior,
    zoom: f64,
    valid: Option<Vec<bool>>,
    /// A virtual frame to render and search instead of `image`.
    mosaic: Option<MosaicJob>,
}

/// A finished search: the frame it was for and its outcome (`None`: the source made no
/// attempt).
pub(crate) type Finished = (
    usize,
    std::result::Result<Option<Located>, jointloc_absloc::AbslocError>,
);

/// The thread and its two channels.
pub(crate) struct AbsoluteWorker {
    requests: Option<SyncSender<Request>>,
    results: Receiver<Finished>,
    handle: Option<JoinHandle<()>>,
    busy: bool,
}

impl std::fmt::Debug for AbsoluteWorker {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AbsoluteWorker")
            .field("busy", &self.busy)
            .finish()
    }
}

impl AbsoluteWorker {
    pub(crate) fn spawn(mut source: Box<dyn FixSource>) -> Result<Self> {
        let (req_tx, req_rx) = sync_channel::<Request>(1);
        let (res_tx, res_rx) = sync_channel::<Finished>(4);
        let handle = std::thread::Builder::new()
            .name("jointloc-absolute".into())
            .spawn(move || {
                while let Ok(r) = req_rx.recv() {
                    let began = std::time::Instant::now();
                    let rendered = r.mosaic.as_ref().map(MosaicJob::render);
                    let (image, zoom, valid) = match &rendered {
                        Some(Some(m)) => (&m.image, m.zoom, Some(m.valid.as_slice())),
                        _ => (&r.image, r.zoom, r.valid.as_deref()),
                    };
                    let out = match rendered {
                        // The virtual frame covered too little: a failed search.
                        Some(None) => Ok(Some(Located {
                            outcome: Outcome::Failed(Failure {
                                reason: FailureReason::NoPeak(NoPeak::TooSmall { valid_px: 0 }),
                                searched_tiles: 0,
                                global: false,
                                next_radius: search_radius(0.0),
                                ms: began.elapsed().as_secs_f64() * 1e3,
                            }),
                            injected: false,
                        })),
                        _ => source.localize(&FixRequest {
                            frame: r.frame,
                            timestamp: r.timestamp,
                            image,
                            altitude: r.altitude,
                            prior: &r.prior,
                            zoom,
                            valid,
                        }),
                    };
                    if res_tx.send((r.frame, out)).is_err() {
                        break;
                    }
                }
            })
            .map_err(|e| JointLocError::Thread {
                message: e.to_string(),
            })?;
        Ok(Self {
            requests: Some(req_tx),
            results: res_rx,
            handle: Some(handle),
            busy: false,
        })
    }

    /// Whether a search is in flight (a request now would be refused).
    pub(crate) fn is_busy(&self) -> bool {
        self.busy
    }

    /// Hands a frame to the thread if it is idle; false (frame skipped) when it is busy.
    pub(crate) fn try_submit(
        &mut self,
        request: &FixRequest<'_>,
        mosaic: Option<MosaicJob>,
    ) -> bool {
        if self.busy {
            return false;
        }
        let Some(tx) = &self.requests else {
            return false;
        };
        let request = Request {
            frame: request.frame,
            timestamp: request.timestamp,
            image: request.image.clone(),
            altitude: request.altitude,
            prior: *request.prior,
            zoom: request.zoom,
            valid: request.valid.map(<[bool]>::to_vec),
            mosaic,
        };
        // At most one request is ever outstanding (`busy`), so the slot is free.
        match tx.try_send(request) {
            Ok(()) => {
                self.busy = true;
                true
            }
            Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => false,
        }
    }

    /// The next finished search, if one is ready; an error when the thread died.
    pub(crate) fn try_next(&mut self) -> Result<Option<Finished>> {
        match self.results.try_recv() {
            Ok(f) => {
                self.busy = false;
                Ok(Some(f))
            }
            Err(TryRecvError::Empty) => Ok(None),
            Err(TryRecvError::Disconnected) => Err(JointLocError::Thread {
                message: "the absolute-localisation thread stopped".into(),
            }),
        }
    }

    /// Waits for the search in flight, if any.
    pub(crate) fn wait(&mut self) -> Result<Option<Finished>> {
        if !self.busy {
            return Ok(None);
        }
        match self.results.recv() {
            Ok(f) => {
                self.busy = false;
                Ok(Some(f))
            }
            Err(_) => Err(JointLocError::Thread {
                message: "the absolute-localisation thread stopped".into(),
            }),
        }
    }
}

impl Drop for AbsoluteWorker {
    fn drop(&mut self) {
        // Closing the request channel ends the thread's loop; drain a pending result so its
        // send cannot block, then join.
        self.requests = None;
        while self.results.try_recv().is_ok() {}
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}
