//! On-disk cache of the tile features: extracted once per detector and map, read back tile by
//! tile as the search needs them (the paper extracts tile features offline). A 2 km map at
//! 25 cm/px has about 1000 tiles and 0.5 GB of features; a 5 km map six times as many, more
//! than a small flight computer holds, so the file is indexed and never read whole
//! ([`crate::tile_store`] keeps the tiles in use in memory).
//!
//! One file per detector, `<map folder>/jointloc-cache/<detector id>.tiles`, only ever written
//! by this module (through a temporary file and a rename, so a crash never leaves half a file).
//! Layout, little endian:
//!
//! ```text
//! header   magic "JLTILEFT"  version u32  key_len u32  key (UTF-8)  tiles u32
//! records  per tile: n u32  dim u32  width u32  height u32  encoding u8 (0 f32, 1 bits)
//!          keypoints n×2 f32  scores n f32  descriptors (n×dim f32, or n×⌈dim/8⌉ bytes)
//! index    per tile: offset u64  length u64  keypoints u32  checksum u64 (of its record)
//! trailer  index offset u64  checksum u64 (FNV-1a of the header and the index)
//! ```
//!
//! The key names the detector, its weights hash and configuration, and the map fingerprint:
//! any change rebuilds the file. A header or index that fails to verify rebuilds the file with
//! a warning; a record that fails its checksum when read is extracted again from the map (see
//! [`crate::tile_store`]). Binary descriptors (ORB, stored as 0/1 floats in [`Features`]) are
//! packed to bits.

use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use jointloc_features::Features;

use crate::error::{Result, io_err};
use crate::tiles::MapTiles;

const MAGIC: &[u8; 8] = b"JLTILEFT";
/// Version of the file layout; bumped whenever it changes (2: indexed, per-tile checksums).
pub const CACHE_VERSION: u32 = 2;
/// Bytes of one index entry.
const ENTRY_BYTES: usize = 8 + 8 + 4 + 8;
/// Bytes of the trailer.
const TRAILER_BYTES: usize = 16;

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

