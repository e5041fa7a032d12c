//! Readers for the files a dataset holds, written independently of the writer's code paths,
//! and the small camera of the fast tests.

#![allow(dead_code)]

use std::path::Path;

use jointloc_geometry::CameraToWorld;

/// `(timestamp, pose)` lines of a TUM file.
pub fn read_tum(path: &Path) -> Vec<(String, CameraToWorld)> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            assert_eq!(f.len(), 8, "TUM line `{l}`");
            let v: Vec<f64> = f[1..].iter().map(|s| s.parse().unwrap()).collect();
            (
                f[0].to_string(),
                CameraToWorld::from_translation_quaternion(
                    [v[0], v[1], v[2]],
                    [v[3], v[4], v[5], v[6]],
                ),
            )
        })
        .collect()
}

/// `(timestamp, rest of the line)` of a two-column text file.
pub fn read_pairs(path: &Path) -> Vec<(String, String)> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let (a, b) = l.split_once(' ').unwrap();
            (a.to_string(), b.trim().to_string())
        })
        .collect()
}

/// An 8-bit grey PNG as `(width, height, pixels)`.
pub fn read_grey(path: &Path) -> (usize, usize, Vec<u8>) {
    let img = image::open(path).unwrap();
    assert_eq!(img.color(), image::ColorType::L8, "{}", path.display());
    let img = img.to_luma8();
    (img.width() as usize, img.height() as usize, img.into_raw())
}

/// A 160 × 120 camera at f = 160 px and a 6 m margin: datasets that render in seconds.
pub fn small_camera(cfg: &mut jointloc_sim::SimConfig) {
    cfg.camera.width = 160;
    cfg.camera.height = 120;
    cfg.camera.fx = 160.0;
    cfg.camera.fy = 160.0;
    cfg.camera.cx = 79.5;
    cfg.camera.cy = 59.5;
    cfg.margin_m = 6.0;
}
