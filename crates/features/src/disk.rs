//! DISK: "DISK: Learning local features with policy gradient" (Tyszkiewicz, Fua, Trulls,
//! NeurIPS 2020), with the `disk-depth-save.pth` weights ([`WeightsFile::Disk`], the depth-
//! supervised model that LightGlue's DISK matcher was trained on).
//!
//! The U-Net runs as one ONNX graph (dynamic size, see [`graph`]); resizing, padding, the
//! heatmap NMS, the top-`n` rule and descriptor lookup run here, following kornia's DISK as
//! wrapped by LightGlue's extractor (the settings of the golden files): grey image in [0, 1]
//! repeated to RGB, long side resized to 1024, zero padding to a multiple of 16, strict 5×5
//! maxima with a positive heatmap, the best 1024 kept, 128-D descriptors read at the integer
//! keypoint pixels and L2-normalised, keypoints mapped back to the input image.

pub mod graph;
mod post;
mod resize;

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::engine::{Engine, EngineConfig, NetTensor, OrtEngine};
use crate::error::{FeaturesError, Result};
use crate::graph_cache;
use crate::models::{ModelStore, WeightsFile};
use crate::pth::StateDict;
use crate::types::{Detector, Features};

pub use graph::DESCRIPTOR_DIM;
pub(crate) use post::normalize as normalize_l2;

/// Smallest accepted image side: below it the 5×5 NMS and the U-Net's four poolings leave
/// nothing meaningful.
pub const MIN_SIDE: u32 = 16;

/// DISK settings; [`Default`] is the reference extractor's configuration used for the golden
/// files (`DISK(max_num_keypoints=1024)`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DiskConfig {
    /// Keep at most this many keypoints (the best by heatmap value); `None` keeps all maxima.
    pub max_keypoints: Option<usize>,
    /// Side of the square NMS window (odd, ≥ 3).
    pub nms_window: usize,
    /// Keep maxima whose heatmap value (a log-probability) is above this.
    pub score_threshold: f32,
    /// Resize so the long side has this length before the network (LightGlue's extractor
    /// uses 1024, also for smaller images); `None` runs at the input size, about 4× faster
    /// for a 500×500 image but not what the reference does.
    pub resize: Option<u32>,
    /// Blur with a Gaussian before shrinking (kornia's `antialias`); no effect when enlarging.
    pub antialias: bool,
    /// ONNX Runtime settings.
    pub engine: EngineConfig,
}

impl Default for DiskConfig {
    fn default() -> Self {
        Self {
            max_keypoints: Some(1024),
            nms_window: 5,
            score_threshold: 0.0,
            resize: Some(1024),
            antialias: true,
            engine: EngineConfig::default(),
        }
    }
}

