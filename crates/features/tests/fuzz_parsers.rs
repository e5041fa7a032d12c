//! Property/fuzz tests of the readers of network files that come from outside the program:
//! PyTorch checkpoints (`.pth`: the legacy pickle stream and the zip archive, through
//! [`StateDict::read`]) and ONNX graphs (protobuf, [`ModelProto::decode`], as the graph cache
//! reads them back). Arbitrary bytes and mutations of a valid file (bit flips, truncation,
//! hostile sizes written over the bytes) give `Ok` or an error naming the file, never a panic,
//! a stack overflow or an allocation sized by a field of the file.
//!
//! Cases per property: `JOINTLOC_FUZZ_CASES` (default 500, the bounded CI run); the longer run
//! is `JOINTLOC_FUZZ_CASES=100000 cargo test --workspace fuzz` (see docs/testing.md), with
//! `JOINTLOC_FUZZ_SEED` to explore other inputs.

use std::io::Write;

use jointloc_features::FeaturesError;
use jointloc_features::onnx::proto::ModelProto;
use jointloc_features::onnx::{Dim, GraphBuilder};
use jointloc_features::pth::StateDict;
use proptest::prelude::*;
use proptest::sample::Index;
use proptest::test_runner::{Config, RngSeed, TestRunner};

fn runner() -> TestRunner {
    let env = |name: &str| std::env::var(name).ok().and_then(|v| v.parse::<u64>().ok());
    TestRunner::new(Config {
        cases: env("JOINTLOC_FUZZ_CASES").map_or(500, |n| n as u32),
        rng_seed: RngSeed::Fixed(env("JOINTLOC_FUZZ_SEED").unwrap_or(0)),
        failure_persistence: None,
        ..Config::default()
    })
}

/// Runs `check` on bytes from `strategy`; a failure (or panic) prints the shrunk input.
fn fuzz(strategy: impl Strategy<Value = Vec<u8>>, check: impl Fn(&[u8]) -> Result<(), String>) {
    runner()
        .run(&strategy, |bytes| {
            check(&bytes).map_err(TestCaseError::fail)
        })
        .unwrap_or_else(|e| panic!("{e}"));
}

/// Numbers and words that break naive parsers.
const HOSTILE: &[&str] = &[
    "NaN",
    "nan",
    "inf",
    "-inf",
    "infinity",
    "1e309",
    "-1e309",
    "1e-320",
    "0",
    "-0",
    "-1",
    "1e300",
    "-1e300",
    "18446744073709551616",
    "4294967296",
    "9223372036854775807",
    "0x10",
    "1,5",
    "",
    " ",
    "#",
    "\u{feff}",
    "\u{0}",
    "é",
    "(",
    ".",
];

#[derive(Debug, Clone)]
enum Mutation {
    FlipBit(Index, u8),
    Truncate(Index),
    /// The token (run of non-separator bytes) at the index becomes a hostile word.
    Hostile(Index, Index),
    LongLine(Index, usize),
    Insert(Index, Vec<u8>),
    Remove(Index, Index),
    DuplicateLine(Index),
    /// Little-endian bytes of a hostile size written over the input at the index.
    Overwrite(Index, Vec<u8>),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        1 => (any::<Index>(), 0u8..8).prop_map(|(i, b)| Mutation::FlipBit(i, b)),
        1 => any::<Index>().prop_map(Mutation::Truncate),
        3 => (any::<Index>(), any::<Index>()).prop_map(|(i, h)| Mutation::Hostile(i, h)),
        1 => (any::<Index>(), 1usize..200_000).prop_map(|(i, n)| Mutation::LongLine(i, n)),
        1 => (any::<Index>(), prop::collection::vec(any::<u8>(), 1..16))
            .prop_map(|(i, b)| Mutation::Insert(i, b)),
        1 => (any::<Index>(), any::<Index>()).prop_map(|(i, j)| Mutation::Remove(i, j)),
        1 => any::<Index>().prop_map(Mutation::DuplicateLine),
        3 => (any::<Index>(), hostile_size()).prop_map(|(i, b)| Mutation::Overwrite(i, b)),
    ]
}

