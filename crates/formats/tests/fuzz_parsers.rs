//! Property/fuzz tests of the readers of files that come from outside the program: `map.toml`,
//! `camera.yaml`, the UAV sequence (`uav/images.txt`, `altimeter.txt`, `gt.txt`), and the output
//! files read back (`trajectory.tum`, `fixes.txt`, `summary.json`). Arbitrary bytes and
//! mutations of a valid file (bit flips, truncation, hostile numbers in size fields, NaN/inf,
//! very long lines) give `Ok` with sane values or an error naming the file, never a panic or an
//! allocation sized by a field of the file.
//!
//! Cases per property: `JOINTLOC_FUZZ_CASES` (default 500, the bounded CI run); the longer run
//! is `JOINTLOC_FUZZ_CASES=100000 cargo test --workspace fuzz` (see docs/testing.md), with
//! `JOINTLOC_FUZZ_SEED` to explore other inputs.

mod common;

use std::path::{Path, PathBuf};

use jointloc_formats::outputs::{
    FixRow, OnlineFrame, OnlineStatus, Summary, read_fixes, read_json, read_online_tum,
    write_fixes, write_json, write_online_tum,
};
use jointloc_formats::sequence::{FrameRecord, write_sequence};
use jointloc_formats::{
    ElevationInfo, FormatError, MapInfo, Sequence, read_camera_yaml, write_camera_yaml,
};
use jointloc_geometry::{CameraToWorld, KannalaBrandt, PinholeCamera, RadTan};
use proptest::prelude::*;
use proptest::sample::Index;

use common::{fuzz, runner};

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
    "4294967295",
    "4000000000",
    "2147483648",
    "1",
    "2",
    "1,5",
    "",
    " ",
    "#",
    "\u{feff}",
    "\u{0}",
    "é",
    "\"x\"",
    "[",
    "]",
    "{",
    "true",
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

/// `Ok(())` for an `Ok` value that passes `sane`, or an error naming `name`.
fn judge<T: std::fmt::Debug>(
    result: Result<T, FormatError>,
    name: &str,
    sane: impl FnOnce(&T) -> bool,
) -> Result<(), String> {
    match result {
        Ok(v) if sane(&v) => Ok(()),
        Ok(v) => Err(format!("implausible value read: {v:?}")),
        Err(e) if e.to_string().contains(name) => Ok(()),
        Err(e) => Err(format!("error does not name {name}: {e}")),
    }
}

fn map_seed() -> Vec<u8> {
    let mut info = MapInfo::new(0.05, 1000, 750, 500, 500, 0.5).unwrap();
    info.elevation = Some(ElevationInfo {
        image: "elevation.png".into(),
        gsd_m: 0.2,
        width_px: 250,
        height_px: 188,
        origin_x_m: 0.075,
        origin_y_m: -0.075,
        offset_m: -5.0,
        scale_m: 0.001,
        sigma_m: 0.05,
    });
    info.to_toml_string().into_bytes()
}

fn sane_map(info: &MapInfo) -> bool {
    let t = &info.tiles;
    info.gsd_m.is_finite()
        && info.gsd_m > 0.0
        && info.tile_list().len() == t.cols as usize * t.rows as usize
}

#[test]
fn fuzz_map_toml() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fuzz-map.toml");
    fuzz(inputs(map_seed()), |bytes| {
        std::fs::write(&path, bytes).unwrap();
        judge(MapInfo::read(&path), "fuzz-map.toml", sane_map)
    });
}

/// Sizes that overflow `u32` arithmetic or ask for huge tile lists.
fn size_field() -> impl Strategy<Value = u32> {
    prop_oneof![
        Just(0u32),
        Just(1),
        Just(2),
        Just(250),
        Just(500),
        Just(1000),
        Just(1 << 31),
        Just(4_000_000_000),
        Just(u32::MAX - 1),
        Just(u32::MAX),
        any::<u32>(),
    ]
}

/// The tile layout of `map.toml` from hostile values (a grammar-aware property: random
/// mutations rarely change two size fields at once).
#[test]
fn fuzz_map_toml_tile_layout() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fuzz-layout.toml");
    let strategy = (prop::collection::vec(size_field(), 8), 0.0f64..1.0);
    runner()
        .run(&strategy, |(v, overlap)| {
            let text = format!(
                "format_version = 1\nimage = \"satellite.png\"\ngsd_m = 0.05\n\
                 width_px = {}\nheight_px = {}\norigin = \"pixel-center\"\n\n[tiles]\n\
                 dir = \"satellite\"\nwidth_px = {}\nheight_px = {}\noverlap = {overlap}\n\
                 stride_x_px = {}\nstride_y_px = {}\ncols = {}\nrows = {}\n",
                v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7]
            );
            std::fs::write(&path, text).unwrap();
            judge(MapInfo::read(&path), "fuzz-layout.toml", sane_map).map_err(TestCaseError::fail)
        })
        .unwrap_or_else(|e| panic!("{e}"));
}

