//! Loop closing's expensive steps on their own thread (ORB-SLAM2 runs its `LoopClosing` and
//! global BA threads beside tracking): the essential-graph optimisation of a loop correction,
//! then the global BA. Each is set up from the map, solved away from it and applied when done.
//! While the essential graph is solved, the map must not change (ORB-SLAM2 stops local mapping
//! for the correction): the system inserts no keyframe meanwhile, tracking goes on. The global
//! BA lets mapping go on and carries what was mapped meanwhile along (see
//! [`GlobalBaSolution::apply`]); a later loop makes a running global BA stale (its solution
//! would undo that loop's correction), and the map is solved again once it has finished.

use std::thread::JoinHandle;

use jointloc_geometry::{PinholeCamera, Sim3};

use super::correction::{EssentialGraph, SolvedEssentialGraph};
use super::global_ba::{GlobalBaJob, GlobalBaSolution, GlobalBaStats};
use crate::error::{Result, SlamError};
use crate::local_mapping::LocalBaConfig;
use crate::map::Map;

/// What a poll applied.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Applied {
    /// An essential graph: every keyframe and point moved.
    pub essential_graph: bool,
    /// A global BA, with its figures.
    pub global_ba: Option<GlobalBaStats>,
}

impl Applied {
    /// Whether keyframes moved.
    pub fn moved(&self) -> bool {
        self.essential_graph || self.global_ba.is_some()
    }
}

#[derive(Debug, Default)]
pub(super) struct Background {
    graph: Option<JoinHandle<Result<SolvedEssentialGraph>>>,
    /// A global BA to start once the essential graph is applied.
    global_ba_after_graph: bool,
    global_ba: Option<JoinHandle<Result<GlobalBaSolution>>>,
    /// A loop was corrected after the running global BA was set up.
    stale: bool,
}

fn joined<T>(handle: JoinHandle<Result<T>>, what: &str) -> Result<T> {
    handle
        .join()
        .map_err(|_| SlamError::InvalidProblem(format!("the {what} thread panicked")))?
}

impl Background {
    pub(super) fn running(&self) -> bool {
        self.graph.is_some() || self.global_ba.is_some()
    }

    /// Whether an essential graph is being solved (the map must not change).
    pub(super) fn correcting(&self) -> bool {
        self.graph.is_some()
    }

    /// Solves `graph` on its own thread, then (`global_ba`) a global BA; where no thread can
    /// be started, solves the graph in place.
    pub(super) fn start_graph(
        &mut self,
        graph: EssentialGraph,
        global_ba: bool,
        map: &mut Map,
    ) -> Result<()> {
        // A global BA set up before this loop would undo its correction.
        self.stale |= self.global_ba.is_some();
        self.global_ba_after_graph = global_ba;
        let nodes = graph.n_nodes();
        let spare = graph.clone();
        match std::thread::Builder::new()
            .name("essential-graph".into())
            .spawn(move || graph.solve())
        {
            Ok(handle) => {
                tracing::debug!(nodes, "essential graph started on its thread");
                self.graph = Some(handle);
                Ok(())
            }
            Err(e) => {
                tracing::warn!(error = %e, "no thread for the essential graph: solving it in place");
                spare.solve()?.apply(map);
                Ok(())
            }
        }
    }

    /// Starts a global BA of `map` as it is now; with one already running, marks that one
    /// stale so that the map is solved again when it ends. Where no thread can be started,
    /// solves in place.
    pub(super) fn start_global_ba(
        &mut self,
        map: &mut Map,
        camera: &PinholeCamera,
        ba: &LocalBaConfig,
        slam_to_world: Option<&Sim3>,
    ) {
        if self.global_ba.is_some() {
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
                self.global_ba = Some(handle);
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

    /// See [`super::LoopCloser::poll_background`].
    pub(super) fn poll(
        &mut self,
        map: &mut Map,
        camera: &PinholeCamera,
        ba: &LocalBaConfig,
        slam_to_world: Option<&Sim3>,
        wait: bool,
    ) -> Result<Applied> {
        let mut applied = Applied::default();
        if let Some(handle) = self.graph.take_if(|h| wait || h.is_finished()) {
            joined(handle, "essential graph")?.apply(map);
            applied.essential_graph = true;
            if self.global_ba_after_graph {
                self.start_global_ba(map, camera, ba, slam_to_world);
            }
        }
        if self.graph.is_some() {
            return Ok(applied);
        }
        while let Some(handle) = self.global_ba.take_if(|h| wait || h.is_finished()) {
            let solution = joined(handle, "global BA");
            if self.stale {
                tracing::debug!("global BA overtaken by a later loop: solving again");
                self.start_global_ba(map, camera, ba, slam_to_world);
                if !wait {
                    break;
                }
                continue;
            }
            applied.global_ba = Some(solution?.apply(map));
            break;
        }
        Ok(applied)
    }
}