/// Sizes that overflow arithmetic or ask for huge allocations, as 1, 2, 4 or 8 LE bytes.
fn hostile_size() -> impl Strategy<Value = Vec<u8>> {
    let values = prop_oneof![
        Just(u64::MAX),
        Just(u64::MAX - 3),
        Just(1u64 << 63),
        Just(1 << 62),
        Just(1 << 40),
        Just(1 << 32),
        Just(u64::from(u32::MAX)),
        Just(1 << 31),
        Just(0x7fff_ffff),
        Just(0),
        Just(1),
        any::<u64>(),
    ];
    (values, prop_oneof![Just(1usize), Just(2), Just(4), Just(8)])
        .prop_map(|(v, n)| v.to_le_bytes()[..n].to_vec())
}

fn is_token_byte(b: u8) -> bool {
    !(b.is_ascii_whitespace() || b == b',' || b == b'=' || b == b':')
}

fn apply(bytes: &mut Vec<u8>, m: &Mutation) {
    let at = |i: &Index, len: usize| if len == 0 { 0 } else { i.index(len) };
    match m {
        Mutation::FlipBit(i, b) if !bytes.is_empty() => {
            let k = at(i, bytes.len());
            bytes[k] ^= 1 << b;
        }
        Mutation::Truncate(i) => bytes.truncate(at(i, bytes.len() + 1)),
        Mutation::Hostile(i, h) => {
            let k = at(i, bytes.len());
            let (mut s, mut e) = (k, k);
            while s > 0 && is_token_byte(bytes[s - 1]) {
                s -= 1;
            }
            while e < bytes.len() && is_token_byte(bytes[e]) {
                e += 1;
            }
            let word = HOSTILE[h.index(HOSTILE.len())].as_bytes();
            bytes.splice(s..e, word.iter().copied());
        }
        Mutation::LongLine(i, n) => {
            let k = at(i, bytes.len() + 1);
            let line: Vec<u8> = b"1.5 ".iter().copied().cycle().take(*n).collect();
            bytes.splice(k..k, line);
        }
        Mutation::Insert(i, b) => {
            let k = at(i, bytes.len() + 1);
            bytes.splice(k..k, b.iter().copied());
        }
        Mutation::Remove(i, j) => {
            let (a, b) = (at(i, bytes.len() + 1), at(j, bytes.len() + 1));
            bytes.drain(a.min(b)..a.max(b));
        }
        Mutation::DuplicateLine(i) => {
            let k = at(i, bytes.len());
            let s = bytes[..k]
                .iter()
                .rposition(|&b| b == b'\n')
                .map_or(0, |p| p + 1);
            let e = bytes[k..]
                .iter()
                .position(|&b| b == b'\n')
                .map_or(bytes.len(), |p| k + p + 1);
            let line = bytes[s..e].to_vec();
            bytes.splice(e..e, line);
        }
        Mutation::Overwrite(i, b) => {
            let k = at(i, bytes.len() + 1);
            let end = (k + b.len()).min(bytes.len());
            bytes.splice(k..end, b.iter().copied());
        }
        Mutation::FlipBit(..) => {}
    }
}

/// A valid file with 1-4 mutations, or arbitrary bytes.
fn inputs(seed: Vec<u8>) -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        4 => prop::collection::vec(mutation(), 1..5).prop_map(move |ms| {
            let mut bytes = seed.clone();
            for m in &ms {
                apply(&mut bytes, m);
            }
            bytes
        }),
        1 => prop::collection::vec(any::<u8>(), 0..512),
    ]
}

/// Pickle (protocol 2) of a state dict with `conv.weight` (2×3 on storage "0") and `conv.bias`
/// (3 on storage "1"), as torch writes it: globals, persistent ids, memo puts and gets.
fn state_dict_pickle(storage_type: &str) -> Vec<u8> {
    let mut p = b"\x80\x02ccollections\nOrderedDict\nq\x00)Rq\x01(".to_vec();
    let s = |p: &mut Vec<u8>, text: &str| {
        p.push(b'X');
        p.extend_from_slice(&(text.len() as u32).to_le_bytes());
        p.extend_from_slice(text.as_bytes());
    };
    for (i, (name, size, stride)) in [
        (
            "conv.weight",
            &b"K\x02K\x03\x86"[..],
            &b"K\x03K\x01\x86"[..],
        ),
        ("conv.bias", b"K\x03\x85", b"K\x01\x85"),
    ]
    .into_iter()
    .enumerate()
    {
        s(&mut p, name);
        if i == 0 {
            p.extend_from_slice(b"ctorch._utils\n_rebuild_tensor_v2\nq\x02");
        } else {
            p.extend_from_slice(b"h\x02");
        }
        p.extend_from_slice(b"((");
        s(&mut p, "storage");
        p.extend_from_slice(format!("ctorch\n{storage_type}\n").as_bytes());
        s(&mut p, &i.to_string());
        s(&mut p, "cpu");
        p.extend_from_slice(b"K\x06tQK\x00");
        p.extend_from_slice(size);
        p.extend_from_slice(stride);
        p.extend_from_slice(b"\x89ccollections\nOrderedDict\n)RtR");
    }
    p.extend_from_slice(b"u.");
    p
}

