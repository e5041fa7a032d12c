//! The JointLoc system (paper §III-A, §III-C): absolute fixes and SLAM poses fused inside the
//! local bundle adjustment, with an online SLAM→world Sim(3). This crate is the front door:
//!
//! ```no_run
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use jointloc_system::{JointLoc, JointLocConfig, MapTiles, Mode};
//! let dataset = std::path::Path::new("flight");
//! let camera = jointloc_formats::camera_yaml::read_camera_yaml(&dataset.join("camera.yaml"))?.camera;
//! let tiles = MapTiles::open(dataset)?;
//! let mut system = JointLoc::builder(camera, tiles, JointLocConfig::default())
//!     .mode(Mode::Threaded)
//!     .build()?;
//! # let (image, timestamp, altitude) = (image::GrayImage::new(500, 500), 0.0, Some(10.0));
//! let frame = system.process(&image, timestamp, altitude)?; // for every camera frame
//! if let Some(pose) = frame.world_pose { /* camera-to-world in the map's frame */ }
//! let outputs = system.finish()?;
//! outputs.write(std::path::Path::new("run"), false)?;
//! # Ok(()) }
//! ```
//!
//! - [`builder`]: [`JointLocBuilder`], from (camera, map, settings) to a running system;
//! - [`system`]: the driver [`JointLoc`]: `process` a frame, `finish` the run;
//! - [`fix_source`]: where fixes come from ([`FixSource`]: the map localiser, or yours);
//! - [`observer`]: watching a run as it goes;
//! - [`outputs`]: [`Outputs`] and the files of a run;
//! - [`config`]: [`JointLocConfig`] (fusion frequency, alignment, nested SLAM and absolute
//!   localisation settings);
//! - [`alignment`]: the robust, confidence-weighted SLAM→world similarity;
//! - `ties`: fixes tied to keyframes, the alignment re-fit and the global factors;
//! - [`altitude`]: altimeter-aided z of the reported poses;
//! - [`dead_reckoning`]: the search prior while there is no world pose;
//! - [`terrain_shift`]: the fixes' common bias, from where the map points sit on the
//!   elevation model;
//! - `end_outputs`, [`final_ba`]: the trajectories as known at the end, through the global
//!   bundle adjustment;
//! - [`faults`]: wrong fixes, outages and a blinded camera, as wrappers of the fix source and
//!   the frames, for the robustness evaluation.

pub mod alignment;
pub mod altimeter_gate;
pub mod altitude;
pub mod builder;
mod camera_tilt;
pub mod config;
pub mod dead_reckoning;
mod end_outputs;
pub mod error;
pub mod faults;
pub mod final_ba;
pub mod fix_source;
mod flight_time;
pub mod ground;
mod map_merge;
pub mod observer;
pub mod outputs;
mod records;
pub mod system;
mod takeoff;
pub mod terrain_shift;
mod ties;
pub mod virtual_frames;
mod worker;

pub use builder::JointLocBuilder;
pub use config::JointLocConfig;
pub use error::{JointLocError, Result};
pub use fix_source::{FixRequest, FixSource, Located};
pub use observer::Observer;
pub use outputs::Outputs;
pub use system::{FixRecord, FusedFrame, FusionTiming, JointLoc, Mode};

// The types that appear in this crate's API, so a user needs no other jointloc crate.
pub use jointloc_absloc::{AbsLocConfig, Failure, FailureReason, Fix, MapTiles, Outcome, Prior};
pub use jointloc_formats::outputs::{
    FinalBaStats, FixRow, OnlineFrame, OnlineStatus, RealtimeSummary, Summary, TerrainSummary,
    TimingSummary,
};
pub use jointloc_geometry::{CameraToWorld, PinholeCamera, Sim3};
pub use jointloc_slam::map::KeyFrameId;
pub use jointloc_slam::tracking::TrackingState;
