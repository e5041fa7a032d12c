//! Property/fuzz tests of the trajectory readers (TUM, EuRoC): arbitrary bytes and mutations of
//! a valid file (bit flips, truncation, hostile numbers, NaN/inf, very long lines) give `Ok` or
//! an error naming the file, never a panic; what is read is finite.
//!
//! Cases per property: `JOINTLOC_FUZZ_CASES` (default 500, the bounded CI run); the longer run
//! is `JOINTLOC_FUZZ_CASES=100000 cargo test --workspace fuzz` (see docs/testing.md), with
//! `JOINTLOC_FUZZ_SEED` to explore other inputs.

use std::path::Path;

use jointloc_geometry::GeometryError;
use jointloc_geometry::trajectory::{QuaternionOrder, Trajectory, TumOptions};
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
    ]
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
        Mutation::FlipBit(..) => {}
    }
}

/// A valid file with 1-4 mutations, or arbitrary bytes.
fn inputs(seed: &'static [u8]) -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        4 => prop::collection::vec(mutation(), 1..5).prop_map(move |ms| {
            let mut bytes = seed.to_vec();
            for m in &ms {
                apply(&mut bytes, m);
            }
            bytes
        }),
        1 => prop::collection::vec(any::<u8>(), 0..512),
    ]
}

const TUM: &[u8] = b"# timestamp tx ty tz qx qy qz qw\n\
1.0 1 2 3 0 0 0 1\n\
1.5 4.25 -5 6e2 0 0 0.7071067811865476 0.7071067811865476\n\
\n\
2.0 -1.5 0.001 3 0.1 -0.2 0.3 0.9273618495495703\n";

const EUROC: &[u8] = b"\xef\xbb\xbf#timestamp [ns], p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], v_x\n\
1403636579758555392,4.688319,-1.786938,0.783338,0.534108,-0.153029,-0.827383,-0.082152,0.1\n\
1403636579763555584,4.688177,-1.786770,0.787350,0.534640,-0.152990,-0.826976,-0.082863,0.2\n";

/// `Ok` is finite and increasing; `Err` names the file.
fn judge(result: Result<Trajectory, GeometryError>, name: &str) -> Result<(), String> {
    match result {
        Ok(t) => {
            if t.is_empty() || t.timestamps.len() != t.poses.len() {
                return Err(format!("inconsistent trajectory {t:?}"));
            }
            if !t.timestamps.iter().all(|s| s.is_finite()) || !t.poses.iter().all(|p| p.is_finite())
            {
                return Err(format!("non-finite trajectory read: {t:?}"));
            }
            if let Some(p) = t
                .poses
                .iter()
                .find(|p| (p.rotation().coords.norm() - 1.0).abs() > 1e-9)
            {
                return Err(format!("rotation is not a unit quaternion: {p:?}"));
            }
            if t.timestamps.windows(2).any(|w| w[1] <= w[0]) {
                return Err(format!("timestamps not increasing: {:?}", t.timestamps));
            }
            Ok(())
        }
        Err(e) if e.to_string().contains(name) => Ok(()),
        Err(e) => Err(format!("error does not name {name}: {e}")),
    }
}

#[test]
fn fuzz_tum_reader() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fuzz-gt.txt");
    for order in [QuaternionOrder::Xyzw, QuaternionOrder::Wxyz] {
        let options = TumOptions {
            quaternion_order: order,
        };
        fuzz(inputs(TUM), |bytes| {
            std::fs::write(&path, bytes).unwrap();
            judge(Trajectory::read_tum(&path, &options), "fuzz-gt.txt")?;
            let text = String::from_utf8_lossy(bytes);
            judge(
                Trajectory::parse_tum(&text, Path::new("lossy.txt"), &options),
                "lossy.txt",
            )
        });
    }
}

#[test]
fn fuzz_euroc_reader() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fuzz-data.csv");
    fuzz(inputs(EUROC), |bytes| {
        std::fs::write(&path, bytes).unwrap();
        judge(Trajectory::read_euroc(&path), "fuzz-data.csv")?;
        let text = String::from_utf8_lossy(bytes);
        judge(
            Trajectory::parse_euroc(&text, Path::new("lossy.csv")),
            "lossy.csv",
        )
    });
}

/// Found by this file: a quaternion whose norm overflows (components near 1e300) was
/// "normalised" to NaN instead of being refused.
#[test]
fn huge_quaternion_is_an_error() {
    let text = "1.0 0 0 0 1e300 1e300 0 1e300\n";
    let e = Trajectory::parse_tum(text, Path::new("q.txt"), &TumOptions::default()).unwrap_err();
    assert!(e.to_string().contains("q.txt:1"), "{e}");
}
