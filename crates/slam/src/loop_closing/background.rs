//! The global BA on its own thread (ORB-SLAM2's `RunGlobalBundleAdjustment` thread): set up
//! from the map when a loop is closed, solved away from it, applied when done; a later loop
//! makes a running one stale (its solution would undo that loop's correction), and the
//! latest map is solved again once the stale one has finished.

use std::thread::JoinHandle;

use jointloc_geometry::{PinholeCamera, Sim3};

use super::global_ba::{GlobalBaJob, GlobalBaSolution, GlobalBaStats};
use crate::error::{Result, SlamError};
use crate::local_mapping::LocalBaConfig;
use crate::map::Map;

#[derive(Debug, Default)]
pub(super) struct BackgroundGba {
    running: Option<JoinHandle<Result<GlobalBaSolution>>>,
    /// A loop was corrected after the running job was set up.
    stale: bool,
}

impl BackgroundGba {
    pub(super) fn running(&self) -> bool {
        self.running.is_some()
    }

    /// Starts a global BA of `map` as it is now; with one already running, marks that one
    /// stale so that the map is solved again when it ends. Where no thread can be started,
    /// solves in place.
    pub(super) fn start(
        &mut self,
        map: &mut Map,
        camera: &PinholeCamera,
        ba: &LocalBaConfig,
        slam_to_world: Option<&Sim3>,
    ) {
        if self.running.is_some() {
            self.stale = true;
            return;
        }
        let job = GlobalBaJob::prepare(map, camera, ba, slam_to_world);
        let keyframes = job.n_keyframes();
        match std::thread::Builder::new()
            .name("global-ba".into())
            .spawn(move || job.solve())
        {
            Ok(handle) => {
                tracing::debug!(keyframes, "global BA started on its thread");
                self.running = Some(handle);
                self.stale = false;
            }
            Err(e) => {
                tracing::warn!(error = %e, "no thread for the global BA: solving it in place");
                let job = GlobalBaJob::prepare(map, camera, ba, slam_to_world);
                match job.solve() {
                    Ok(solution) => {
                        solution.apply(map);
                    }
                    Err(e) => tracing::warn!(error = %e, "global BA failed"),
                }
            }
        }
    }

    /// See [`super::LoopCloser::poll_global_ba`].
    pub(super) fn poll(
        &mut self,
        map: &mut Map,
        camera: &PinholeCamera,
        ba: &LocalBaConfig,
        slam_to_world: Option<&Sim3>,
        wait: bool,
    ) -> Result<Option<GlobalBaStats>> {
        loop {
            let Some(handle) = self.running.take_if(|h| wait || h.is_finished()) else {
                return Ok(None);
            };
            let solution = handle
                .join()
                .map_err(|_| SlamError::InvalidProblem("the global BA thread panicked".into()))?;
            if self.stale {
                tracing::debug!("global BA overtaken by a later loop: solving again");
                self.start(map, camera, ba, slam_to_world);
                if !wait {
                    return Ok(None);
                }
                continue;
            }
            return Ok(Some(solution?.apply(map)));
        }
    }
}