/// Checksum of a record: FNV-1a's step over 8-byte words (8× faster than per byte on the
/// 0.5 GB a whole-map search reads). Each step is a bijection of the state for a given word,
/// so any change of a single word, and any truncation, changes the result.
pub fn record_checksum(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325 ^ bytes.len() as u64;
    let mut words = bytes.chunks_exact(8);
    for w in &mut words {
        let w = u64::from_le_bytes([w[0], w[1], w[2], w[3], w[4], w[5], w[6], w[7]]);
        h = (h ^ w).wrapping_mul(0x0000_0100_0000_01b3);
        h ^= h >> 29;
    }
    for &b in words.remainder() {
        h = (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// What happened to the cache when it was opened.
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

/// Where one tile's record lies in the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct RecordEntry {
    pub offset: u64,
    pub len: u64,
    /// Keypoints in the record (known without reading it).
    pub keypoints: u32,
    pub checksum: u64,
}

/// Why a cache file could not be used.
#[derive(Debug, Clone, PartialEq)]
pub enum DecodeError {
    /// Not our file or damaged.
    Corrupt(String),
    /// Our file, another layout version.
    Version(u32),
    /// Our file, another key (detector, weights, configuration or map) or tile count.
    Stale,
}

impl DecodeError {
    pub(crate) fn message(&self) -> String {
        match self {
            Self::Corrupt(m) => m.clone(),
            Self::Version(v) => format!("version {v}"),
            Self::Stale => "another key".into(),
        }
    }
}

fn corrupt(m: &str) -> DecodeError {
    DecodeError::Corrupt(m.to_string())
}

fn header_bytes(key: &str, tiles: usize) -> Vec<u8> {
    let mut out = Vec::with_capacity(20 + key.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&CACHE_VERSION.to_le_bytes());
    out.extend_from_slice(&(key.len() as u32).to_le_bytes());
    out.extend_from_slice(key.as_bytes());
    out.extend_from_slice(&(tiles as u32).to_le_bytes());
    out
}

fn index_bytes(entries: &[RecordEntry]) -> Vec<u8> {
    let mut out = Vec::with_capacity(entries.len() * ENTRY_BYTES);
    for e in entries {
        out.extend_from_slice(&e.offset.to_le_bytes());
        out.extend_from_slice(&e.len.to_le_bytes());
        out.extend_from_slice(&e.keypoints.to_le_bytes());
        out.extend_from_slice(&e.checksum.to_le_bytes());
    }
    out
}

fn header_index_checksum(header: &[u8], index: &[u8]) -> u64 {
    let mut h = Fnv64::new();
    h.write(header);
    h.write(index);
    h.finish()
}

/// Whether every descriptor value is exactly 0 or 1 (binary descriptors stored as floats).
fn is_binary(f: &Features) -> bool {
    !f.descriptors.is_empty() && f.descriptors.iter().all(|&v| v == 0.0 || v == 1.0)
}

/// Serialises one tile's features (a record of the layout in the module docs).
pub fn encode_record(f: &Features) -> Vec<u8> {
    let binary = is_binary(f);
    let desc_bytes = if binary {
        f.len() * f.descriptor_dim.div_ceil(8)
    } else {
        f.descriptors.len() * 4
    };
    let mut out = Vec::with_capacity(17 + f.len() * 12 + desc_bytes);
    for v in [
        f.len() as u32,
        f.descriptor_dim as u32,
        f.image_size.0,
        f.image_size.1,
    ] {
        out.extend_from_slice(&v.to_le_bytes());
    }
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
            for chunk in f.descriptor(i).chunks(8) {
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
    out
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
            .ok_or_else(|| corrupt("truncated"))?;
        let s = &self.bytes[self.at..end];
        self.at = end;
        Ok(s)
    }

    fn u32(&mut self) -> Result<u32, DecodeError> {
        Ok(u32::from_le_bytes(
            self.take(4)?.try_into().unwrap_or_default(),
        ))
    }

    fn u64(&mut self) -> Result<u64, DecodeError> {
        Ok(u64::from_le_bytes(
            self.take(8)?.try_into().unwrap_or_default(),
        ))
    }

    fn f32s(&mut self, n: usize) -> Result<Vec<f32>, DecodeError> {
        let raw = self.take(n.checked_mul(4).ok_or_else(|| corrupt("size overflow"))?)?;
        Ok(raw
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect())
    }
}

/// Parses one record (its whole bytes, nothing after them).
pub fn decode_record(bytes: &[u8]) -> Result<Features, DecodeError> {
    let mut r = Reader { bytes, at: 0 };
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
    if r.at != bytes.len() {
        return Err(corrupt("trailing bytes in a record"));
    }
    Ok(Features {
        keypoints,
        scores,
        descriptors,
        descriptor_dim: dim,
        image_size,
    })
}

/// Serialises `features` under `key`: a whole cache file in memory (tests, small maps).
pub fn encode(key: &str, features: &[Features]) -> Vec<u8> {
    let header = header_bytes(key, features.len());
    let mut out = header.clone();
    let mut entries = Vec::with_capacity(features.len());
    for f in features {
        let rec = encode_record(f);
        entries.push(RecordEntry {
            offset: out.len() as u64,
            len: rec.len() as u64,
            keypoints: f.len() as u32,
            checksum: record_checksum(&rec),
        });
        out.extend_from_slice(&rec);
    }
    let index_at = out.len() as u64;
    let index = index_bytes(&entries);
    out.extend_from_slice(&index);
    out.extend_from_slice(&index_at.to_le_bytes());
    out.extend_from_slice(&header_index_checksum(&header, &index).to_le_bytes());
    out
}

/// Parses a whole cache file held in memory: `(key, features)`.
pub fn decode(bytes: &[u8]) -> Result<(String, Vec<Features>), DecodeError> {
    let layout = parse_layout(bytes, bytes.len() as u64, |at, len| {
        let (at, len) = (usize::try_from(at).ok()?, usize::try_from(len).ok()?);
        bytes.get(at..at.checked_add(len)?).map(<[u8]>::to_vec)
    })?;
    let mut features = Vec::with_capacity(layout.entries.len());
    for e in &layout.entries {
        let rec = &bytes[e.offset as usize..(e.offset + e.len) as usize];
        if record_checksum(rec) != e.checksum {
            return Err(corrupt("record checksum mismatch"));
        }
        features.push(decode_record(rec)?);
    }
    Ok((layout.key, features))
}

/// The header and index of a file.
struct Layout {
    key: String,
    entries: Vec<RecordEntry>,
}

/// Reads and verifies the header and index through `read(offset, len)`; `size` is the file's.
fn parse_layout(
    head: &[u8],
    size: u64,
    read: impl Fn(u64, u64) -> Option<Vec<u8>>,
) -> Result<Layout, DecodeError> {
    if head.len() < 16 || &head[..MAGIC.len()] != MAGIC {
        return Err(corrupt("not a tile feature cache"));
    }
    let version = u32::from_le_bytes(head[8..12].try_into().unwrap_or_default());
    if version != CACHE_VERSION {
        return Err(DecodeError::Version(version));
    }
    let mut r = Reader {
        bytes: head,
        at: 12,
    };
    let key_len = r.u32()? as usize;
    let key =
        String::from_utf8(r.take(key_len)?.to_vec()).map_err(|_| corrupt("key is not UTF-8"))?;
    let tiles = r.u32()? as usize;
    let header_len = r.at as u64;
    let header = head[..r.at].to_vec();
    if size < header_len + TRAILER_BYTES as u64 {
        return Err(corrupt("truncated"));
    }
    let trailer = read(size - TRAILER_BYTES as u64, TRAILER_BYTES as u64)
        .ok_or_else(|| corrupt("truncated"))?;
    let mut t = Reader {
        bytes: &trailer,
        at: 0,
    };
    let index_at = t.u64()?;
    let sum = t.u64()?;
    let index_len = (tiles as u64)
        .checked_mul(ENTRY_BYTES as u64)
        .ok_or_else(|| corrupt("size overflow"))?;
    if index_at < header_len || index_at.checked_add(index_len) != Some(size - TRAILER_BYTES as u64)
    {
        return Err(corrupt("index out of place"));
    }
    let index = read(index_at, index_len).ok_or_else(|| corrupt("truncated"))?;
    if header_index_checksum(&header, &index) != sum {
        return Err(corrupt("header or index checksum mismatch"));
    }
    let mut r = Reader {
        bytes: &index,
        at: 0,
    };
    let mut entries = Vec::with_capacity(tiles);
    let mut next = header_len;
    for _ in 0..tiles {
        let e = RecordEntry {
            offset: r.u64()?,
            len: r.u64()?,
            keypoints: r.u32()?,
            checksum: r.u64()?,
        };
        if e.offset != next {
            return Err(corrupt("records out of order"));
        }
        next = e
            .offset
            .checked_add(e.len)
            .ok_or_else(|| corrupt("size overflow"))?;
        entries.push(e);
    }
    if next != index_at {
        return Err(corrupt("records and index do not meet"));
    }
    Ok(Layout { key, entries })
}

/// An opened, verified cache file: tiles are read one at a time.
#[derive(Debug)]
pub(crate) struct CacheFile {
    path: PathBuf,
    file: Mutex<std::fs::File>,
    entries: Vec<RecordEntry>,
}

/// Why a record could not be read.
#[derive(Debug)]
pub(crate) enum RecordError {
    Io(std::io::Error),
    Decode(DecodeError),
}

impl std::fmt::Display for RecordError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Io(e) => write!(f, "{e}"),
            Self::Decode(e) => write!(f, "{}", e.message()),
        }
    }
}

