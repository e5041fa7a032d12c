//! The JointLoc system (paper §III-A, §III-C): absolute fixes and SLAM poses fused inside the
//! local bundle adjustment, with an online SLAM→world Sim(3).
//!
//! - [`config`]: [`JointLocConfig`] (fusion frequency, alignment, nested SLAM and absolute
//!   localisation settings);
//! - [`alignment`]: the robust, confidence-weighted SLAM→world similarity;
//! - [`system`]: the driver [`JointLoc`], sequential or threaded;
//! - [`altitude`]: altimeter-aided z of the reported poses;
//! - [`dead_reckoning`]: the search prior while there is no world pose;
//! - [`terrain_shift`]: the fixes' common bias, from where the map points sit on the
//!   elevation model;
//! - [`final_ba`]: the global bundle adjustment behind the outputs written at the end;
//! - [`faults`]: wrong fixes and outages injected for the robustness evaluation.

pub mod alignment;
pub mod altitude;
pub mod config;
pub mod dead_reckoning;
pub mod error;
pub mod faults;
pub mod final_ba;
pub mod ground;
pub mod system;
pub mod terrain_shift;
mod worker;

pub use config::JointLocConfig;
pub use error::{JointLocError, Result};
pub use system::{EndOutputs, FixRecord, FusedFrame, FusionTiming, JointLoc};