/// Found by this file: a stride near `u32::MAX` overflowed the tile offset arithmetic (a
/// panic), and 1-px tiles on a 4-gigapixel-wide map built a list of billions of offsets before
/// comparing its length with `cols`.
#[test]
fn hostile_tile_layouts_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("map.toml");
    for (w, tw, stride, cols) in [
        (4_294_967_295u32, 500u32, 4_000_000_000u32, 2u32),
        (4_294_967_295, 1, 1, 4_294_967_295),
        (1 << 21, 1, 1, 1 << 21),
    ] {
        let text = format!(
            "format_version = 1\nimage = \"s.png\"\ngsd_m = 0.05\nwidth_px = {w}\n\
             height_px = 1\norigin = \"pixel-center\"\n[tiles]\ndir = \"s\"\nwidth_px = {tw}\n\
             height_px = 1\noverlap = 0.0\nstride_x_px = {stride}\nstride_y_px = 1\n\
             cols = {cols}\nrows = 1\n"
        );
        std::fs::write(&path, text).unwrap();
        let e = MapInfo::read(&path).unwrap_err();
        assert!(e.to_string().contains("map.toml"), "{e}");
    }
}

/// Seeds: a radial-tangential pinhole (ORB-SLAM2 layout) and a Kannala-Brandt fisheye
/// (ORB-SLAM3 layout, `Camera.type` and `Camera1.*` keys).
fn camera_seeds(dir: &Path) -> [Vec<u8>; 2] {
    let pinhole = PinholeCamera {
        fx: 512.123456789,
        fy: 498.1,
        cx: 251.3,
        cy: 247.0,
        width: 640,
        height: 480,
        distortion: Some(
            RadTan {
                k1: -0.12,
                k2: 0.031,
                p1: 1e-4,
                p2: -2.5e-5,
                k3: 0.0,
            }
            .into(),
        ),
    };
    let fisheye = PinholeCamera::fisheye(
        133.0,
        640,
        480,
        KannalaBrandt {
            k1: 0.0034823894022493434,
            k2: 0.0007150348452162257,
            k3: -0.0020532361418706202,
            k4: 0.00020293673591811182,
        },
    )
    .unwrap();
    [pinhole, fisheye].map(|cam| {
        let path = dir.join("seed.yaml");
        write_camera_yaml(&path, &cam, 5.0).unwrap();
        std::fs::read(path).unwrap()
    })
}

#[test]
fn fuzz_camera_yaml() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fuzz-camera.yaml");
    let [pinhole, fisheye] = camera_seeds(dir.path());
    fuzz(prop_oneof![inputs(pinhole), inputs(fisheye)], |bytes| {
        std::fs::write(&path, bytes).unwrap();
        judge(read_camera_yaml(&path), "fuzz-camera.yaml", |c| {
            let k = &c.camera;
            [k.fx, k.fy, k.cx, k.cy, c.fps]
                .iter()
                .all(|v| v.is_finite())
                && k.fx > 0.0
                && k.fy > 0.0
                && k.width >= 1
                && k.height >= 1
                && k.distortion
                    .is_none_or(|d| d.coefficients().iter().all(|v| v.is_finite()))
        })
    });
}

/// A dataset folder with three (empty) frames, a reading and a pose for each.
fn sequence_dir() -> (tempfile::TempDir, [Vec<u8>; 3]) {
    let dir = tempfile::tempdir().unwrap();
    let uav = dir.path().join("uav");
    std::fs::create_dir_all(&uav).unwrap();
    let frames: Vec<FrameRecord> = (0..3)
        .map(|i| FrameRecord {
            timestamp: 1.0 + 0.2 * i as f64,
            image: format!("{i:06}.png"),
            altitude: Some(50.0 + i as f64),
            ground_truth: Some(CameraToWorld::from_translation_quaternion(
                [i as f64, -2.5, 50.0],
                [0.0, 0.0, 0.6, 0.8],
            )),
        })
        .collect();
    for f in &frames {
        std::fs::write(uav.join(&f.image), b"").unwrap();
    }
    write_sequence(&uav, &frames).unwrap();
    let seeds =
        ["images.txt", "altimeter.txt", "gt.txt"].map(|f| std::fs::read(uav.join(f)).unwrap());
    (dir, seeds)
}

fn sane_sequence(s: &Sequence) -> bool {
    !s.frames.is_empty()
        && s.frames.windows(2).all(|w| w[1].timestamp > w[0].timestamp)
        && s.frames.iter().all(|f| {
            f.timestamp.is_finite()
                && f.altitude.is_none_or(|a| a.is_finite() && a > 0.0)
                && f.ground_truth.is_none_or(|p| p.is_finite())
        })
}