impl CacheFile {
    /// Opens `path` and verifies its header and index against `key` and `tiles`: `Ok(None)`
    /// when there is no file.
    pub(crate) fn open(
        path: &Path,
        key: &str,
        tiles: usize,
    ) -> std::result::Result<Option<Self>, DecodeError> {
        let mut file = match std::fs::File::open(path) {
            Ok(f) => f,
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::NotFound | std::io::ErrorKind::NotADirectory
                ) =>
            {
                return Ok(None);
            }
            Err(e) => return Err(DecodeError::Corrupt(format!("unreadable: {e}"))),
        };
        let size = file
            .metadata()
            .map_err(|e| DecodeError::Corrupt(format!("unreadable: {e}")))?
            .len();
        let mut head = vec![0u8; 16];
        file.read_exact(&mut head)
            .map_err(|_| corrupt("not a tile feature cache"))?;
        if &head[..MAGIC.len()] == MAGIC
            && u32::from_le_bytes(head[8..12].try_into().unwrap_or_default()) == CACHE_VERSION
        {
            // The key and the tile count follow.
            let key_len = u32::from_le_bytes(head[12..16].try_into().unwrap_or_default()) as u64;
            if key_len > size {
                return Err(corrupt("truncated"));
            }
            let mut rest = vec![0u8; key_len as usize + 4];
            file.read_exact(&mut rest)
                .map_err(|_| corrupt("truncated"))?;
            head.extend_from_slice(&rest);
        }
        let file = Mutex::new(file);
        let read = |at: u64, len: u64| -> Option<Vec<u8>> {
            let mut f = file.lock().ok()?;
            f.seek(SeekFrom::Start(at)).ok()?;
            let mut buf = vec![0u8; usize::try_from(len).ok()?];
            f.read_exact(&mut buf).ok()?;
            Some(buf)
        };
        let layout = parse_layout(&head, size, read)?;
        if layout.key != key || layout.entries.len() != tiles {
            return Err(DecodeError::Stale);
        }
        Ok(Some(Self {
            path: path.to_path_buf(),
            file,
            entries: layout.entries,
        }))
    }

    pub(crate) fn path(&self) -> &Path {
        &self.path
    }

    pub(crate) fn entries(&self) -> &[RecordEntry] {
        &self.entries
    }

    /// Reads and verifies tile `i`'s record.
    pub(crate) fn read(&self, i: usize) -> std::result::Result<Features, RecordError> {
        let e = self.entries[i];
        let mut buf = vec![0u8; e.len as usize];
        {
            let mut f = self
                .file
                .lock()
                .map_err(|_| RecordError::Io(std::io::Error::other("cache file lock poisoned")))?;
            f.seek(SeekFrom::Start(e.offset)).map_err(RecordError::Io)?;
            f.read_exact(&mut buf).map_err(RecordError::Io)?;
        }
        if record_checksum(&buf) != e.checksum {
            return Err(RecordError::Decode(corrupt("record checksum mismatch")));
        }
        decode_record(&buf).map_err(RecordError::Decode)
    }
}

