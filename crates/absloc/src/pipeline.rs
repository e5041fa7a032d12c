//! A detector and a matcher under one name (e.g. `xfeat-lighterglue`), plus what identifies
//! the detector's output for the tile cache. Any [`Detector`]/[`Matcher`] pair works; the
//! named ones come from [`crate::registry`].

use std::sync::Arc;

use jointloc_features::{Detector, Matcher};

/// A matching pipeline.
#[derive(Debug, Clone)]
pub struct FeaturePipeline {
    /// Display name, e.g. `xfeat-mnn`.
    pub name: String,
    pub detector: Arc<dyn Detector>,
    pub matcher: Arc<dyn Matcher>,
    /// Short, file-name-safe detector name: one cache file per detector, shared by the
    /// matchers that use it.
    pub detector_id: String,
    /// Everything the tile features depend on besides the map: detector name, weights hash,
    /// detector configuration. The cache is rebuilt whenever it changes.
    pub detector_key: String,
}

impl FeaturePipeline {
    /// A pipeline from parts.
    pub fn new(
        name: impl Into<String>,
        detector: Arc<dyn Detector>,
        matcher: Arc<dyn Matcher>,
        detector_id: impl Into<String>,
        detector_key: impl Into<String>,
    ) -> Self {
        Self {
            name: name.into(),
            detector,
            matcher,
            detector_id: detector_id.into(),
            detector_key: detector_key.into(),
        }
    }
}
