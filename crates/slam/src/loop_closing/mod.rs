//! Loop closing (ORB-SLAM2's `LoopClosing`): after each keyframe is mapped, look for an old
//! keyframe over the same ground, verify it with a Sim(3), correct the loop (pose graph over
//! the essential graph) and run a global bundle adjustment. Sequential and seeded, so runs
//! stay deterministic.

pub mod appearance;
mod background;
pub mod correction;

pub use background::Applied;
pub mod detection;
pub mod global_ba;
pub mod pose_graph;
pub mod sim3_ransac;

use std::collections::BTreeSet;
use std::sync::Arc;
use std::time::Instant;

use jointloc_geometry::{PinholeCamera, Sim3};
use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::local_mapping::LocalBaConfig;
use crate::map::{KeyFrameId, Map};
use crate::place::Vocabulary;

pub use correction::CorrectionStats;
pub use detection::VerifiedLoop;
pub use global_ba::GlobalBaStats;
pub use pose_graph::PoseGraphConfig;

/// Where loop candidates come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CandidateSource {
    /// Keyframes whose camera centre is within reach of the new one's (no vocabulary).
    Position,
    /// Keyframes that look like the new one by bag of words (ORB-SLAM2's way; the embedded
    /// vocabulary trained on our rendered frames).
    Appearance,
    /// Position candidates first, then appearance ones not among them.
    Both,
}

/// Settings of loop closing (`[loop_closing]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LoopClosingConfig {
    /// Off: keyframes are never checked for loops.
    pub enabled: bool,
    /// Where candidates come from (`"position"`, `"appearance"`, `"both"`).
    pub candidates: CandidateSource,
    /// A candidate's camera centre is within this many of the new keyframe's median depths
    /// (one depth ≈ the footprint's width at a 53° field of view) …
    pub reach_depths: f64,
    /// … plus this fraction of the path flown between the two (the drift allowed; 3 %, three
    /// times the worst drift measured without loops).
    pub drift_fraction: f64,
    /// Candidates lie at least this many depths of path behind (nearer is not a loop).
    pub min_path_depths: f64,
    /// Candidates verified per keyframe at most, nearest first.
    pub max_candidates: usize,
    /// Descriptor matches between the two keyframes' map points needed to try a Sim(3)
    /// (ORB-SLAM2: 20).
    pub min_matches: usize,
    /// RANSAC iterations of the Sim(3) (ORB-SLAM2: 300).
    pub ransac_iterations: usize,
    /// Pairs that must support the Sim(3) (ORB-SLAM2: 20).
    pub min_sim3_inliers: usize,
    /// A verified loop may move the new keyframe by at most this many depths plus
    /// `drift_fraction` of the path …
    pub correction_depths: f64,
    /// … and turn it by at most this many degrees: a larger correction is a false match.
    pub max_turn_deg: f64,
    /// Largest scale change a loop may bring, as a fraction (0.3: scale within 1/1.3…1.3).
    pub max_scale_change: f64,
    /// Loop points that must match in the new keyframe at the corrected pose (ORB-SLAM2: 40).
    pub min_projected_matches: usize,
    /// Keyframes after a closed loop before the next one is looked for (ORB-SLAM2: 10).
    pub min_keyframes_between: u64,
    /// The essential-graph optimisation.
    pub pose_graph: PoseGraphConfig,
    /// Run a global bundle adjustment after each loop correction.
    pub global_ba: bool,
    /// Solve the global BA on its own thread while tracking and local mapping go on, and
    /// apply it when it is done (ORB-SLAM2's way): no stall of tracking, but the frame it
    /// lands on depends on timing, so runs are no longer reproducible. Off by default and in
    /// every `--sequential` run; `jointloc vo` without `--sequential` turns it on. On a
    /// 1000 m flight without the keyframe cap an inline global BA stalled tracking for
    /// 7–25 s (docs/vo.md §6.1a).
    pub global_ba_thread: bool,
    /// Also close loops once the map is geo-referenced (a SLAM→world similarity is set).
    /// Off by default: there the absolute fixes already bound the drift, and the fusion's
    /// ties between fixes and keyframes are not yet re-derived after a correction, so a loop
    /// made JointLoc's outputs worse (three 150 m flights at 10 m: online 0.064 / 0.068 /
    /// 0.053 m without, 0.082 / 0.066 / 0.118 m with; docs/vo.md §6).
    pub when_geo_referenced: bool,
}

