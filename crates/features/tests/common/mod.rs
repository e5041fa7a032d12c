//! Shared helpers of the ORB integration tests.

pub mod metrics;
pub mod sim_frames;