#[test]
fn fuzz_sequence_files() {
    let (dir, seeds) = sequence_dir();
    let uav: PathBuf = dir.path().join("uav");
    for (k, name) in ["images.txt", "altimeter.txt", "gt.txt"].iter().enumerate() {
        let path = uav.join(name);
        fuzz(inputs(seeds[k].clone()), |bytes| {
            std::fs::write(&path, bytes).unwrap();
            judge(Sequence::open(dir.path()), name, sane_sequence)?;
            match Sequence::open_tolerant(dir.path()) {
                Ok((s, faults)) => {
                    if !sane_sequence(&s) {
                        return Err(format!("implausible tolerant read: {s:?}"));
                    }
                    match faults.iter().find(|f| !f.message.contains("uav")) {
                        Some(f) => Err(format!("fault does not name its file: {f:?}")),
                        None => Ok(()),
                    }
                }
                Err(e) => judge::<()>(Err(e), name, |_| true),
            }
        });
        std::fs::write(&path, &seeds[k]).unwrap();
    }
}

#[test]
fn fuzz_altimeter_and_ground_truth_readers() {
    let (dir, seeds) = sequence_dir();
    let uav = dir.path().join("uav");
    let alt = uav.join("altimeter.txt");
    fuzz(inputs(seeds[1].clone()), |bytes| {
        std::fs::write(&alt, bytes).unwrap();
        let read = jointloc_formats::sequence::read_altimeter(&alt);
        judge(read, "altimeter.txt", |r| {
            r.iter()
                .all(|(t, a)| t.is_finite() && a.is_finite() && *a > 0.0)
        })
    });
    let gt = uav.join("gt.txt");
    fuzz(inputs(seeds[2].clone()), |bytes| {
        std::fs::write(&gt, bytes).unwrap();
        let read = jointloc_formats::sequence::read_ground_truth(&gt);
        judge(read, "gt.txt", |r| {
            r.iter().all(|(t, p)| t.is_finite() && p.is_finite())
        })
    });
}

#[test]
fn fuzz_online_trajectory() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fuzz-trajectory.tum");
    let pose = CameraToWorld::from_translation_quaternion([3.0, -2.5, 50.0], [0.0, 0.0, 0.6, 0.8]);
    let frames = [
        (1.0, OnlineStatus::NotTracked),
        (1.2, OnlineStatus::NotGeoReferenced),
        (1.4, OnlineStatus::World(pose)),
    ]
    .map(|(timestamp, status)| OnlineFrame { timestamp, status });
    write_online_tum(&path, &frames).unwrap();
    let seed = std::fs::read(&path).unwrap();
    fuzz(inputs(seed), |bytes| {
        std::fs::write(&path, bytes).unwrap();
        judge(read_online_tum(&path), "fuzz-trajectory.tum", |fs| {
            fs.iter()
                .all(|f| f.timestamp.is_finite() && f.world_pose().is_none_or(|p| p.is_finite()))
        })
    });
}

#[test]
fn fuzz_fixes() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fuzz-fixes.txt");
    let rows: Vec<FixRow> = (0..3)
        .map(|i| FixRow {
            timestamp: 1.0 + i as f64,
            position: [12.3456, -7.5, 3.25],
            orientation: [0.0, 0.0, 0.0, 1.0],
            confidence: 0.4321,
            tile: 7,
            ssim: 0.61,
            match_score: 0.7083,
            inliers: 153,
            used: i % 2 == 0,
            inlier: false,
            injected: i == 2,
        })
        .collect();
    write_fixes(&path, &rows).unwrap();
    let seed = std::fs::read(&path).unwrap();
    fuzz(inputs(seed), |bytes| {
        std::fs::write(&path, bytes).unwrap();
        judge(read_fixes(&path), "fuzz-fixes.txt", |rs| {
            rs.iter().all(|r| {
                [r.timestamp, r.confidence, r.ssim, r.match_score]
                    .iter()
                    .chain(&r.position)
                    .all(|v| v.is_finite())
            })
        })
    });
}

#[test]
fn fuzz_summary_json() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fuzz-summary.json");
    let summary = Summary {
        frames: 10,
        world_poses: 7,
        geo_referenced_from: Some(3),
        mode: "sequential".into(),
        ..Default::default()
    };
    write_json(&path, &summary).unwrap();
    let seed = std::fs::read(&path).unwrap();
    fuzz(inputs(seed), |bytes| {
        std::fs::write(&path, bytes).unwrap();
        judge(read_json::<Summary>(&path), "fuzz-summary.json", |_| true)
    });
}
