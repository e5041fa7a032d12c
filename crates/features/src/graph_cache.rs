//! Compiled ONNX graphs, cached in the models directory's `onnx/` folder.
//!
//! A graph's file name carries a hash of everything it is built from (network name, builder
//! settings, weights file content, [`GRAPH_FORMAT`]), so a changed weight file or network code
//! gives a new file and a stale one is never used. Files are written atomically; a corrupt or
//! truncated file fails to load in the engine and is rebuilt.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use sha2::{Digest, Sha256};

use crate::error::{FeaturesError, Result};
use crate::models::sha256_file;

/// Bump when any network's graph construction changes, to invalidate cached graphs.
pub const GRAPH_FORMAT: u32 = 1;

/// Returns the ONNX bytes for `name` built from `weights` with `settings`, from the cache in
/// `onnx_dir` or by calling `build` (and caching its result).
pub fn load_or_build(
    onnx_dir: &Path,
    name: &str,
    settings: &str,
    weights: &Path,
    build: impl FnOnce() -> Result<Vec<u8>>,
) -> Result<(PathBuf, Vec<u8>)> {
    let (weights_hash, _) = sha256_file(weights)?;
    let mut h = Sha256::new();
    h.update(format!("{GRAPH_FORMAT}\n{name}\n{settings}\n{weights_hash}").as_bytes());
    let key: String = h.finalize()[..8]
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    let path = onnx_dir.join(format!("{name}-{key}.onnx"));
    if let Ok(bytes) = std::fs::read(&path)
        && !bytes.is_empty()
    {
        return Ok((path, bytes));
    }
    let bytes = build()?;
    let io = |source| FeaturesError::Io {
        path: path.clone(),
        source,
    };
    std::fs::create_dir_all(onnx_dir).map_err(io)?;
    // One temporary file per writer: threads of one process (tests run in parallel) may
    // build the same graph at once, and each renames its own file into place.
    static WRITERS: AtomicU64 = AtomicU64::new(0);
    let writer = WRITERS.fetch_add(1, Ordering::Relaxed);
    let tmp = path.with_extension(format!("onnx.tmp{}-{writer}", std::process::id()));
    std::fs::write(&tmp, &bytes).map_err(io)?;
    std::fs::rename(&tmp, &path).map_err(io)?;
    tracing::info!(graph = %path.display(), "compiled ONNX graph");
    Ok((path, bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn threads_building_the_same_graph_at_once_all_succeed() {
        let dir = tempfile::tempdir().unwrap();
        let weights = dir.path().join("w.bin");
        std::fs::write(&weights, b"weights").unwrap();
        let onnx = dir.path().join("onnx");
        // Every thread finishes building at the same moment, then writes.
        let barrier = std::sync::Barrier::new(8);
        std::thread::scope(|scope| {
            let handles: Vec<_> = (0..8)
                .map(|_| {
                    let (onnx, weights, barrier) = (&onnx, &weights, &barrier);
                    scope.spawn(move || {
                        load_or_build(onnx, "net", "s", weights, || {
                            barrier.wait();
                            Ok(vec![1; 1 << 20])
                        })
                    })
                })
                .collect();
            for h in handles {
                let (path, bytes) = h.join().unwrap().unwrap();
                assert_eq!(bytes.len(), 1 << 20);
                assert!(path.exists());
            }
        });
        let names: Vec<_> = std::fs::read_dir(&onnx)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names.len(), 1, "temporary files left: {names:?}");
    }
}