impl Default for LoopClosingConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            candidates: CandidateSource::Position,
            reach_depths: 1.0,
            drift_fraction: 0.03,
            min_path_depths: 3.0,
            max_candidates: 3,
            min_matches: 20,
            ransac_iterations: 300,
            min_sim3_inliers: 20,
            correction_depths: 0.1,
            max_turn_deg: 10.0,
            max_scale_change: 0.3,
            min_projected_matches: 40,
            min_keyframes_between: 10,
            pose_graph: PoseGraphConfig::default(),
            global_ba: true,
            global_ba_thread: false,
            when_geo_referenced: false,
        }
    }
}

/// One loop closed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LoopClosure {
    /// The new keyframe and the old one it was matched to, by id.
    pub keyframe: u64,
    pub loop_keyframe: u64,
    /// Index of the frame that became the new keyframe.
    pub frame_index: usize,
    /// Sim(3) RANSAC inliers and loop points matched at the corrected pose.
    pub sim3_inliers: usize,
    pub matches: usize,
    /// How far the new keyframe moved (SLAM units) and its scale correction.
    pub correction: f64,
    pub scale: f64,
    /// Essential-graph size.
    pub graph_nodes: usize,
    pub graph_edges: usize,
    /// Wall time of verification + correction + global BA, milliseconds.
    pub ms: f64,
    /// Its shares: finding and verifying the loop, correcting the map (fusion and the
    /// essential graph), and the global BA (on its own thread: setting it up and starting it).
    #[serde(default)]
    pub detection_ms: f64,
    #[serde(default)]
    pub correction_ms: f64,
    pub global_ba_ms: f64,
}

/// The loop closer's state between keyframes.
#[derive(Debug)]
pub struct LoopCloser {
    pub config: LoopClosingConfig,
    last_loop: Option<KeyFrameId>,
    loop_edges: BTreeSet<(KeyFrameId, KeyFrameId)>,
    closed: Vec<LoopClosure>,
    background: background::Background,
    /// Loaded when appearance candidates are asked for.
    vocabulary: Option<Arc<Vocabulary>>,
    bows: appearance::BowCache,
}

impl LoopCloser {
    pub fn new(config: LoopClosingConfig) -> Self {
        let vocabulary = (config.enabled && config.candidates != CandidateSource::Position)
            .then(Vocabulary::shared);
        Self {
            config,
            last_loop: None,
            loop_edges: BTreeSet::new(),
            closed: Vec::new(),
            background: background::Background::default(),
            vocabulary,
            bows: appearance::BowCache::default(),
        }
    }

    /// The loop candidates of `kf`, by the configured source.
    fn candidates(&mut self, map: &Map, kf: KeyFrameId) -> Vec<KeyFrameId> {
        let cfg = &self.config;
        let mut out = Vec::new();
        if cfg.candidates != CandidateSource::Appearance {
            out = detection::position_candidates(map, kf, cfg);
        }
        if let (CandidateSource::Appearance | CandidateSource::Both, Some(v)) =
            (cfg.candidates, &self.vocabulary)
        {
            self.bows.retain_in(map);
            for c in
                appearance::appearance_candidates(map, kf, v, &mut self.bows, cfg.max_candidates)
            {
                if !out.contains(&c) {
                    out.push(c);
                }
            }
        }
        out
    }

