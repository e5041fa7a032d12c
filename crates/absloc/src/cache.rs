//! On-disk cache of the tile features: extracted once per detector and map, read back on the
//! next run (the paper extracts tile features offline).
//!
//! One file per detector, `<map folder>/jointloc-cache/<detector id>.tiles`, only ever written
//! by this module (through a temporary file and a rename, so a crash never leaves half a file).
//! Layout, little endian:
//!
//! ```text
//! magic "JLTILEFT"  version u32  key_len u32  key (UTF-8)  tiles u32
//! per tile: n u32  dim u32  width u32  height u32  encoding u8 (0 f32, 1 bits)
//!           keypoints n×2 f32  scores n f32  descriptors (n×dim f32, or n×⌈dim/8⌉ bytes)
//! checksum u64 (FNV-1a of everything before it)
//! ```
//!
//! The key names the detector, its weights hash and configuration, and the map fingerprint:
//! any change rebuilds the file. A file that fails to parse or verify is rebuilt with a
//! warning. Binary descriptors (ORB, stored as 0/1 floats in [`Features`]) are packed to bits.

use std::io::Write;
use std::path::{Path, PathBuf};

use jointloc_features::{Detector, Features};
use rayon::prelude::*;

use crate::error::{Result, io_err};
use crate::tiles::MapTiles;

const MAGIC: &[u8; 8] = b"JLTILEFT";
/// Version of the file layout; bumped whenever it changes.
pub const CACHE_VERSION: u32 = 1;

/// 64-bit FNV-1a: a cheap checksum and fingerprint (not a cryptographic hash).
#[derive(Debug, Clone)]
pub struct Fnv64(u64);

impl Default for Fnv64 {
    fn default() -> Self {
        Self::new()
    }
}

impl Fnv64 {
    /// The FNV offset basis.
    pub fn new() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }

    /// Absorbs `bytes`.
    pub fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 ^= u64::from(b);
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }

    /// The hash so far.
    pub fn finish(&self) -> u64 {
        self.0
    }
}

/// What happened to the cache when loading.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CacheStatus {
    /// Read back, key matching.
    Hit,
    /// No file yet: features extracted and written.
    Built,
    /// The key (detector, weights, config or map) changed: rebuilt.
    Stale,
    /// The file did not parse or verify: rebuilt (with a warning).
    Corrupt,
    /// Caching disabled: features extracted, nothing written.
    Disabled,
}

/// Tile features and how they were obtained.
#[derive(Debug, Clone)]
pub struct TileFeatures {
    /// One entry per tile, in [`MapTiles::tiles`] order, in tile pixels.
    pub features: Vec<Features>,
    pub status: CacheStatus,
    /// The cache file (None when disabled).
    pub path: Option<PathBuf>,
}

/// Cache file of detector `detector_id` for `tiles`: `dir` when given, else
/// `<map folder>/jointloc-cache`.
pub fn cache_path(tiles: &MapTiles, dir: Option<&Path>, detector_id: &str) -> PathBuf {
    let safe: String = detector_id
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    dir.map(Path::to_path_buf)
        .unwrap_or_else(|| tiles.root().join("jointloc-cache"))
        .join(format!("{safe}.tiles"))
}

/// Full cache key: the detector key and the map fingerprint.
pub fn cache_key(tiles: &MapTiles, detector_key: &str) -> String {
    format!("{detector_key}|map={:016x}", tiles.fingerprint())
}

/// Extracts the features of every tile (in parallel).
pub fn extract_all(tiles: &MapTiles, detector: &dyn Detector) -> Result<Vec<Features>> {
    (0..tiles.len())
        .into_par_iter()
        .map(|i| Ok(detector.detect(&tiles.tile_image(i))?))
        .collect()
}

/// Loads the tile features from `path` when its key is `key`, else extracts and writes them.
/// With `path = None` nothing is read or written. A write failure (read-only dataset) is a
/// warning, not an error: the features are still returned.
pub fn load_or_build(
    tiles: &MapTiles,
    detector: &dyn Detector,
    key: &str,
    path: Option<&Path>,
) -> Result<TileFeatures> {
    let Some(path) = path else {
        return Ok(TileFeatures {
            features: extract_all(tiles, detector)?,
            status: CacheStatus::Disabled,
            path: None,
        });
    };
    let status = match std::fs::read(path) {
        Ok(bytes) => match decode(&bytes) {
            Ok((k, features)) if k == key && features.len() == tiles.len() => {
                tracing::debug!(path = %path.display(), "tile features from cache");
                return Ok(TileFeatures {
                    features,
                    status: CacheStatus::Hit,
                    path: Some(path.to_path_buf()),
                });
            }
            Ok(_) => {
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
        },
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => CacheStatus::Built,
        Err(e) => {
            tracing::warn!(path = %path.display(), error = %e, "tile feature cache unreadable, rebuilding");
            CacheStatus::Corrupt
        }
    };
    let features = extract_all(tiles, detector)?;
    if let Err(e) = write_atomic(path, &encode(key, &features)) {
        tracing::warn!(error = %e, "could not write the tile feature cache; continuing without it");
    }
    Ok(TileFeatures {
        features,
        status,
        path: Some(path.to_path_buf()),
    })
}

fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let dir = path.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).map_err(io_err(dir))?;
    let tmp = dir.join(format!(
        ".{}.tmp-{}",
        path.file_name().and_then(|n| n.to_str()).unwrap_or("cache"),
        std::process::id()
    ));
    let mut f = std::fs::File::create(&tmp).map_err(io_err(&tmp))?;
    f.write_all(bytes).map_err(io_err(&tmp))?;
    f.sync_all().map_err(io_err(&tmp))?;
    drop(f);
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        io_err(path)(e)
    })
}