/// Writes a cache file tile by tile: into a temporary file beside `path`, renamed over it
/// by [`CacheWriter::finish`] (a crash or an error leaves the old file, or none).
pub(crate) struct CacheWriter {
    path: PathBuf,
    tmp: PathBuf,
    /// `None` once finished.
    out: Option<std::io::BufWriter<std::fs::File>>,
    header: Vec<u8>,
    at: u64,
    entries: Vec<RecordEntry>,
}

impl CacheWriter {
    pub(crate) fn create(path: &Path, key: &str, tiles: usize) -> Result<Self> {
        let dir = path.parent().unwrap_or(Path::new("."));
        std::fs::create_dir_all(dir).map_err(io_err(dir))?;
        let tmp = dir.join(format!(
            ".{}.tmp-{}",
            path.file_name().and_then(|n| n.to_str()).unwrap_or("cache"),
            std::process::id()
        ));
        let file = std::fs::File::create(&tmp).map_err(io_err(&tmp))?;
        let mut out = std::io::BufWriter::with_capacity(1 << 20, file);
        let header = header_bytes(key, tiles);
        out.write_all(&header).map_err(io_err(&tmp))?;
        Ok(Self {
            path: path.to_path_buf(),
            tmp,
            out: Some(out),
            at: header.len() as u64,
            header,
            entries: Vec::with_capacity(tiles),
        })
    }

    /// Appends the next tile's features.
    pub(crate) fn push(&mut self, f: &Features) -> Result<()> {
        let rec = encode_record(f);
        let out = self
            .out
            .as_mut()
            .ok_or_else(|| io_err(&self.tmp)(std::io::Error::other("cache already written")))?;
        out.write_all(&rec).map_err(io_err(&self.tmp))?;
        self.entries.push(RecordEntry {
            offset: self.at,
            len: rec.len() as u64,
            keypoints: f.len() as u32,
            checksum: record_checksum(&rec),
        });
        self.at += rec.len() as u64;
        Ok(())
    }

    /// Writes the index and renames the file into place.
    pub(crate) fn finish(mut self) -> Result<()> {
        let index = index_bytes(&self.entries);
        let sum = header_index_checksum(&self.header, &index);
        let at = self.at;
        let Some(mut out) = self.out.take() else {
            return Ok(());
        };
        let written = (|| -> std::io::Result<()> {
            out.write_all(&index)?;
            out.write_all(&at.to_le_bytes())?;
            out.write_all(&sum.to_le_bytes())?;
            out.flush()?;
            out.get_ref().sync_all()
        })();
        drop(out);
        written.map_err(io_err(&self.tmp))?;
        std::fs::rename(&self.tmp, &self.path).map_err(io_err(&self.path))
    }
}

