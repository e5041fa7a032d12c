//! PyTorch checkpoints (`torch.save` of a state dict) read without Python.
//!
//! Both formats torch writes are supported: the zip archive (`<name>/data.pkl` plus one file per
//! storage, torch ≥ 1.6) and the legacy single stream (magic number, protocol, system info, the
//! pickle, then the raw storages in key order). Nested dicts are flattened with `.` so a
//! checkpoint `{"extractor": {"conv.weight": …}}` yields `extractor.conv.weight`. Every tensor is
//! returned as contiguous row-major `f32`, whatever its stored type.

mod pickle;

use std::collections::{BTreeMap, HashMap};
use std::io::Read;
use std::path::{Path, PathBuf};

use crate::error::{FeaturesError, Result};
pub use pickle::{TensorView, Value};

/// One weight tensor: shape and contiguous row-major values.
#[derive(Debug, Clone, PartialEq)]
pub struct Tensor {
    pub shape: Vec<usize>,
    pub data: Vec<f32>,
}

impl Tensor {
    /// Number of elements (1 for a scalar).
    pub fn numel(&self) -> usize {
        self.shape.iter().product()
    }
}

/// All tensors of a checkpoint, by flattened name.
#[derive(Debug, Clone)]
pub struct StateDict {
    path: PathBuf,
    tensors: BTreeMap<String, Tensor>,
}

impl StateDict {
    /// Reads a checkpoint in either of torch's formats.
    pub fn read(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|source| FeaturesError::Io {
            path: path.to_owned(),
            source,
        })?;
        let bad = |reason: String| FeaturesError::Checkpoint {
            path: path.to_owned(),
            reason,
        };
        let tensors = if bytes.starts_with(b"PK") {
            read_zip(&bytes).map_err(bad)?
        } else {
            read_legacy(&bytes).map_err(bad)?
        };
        if tensors.is_empty() {
            return Err(bad("no tensors found".into()));
        }
        Ok(Self {
            path: path.to_owned(),
            tensors,
        })
    }

    /// The file this was read from (for error messages).
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Tensor names in sorted order.
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.tensors.keys().map(String::as_str)
    }

    /// Whether a tensor of that name exists.
    pub fn contains(&self, name: &str) -> bool {
        self.tensors.contains_key(name)
    }

    /// A tensor by name, or [`FeaturesError::MissingWeight`].
    pub fn get(&self, name: &str) -> Result<&Tensor> {
        self.tensors
            .get(name)
            .ok_or_else(|| FeaturesError::MissingWeight {
                path: self.path.clone(),
                name: name.to_owned(),
            })
    }

    /// A tensor by name whose shape must equal `shape`.
    pub fn get_shaped(&self, name: &str, shape: &[usize]) -> Result<&Tensor> {
        let t = self.get(name)?;
        if t.shape != shape {
            return Err(FeaturesError::WeightShape {
                name: name.to_owned(),
                expected: shape.to_vec(),
                found: t.shape.clone(),
            });
        }
        Ok(t)
    }

    /// The tensors under `prefix.`, with the prefix removed (a sub-module's state dict).
    pub fn sub(&self, prefix: &str) -> StateDict {
        let p = format!("{prefix}.");
        let tensors = self
            .tensors
            .iter()
            .filter_map(|(k, v)| k.strip_prefix(&p).map(|s| (s.to_owned(), v.clone())))
            .collect();
        StateDict {
            path: self.path.clone(),
            tensors,
        }
    }

    /// Builds a state dict from tensors (tests, user-supplied weights in other formats).
    pub fn from_tensors(path: PathBuf, tensors: BTreeMap<String, Tensor>) -> Self {
        Self { path, tensors }
    }
}

type Storages = HashMap<String, Vec<u8>>;

fn read_zip(bytes: &[u8]) -> Result<BTreeMap<String, Tensor>, String> {
    let mut archive =
        zip::ZipArchive::new(std::io::Cursor::new(bytes)).map_err(|e| format!("zip: {e}"))?;
    let names: Vec<String> = archive
        .file_names()
        .filter_map(|n| n.ok().map(|n| n.into_owned()))
        .collect();
    let pkl = names
        .iter()
        .find(|n| n.ends_with("data.pkl"))
        .ok_or("zip archive without data.pkl")?
        .clone();
    let prefix = pkl.trim_end_matches("data.pkl").to_owned();
    let read_entry = |archive: &mut zip::ZipArchive<_>, name: &str| -> Result<Vec<u8>, String> {
        let mut f = archive.by_name(name).map_err(|e| format!("{name}: {e}"))?;
        let mut buf = Vec::new();
        f.read_to_end(&mut buf)
            .map_err(|e| format!("{name}: {e}"))?;
        Ok(buf)
    };
    if let Ok(order) = read_entry(&mut archive, &format!("{prefix}byteorder"))
        && order.trim_ascii() != b"little"
    {
        return Err("big-endian checkpoints are not supported".into());
    }
    let (root, _) = pickle::unpickle(&read_entry(&mut archive, &pkl)?).map_err(|e| e.0)?;
    let mut views = Vec::new();
    collect_views(&root, String::new(), &mut views);
    let mut storages = Storages::new();
    for (_, view) in &views {
        if !storages.contains_key(&view.storage_key) {
            let data = read_entry(&mut archive, &format!("{prefix}data/{}", view.storage_key))?;
            storages.insert(view.storage_key.clone(), data);
        }
    }
    materialise(views, &storages)
}

