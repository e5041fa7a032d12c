//! What detectors return and matchers take: one contract for every network and for ORB.

use crate::error::Result;

/// Sparse local features of one image.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Features {
    /// Keypoints in pixels of the input image, `(x, y)`, pixel centres at integers.
    pub keypoints: Vec<[f32; 2]>,
    /// Detection score per keypoint.
    pub scores: Vec<f32>,
    /// Row-major `keypoints.len() × descriptor_dim` descriptors (L2-normalised where the
    /// network does so).
    pub descriptors: Vec<f32>,
    /// Length of one descriptor.
    pub descriptor_dim: usize,
    /// `(width, height)` of the image the features come from (LightGlue normalises by it).
    pub image_size: (u32, u32),
}

impl Features {
    /// Number of keypoints.
    pub fn len(&self) -> usize {
        self.keypoints.len()
    }

    /// Whether there are no keypoints.
    pub fn is_empty(&self) -> bool {
        self.keypoints.is_empty()
    }

    /// Descriptor of keypoint `i`.
    pub fn descriptor(&self, i: usize) -> &[f32] {
        &self.descriptors[i * self.descriptor_dim..(i + 1) * self.descriptor_dim]
    }
}

/// Correspondences between two feature sets.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Matches {
    /// `(index in a, index in b)`, sorted by the index in `a`.
    pub pairs: Vec<(usize, usize)>,
    /// Matching confidence per pair in [0, 1] (LightGlue's score; MNN: a similarity).
    pub scores: Vec<f32>,
}

/// A keypoint detector and descriptor.
pub trait Detector: Send + Sync + std::fmt::Debug {
    /// Detects and describes features in a grey image.
    fn detect(&self, image: &image::GrayImage) -> Result<Features>;
}

/// A feature matcher.
pub trait Matcher: Send + Sync + std::fmt::Debug {
    /// Matches `a` against `b`.
    fn match_features(&self, a: &Features, b: &Features) -> Result<Matches>;
}