/// Whether every descriptor value is exactly 0 or 1 (binary descriptors stored as floats).
fn is_binary(f: &Features) -> bool {
    !f.descriptors.is_empty() && f.descriptors.iter().all(|&v| v == 0.0 || v == 1.0)
}

/// Serialises `features` under `key` (the file layout in the module docs).
pub fn encode(key: &str, features: &[Features]) -> Vec<u8> {
    let mut out = Vec::new();
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&CACHE_VERSION.to_le_bytes());
    out.extend_from_slice(&(key.len() as u32).to_le_bytes());
    out.extend_from_slice(key.as_bytes());
    out.extend_from_slice(&(features.len() as u32).to_le_bytes());
    for f in features {
        for v in [
            f.len() as u32,
            f.descriptor_dim as u32,
            f.image_size.0,
            f.image_size.1,
        ] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        let binary = is_binary(f);
        out.push(u8::from(binary));
        for kp in &f.keypoints {
            out.extend_from_slice(&kp[0].to_le_bytes());
            out.extend_from_slice(&kp[1].to_le_bytes());
        }
        for s in &f.scores {
            out.extend_from_slice(&s.to_le_bytes());
        }
        if binary {
            for i in 0..f.len() {
                let d = f.descriptor(i);
                for chunk in d.chunks(8) {
                    let byte = chunk
                        .iter()
                        .enumerate()
                        .fold(0u8, |acc, (b, &v)| acc | (u8::from(v != 0.0) << b));
                    out.push(byte);
                }
            }
        } else {
            for v in &f.descriptors {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
    }
    let mut h = Fnv64::new();
    h.write(&out);
    out.extend_from_slice(&h.finish().to_le_bytes());
    out
}

/// Why a cache file could not be read.
#[derive(Debug, Clone, PartialEq)]
pub enum DecodeError {
    /// Not our file or damaged.
    Corrupt(String),
    /// Our file, another layout version.
    Version(u32),
}

impl DecodeError {
    fn message(&self) -> String {
        match self {
            Self::Corrupt(m) => m.clone(),
            Self::Version(v) => format!("version {v}"),
        }
    }
}

struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8], DecodeError> {
        let end = self
            .at
            .checked_add(n)
            .filter(|&e| e <= self.bytes.len())
            .ok_or_else(|| DecodeError::Corrupt("truncated".into()))?;
        let s = &self.bytes[self.at..end];
        self.at = end;
        Ok(s)
    }

    fn u32(&mut self) -> Result<u32, DecodeError> {
        Ok(u32::from_le_bytes(
            self.take(4)?.try_into().unwrap_or_default(),
        ))
    }

    fn f32s(&mut self, n: usize) -> Result<Vec<f32>, DecodeError> {
        let raw = self.take(
            n.checked_mul(4)
                .ok_or_else(|| DecodeError::Corrupt("size overflow".into()))?,
        )?;
        Ok(raw
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect())
    }
}