fn read_legacy(bytes: &[u8]) -> Result<BTreeMap<String, Tensor>, String> {
    let mut pos = 0;
    let mut next = |what: &str| -> Result<Value, String> {
        let (v, used) = pickle::unpickle(&bytes[pos..]).map_err(|e| format!("{what}: {}", e.0))?;
        pos += used;
        Ok(v)
    };
    let magic = next("magic number")?;
    if !matches!(magic, Value::Bytes(ref b) if b.as_slice() == LEGACY_MAGIC) {
        return Err("neither a zip archive nor a legacy torch file (bad magic number)".into());
    }
    next("protocol version")?;
    next("system info")?;
    let root = next("state dict")?;
    let keys = match next("storage keys")? {
        Value::List(k) => k,
        _ => return Err("storage key list is not a list".into()),
    };
    let mut views = Vec::new();
    collect_views(&root, String::new(), &mut views);
    let types: HashMap<&str, &str> = views
        .iter()
        .map(|(_, v)| (v.storage_key.as_str(), v.storage_type.as_str()))
        .collect();
    let mut storages = Storages::new();
    for key in keys {
        let Value::Str(key) = key else {
            return Err("storage key is not a string".into());
        };
        let size = types.get(key.as_str()).map_or(Ok(4), |t| element_size(t))?;
        let header = bytes.get(pos..pos + 8).ok_or("truncated storage header")?;
        let numel = u64::from_le_bytes(header.try_into().expect("8 bytes")) as usize;
        pos += 8;
        let len = numel.checked_mul(size).ok_or("storage size overflows")?;
        let end = pos
            .checked_add(len)
            .filter(|&end| end <= bytes.len())
            .ok_or_else(|| format!("storage {key} truncated"))?;
        let data = &bytes[pos..end];
        pos = end;
        storages.insert(key, data.to_vec());
    }
    materialise(views, &storages)
}

/// `0x1950a86a20f9469cfc6c`, little-endian, as pickled by torch's legacy format.
const LEGACY_MAGIC: &[u8] = &[0x6c, 0xfc, 0x9c, 0x46, 0xf9, 0x20, 0x6a, 0xa8, 0x50, 0x19];

fn collect_views(v: &Value, prefix: String, out: &mut Vec<(String, TensorView)>) {
    match v {
        Value::Tensor(t) => out.push((prefix, t.clone())),
        Value::Dict(items) => {
            for (k, v) in items {
                let key = match k {
                    Value::Str(s) => s.clone(),
                    Value::Int(i) => i.to_string(),
                    _ => continue,
                };
                let name = if prefix.is_empty() {
                    key
                } else {
                    format!("{prefix}.{key}")
                };
                collect_views(v, name, out);
            }
        }
        _ => {}
    }
}

fn element_size(storage_type: &str) -> Result<usize, String> {
    Ok(match storage_type {
        "FloatStorage" | "IntStorage" => 4,
        "DoubleStorage" | "LongStorage" => 8,
        "HalfStorage" | "BFloat16Storage" | "ShortStorage" => 2,
        "ByteStorage" | "CharStorage" | "BoolStorage" => 1,
        other => return Err(format!("unsupported storage type {other}")),
    })
}

fn decode(storage_type: &str, raw: &[u8]) -> Result<Vec<f32>, String> {
    let size = element_size(storage_type)?;
    let chunks = raw.chunks_exact(size);
    Ok(match storage_type {
        "FloatStorage" => chunks
            .map(|c| f32::from_le_bytes(c.try_into().expect("4")))
            .collect(),
        "DoubleStorage" => chunks
            .map(|c| f64::from_le_bytes(c.try_into().expect("8")) as f32)
            .collect(),
        "HalfStorage" => chunks
            .map(|c| half_to_f32(u16::from_le_bytes([c[0], c[1]])))
            .collect(),
        "BFloat16Storage" => chunks
            .map(|c| f32::from_bits(u32::from(u16::from_le_bytes([c[0], c[1]])) << 16))
            .collect(),
        "LongStorage" => chunks
            .map(|c| i64::from_le_bytes(c.try_into().expect("8")) as f32)
            .collect(),
        "IntStorage" => chunks
            .map(|c| i32::from_le_bytes(c.try_into().expect("4")) as f32)
            .collect(),
        "ShortStorage" => chunks
            .map(|c| f32::from(i16::from_le_bytes([c[0], c[1]])))
            .collect(),
        "CharStorage" => chunks.map(|c| f32::from(c[0] as i8)).collect(),
        _ => chunks.map(|c| f32::from(c[0])).collect(),
    })
}

