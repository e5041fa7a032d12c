//! Folders for the datasets a test or bench process renders once and shares between its tests.
//!
//! A `static` that holds a `tempfile::TempDir` is never dropped (statics have no destructor
//! at process exit), so every test run left its rendered flights behind: gigabytes a day on a
//! CI machine. A [`ProcessScratch`] holds an exclusive lock on a file beside its folder for as
//! long as its process lives; making one removes every folder under the same root and prefix
//! whose lock is free, that is, whose process has ended (however it ended).

use std::fs::{self, File};
use std::io;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{SystemTime, UNIX_EPOCH};

/// A folder owned by this process until it ends; removed by the next [`ProcessScratch::new`]
/// under the same root and prefix after that.
#[derive(Debug)]
pub struct ProcessScratch {
    path: PathBuf,
    /// Locked for the life of the process; the lock is what marks the folder as in use.
    _lock: File,
}

impl ProcessScratch {
    /// Makes a new folder `<root>/<prefix>-<pid>-<nanos>-<n>` after removing the abandoned
    /// ones of `prefix` under `root` (a test passes `env!("CARGO_TARGET_TMPDIR")`).
    pub fn new(root: impl AsRef<Path>, prefix: &str) -> io::Result<Self> {
        let root = root.as_ref();
        fs::create_dir_all(root)?;
        remove_abandoned(root, prefix);
        static COUNTER: AtomicU64 = AtomicU64::new(0);
        let nanos = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos());
        let name = format!(
            "{prefix}-{}-{nanos}-{}",
            std::process::id(),
            COUNTER.fetch_add(1, Ordering::Relaxed)
        );
        // Locked under a name the sweep does not match, then renamed: another process's
        // sweep never sees the lock file unlocked.
        let pending = root.join(format!(".{name}.pending"));
        let lock = File::create_new(&pending)?;
        lock.lock()?;
        fs::rename(&pending, lock_path(root, &name))?;
        let path = root.join(&name);
        fs::create_dir(&path)?;
        Ok(Self { path, _lock: lock })
    }

    /// The folder.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

fn lock_path(root: &Path, name: &str) -> PathBuf {
    root.join(format!("{name}.lock"))
}

/// Removes the folders of `prefix` under `root` whose lock no process holds. Best effort: a
/// folder that cannot be removed now is tried again next time.
fn remove_abandoned(root: &Path, prefix: &str) {
    let Ok(entries) = fs::read_dir(root) else {
        return;
    };
    let start = format!("{prefix}-");
    for entry in entries.flatten() {
        let file_name = entry.file_name();
        let Some(name) = file_name.to_str().and_then(|n| n.strip_suffix(".lock")) else {
            continue;
        };
        // Exactly `<prefix>-<pid>-<nanos>-<n>`: a longer prefix's folders are not ours.
        let ours = name.strip_prefix(&start).is_some_and(|rest| {
            let fields: Vec<&str> = rest.split('-').collect();
            fields.len() == 3
                && fields
                    .iter()
                    .all(|f| !f.is_empty() && f.bytes().all(|b| b.is_ascii_digit()))
        });
        if !ours {
            continue;
        }
        let Ok(lock) = File::open(entry.path()) else {
            continue;
        };
        // Held (or unreadable): in use, or not ours to judge.
        if lock.try_lock().is_ok() {
            let folder = root.join(name);
            if fs::remove_dir_all(&folder).is_ok() || !folder.exists() {
                let _ = fs::remove_file(entry.path());
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_folder_in_use_is_kept_and_an_abandoned_one_removed() {
        let root = tempfile::tempdir().unwrap();
        let live = ProcessScratch::new(root.path(), "flight").unwrap();
        fs::write(live.path().join("frame.png"), b"x").unwrap();

        // An abandoned folder: its lock file exists and nobody holds it (a process that ended).
        let dead = root.path().join("flight-1-2-3");
        fs::create_dir(&dead).unwrap();
        fs::write(dead.join("frame.png"), b"x").unwrap();
        File::create(lock_path(root.path(), "flight-1-2-3")).unwrap();
        // Another prefix's abandoned folders are not this sweep's business, even one that
        // starts with this prefix.
        let other = root.path().join("map-1-2-3");
        let longer = root.path().join("flight-b-1-2-3");
        for folder in [&other, &longer] {
            fs::create_dir(folder).unwrap();
            let name = folder.file_name().unwrap().to_str().unwrap();
            File::create(lock_path(root.path(), name)).unwrap();
        }

        let second = ProcessScratch::new(root.path(), "flight").unwrap();
        assert!(!dead.exists(), "the abandoned folder is removed");
        assert!(!lock_path(root.path(), "flight-1-2-3").exists());
        assert!(
            live.path().join("frame.png").exists(),
            "a held folder stays"
        );
        assert!(second.path().is_dir());
        assert_ne!(live.path(), second.path());
        assert!(
            other.exists() && longer.exists(),
            "other prefixes are left alone"
        );
    }

    #[test]
    fn a_folder_is_freed_once_its_lock_is_released() {
        // The lock dies with its holder: dropping the file stands for the process ending.
        let root = tempfile::tempdir().unwrap();
        let name = "flight-9-9-9";
        fs::create_dir(root.path().join(name)).unwrap();
        let lock = File::create(lock_path(root.path(), name)).unwrap();
        lock.lock().unwrap();
        remove_abandoned(root.path(), "flight");
        assert!(root.path().join(name).exists(), "held by this process");
        drop(lock);
        remove_abandoned(root.path(), "flight");
        assert!(!root.path().join(name).exists());
    }
}
