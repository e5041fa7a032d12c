//! Tile features as the search asks for them: read tile by tile from the on-disk cache
//! ([`crate::cache`]) and kept in memory up to a budget, the least recently used first out.
//!
//! A local search touches a handful of tiles around the prior, and those stay in memory; a
//! whole-map search (the first fix with no prior, the search after a loss) streams every tile
//! once from the file, which the operating system's page cache keeps warm when it has room.
//! So the features of a map of any size cost at most the budget
//! ([`crate::AbsLocConfig::tile_memory_mb`]). With the cache off every tile is extracted at
//! once and kept, as there is nothing to read back.

use std::collections::HashMap;
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use jointloc_features::{Detector, Features};
use rayon::prelude::*;

use crate::cache::{CacheFile, CacheStatus, CacheWriter, DecodeError, RecordError};
use crate::error::{AbslocError, Result};
use crate::tiles::MapTiles;

/// Tiles extracted together while the cache file is built (memory: this many tiles' features).
const BUILD_CHUNK: usize = 32;

/// Where the features live.
#[derive(Debug)]
enum Backing {
    /// Every tile in memory (the cache is off, or could not be written).
    Memory(Vec<Arc<Features>>),
    /// Read from the cache file on demand.
    File(CacheFile),
}

/// The tiles read so far, with their last use.
#[derive(Debug, Default)]
struct Resident {
    tiles: HashMap<usize, (Arc<Features>, u64)>,
    bytes: usize,
    clock: u64,
}

/// The tile features of one map and detector.
#[derive(Debug)]
pub struct TileStore {
    backing: Backing,
    status: CacheStatus,
    /// Extracts a damaged record again (`None`: features given by the caller, no file).
    detector: Option<Arc<dyn Detector>>,
    budget_bytes: usize,
    resident: Mutex<Resident>,
    reads: AtomicUsize,
}

/// Bytes of `f` in memory.
fn bytes_of(f: &Features) -> usize {
    f.keypoints.len() * 8 + f.scores.len() * 4 + f.descriptors.len() * 4
}

/// Extracts the features of every tile (in parallel).
pub fn extract_all(tiles: &MapTiles, detector: &dyn Detector) -> Result<Vec<Features>> {
    (0..tiles.len())
        .into_par_iter()
        .map(|i| Ok(detector.detect(&tiles.tile_image(i))?))
        .collect()
}

impl TileStore {
    /// Opens the cache file at `path` when its key is `key`, else extracts the features and
    /// writes it (`BUILD_CHUNK` tiles at a time, never the whole map in memory). With `path`
    /// `None` nothing is read or written and every tile is kept. A write failure (a read-only
    /// dataset) is a warning, not an error: the features are kept in memory instead.
    pub fn open(
        tiles: &MapTiles,
        detector: Arc<dyn Detector>,
        key: &str,
        path: Option<&Path>,
        budget_bytes: usize,
    ) -> Result<Self> {
        let store = |backing, status| Self {
            backing,
            status,
            detector: Some(detector.clone()),
            budget_bytes,
            resident: Mutex::new(Resident::default()),
            reads: AtomicUsize::new(0),
        };
        let Some(path) = path else {
            let all = extract_all(tiles, detector.as_ref())?;
            return Ok(store(
                Backing::Memory(all.into_iter().map(Arc::new).collect()),
                CacheStatus::Disabled,
            ));
        };
        let status = match CacheFile::open(path, key, tiles.len()) {
            Ok(Some(file)) => {
                tracing::debug!(path = %path.display(), "tile features from cache");
                return Ok(store(Backing::File(file), CacheStatus::Hit));
            }
            Ok(None) => CacheStatus::Built,
            Err(DecodeError::Stale) => {
                tracing::info!(path = %path.display(), "tile feature cache is stale, rebuilding");
                CacheStatus::Stale
            }
            Err(DecodeError::Version(v)) => {
                tracing::info!(path = %path.display(), version = v, "tile feature cache has another version, rebuilding");
                CacheStatus::Stale
            }
            Err(e) => {
                tracing::warn!(path = %path.display(), error = %e.message(), "tile feature cache is corrupt, rebuilding");
                CacheStatus::Corrupt
            }
        };
        let backing = match build(tiles, detector.as_ref(), key, path) {
            Ok(file) => Backing::File(file),
            Err(e) => {
                tracing::warn!(error = %e, "could not write the tile feature cache; keeping the features in memory");
                let all = extract_all(tiles, detector.as_ref())?;
                Backing::Memory(all.into_iter().map(Arc::new).collect())
            }
        };
        Ok(store(backing, status))
    }