/// IEEE 754 binary16 to f32 (normals, subnormals, infinities, NaN).
fn half_to_f32(h: u16) -> f32 {
    let sign = if h & 0x8000 != 0 { -1.0 } else { 1.0 };
    let exp = (h >> 10) & 0x1f;
    let frac = f32::from(h & 0x3ff);
    match exp {
        0 => sign * frac * 2f32.powi(-24),
        31 if frac == 0.0 => sign * f32::INFINITY,
        31 => f32::NAN,
        e => sign * (1.0 + frac / 1024.0) * 2f32.powi(i32::from(e) - 15),
    }
}

/// Elements that views may read beyond their storages' sizes in all (a view with stride 0, as
/// of an expanded tensor, reads elements more than once): the bound keeps a tiny file from
/// asking for a huge tensor.
const MAX_REPEATED_ELEMENTS: usize = 1 << 24;

fn materialise(
    views: Vec<(String, TensorView)>,
    storages: &Storages,
) -> Result<BTreeMap<String, Tensor>, String> {
    let mut decoded: HashMap<&str, Vec<f32>> = HashMap::new();
    let mut out = BTreeMap::new();
    let mut repeats_left = MAX_REPEATED_ELEMENTS;
    for (name, view) in views {
        if !decoded.contains_key(view.storage_key.as_str()) {
            let raw = storages
                .get(&view.storage_key)
                .ok_or_else(|| format!("{name}: storage {} missing", view.storage_key))?;
            let (key, _) = storages.get_key_value(&view.storage_key).expect("present");
            decoded.insert(key.as_str(), decode(&view.storage_type, raw)?);
        }
        let storage = &decoded[view.storage_key.as_str()];
        if view.shape.len() != view.stride.len() {
            return Err(format!("{name}: size and stride differ in length"));
        }
        // Sizes and strides come from the file: checked before anything is allocated.
        let numel = view
            .shape
            .iter()
            .try_fold(1usize, |n, &d| n.checked_mul(d))
            .ok_or_else(|| format!("{name}: size {:?} overflows", view.shape))?;
        if numel > 0 {
            let last = view
                .shape
                .iter()
                .zip(&view.stride)
                .try_fold(view.offset, |at, (&d, &s)| {
                    (d - 1).checked_mul(s).and_then(|step| at.checked_add(step))
                });
            if last.is_none_or(|last| last >= storage.len()) {
                return Err(format!("{name}: view exceeds its storage"));
            }
        }
        if let Some(repeats) = numel.checked_sub(storage.len()).filter(|&r| r > 0) {
            repeats_left = repeats_left.checked_sub(repeats).ok_or_else(|| {
                format!(
                    "{name}: view of {numel} elements on a storage of {} repeats more \
                     elements than the {MAX_REPEATED_ELEMENTS} allowed",
                    storage.len()
                )
            })?;
        }
        let mut data = Vec::with_capacity(numel);
        let mut index = vec![0usize; view.shape.len()];
        for _ in 0..numel {
            let at = view.offset
                + index
                    .iter()
                    .zip(&view.stride)
                    .map(|(i, s)| i * s)
                    .sum::<usize>();
            data.push(
                *storage
                    .get(at)
                    .ok_or_else(|| format!("{name}: view exceeds its storage"))?,
            );
            for d in (0..index.len()).rev() {
                index[d] += 1;
                if index[d] < view.shape[d] {
                    break;
                }
                index[d] = 0;
            }
        }
        out.insert(
            name,
            Tensor {
                shape: view.shape,
                data,
            },
        );
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn half_precision_values() {
        assert_eq!(half_to_f32(0x3c00), 1.0);
        assert_eq!(half_to_f32(0xc000), -2.0);
        assert_eq!(half_to_f32(0x0001), 2f32.powi(-24));
        assert!(half_to_f32(0x7e00).is_nan());
    }

    #[test]
    fn garbage_is_an_error_not_a_panic() {
        let dir = tempfile::tempdir().unwrap();
        for (i, bytes) in [
            &b""[..],
            b"PK\x03\x04junk",
            b"\x80\x02}q\x00",
            &[0x8a, 0x0a, 1, 2],
        ]
        .iter()
        .enumerate()
        {
            let p = dir.path().join(format!("{i}.pth"));
            std::fs::write(&p, bytes).unwrap();
            let e = StateDict::read(&p).unwrap_err();
            assert!(matches!(e, FeaturesError::Checkpoint { .. }), "{e}");
            assert!(e.to_string().contains(&format!("{i}.pth")));
        }
    }
}