impl DiskConfig {
    /// Checks every field's range.
    pub fn validate(&self) -> Result<()> {
        if self.nms_window < 3 || self.nms_window.is_multiple_of(2) {
            return Err(FeaturesError::InvalidConfig {
                field: "nms_window",
                value: self.nms_window.to_string(),
                reason: "odd and at least 3",
            });
        }
        if self.max_keypoints == Some(0) {
            return Err(FeaturesError::InvalidConfig {
                field: "max_keypoints",
                value: "0".into(),
                reason: "at least 1, or none for all",
            });
        }
        if self.score_threshold.is_nan() {
            return Err(FeaturesError::InvalidConfig {
                field: "score_threshold",
                value: "NaN".into(),
                reason: "a number",
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
            Some(side) => resize::target_size(height as usize, width as usize, side as usize),
            None => (height as usize, width as usize),
        }
    }

    /// FLOPs of the network (2 × multiply-adds of its convolutions) for a `width × height`
    /// input image, counting the resizing and padding this configuration applies.
    pub fn flops(&self, width: u32, height: u32) -> u64 {
        let (h, w) = self.network_size(width, height);
        graph::flops(
            w.next_multiple_of(graph::DIVISOR),
            h.next_multiple_of(graph::DIVISOR),
        )
    }
}

/// The DISK detector and descriptor.
#[derive(Debug)]
pub struct Disk {
    config: DiskConfig,
    engine: Box<dyn Engine>,
}

impl Disk {
    /// DISK from a complete model store (weights, runtime, graph cache).
    pub fn new(store: &ModelStore, config: DiskConfig) -> Result<Self> {
        let weights = store.require_weights(WeightsFile::Disk)?;
        let library = store.require_onnxruntime_library()?;
        Self::from_files(&weights, &library, Some(&store.onnx_dir()), config)
    }

    /// DISK from a checkpoint and an ONNX Runtime library; the compiled graph is cached in
    /// `onnx_cache` when given.
    pub fn from_files(
        weights: &Path,
        ort_library: &Path,
        onnx_cache: Option<&Path>,
        config: DiskConfig,
    ) -> Result<Self> {
        config.validate()?;
        let build = || graph::build(&StateDict::read(weights)?);
        let onnx = match onnx_cache {
            Some(dir) => {
                graph_cache::load_or_build(dir, "disk", graph::GRAPH_VERSION, weights, build)?.1
            }
            None => build()?,
        };
        let engine = OrtEngine::new(ort_library, &onnx, "disk", &config.engine)?;
        Self::with_engine(Box::new(engine), config)
    }

    /// DISK on any engine running the graph of [`graph::build`].
    pub fn with_engine(engine: Box<dyn Engine>, config: DiskConfig) -> Result<Self> {
        config.validate()?;
        Ok(Self { config, engine })
    }

    /// The settings.
    pub fn config(&self) -> &DiskConfig {
        &self.config
    }
}

/// Grey image in [0, 1], row-major.
fn to_unit(image: &image::GrayImage) -> Vec<f32> {
    image.as_raw().iter().map(|&v| v as f32 / 255.0).collect()
}

impl Detector for Disk {
    fn detect(&self, image: &image::GrayImage) -> Result<Features> {
        let (width, height) = image.dimensions();
        if width < MIN_SIDE || height < MIN_SIDE {
            return Err(FeaturesError::InvalidInput(format!(
                "DISK needs an image of at least {MIN_SIDE}×{MIN_SIDE} pixels, got {width}×{height}"
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
        let mut pixels = to_unit(image);
        if (h, w) != (height as usize, width as usize) {
            pixels = resize::resize(&pixels, height as usize, width as usize, h, w, c.antialias);
        }
        let (hp, wp) = (
            h.next_multiple_of(graph::DIVISOR),
            w.next_multiple_of(graph::DIVISOR),
        );
        let mut padded = vec![0.0f32; hp * wp];
        for (dst, src) in padded.chunks_exact_mut(wp).zip(pixels.chunks_exact(w)) {
            dst[..w].copy_from_slice(src);
        }
        let out = self.engine.run(vec![(
            graph::INPUT,
            NetTensor::f32(&[1, 1, hp, wp], padded),
        )])?;
        let t = out.get(graph::OUTPUT)?;
        if t.shape != [1, DESCRIPTOR_DIM + 1, hp, wp] {
            return Err(FeaturesError::Engine(format!(
                "disk: output shape {:?}, expected [1, {}, {hp}, {wp}]",
                t.shape,
                DESCRIPTOR_DIM + 1
            )));
        }
        let dense = t.as_f32(graph::OUTPUT)?;
        // The heatmap without the padding; descriptors are read in place (row stride `wp`).
        let crop = |plane: &[f32]| -> Vec<f32> {
            plane
                .chunks_exact(wp)
                .take(h)
                .flat_map(|r| &r[..w])
                .copied()
                .collect()
        };
        let plane = hp * wp;
        let heat = crop(&dense[DESCRIPTOR_DIM * plane..]);
        let peaks = post::peaks(&heat, w, h, c.nms_window, c.score_threshold);
        let peaks = post::keep_best(peaks, c.max_keypoints);
        let descriptors = gather(dense, wp, &peaks);
        // Back to input pixels as the reference extractor does: (k + 0.5) / scale - 0.5.
        let sx = (w as f64 / width as f64) as f32;
        let sy = (h as f64 / height as f64) as f32;
        let keypoints = peaks
            .iter()
            .map(|p| [(p.x as f32 + 0.5) / sx - 0.5, (p.y as f32 + 0.5) / sy - 0.5])
            .collect();
        tracing::debug!(keypoints = peaks.len(), width, height, "disk");
        Ok(Features {
            keypoints,
            scores: peaks.iter().map(|p| p.logp).collect(),
            descriptors,
            descriptor_dim: DESCRIPTOR_DIM,
            image_size: (width, height),
        })
    }
}

/// Descriptors at the peaks from the padded `129 × hp × wp` output (row stride `wp`).
fn gather(dense: &[f32], wp: usize, peaks: &[post::Peak]) -> Vec<f32> {
    let hp = dense.len() / ((DESCRIPTOR_DIM + 1) * wp);
    post::gather_descriptors(
        &dense[..DESCRIPTOR_DIM * hp * wp],
        wp,
        hp,
        DESCRIPTOR_DIM,
        peaks,
    )
}