    /// Tile features the caller extracted, all kept in memory (no file).
    pub fn from_features(features: Vec<Features>) -> Self {
        Self {
            backing: Backing::Memory(features.into_iter().map(Arc::new).collect()),
            status: CacheStatus::Disabled,
            detector: None,
            budget_bytes: usize::MAX,
            resident: Mutex::new(Resident::default()),
            reads: AtomicUsize::new(0),
        }
    }

    /// A store over an opened cache file (tests of the streaming paths).
    #[cfg(test)]
    pub(crate) fn from_cache_file(file: CacheFile, budget_bytes: usize) -> Self {
        Self {
            backing: Backing::File(file),
            status: CacheStatus::Hit,
            detector: None,
            budget_bytes,
            resident: Mutex::new(Resident::default()),
            reads: AtomicUsize::new(0),
        }
    }

    /// How the cache was found.
    pub fn status(&self) -> CacheStatus {
        self.status
    }

    /// The cache file, when the features are read from one.
    pub fn path(&self) -> Option<&Path> {
        match &self.backing {
            Backing::File(f) => Some(f.path()),
            Backing::Memory(_) => None,
        }
    }

    /// Number of tiles.
    pub fn len(&self) -> usize {
        match &self.backing {
            Backing::File(f) => f.entries().len(),
            Backing::Memory(v) => v.len(),
        }
    }

    /// Whether the map has no tiles.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Keypoints of tile `i`, known without reading its features.
    pub fn keypoints(&self, i: usize) -> usize {
        match &self.backing {
            Backing::File(f) => f.entries()[i].keypoints as usize,
            Backing::Memory(v) => v[i].len(),
        }
    }

    /// Records read from the file so far (tiles not found in memory).
    pub fn reads(&self) -> usize {
        self.reads.load(Ordering::Relaxed)
    }

    /// Bytes of tile features held in memory now.
    pub fn resident_bytes(&self) -> usize {
        match &self.backing {
            Backing::Memory(v) => v.iter().map(|f| bytes_of(f)).sum(),
            Backing::File(_) => self.resident.lock().map_or(0, |r| r.bytes),
        }
    }

    /// The features of tile `i` of `tiles` (the map this store was opened for). A record that
    /// fails its checksum is extracted again from the map, with a warning; an unreadable file
    /// is an error naming it.
    pub fn get(&self, tiles: &MapTiles, i: usize) -> Result<Arc<Features>> {
        let file = match &self.backing {
            Backing::Memory(v) => return Ok(v[i].clone()),
            Backing::File(f) => f,
        };
        if let Ok(mut r) = self.resident.lock() {
            r.clock += 1;
            let now = r.clock;
            if let Some((f, used)) = r.tiles.get_mut(&i) {
                *used = now;
                return Ok(f.clone());
            }
        }
        self.reads.fetch_add(1, Ordering::Relaxed);
        let features = match file.read(i) {
            Ok(f) => f,
            Err(RecordError::Io(source)) => {
                return Err(AbslocError::Io {
                    path: file.path().to_path_buf(),
                    source,
                });
            }
            Err(RecordError::Decode(e)) => {
                let Some(detector) = &self.detector else {
                    return Err(AbslocError::Io {
                        path: file.path().to_path_buf(),
                        source: std::io::Error::other(format!("tile {i}: {}", e.message())),
                    });
                };
                tracing::warn!(path = %file.path().display(), tile = i, error = %e.message(), "tile feature record is corrupt; extracting it again");
                detector.detect(&tiles.tile_image(i))?
            }
        };
        let features = Arc::new(features);
        if let Ok(mut r) = self.resident.lock() {
            let now = r.clock;
            if r.tiles.insert(i, (features.clone(), now)).is_none() {
                r.bytes += bytes_of(&features);
            }
            while r.bytes > self.budget_bytes && r.tiles.len() > 1 {
                let Some(oldest) = r
                    .tiles
                    .iter()
                    .filter(|(k, _)| **k != i)
                    .min_by_key(|(k, (_, used))| (*used, **k))
                    .map(|(k, _)| *k)
                else {
                    break;
                };
                if let Some((f, _)) = r.tiles.remove(&oldest) {
                    r.bytes -= bytes_of(&f);
                }
            }
        }
        Ok(features)
    }
}

