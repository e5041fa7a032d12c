//! The JointLoc system (paper §III-A, §III-C): absolute fixes and SLAM poses fused inside the
//! local bundle adjustment, with an online SLAM→world Sim(3).
//!
//! - [`config`]: [`JointLocConfig`] (fusion frequency, alignment, nested SLAM and absolute
//!   localisation settings);
//! - [`alignment`]: the robust, confidence-weighted SLAM→world similarity;
//! - [`system`]: the sequential driver [`JointLoc`].

pub mod alignment;
pub mod config;
pub mod error;
pub mod system;

pub use config::JointLocConfig;
pub use error::{JointLocError, Result};
pub use system::{FixRecord, FusedFrame, FusionTiming, JointLoc};