/// A legacy (non-zip) torch file: magic, protocol, system info, the state dict, the storage
/// keys, then each storage as an element count and raw little-endian values.
fn legacy_checkpoint(storage_type: &str) -> Vec<u8> {
    let mut f = b"\x80\x02\x8a\x0a\x6c\xfc\x9c\x46\xf9\x20\x6a\xa8\x50\x19.".to_vec();
    f.extend_from_slice(b"\x80\x02M\xe9\x03.\x80\x02}q\x00.");
    f.extend_from_slice(&state_dict_pickle(storage_type));
    f.extend_from_slice(b"\x80\x02]q\x00(X\x01\x00\x00\x000X\x01\x00\x00\x001e.");
    for n in [6u64, 3] {
        f.extend_from_slice(&n.to_le_bytes());
        for k in 0..n {
            match storage_type {
                "ByteStorage" => f.push(k as u8),
                _ => f.extend_from_slice(&(k as f32 * 0.5 - 1.0).to_le_bytes()),
            }
        }
    }
    f
}

/// A zip torch file (torch ≥ 1.6) with `pickle` as its `data.pkl`.
fn zip_checkpoint(pickle: &[u8]) -> Vec<u8> {
    let mut zip = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    let stored =
        zip::write::SimpleFileOptions::default().compression_method(zip::CompressionMethod::Stored);
    let mut entry = |name: &str, bytes: &[u8]| {
        zip.start_file(format!("archive/{name}"), stored).unwrap();
        zip.write_all(bytes).unwrap();
    };
    entry("data.pkl", pickle);
    entry("byteorder", b"little");
    let floats = |n: usize| -> Vec<u8> { (0..n).flat_map(|k| (k as f32).to_le_bytes()).collect() };
    entry("data/0", &floats(6));
    entry("data/1", &floats(3));
    zip.finish().unwrap().into_inner()
}

fn judge(result: Result<StateDict, FeaturesError>, name: &str) -> Result<(), String> {
    match result {
        Ok(sd) => {
            for n in sd.names() {
                let t = sd.get(n).map_err(|e| e.to_string())?;
                if t.data.len() != t.numel() {
                    return Err(format!(
                        "{n}: {} values for shape {:?}",
                        t.data.len(),
                        t.shape
                    ));
                }
            }
            Ok(())
        }
        Err(e) if e.to_string().contains(name) => Ok(()),
        Err(e) => Err(format!("error does not name {name}: {e}")),
    }
}

#[test]
fn seeds_are_valid_checkpoints() {
    let dir = tempfile::tempdir().unwrap();
    for (name, bytes) in [
        ("legacy.pth", legacy_checkpoint("FloatStorage")),
        ("legacy-bytes.pth", legacy_checkpoint("ByteStorage")),
        (
            "zip.pth",
            zip_checkpoint(&state_dict_pickle("FloatStorage")),
        ),
    ] {
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).unwrap();
        let sd = StateDict::read(&path).unwrap();
        assert_eq!(sd.get_shaped("conv.weight", &[2, 3]).unwrap().data.len(), 6);
        assert_eq!(sd.get_shaped("conv.bias", &[3]).unwrap().data.len(), 3);
    }
}

#[test]
fn fuzz_legacy_checkpoint() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fuzz-legacy.pth");
    for storage in ["FloatStorage", "ByteStorage"] {
        fuzz(inputs(legacy_checkpoint(storage)), |bytes| {
            std::fs::write(&path, bytes).unwrap();
            judge(StateDict::read(&path), "fuzz-legacy.pth")
        });
    }
}

#[test]
fn fuzz_zip_checkpoint() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fuzz-zip.pth");
    // The whole archive (mostly caught by the zip reader and its CRCs)...
    fuzz(
        inputs(zip_checkpoint(&state_dict_pickle("FloatStorage"))),
        |bytes| {
            std::fs::write(&path, bytes).unwrap();
            judge(StateDict::read(&path), "fuzz-zip.pth")
        },
    );
    // ...and a mutated data.pkl in a well-formed archive, which reaches the unpickler.
    for storage in ["FloatStorage", "ByteStorage", "HalfStorage", "LongStorage"] {
        fuzz(inputs(state_dict_pickle(storage)), |pickle| {
            std::fs::write(&path, zip_checkpoint(pickle)).unwrap();
            judge(StateDict::read(&path), "fuzz-zip.pth")
        });
    }
}