/// Extracts every tile's features into a new cache file at `path` and opens it.
fn build(tiles: &MapTiles, detector: &dyn Detector, key: &str, path: &Path) -> Result<CacheFile> {
    let mut writer = CacheWriter::create(path, key, tiles.len())?;
    let all: Vec<usize> = (0..tiles.len()).collect();
    for chunk in all.chunks(BUILD_CHUNK) {
        let features: Vec<Features> = chunk
            .par_iter()
            .map(|&i| Ok(detector.detect(&tiles.tile_image(i))?))
            .collect::<Result<_>>()?;
        for f in &features {
            writer.push(f)?;
        }
    }
    writer.finish()?;
    match CacheFile::open(path, key, tiles.len()) {
        Ok(Some(file)) => Ok(file),
        Ok(None) => Err(AbslocError::Io {
            path: path.to_path_buf(),
            source: std::io::Error::new(
                std::io::ErrorKind::NotFound,
                "cache file vanished after writing",
            ),
        }),
        Err(e) => Err(AbslocError::Io {
            path: path.to_path_buf(),
            source: std::io::Error::other(format!(
                "cache file unreadable after writing: {}",
                e.message()
            )),
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cache::{cache_key, cache_path, encode};
    use std::sync::atomic::AtomicUsize;

    /// Grid corners as keypoints, descriptors from the pixel values; counts its calls.
    #[derive(Debug, Default)]
    struct Counting {
        calls: AtomicUsize,
        binary: bool,
    }

    impl Detector for Counting {
        fn detect(&self, image: &image::GrayImage) -> jointloc_features::Result<Features> {
            self.calls.fetch_add(1, Ordering::SeqCst);
            let mut f = Features {
                descriptor_dim: 10,
                image_size: image.dimensions(),
                ..Default::default()
            };
            for (i, y) in (5..image.height()).step_by(17).enumerate() {
                let x = (i as u32 * 11) % image.width();
                f.keypoints.push([x as f32, y as f32 + 0.25]);
                f.scores.push(0.5 + i as f32 * 1e-3);
                let p = image.get_pixel(x, y)[0];
                f.descriptors.extend((0..10).map(|b| {
                    if self.binary {
                        f32::from((p >> (b % 8)) & 1)
                    } else {
                        p as f32 / 255.0 + b as f32
                    }
                }));
            }
            Ok(f)
        }
    }

    fn map() -> MapTiles {
        let img = image::GrayImage::from_fn(400, 250, |x, y| {
            image::Luma([((x * 3 + y * 5 + x * y / 7) % 256) as u8])
        });
        MapTiles::from_image(img, 0.1, (100, 100), 0.5, Path::new(".")).unwrap()
    }

    fn all(store: &TileStore, m: &MapTiles) -> Vec<Features> {
        (0..store.len())
            .map(|i| (*store.get(m, i).unwrap()).clone())
            .collect()
    }

    #[test]
    fn cache_is_reused_invalidated_and_repaired() {
        let dir = tempfile::tempdir().unwrap();
        let m = map();
        let path = cache_path(&m, Some(dir.path()), "test det/1");
        assert!(path.ends_with("test_det_1.tiles"));
        let det = Arc::new(Counting::default());
        let key = cache_key(&m, "det=test;weights=abc;cfg=1");
        let a = TileStore::open(&m, det.clone(), &key, Some(&path), usize::MAX).unwrap();
        assert_eq!(a.status(), CacheStatus::Built);
        let n = det.calls.load(Ordering::SeqCst);
        assert_eq!(n, m.len());
        let reference = extract_all(&m, det.as_ref()).unwrap();
        assert_eq!(all(&a, &m), reference);
        let n = det.calls.load(Ordering::SeqCst);
        // Same key: read back, no extraction.
        let b = TileStore::open(&m, det.clone(), &key, Some(&path), usize::MAX).unwrap();
        assert_eq!(b.status(), CacheStatus::Hit);
        assert_eq!(all(&b, &m), reference);
        assert_eq!(det.calls.load(Ordering::SeqCst), n);
        // Another weights hash: stale, rebuilt, and the new key sticks.
        let key2 = cache_key(&m, "det=test;weights=abd;cfg=1");
        let open = |k: &str| TileStore::open(&m, det.clone(), k, Some(&path), usize::MAX).unwrap();
        assert_eq!(open(&key2).status(), CacheStatus::Stale);
        assert_eq!(open(&key2).status(), CacheStatus::Hit);
        // A changed map changes the key.
        let mut img = m.map().clone();
        img.put_pixel(3, 3, image::Luma([img.get_pixel(3, 3)[0].wrapping_add(1)]));
        let m2 = MapTiles::from_image(img, 0.1, (100, 100), 0.5, Path::new(".")).unwrap();
        assert_ne!(cache_key(&m2, "det=test;weights=abd;cfg=1"), key2);
        // Damage to the header or index (or garbage, or an empty file) is detected and the
        // file rebuilt.
        let good = std::fs::read(&path).unwrap();
        for damage in [
            {
                let mut d = good.clone();
                d[20] ^= 0x40;
                d
            },
            {
                let mut d = good.clone();
                let at = d.len() - 30;
                d[at] ^= 0x40;
                d
            },
            good[..good.len() - 3].to_vec(),
            b"not a cache at all".to_vec(),
            Vec::new(),
        ] {
            std::fs::write(&path, &damage).unwrap();
            let r = open(&key2);
            assert_eq!(r.status(), CacheStatus::Corrupt);
            assert_eq!(all(&r, &m), reference);
            assert_eq!(std::fs::read(&path).unwrap(), good);
        }
        // Another layout version is stale, not corrupt.
        let mut other = good.clone();
        other[8] = 99;
        std::fs::write(&path, &other).unwrap();
        assert_eq!(open(&key2).status(), CacheStatus::Stale);
        // Only the cache file is in the cache folder (the temporary file was renamed).
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names.len(), 1, "{names:?}");
    }

    #[test]
    fn a_damaged_record_is_extracted_again() {
        let dir = tempfile::tempdir().unwrap();
        let m = map();
        let det = Arc::new(Counting {
            binary: true,
            ..Default::default()
        });
        let reference = extract_all(&m, det.as_ref()).unwrap();
        let path = dir.path().join("t.tiles");
        let mut bytes = encode("k", &reference);
        // A byte in the middle of the first record's keypoints: the index still verifies.
        bytes[40] ^= 0x01;
        std::fs::write(&path, &bytes).unwrap();
        let store = TileStore::open(&m, det.clone(), "k", Some(&path), usize::MAX).unwrap();
        assert_eq!(store.status(), CacheStatus::Hit);
        let before = det.calls.load(Ordering::SeqCst);
        assert_eq!(all(&store, &m), reference);
        assert_eq!(det.calls.load(Ordering::SeqCst), before + 1);
    }

    #[test]
    fn memory_stays_within_the_budget() {
        let dir = tempfile::tempdir().unwrap();
        let m = map();
        assert!(m.len() >= 6, "{}", m.len());
        let det = Arc::new(Counting::default());
        let path = dir.path().join("t.tiles");
        let one = bytes_of(&extract_all(&m, det.as_ref()).unwrap()[0]);
        // Room for two tiles.
        let store = TileStore::open(&m, det.clone(), "k", Some(&path), 2 * one + one / 2).unwrap();
        assert_eq!(
            store.resident_bytes(),
            0,
            "nothing is read before it is asked for"
        );
        store.get(&m, 0).unwrap();
        store.get(&m, 1).unwrap();
        assert_eq!(store.reads(), 2);
        store.get(&m, 0).unwrap();
        assert_eq!(store.reads(), 2, "tile 0 stays in memory");
        // Tile 2 pushes out the least recently used, tile 1.
        store.get(&m, 2).unwrap();
        assert!(store.resident_bytes() <= 2 * one + one / 2);
        store.get(&m, 0).unwrap();
        assert_eq!(store.reads(), 3);
        store.get(&m, 1).unwrap();
        assert_eq!(store.reads(), 4);
        // A whole pass over the map reads each tile and keeps within the budget.
        for i in 0..m.len() {
            store.get(&m, i).unwrap();
            assert!(store.resident_bytes() <= 2 * one + one / 2);
        }
        assert_eq!(store.keypoints(3), store.get(&m, 3).unwrap().len());
    }

    #[test]
    fn disabled_cache_writes_nothing() {
        let m = map();
        let det = Arc::new(Counting::default());
        let r = TileStore::open(&m, det, "k", None, 0).unwrap();
        assert_eq!(r.status(), CacheStatus::Disabled);
        assert_eq!(r.len(), m.len());
        assert!(r.path().is_none());
    }

    #[test]
    fn a_read_only_folder_keeps_the_features_in_memory() {
        let dir = tempfile::tempdir().unwrap();
        let m = map();
        let det = Arc::new(Counting::default());
        // The cache's folder is a file: it cannot be created.
        let blocker = dir.path().join("blocked");
        std::fs::write(&blocker, b"x").unwrap();
        let r = TileStore::open(&m, det.clone(), "k", Some(&blocker.join("t.tiles")), 0).unwrap();
        assert_eq!(r.status(), CacheStatus::Built);
        assert!(r.path().is_none());
        assert_eq!(all(&r, &m), extract_all(&m, det.as_ref()).unwrap());
    }
}