/// Parses a cache file: `(key, features)`.
pub fn decode(bytes: &[u8]) -> Result<(String, Vec<Features>), DecodeError> {
    let corrupt = |m: &str| DecodeError::Corrupt(m.to_string());
    if bytes.len() < MAGIC.len() + 4 + 8 || &bytes[..MAGIC.len()] != MAGIC {
        return Err(corrupt("not a tile feature cache"));
    }
    let version = u32::from_le_bytes(bytes[8..12].try_into().unwrap_or_default());
    if version != CACHE_VERSION {
        return Err(DecodeError::Version(version));
    }
    let (body, sum) = bytes.split_at(bytes.len() - 8);
    let mut h = Fnv64::new();
    h.write(body);
    if h.finish().to_le_bytes() != sum {
        return Err(corrupt("checksum mismatch"));
    }
    let mut r = Reader {
        bytes: body,
        at: 12,
    };
    let key_len = r.u32()? as usize;
    let key =
        String::from_utf8(r.take(key_len)?.to_vec()).map_err(|_| corrupt("key is not UTF-8"))?;
    let n_tiles = r.u32()? as usize;
    let mut features = Vec::with_capacity(n_tiles.min(1 << 16));
    for _ in 0..n_tiles {
        let n = r.u32()? as usize;
        let dim = r.u32()? as usize;
        let image_size = (r.u32()?, r.u32()?);
        let binary = match r.take(1)?[0] {
            0 => false,
            1 => true,
            _ => return Err(corrupt("unknown descriptor encoding")),
        };
        let kp = r.f32s(n.checked_mul(2).ok_or_else(|| corrupt("size overflow"))?)?;
        let keypoints = kp.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
        let scores = r.f32s(n)?;
        let descriptors = if binary {
            let per = dim.div_ceil(8);
            let raw = r.take(n.checked_mul(per).ok_or_else(|| corrupt("size overflow"))?)?;
            let mut d = Vec::with_capacity(n * dim);
            for row in raw.chunks_exact(per.max(1)).take(n) {
                d.extend((0..dim).map(|b| f32::from((row[b / 8] >> (b % 8)) & 1)));
            }
            d
        } else {
            r.f32s(n.checked_mul(dim).ok_or_else(|| corrupt("size overflow"))?)?
        };
        features.push(Features {
            keypoints,
            scores,
            descriptors,
            descriptor_dim: dim,
            image_size,
        });
    }
    if r.at != body.len() {
        return Err(corrupt("trailing bytes"));
    }
    Ok((key, features))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};

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
        let img = image::GrayImage::from_fn(200, 150, |x, y| {
            image::Luma([((x * 3 + y * 5) % 256) as u8])
        });
        MapTiles::from_image(img, 0.1, (100, 100), 0.5, Path::new(".")).unwrap()
    }

    #[test]
    fn round_trips_float_and_binary_descriptors() {
        let m = map();
        for binary in [false, true] {
            let det = Counting {
                binary,
                ..Default::default()
            };
            let feats = extract_all(&m, &det).unwrap();
            let bytes = encode("k", &feats);
            let (key, back) = decode(&bytes).unwrap();
            assert_eq!(key, "k");
            assert_eq!(back, feats);
        }
    }

    #[test]
    fn cache_is_reused_invalidated_and_repaired() {
        let dir = tempfile::tempdir().unwrap();
        let m = map();
        let path = cache_path(&m, Some(dir.path()), "test det/1");
        assert!(path.ends_with("test_det_1.tiles"));
        let det = Counting::default();
        let key = cache_key(&m, "det=test;weights=abc;cfg=1");
        let a = load_or_build(&m, &det, &key, Some(&path)).unwrap();
        assert_eq!(a.status, CacheStatus::Built);
        let n = det.calls.load(Ordering::SeqCst);
        assert_eq!(n, m.len());
        // Same key: read back, no extraction.
        let b = load_or_build(&m, &det, &key, Some(&path)).unwrap();
        assert_eq!(b.status, CacheStatus::Hit);
        assert_eq!(b.features, a.features);
        assert_eq!(det.calls.load(Ordering::SeqCst), n);
        // Another weights hash: stale, rebuilt, and the new key sticks.
        let key2 = cache_key(&m, "det=test;weights=abd;cfg=1");
        assert_eq!(
            load_or_build(&m, &det, &key2, Some(&path)).unwrap().status,
            CacheStatus::Stale
        );
        assert_eq!(
            load_or_build(&m, &det, &key2, Some(&path)).unwrap().status,
            CacheStatus::Hit
        );
        // A changed map changes the key.
        let mut img = m.map().clone();
        img.put_pixel(3, 3, image::Luma([img.get_pixel(3, 3)[0].wrapping_add(1)]));
        let m2 = MapTiles::from_image(img, 0.1, (100, 100), 0.5, Path::new(".")).unwrap();
        assert_ne!(cache_key(&m2, "det=test;weights=abd;cfg=1"), key2);
        // Corruption anywhere (a flipped byte, truncation, garbage) is detected and repaired.
        let good = std::fs::read(&path).unwrap();
        for damage in [
            {
                let mut d = good.clone();
                let mid = d.len() / 2;
                d[mid] ^= 0x40;
                d
            },
            good[..good.len() - 3].to_vec(),
            b"not a cache at all".to_vec(),
            Vec::new(),
        ] {
            std::fs::write(&path, &damage).unwrap();
            let r = load_or_build(&m, &det, &key2, Some(&path)).unwrap();
            assert_eq!(r.status, CacheStatus::Corrupt);
            assert_eq!(r.features, a.features);
            assert_eq!(std::fs::read(&path).unwrap(), good);
        }
        // Another layout version is stale, not corrupt.
        let mut other = good.clone();
        other[8] = 99;
        std::fs::write(&path, &other).unwrap();
        assert_eq!(
            load_or_build(&m, &det, &key2, Some(&path)).unwrap().status,
            CacheStatus::Stale
        );
        // Only the cache file is in the cache folder (the temporary file was renamed).
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names.len(), 1, "{names:?}");
    }

    #[test]
    fn disabled_cache_writes_nothing() {
        let m = map();
        let det = Counting::default();
        let r = load_or_build(&m, &det, "k", None).unwrap();
        assert_eq!(r.status, CacheStatus::Disabled);
        assert_eq!(r.features.len(), m.len());
    }
}
