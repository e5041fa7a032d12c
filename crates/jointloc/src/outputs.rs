//! What a run leaves behind, and how it is written: [`JointLoc::finish`] ends the run and gives
//! [`Outputs`]; [`Outputs::write`] writes the files of `jointloc run` through
//! `jointloc_formats` (layout and columns: `docs/architecture.md`).

use std::path::Path;

use jointloc_formats::MapCrs;
use jointloc_formats::outputs::{
    OnlineFrame, OnlineStatus, OutputCrs, Summary, TerrainSummary, TimingSummary, write_fixes,
    write_json, write_online_tum, write_settings_toml,
};
use jointloc_geometry::trajectory::Trajectory;
use jointloc_slam::system::median;
use nalgebra::Vector3;

use crate::config::JointLocConfig;
use crate::error::{JointLocError, Result};
use crate::system::{FixRecord, JointLoc};

/// Everything a run produced.
#[derive(Debug, Clone)]
pub struct Outputs {
    /// Every frame as known online (`trajectory.tum`).
    pub online: Vec<OnlineFrame>,
    /// Every tracked frame as known at the end (`trajectory-final.tum`); `None` when nothing
    /// was geo-referenced.
    pub frames: Option<Trajectory>,
    /// The keyframes as known at the end (`keyframes.tum`).
    pub keyframes: Option<Trajectory>,
    /// Every fix (`fixes.txt`).
    pub fixes: Vec<FixRecord>,
    /// Counts and rates (`summary.json`); add evaluations to `summary.evaluation`.
    pub summary: Summary,
    /// Per-module medians (`timing.json`).
    pub timing: TimingSummary,
    /// The settings the run used (`config.toml`): `--config` repeats the run with them.
    pub config: JointLocConfig,
}

impl Outputs {
    /// Moves every pose and fix from the local world frame into the map's CRS
    /// (`easting = easting_m + x`, `northing = northing_m + y`, heights unchanged) and records
    /// it in the summary. Evaluate against local ground truth before, or shift it the same way.
    pub fn into_map_frame(&mut self, crs: &MapCrs) {
        if self.summary.output_crs.is_some() {
            return;
        }
        let shift = Vector3::new(crs.easting_m, crs.northing_m, 0.0);
        for f in &mut self.online {
            if let OnlineStatus::World(p) = &mut f.status {
                *p = p.translated(shift);
            }
        }
        for t in [&mut self.frames, &mut self.keyframes]
            .into_iter()
            .flatten()
        {
            t.poses.iter_mut().for_each(|p| *p = p.translated(shift));
        }
        for f in &mut self.fixes {
            f.position[0] += crs.easting_m;
            f.position[1] += crs.northing_m;
        }
        self.summary.output_crs = Some(OutputCrs {
            easting_m: crs.easting_m,
            northing_m: crs.northing_m,
            epsg: crs.epsg,
            citation: crs.citation.clone(),
        });
    }

    /// The files [`Outputs::write`] writes.
    pub const FILES: [&str; 7] = [
        "trajectory.tum",
        "trajectory-final.tum",
        "keyframes.tum",
        "fixes.txt",
        "timing.json",
        "summary.json",
        "config.toml",
    ];

    /// Fails, naming the file, if `dir` already holds one of [`Outputs::FILES`] and
    /// `overwrite` is false; call it before a run so a long run cannot end in that error.
    pub fn check_writable(dir: &Path, overwrite: bool) -> Result<()> {
        for name in Self::FILES {
            let path = dir.join(name);
            if path.exists() && !overwrite {
                return Err(JointLocError::WouldOverwrite { path });
            }
        }
        Ok(())
    }

    /// The world poses written to `trajectory.tum`.
    pub fn online_world_poses(&self) -> usize {
        world_poses(&self.online)
    }

