//! Settings of LightGlue / LighterGlue: which trained weights, and the adaptive-computation
//! knobs of the reference implementation.

use serde::{Deserialize, Serialize};

use crate::engine::EngineConfig;
use crate::error::{FeaturesError, Result};
use crate::models::WeightsFile;

/// The descriptors a LightGlue model was trained on (selects the weights file).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LightGlueFeatures {
    /// ALIKED descriptors (128-D), 9 layers, 4 heads of 64.
    Aliked,
    /// DISK descriptors (128-D), 9 layers, 4 heads of 64.
    Disk,
    /// XFeat descriptors (64-D) with LighterGlue: 6 layers, 1 head of 96.
    #[serde(rename = "xfeat")]
    XFeat,
}

impl LightGlueFeatures {
    /// The pinned weights file of this model.
    pub fn weights_file(self) -> WeightsFile {
        match self {
            Self::Aliked => WeightsFile::AlikedLightGlue,
            Self::Disk => WeightsFile::DiskLightGlue,
            Self::XFeat => WeightsFile::XFeatLighterGlue,
        }
    }

    /// Short name used in graph names and logs.
    pub fn name(self) -> &'static str {
        match self {
            Self::Aliked => "aliked_lightglue",
            Self::Disk => "disk_lightglue",
            Self::XFeat => "xfeat_lighterglue",
        }
    }
}

/// LightGlue settings. `Default` is LightGlue on ALIKED with the reference defaults
/// (`LightGlue(features="aliked")`); [`LightGlueConfig::lighterglue`] gives XFeat's
/// LighterGlue defaults (a config file that says only `features = "xfeat"` gets the ALIKED
/// values for the other fields: set them too). Layer count, widths and heads come from the
/// weights.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LightGlueConfig {
    /// Which trained model (and so which descriptors it accepts).
    pub features: LightGlueFeatures,
    /// Adaptive depth: stop after a layer once more than this fraction of all keypoints is
    /// confident (reference default 0.95). `<= 0` runs every layer.
    pub depth_confidence: f64,
    /// Adaptive width: after each layer, drop keypoints whose matchability is below
    /// `1 - width_confidence` and whose token confidence is high (reference default 0.99;
    /// LighterGlue 0.95). `<= 0` keeps every keypoint.
    pub width_confidence: f64,
    /// A mutual best match is kept when its assignment probability exceeds this (0.1).
    pub filter_threshold: f64,
    /// ONNX Runtime settings (1 intra-op thread by default).
    pub engine: EngineConfig,
}

impl Default for LightGlueConfig {
    fn default() -> Self {
        Self::lightglue(LightGlueFeatures::Aliked)
    }
}

impl LightGlueConfig {
    /// Reference defaults of `LightGlue(features=...)` for ALIKED or DISK (adaptive depth 0.95,
    /// width 0.99, threshold 0.1); for XFeat the LighterGlue defaults.
    pub fn lightglue(features: LightGlueFeatures) -> Self {
        if features == LightGlueFeatures::XFeat {
            return Self::lighterglue();
        }
        Self {
            features,
            depth_confidence: 0.95,
            width_confidence: 0.99,
            filter_threshold: 0.1,
            engine: EngineConfig::default(),
        }
    }

    /// XFeat's LighterGlue defaults: no early stop, point pruning at 0.95, threshold 0.1.
    pub fn lighterglue() -> Self {
        Self {
            features: LightGlueFeatures::XFeat,
            depth_confidence: -1.0,
            width_confidence: 0.95,
            filter_threshold: 0.1,
            engine: EngineConfig::default(),
        }
    }

    /// The same model with adaptive depth and width switched off (every layer, every point).
    pub fn full(mut self) -> Self {
        self.depth_confidence = -1.0;
        self.width_confidence = -1.0;
        self
    }

    /// Whether early stopping by token confidence is on.
    pub fn early_stop(&self) -> bool {
        self.depth_confidence > 0.0
    }

    /// Whether point pruning is on.
    pub fn point_pruning(&self) -> bool {
        self.width_confidence > 0.0
    }

    /// Rejects values outside their meaningful ranges.
    pub fn validate(&self) -> Result<()> {
        let bad = |field, value: f64, reason| {
            Err(FeaturesError::InvalidConfig {
                field,
                value: value.to_string(),
                reason,
            })
        };
        if !self.depth_confidence.is_finite() || self.depth_confidence > 1.0 {
            return bad(
                "depth_confidence",
                self.depth_confidence,
                "at most 1 (or <= 0 to disable)",
            );
        }
        if !self.width_confidence.is_finite() || self.width_confidence > 1.0 {
            return bad(
                "width_confidence",
                self.width_confidence,
                "at most 1 (or <= 0 to disable)",
            );
        }
        if !self.filter_threshold.is_finite() || !(0.0..1.0).contains(&self.filter_threshold) {
            return bad("filter_threshold", self.filter_threshold, "in [0, 1)");
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_follow_the_references() {
        let c = LightGlueConfig::default();
        assert_eq!(c.features, LightGlueFeatures::Aliked);
        assert!(c.early_stop() && c.point_pruning());
        let x = LightGlueConfig::lightglue(LightGlueFeatures::XFeat);
        assert!(!x.early_stop() && x.point_pruning());
        assert_eq!(x.width_confidence, 0.95);
        let f = LightGlueConfig::default().full();
        assert!(!f.early_stop() && !f.point_pruning());
        assert!(c.validate().is_ok() && x.validate().is_ok() && f.validate().is_ok());
    }

    #[test]
    fn invalid_values_are_rejected() {
        let c = LightGlueConfig {
            filter_threshold: 1.5,
            ..Default::default()
        };
        assert!(c.validate().is_err());
        let c = LightGlueConfig {
            depth_confidence: f64::NAN,
            ..Default::default()
        };
        assert!(c.validate().is_err());
    }

    #[test]
    fn toml_round_trip() {
        let c = LightGlueConfig::lighterglue();
        let s = toml::to_string(&c).unwrap();
        let back: LightGlueConfig = toml::from_str(&s).unwrap();
        assert_eq!(c, back);
        let partial: LightGlueConfig = toml::from_str("features = \"xfeat\"").unwrap();
        assert_eq!(partial.features, LightGlueFeatures::XFeat);
    }
}