fn read_err(name: &str, bytes: &[u8]) -> String {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    std::fs::write(&path, bytes).unwrap();
    let e = StateDict::read(&path).unwrap_err().to_string();
    assert!(e.contains(name), "{e}");
    e
}

/// Found by this file: a legacy storage of u64::MAX − 3 one-byte elements overflowed the
/// end offset (a panic in debug builds, a wrapped slice range otherwise).
#[test]
fn legacy_storage_size_near_u64_max_is_an_error() {
    let mut f = legacy_checkpoint("ByteStorage");
    // The first storage's element count: before its 6 bytes, the second's count and 3 bytes.
    let at = f.len() - (8 + 6 + 8 + 3);
    assert_eq!(f[at..at + 8], 6u64.to_le_bytes());
    f[at..at + 8].copy_from_slice(&(u64::MAX - 3).to_le_bytes());
    let e = read_err("huge-storage.pth", &f);
    assert!(e.contains("truncated"), "{e}");
}

/// Found by this file: the size (2^40, 2^40) overflowed the element count, and a view of 2^40
/// elements with stride 0 on a one-element storage asked for a 4 TiB tensor before reading it.
#[test]
fn hostile_tensor_sizes_are_errors() {
    for (size, stride) in [
        (
            &b"\x8a\x06\x00\x00\x00\x00\x00\x01\x8a\x06\x00\x00\x00\x00\x00\x01\x86"[..],
            &b"K\x00K\x00\x86"[..],
        ),
        (b"\x8a\x06\x00\x00\x00\x00\x00\x01\x85", b"K\x00\x85"),
        (
            b"\x8a\x06\x00\x00\x00\x00\x00\x01\x85",
            b"J\xff\xff\xff\x7f\x85",
        ),
    ] {
        let mut p = b"\x80\x02}(X\x01\x00\x00\x00wctorch._utils\n_rebuild_tensor_v2\n((X\x07\x00\x00\x00storagectorch\nFloatStorage\nX\x01\x00\x00\x000X\x03\x00\x00\x00cpuK\x01tQK\x00".to_vec();
        p.extend_from_slice(size);
        p.extend_from_slice(stride);
        p.extend_from_slice(b"\x89)tRu.");
        let mut zip = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
        let o = zip::write::SimpleFileOptions::default();
        zip.start_file("a/data.pkl", o).unwrap();
        zip.write_all(&p).unwrap();
        zip.start_file("a/data/0", o).unwrap();
        zip.write_all(&1f32.to_le_bytes()).unwrap();
        let bytes = zip.finish().unwrap().into_inner();
        read_err("huge-view.pth", &bytes);
    }
}

/// Found by this file: memo gets copy values, so 40 × 8 bytes of `( h0 h0 l q0` doubled a
/// list 40 times (2^40 copies); and 100 000 TUPLE1 bytes nested a value so deep that dropping
/// it overflowed the stack.
#[test]
fn pickle_bombs_are_errors() {
    let mut bomb = b"\x80\x02]q\x00".to_vec();
    for _ in 0..40 {
        bomb.extend_from_slice(b"(h\x00h\x00lq\x00");
    }
    bomb.push(b'.');
    let e = read_err("bomb.pth", &zip_checkpoint(&bomb));
    assert!(e.contains("budget"), "{e}");
    let mut deep = b"\x80\x02N".to_vec();
    deep.extend(std::iter::repeat_n(0x85u8, 100_000));
    deep.push(b'.');
    let e = read_err("deep.pth", &zip_checkpoint(&deep));
    assert!(e.contains("nested"), "{e}");
}

fn onnx_seed() -> Vec<u8> {
    let mut g = GraphBuilder::new("fuzz");
    let x = g.input_f32("x", &[1.into(), 3.into(), Dim::from(8), 8.into()]);
    let y = g.relu(&x);
    g.output_f32(&y, "y", &[1.into(), 3.into(), 8.into(), 8.into()]);
    g.to_bytes()
}

#[test]
fn fuzz_onnx_protobuf() {
    use prost::Message;
    fuzz(inputs(onnx_seed()), |bytes| {
        // Ok or Err: prost checks every length against the bytes left and bounds recursion.
        let _ = ModelProto::decode(bytes);
        Ok(())
    });
}
