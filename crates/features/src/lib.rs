//! Learned local features and matchers (paper §III-B, DESIGN §5): SuperPoint, ALIKED, DISK,
//! XFeat, LightGlue and LighterGlue compiled from their pretrained weights to ONNX graphs.

pub mod error;

pub use error::{FeaturesError, Result};
pub mod pth;