impl Drop for CacheWriter {
    fn drop(&mut self) {
        // Unfinished (an error, a panic elsewhere): no temporary file is left behind. After
        // `finish` the temporary file no longer exists and this does nothing.
        let _ = std::fs::remove_file(&self.tmp);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn features(n: usize, dim: usize, binary: bool, seed: u32) -> Features {
        let mut f = Features {
            descriptor_dim: dim,
            image_size: (100 + seed, 80),
            ..Default::default()
        };
        for i in 0..n {
            f.keypoints
                .push([i as f32 * 1.5, (i as u32 * 7 + seed) as f32 + 0.25]);
            f.scores.push(0.5 + i as f32 * 1e-3);
            f.descriptors.extend((0..dim).map(|b| {
                let v = ((i as u32 * 31 + b as u32 * 17 + seed) % 97) as f32;
                if binary {
                    f32::from(v > 48.0)
                } else {
                    v / 97.0 - 0.3
                }
            }));
        }
        f
    }

    #[test]
    fn round_trips_float_and_binary_descriptors() {
        for binary in [false, true] {
            let feats: Vec<Features> = (0..5)
                .map(|t| features(t * 3, if binary { 256 } else { 10 }, binary, t as u32))
                .collect();
            let bytes = encode("k", &feats);
            let (key, back) = decode(&bytes).unwrap();
            assert_eq!(key, "k");
            assert_eq!(back, feats);
        }
    }

    #[test]
    fn any_damage_is_detected() {
        let feats: Vec<Features> = (0..4).map(|t| features(20, 8, false, t)).collect();
        let good = encode("key", &feats);
        // A flipped bit anywhere: in a record (its checksum), the header or the index.
        for at in (0..good.len()).step_by(7) {
            let mut d = good.clone();
            d[at] ^= 0x10;
            assert!(decode(&d).is_err(), "flip at {at} of {}", good.len());
        }
        for cut in [1, 8, 17, good.len() / 2] {
            assert!(decode(&good[..good.len() - cut]).is_err());
        }
        assert!(decode(b"not a cache at all, really not").is_err());
        let mut other = good.clone();
        other[8] = 99;
        assert_eq!(decode(&other).unwrap_err(), DecodeError::Version(99));
    }

    #[test]
    fn the_record_checksum_sees_every_word_and_the_length() {
        let base: Vec<u8> = (0..103u32).map(|i| (i * 37 % 251) as u8).collect();
        let h = record_checksum(&base);
        for at in 0..base.len() {
            let mut d = base.clone();
            d[at] ^= 1;
            assert_ne!(record_checksum(&d), h, "byte {at}");
        }
        assert_ne!(record_checksum(&base[..base.len() - 1]), h);
        let mut longer = base.clone();
        longer.push(0);
        assert_ne!(record_checksum(&longer), h);
    }

    #[test]
    fn a_file_is_read_tile_by_tile() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.tiles");
        let feats: Vec<Features> = (0..6)
            .map(|t| features(t as usize * 5, 12, false, t))
            .collect();
        let mut w = CacheWriter::create(&path, "key", feats.len()).unwrap();
        for f in &feats {
            w.push(f).unwrap();
        }
        w.finish().unwrap();
        // The streamed file is the in-memory encoding, byte for byte.
        assert_eq!(std::fs::read(&path).unwrap(), encode("key", &feats));
        let file = CacheFile::open(&path, "key", 6).unwrap().unwrap();
        for i in [5, 0, 3] {
            assert_eq!(file.read(i).unwrap(), feats[i]);
            assert_eq!(file.entries()[i].keypoints as usize, feats[i].len());
        }
        assert_eq!(
            CacheFile::open(&path, "other", 6).unwrap_err(),
            DecodeError::Stale
        );
        assert_eq!(
            CacheFile::open(&path, "key", 7).unwrap_err(),
            DecodeError::Stale
        );
        assert!(
            CacheFile::open(&dir.path().join("none"), "key", 6)
                .unwrap()
                .is_none()
        );
        // Only the file itself is left in the folder.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn an_unfinished_writer_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.tiles");
        {
            let mut w = CacheWriter::create(&path, "key", 3).unwrap();
            w.push(&features(4, 8, false, 1)).unwrap();
        }
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }
}