    /// Applies what finished on the background threads (`wait`: waits for all of it): an
    /// essential graph (then starts the global BA after it), a global BA. A global BA
    /// overtaken by a later loop correction is dropped and the latest map solved instead.
    pub fn poll_background(
        &mut self,
        map: &mut Map,
        camera: &PinholeCamera,
        ba: &LocalBaConfig,
        slam_to_world: Option<&Sim3>,
        wait: bool,
    ) -> Result<Applied> {
        self.background.poll(map, camera, ba, slam_to_world, wait)
    }

    /// Whether work runs on a background thread.
    pub fn background_running(&self) -> bool {
        self.background.running()
    }

    /// Loops closed so far, in order.
    pub fn closed(&self) -> &[LoopClosure] {
        &self.closed
    }

    /// Whether a loop correction's essential graph is being solved: the map must not change
    /// (no keyframe insertion) until it is applied.
    pub fn correcting(&self) -> bool {
        self.background.correcting()
    }

    /// Looks for a loop at the newly mapped keyframe `kf` and, when one verifies, corrects the
    /// map. Returns the loop closed, if any.
    pub fn process(
        &mut self,
        map: &mut Map,
        kf: KeyFrameId,
        camera: &PinholeCamera,
        ba: &LocalBaConfig,
        slam_to_world: Option<&Sim3>,
    ) -> Result<Option<LoopClosure>> {
        let cfg = self.config;
        if !cfg.enabled
            || self.background.correcting()
            || (slam_to_world.is_some() && !cfg.when_geo_referenced)
            || map.n_keyframes() < 10
            || self
                .last_loop
                .is_some_and(|l| kf.0 < l.0 + cfg.min_keyframes_between)
        {
            return Ok(None);
        }
        let t0 = Instant::now();
        let candidates = self.candidates(map, kf);
        let Some(found) = candidates
            .into_iter()
            .find_map(|c| detection::verify(map, kf, c, camera, &cfg))
        else {
            return Ok(None);
        };
        let Some(k) = map.keyframe(kf) else {
            return Ok(None);
        };
        let (centre_before, frame_index) = (k.centre(), k.frame_index);
        let t_found = Instant::now();
        let threaded = cfg.global_ba_thread;
        let stats = if threaded {
            let (stats, graph) = correction::correct_locally(
                map,
                kf,
                &found,
                camera,
                &self.loop_edges,
                &cfg.pose_graph,
            );
            if graph.n_nodes() > 0 {
                self.background.start_graph(graph, cfg.global_ba, map)?;
            }
            stats
        } else {
            correction::correct_loop(map, kf, &found, camera, &self.loop_edges, &cfg.pose_graph)?
        };
        self.loop_edges.insert((kf, found.loop_keyframe));
        let t1 = Instant::now();
        if cfg.global_ba && !threaded {
            global_ba::global_bundle_adjustment(map, camera, ba, slam_to_world)?;
        }
        let t2 = Instant::now();
        self.last_loop = Some(kf);
        let correction = map
            .keyframe(kf)
            .map_or(0.0, |k| (k.centre() - centre_before).norm());
        let closure = LoopClosure {
            keyframe: kf.0,
            loop_keyframe: found.loop_keyframe.0,
            frame_index,
            sim3_inliers: found.sim3_inliers,
            matches: found.matches.len(),
            correction,
            scale: found.corrected.scale,
            graph_nodes: stats.nodes,
            graph_edges: stats.edges,
            ms: (t2 - t0).as_secs_f64() * 1e3,
            detection_ms: (t_found - t0).as_secs_f64() * 1e3,
            correction_ms: (t1 - t_found).as_secs_f64() * 1e3,
            global_ba_ms: (t2 - t1).as_secs_f64() * 1e3,
        };
        tracing::info!(
            ?closure,
            fused = stats.fused,
            links = stats.loop_links,
            pose_graph_ms = stats.pose_graph_ms,
            nodes = stats.nodes,
            edges = stats.edges,
            "loop closed"
        );
        self.closed.push(closure);
        Ok(Some(closure))
    }
}