    /// Writes every file into `dir` (created if missing); existing files are replaced only
    /// with `overwrite`.
    pub fn write(&self, dir: &Path, overwrite: bool) -> Result<()> {
        Self::check_writable(dir, overwrite)?;
        std::fs::create_dir_all(dir).map_err(|source| jointloc_formats::FormatError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
        write_online_tum(&dir.join("trajectory.tum"), &self.online)?;
        if let Some(k) = &self.keyframes {
            k.write_tum(dir.join("keyframes.tum"))?;
        }
        if let Some(f) = &self.frames {
            f.write_tum(dir.join("trajectory-final.tum"))?;
        }
        let rows: Vec<_> = self.fixes.iter().map(FixRecord::to_row).collect();
        write_fixes(&dir.join("fixes.txt"), &rows)?;
        write_json(&dir.join("timing.json"), &self.timing)?;
        write_settings_toml(&dir.join("config.toml"), CONFIG_HEADER, &self.config)?;
        self.write_summary(dir)
    }

    /// Writes (or rewrites) `summary.json` alone, e.g. after adding evaluations.
    pub fn write_summary(&self, dir: &Path) -> Result<()> {
        Ok(write_json(&dir.join("summary.json"), &self.summary)?)
    }
}

impl JointLoc {
    /// Ends the run: waits for the absolute search in flight (threaded mode), computes the
    /// outputs known as a whole at the end (the global BA, [`crate::final_ba`]) once, and
    /// gives everything the run produced.
    pub fn finish(mut self) -> Result<Outputs> {
        self.flush()?;
        self.slam.finish_background_work()?;
        if self.merge_earlier_maps(true) {
            self.refit();
        }
        let end = self.end_outputs()?;
        let n = self.frames();
        let timing = self.timing();
        let busy_s: f64 = timing.frame_ms.iter().sum::<f64>() / 1e3;
        let wall_s = match (self.first_frame_at, self.last_done_at) {
            (Some(a), Some(b)) => b.duration_since(a).as_secs_f64(),
            _ => 0.0,
        };
        let hz = n as f64 / wall_s.max(1e-9);
        let capacity_hz = n as f64 / busy_s.max(1e-9);
        let slam = self.slam().timing();
        let fixes = self.fixes();
        let online = self.online().to_vec();
        let terrain = self.terrain_correction();
        let summary = Summary {
            frames: n,
            world_poses: world_poses(&online),
            geo_referenced_from: online.iter().position(|f| f.world_pose().is_some()),
            lost: self.lost_frames(),
            new_maps: self.new_maps(),
            maps_merged: self.maps_merged(),
            maps_at_end: self.maps_at_end(),
            loops_closed: self.loops_closed(),
            fixes_found: fixes.len(),
            fixes_used: fixes.iter().filter(|f| f.used).count(),
            fixes_inliers: fixes.iter().filter(|f| f.inlier).count(),
            hz,
            capacity_hz,
            mode: self.mode().name().to_string(),
            absolute_attempts: timing.absolute_ms.len(),
            skipped_busy: timing.skipped_busy,
            skipped_outage: timing.skipped_outage,
            skipped_untracked: timing.skipped_untracked,
            virtual_frames: timing.virtual_frames,
            skipped_no_view: timing.skipped_no_view,
            skipped_backoff: timing.skipped_backoff,
            fixes_injected_wrong: fixes.iter().filter(|f| f.injected).count(),
            first_fix_global: fixes.first().map(|f| f.global),
            first_fix_searched_tiles: fixes.first().map(|f| f.searched_tiles),
            terrain_correction: TerrainSummary {
                x: terrain.offset.x,
                y: terrain.offset.y,
                updates: terrain.updates,
            },
            camera_tilt: self.camera_tilt_deg(),
            final_ba: end.final_ba,
            realtime: None,
            input_faults: self.altimeter_gate.counts(),
            output_crs: None,
            evaluation: Default::default(),
        };
        let timing = TimingSummary {
            absolute_localisation_ms: median(&timing.absolute_ms),
            alignment_ms: median(&timing.alignment_ms),
            orb_extraction_ms: median(&slam.orb_ms),
            tracking_ms: median(&slam.tracking_ms),
            local_mapping_ms: median(&slam.local_mapping_ms),
            local_ba_ms: median(&slam.lba_ms),
            frame_ms: median(&timing.frame_ms),
            hz,
            capacity_hz,
        };
        Ok(Outputs {
            online,
            frames: end.frames,
            keyframes: end.keyframes,
            fixes: fixes.to_vec(),
            summary,
            timing,
            config: self.config.clone(),
        })
    }
}

/// The comment at the top of `config.toml`.
const CONFIG_HEADER: &str = "The settings of this run: the defaults, the --config file and the flags, merged.\n\
    `jointloc run --config config.toml` runs with them again (flags still override them).";

/// Frames with a world pose in `online`.
fn world_poses(online: &[OnlineFrame]) -> usize {
    online.iter().filter(|f| f.world_pose().is_some()).count()
}
