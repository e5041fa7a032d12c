//! Identifiers of keyframes and map points: ordered, so every iteration over the map is
//! deterministic.

use serde::{Deserialize, Serialize};

/// A keyframe's identifier, increasing in insertion order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct KeyFrameId(pub u64);

/// A map point's identifier, increasing in insertion order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct MapPointId(pub u64);

impl std::fmt::Display for KeyFrameId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "KF{}", self.0)
    }
}

impl std::fmt::Display for MapPointId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "MP{}", self.0)
    }
}
