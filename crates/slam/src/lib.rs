//! Relative localisation (paper §III-C): ORB-SLAM2-style monocular SLAM whose local bundle
//! adjustment accepts confidence-weighted global-position factors.
//!
//! Built in stages (issue #6): ORB features and the bundle adjustment first, then the map,
//! tracking and local mapping on top of them. ORB itself is in `jointloc_features::orb`, shared
//! with the absolute localisation.

pub mod ba;
pub mod cpu_time;
pub mod error;
pub mod frame;
pub mod initializer;
pub mod local_mapping;
pub mod loop_closing;
pub mod map;
pub mod place;
pub mod relocalisation;
pub mod system;
pub mod tracking;

pub use error::{Result, SlamError};
