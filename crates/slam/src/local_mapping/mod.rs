//! Local mapping (ORB-SLAM2's `LocalMapping`, paper §III-C), run for each new keyframe:
//! link the tracked points to it, cull recent points, triangulate new ones with the covisible
//! neighbours, fuse duplicates, run the local bundle adjustment (with the global-position
//! hook), and cull redundant keyframes.

pub mod culling;
pub mod fusion;
pub mod lba;
pub mod triangulation;

use std::time::Instant;

use jointloc_geometry::{PinholeCamera, Sim3};
use serde::{Deserialize, Serialize};

use crate::cpu_time::{cpu_ms, thread_cpu_ns};
use crate::error::Result;
use crate::frame::Frame;
use crate::map::{KeyFrame, KeyFrameId, Map};

pub use culling::CulledKeyFrame;
pub use lba::{GroundModel, LbaStats, LocalBaConfig, local_bundle_adjustment};
pub use triangulation::TriangulationConfig;

/// Settings of the local mapper.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LocalMappingConfig {
    pub triangulation: TriangulationConfig,
    pub ba: LocalBaConfig,
    /// Covisible keyframes searched for duplicate points (ORB-SLAM2 monocular: 20).
    pub fusion_neighbours: usize,
    /// Recent points found in fewer than this fraction of the frames predicting them are
    /// erased (ORB-SLAM2: 0.25).
    pub min_found_ratio: f64,
    /// A keyframe with more than this fraction of redundant points is erased (ORB-SLAM2: 0.9).
    pub keyframe_redundancy: f64,
}

impl Default for LocalMappingConfig {
    fn default() -> Self {
        Self {
            triangulation: TriangulationConfig::default(),
            ba: LocalBaConfig::default(),
            fusion_neighbours: 20,
            min_found_ratio: 0.25,
            keyframe_redundancy: 0.9,
        }
    }
}

/// What processing one keyframe did, with its timings.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LocalMappingReport {
    pub keyframe: Option<KeyFrameId>,
    pub culled_points: usize,
    pub new_points: usize,
    pub fused: usize,
    pub lba: LbaStats,
    pub culled_keyframes: Vec<CulledKeyFrame>,
    /// Local BA time, milliseconds.
    pub lba_ms: f64,
    /// Whole keyframe processing, milliseconds.
    pub total_ms: f64,
    /// The same two as thread CPU time, milliseconds (`None` where unavailable).
    pub lba_cpu_ms: Option<f64>,
    pub total_cpu_ms: Option<f64>,
}

/// The local mapper's state: points created recently, still on probation.
#[derive(Debug, Clone, Default)]
pub struct LocalMapper {
    pub config: LocalMappingConfig,
    recent_points: Vec<crate::map::MapPointId>,
}

impl LocalMapper {
    pub fn new(config: LocalMappingConfig) -> Self {
        Self {
            config,
            recent_points: Vec::new(),
        }
    }

    /// Makes `frame` (tracked) a keyframe: its inlier matches become observations.
    pub fn insert_keyframe(&mut self, map: &mut Map, frame: &Frame) -> Option<KeyFrameId> {
        let pose = frame.pose?;
        let mut kf = KeyFrame::new(
            frame.index,
            frame.timestamp,
            pose,
            frame.features.clone(),
            frame.grid.clone(),
        );
        kf.altitude = frame.altitude;
        let id = map.insert_keyframe(kf);
        for (i, p) in frame.points.iter().enumerate() {
            if let (Some(p), false) = (p, frame.outliers[i])
                && map.add_observation(*p, id, i)
            {
                map.update_normal_and_depth(*p);
                map.update_descriptor(*p);
            }
        }
        map.update_connections(id);
        Some(id)
    }

    /// Runs the mapping steps for keyframe `kf` (already inserted).
    pub fn process(
        &mut self,
        map: &mut Map,
        kf: KeyFrameId,
        camera: &PinholeCamera,
        slam_to_world: Option<&Sim3>,
        ground: Option<&dyn GroundModel>,
    ) -> Result<LocalMappingReport> {
        let start = Instant::now();
        let start_cpu = thread_cpu_ns();
        let mut report = LocalMappingReport {
            keyframe: Some(kf),
            ..LocalMappingReport::default()
        };
        let cfg = self.config;
        report.culled_points =
            culling::cull_recent_points(map, &mut self.recent_points, kf, cfg.min_found_ratio);
        let created = triangulation::create_new_points(map, kf, camera, &cfg.triangulation);
        report.new_points = created.len();
        self.recent_points.extend(created);
        map.update_connections(kf);
        report.fused = fusion::fuse_with_neighbours(map, kf, camera, cfg.fusion_neighbours);
        let t = Instant::now();
        let t_cpu = thread_cpu_ns();
        report.lba = local_bundle_adjustment(map, kf, camera, &cfg.ba, slam_to_world, ground)?;
        report.lba_ms = t.elapsed().as_secs_f64() * 1e3;
        report.lba_cpu_ms = cpu_ms(t_cpu, thread_cpu_ns());
        report.culled_keyframes = culling::cull_keyframes(map, kf, cfg.keyframe_redundancy);
        report.total_ms = start.elapsed().as_secs_f64() * 1e3;
        report.total_cpu_ms = cpu_ms(start_cpu, thread_cpu_ns());
        tracing::debug!(
            keyframe = %kf,
            new_points = report.new_points,
            fused = report.fused,
            culled_points = report.culled_points,
            culled_keyframes = report.culled_keyframes.len(),
            lba_ms = report.lba_ms,
            "keyframe mapped"
        );
        Ok(report)
    }

    /// Marks points created at initialisation as recent.
    pub fn add_recent(&mut self, map: &Map) {
        self.recent_points.extend(map.points().map(|p| p.id));
    }
}
