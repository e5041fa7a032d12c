//! The one way to assemble the system: from the camera, the map and the settings, the builder
//! makes the absolute localiser (the matcher named in the settings, its weights from the
//! models folder), wraps it in the configured faults, starts the SLAM, and runs the absolute
//! localisation inline or on its own thread.

use std::path::PathBuf;

use jointloc_absloc::registry::{RegistryOptions, resolve};
use jointloc_absloc::{AbsLocalizer, MapTiles};
use jointloc_geometry::PinholeCamera;
use jointloc_slam::system::System;

use crate::config::JointLocConfig;
use crate::error::Result;
use crate::faults::FaultyFixes;
use crate::fix_source::FixSource;
use crate::observer::Observer;
use crate::system::{JointLoc, Mode};
use crate::virtual_frames::VirtualFrames;

/// Builds a [`JointLoc`]; see [`JointLoc::builder`].
pub struct JointLocBuilder {
    camera: PinholeCamera,
    tiles: MapTiles,
    config: JointLocConfig,
    mode: Mode,
    models_dir: Option<PathBuf>,
    threads: Option<usize>,
    source: Option<Box<dyn FixSource>>,
    observers: Vec<Box<dyn Observer>>,
    expected_altitude: Option<f64>,
}

impl std::fmt::Debug for JointLocBuilder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("JointLocBuilder")
            .field("mode", &self.mode)
            .field("matcher", &self.config.matcher)
            .field("models_dir", &self.models_dir)
            .field("observers", &self.observers.len())
            .finish_non_exhaustive()
    }
}

impl JointLoc {
    /// A builder for the system that localises `camera`'s frames in `tiles`' map with
    /// `config`; sequential by default.
    pub fn builder(
        camera: PinholeCamera,
        tiles: MapTiles,
        config: JointLocConfig,
    ) -> JointLocBuilder {
        JointLocBuilder {
            camera,
            tiles,
            config,
            mode: Mode::Sequential,
            models_dir: None,
            threads: None,
            source: None,
            observers: Vec::new(),
            expected_altitude: None,
        }
    }
}

impl JointLocBuilder {
    /// Sequential (deterministic, the absolute localisation inline) or threaded (real time).
    pub fn mode(mut self, mode: Mode) -> Self {
        self.mode = mode;
        self
    }

    /// Where the networks' weights are (default: `$JOINTLOC_MODELS` or the user cache).
    pub fn models_dir(mut self, dir: Option<PathBuf>) -> Self {
        self.models_dir = dir;
        self
    }

    /// ONNX Runtime threads per network (default 1).
    pub fn threads(mut self, threads: usize) -> Self {
        self.threads = Some(threads);
        self
    }

    /// Fixes from `source` instead of the map localiser (the map is then used for its
    /// elevation model only); the configured faults still apply.
    pub fn fix_source(mut self, source: Box<dyn FixSource>) -> Self {
        self.source = Some(source);
        self
    }

    /// The altitude the flight starts at (its first altimeter reading). Where single frames
    /// are matched at it, the map's tile features are opened (or extracted and cached) while
    /// building, not at the first search, which in real time would cost the first fixes;
    /// where virtual frames are registered instead they are never loaded.
    pub fn expected_altitude(mut self, altitude: Option<f64>) -> Self {
        self.expected_altitude = altitude.filter(|a| a.is_finite() && *a > 0.0);
        self
    }

    /// Adds an observer, called for every frame and fix.
    pub fn observer(mut self, observer: Box<dyn Observer>) -> Self {
        self.observers.push(observer);
        self
    }

    /// Validates the settings, loads the matcher and starts the system.
    pub fn build(self) -> Result<JointLoc> {
        let mut config = self.config;
        config.validate()?;
        let fov = self.camera.horizontal_fov_deg();
        if config.terrain.gain > 0.0 && fov.is_none_or(|f| f > config.terrain.max_fov_deg) {
            tracing::info!(
                fov_deg = fov,
                max_fov_deg = config.terrain.max_fov_deg,
                "terrain correction off: the camera's field of view is wider than [terrain] max_fov_deg"
            );
            config.terrain.gain = 0.0;
        }
        let ground = self.tiles.ground();
        let map_gsd_m = self.tiles.gsd_m();
        let virtual_frames = VirtualFrames::new(config.mosaic, self.camera, map_gsd_m);
        let source: Box<dyn FixSource> = match self.source {
            Some(source) => source,
            None => {
                let options = RegistryOptions {
                    models_dir: self.models_dir,
                    threads: self.threads,
                    max_keypoints: None,
                };
                let pipeline = resolve(&config.matcher, &options)?;
                let mut localizer =
                    AbsLocalizer::new(self.tiles, self.camera, pipeline, config.absloc.clone())?;
                if let Some(a) = self.expected_altitude
                    && virtual_frames.zoom(a).is_none()
                {
                    localizer.prepare(a)?;
                }
                Box::new(localizer)
            }
        };
        let source: Box<dyn FixSource> = if config.faults.affects_fixes() {
            Box::new(FaultyFixes::new(source, config.faults.clone()))
        } else {
            source
        };
        // The global BA after a loop runs on its own thread only where nothing has to be
        // reproducible: in the threaded mode (tracking must not stall for it).
        let mut slam_config = config.slam.clone();
        slam_config.loop_closing.global_ba_thread = self.mode == Mode::Threaded;
        let slam = System::new(self.camera, slam_config)?;
        JointLoc::assemble(
            slam,
            source,
            self.mode,
            ground,
            virtual_frames,
            self.observers,
            config,
        )
    }
}
