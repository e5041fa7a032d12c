//! Acceptance: the same seed gives byte-identical files (whatever rayon's thread count), a
//! different seed gives different ones; the dataset layout (uav/ sequence, camera.yaml,
//! satellite map and tiles, map.toml, sim.toml) is complete and consistent.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use common::{read_grey, read_pairs, read_tum};
use jointloc_formats::MapInfo;
use jointloc_sim::TerrainKind;
use jointloc_sim::dataset::{SimConfig, Stage, generate_dataset};

fn small(seed: u64, kind: TerrainKind) -> SimConfig {
    let mut cfg = SimConfig {
        seed,
        terrain_kind: kind,
        ..Default::default()
    };
    cfg.trajectory.length_m = 2.0;
    common::small_camera(&mut cfg);
    cfg
}

/// Every file under `dir`, relative path → bytes.
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).unwrap() {
            let p = entry.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.insert(
                    p.strip_prefix(dir).unwrap().to_path_buf(),
                    std::fs::read(&p).unwrap(),
                );
            }
        }
    }
    out
}

fn generate(cfg: &SimConfig, dir: &Path, threads: usize) -> Vec<(Stage, usize, usize)> {
    let mut events = Vec::new();
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(|| {
            generate_dataset(cfg, dir, &mut |s, d, t| events.push((s, d, t))).unwrap();
        });
    events
}

#[test]
fn same_seed_same_bytes_different_seed_different_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    let dirs: Vec<PathBuf> = ["a", "b", "c"].iter().map(|n| tmp.path().join(n)).collect();
    let events = generate(&small(5, TerrainKind::Gravel), &dirs[0], 1);
    generate(&small(5, TerrainKind::Gravel), &dirs[1], 3);
    generate(&small(6, TerrainKind::Gravel), &dirs[2], 2);
    let (a, b, c) = (snapshot(&dirs[0]), snapshot(&dirs[1]), snapshot(&dirs[2]));
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    for (path, bytes) in &a {
        assert!(
            b[path] == *bytes,
            "{} differs between two runs with the same seed",
            path.display()
        );
    }
    for name in [
        "uav/gt.txt",
        "uav/altimeter.txt",
        "satellite.png",
        "uav/images/000000.png",
    ] {
        let p = Path::new(name);
        assert!(
            c.get(p).is_some_and(|bytes| *bytes != a[p]),
            "{name} does not change with the seed"
        );
    }
    // Every stage reported, frames to the end.
    for stage in [
        Stage::Terrain,
        Stage::Shading,
        Stage::Satellite,
        Stage::Frames,
    ] {
        assert!(
            events.iter().any(|e| e.0 == stage),
            "{stage:?} never reported"
        );
    }
    let last = events.last().unwrap();
    assert_eq!((last.0, last.1), (Stage::Frames, last.2));
}

#[test]
fn layout_is_complete_and_consistent() {
    for kind in [TerrainKind::Crater, TerrainKind::Mountain] {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        let cfg = small(11, kind);
        generate(&cfg, dir, 2);
        let images = read_pairs(&dir.join("uav/images.txt"));
        let gt = read_tum(&dir.join("uav/gt.txt"));
        let alt = read_pairs(&dir.join("uav/altimeter.txt"));
        assert_eq!(images.len(), cfg.trajectory.frame_count());
        assert_eq!(gt.len(), images.len());
        assert_eq!(alt.len(), images.len());
        for (k, (((ts, file), (ts_gt, pose)), (ts_alt, _))) in
            images.iter().zip(&gt).zip(&alt).enumerate()
        {
            assert_eq!(ts, ts_gt);
            assert_eq!(ts, ts_alt);
            assert_eq!(file, &format!("images/{k:06}.png"));
            let (w, h, pixels) = read_grey(&dir.join("uav").join(file));
            assert_eq!((w, h), (160, 120));
            // Not blank: the terrain has texture.
            let mean = pixels.iter().map(|&p| p as f64).sum::<f64>() / pixels.len() as f64;
            let var = pixels
                .iter()
                .map(|&p| (p as f64 - mean).powi(2))
                .sum::<f64>()
                / pixels.len() as f64;
            assert!(
                mean > 20.0 && mean < 235.0 && var > 4.0,
                "{file}: mean {mean}, var {var}"
            );
            // Camera looks down from about the flight altitude.
            let axis = pose.rotation() * nalgebra::Vector3::z();
            assert!(axis.z < -0.95);
        }
        let map = MapInfo::read(&dir.join("map.toml")).unwrap();
        let (mw, mh, _) = read_grey(&dir.join(&map.image));
        assert_eq!((mw as u32, mh as u32), (map.width_px, map.height_px));
        let tiles = map.tile_list();
        let on_disk = std::fs::read_dir(dir.join(&map.tiles.dir)).unwrap().count();
        assert_eq!(on_disk, tiles.len());
        for t in &tiles {
            let (tw, th, _) = read_grey(&dir.join(&map.tiles.dir).join(t.file_name()));
            assert_eq!((tw as u32, th as u32), (t.width, t.height));
        }
        // Every frame's centre is inside the map.
        for (_, pose) in &gt {
            let c = pose.centre();
            let (u, v) = map.world_to_pixel(c.x, c.y);
            assert!(u > 0.0 && v > 0.0 && u < mw as f64 && v < mh as f64);
        }
        let back = SimConfig::read(&dir.join("sim.toml")).unwrap();
        assert_eq!(back, cfg);
    }
}
