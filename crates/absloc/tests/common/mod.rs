//! Shared test material: a random texture standing in for a map, frames cut from it by a known
//! similarity, and a small simulated dataset generated once per test binary.

#![allow(dead_code)]

use std::path::Path;
use std::sync::OnceLock;

use image::GrayImage;
use jointloc_absloc::registry::{RegistryOptions, resolve};
use jointloc_absloc::{AbsLocConfig, AbsLocalizer, MapTiles};
use jointloc_geometry::PinholeCamera;
use jointloc_sim::dataset::{SimConfig, generate_dataset};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A localiser with the ORB pipeline (no model files) on a `side × side` [`texture`] of
/// `seed` at `gsd` m/px, 500-pixel tiles overlapping by half, a 500 × 500 ideal camera with
/// f = 500 px, and no feature cache.
pub fn orb_localizer(seed: u64, side: u32, gsd: f64, config: AbsLocConfig) -> AbsLocalizer {
    orb_localizer_with_cache(seed, side, gsd, config, None)
}

/// [`orb_localizer`] with its tile features cached in `dir` (read back tile by tile).
pub fn orb_localizer_cached(
    seed: u64,
    side: u32,
    gsd: f64,
    config: AbsLocConfig,
    dir: &Path,
) -> AbsLocalizer {
    orb_localizer_with_cache(seed, side, gsd, config, Some(dir))
}

fn orb_localizer_with_cache(
    seed: u64,
    side: u32,
    gsd: f64,
    config: AbsLocConfig,
    cache_dir: Option<&Path>,
) -> AbsLocalizer {
    let root = cache_dir.unwrap_or(Path::new("."));
    let map = MapTiles::from_image(texture(side, side, seed), gsd, (500, 500), 0.5, root).unwrap();
    let pipeline = resolve("orb", &RegistryOptions::default()).unwrap();
    AbsLocalizer::new(
        map,
        PinholeCamera::ideal(500.0, 500, 500),
        pipeline,
        AbsLocConfig {
            cache: cache_dir.is_some(),
            cache_dir: cache_dir.map(Path::to_path_buf),
            ..config
        },
    )
    .unwrap()
}

/// A non-repeating texture: random lattices at three scales, bilinearly interpolated.
pub fn texture(w: u32, h: u32, seed: u64) -> GrayImage {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let layers: Vec<(f64, f64, usize, Vec<f64>)> = [(40.0, 90.0), (9.0, 80.0), (3.0, 50.0)]
        .iter()
        .map(|&(cell, amp)| {
            let n = (w.max(h) as f64 / cell).ceil() as usize + 2;
            let g = (0..n * n).map(|_| rng.random_range(0.0..1.0)).collect();
            (cell, amp, n, g)
        })
        .collect();
    GrayImage::from_fn(w, h, |x, y| {
        let mut v = 20.0;
        for (cell, amp, n, g) in &layers {
            let (fx, fy) = (x as f64 / cell, y as f64 / cell);
            let (x0, y0) = (fx.floor() as usize, fy.floor() as usize);
            let (tx, ty) = (fx - x0 as f64, fy - y0 as f64);
            let at = |i: usize, j: usize| g[j.min(n - 1) * n + i.min(n - 1)];
            v += amp
                * ((at(x0, y0) * (1.0 - tx) + at(x0 + 1, y0) * tx) * (1.0 - ty)
                    + (at(x0, y0 + 1) * (1.0 - tx) + at(x0 + 1, y0 + 1) * tx) * ty);
        }
        image::Luma([v.clamp(0.0, 255.0) as u8])
    })
}

/// A `size × size` nadir frame of `map` (GSD `gsd`) centred on map pixel `centre`, with
/// `scale` map pixels per frame pixel and the frame's x axis at `heading` in the map.
pub fn frame_from_map(
    map: &GrayImage,
    centre: (f64, f64),
    scale: f64,
    heading: f64,
    size: u32,
) -> GrayImage {
    let (s, c) = heading.sin_cos();
    let half = (size as f64 - 1.0) / 2.0;
    GrayImage::from_fn(size, size, |x, y| {
        let (dx, dy) = (x as f64 - half, y as f64 - half);
        let u = centre.0 + scale * (c * dx - s * dy);
        let v = centre.1 + scale * (s * dx + c * dy);
        let p = jointloc_absloc::warp::bilinear(map, u, v).unwrap_or(0.0);
        image::Luma([p.round() as u8])
    })
}

/// A small simulated dataset (crater, easy, 8 m at 1 Hz: 9 frames of 500 × 500), generated
/// once per test binary into a temporary folder.
pub fn sim_dataset() -> &'static Path {
    static DIR: OnceLock<jointloc_sim::scratch::ProcessScratch> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir =
            jointloc_sim::scratch::ProcessScratch::new(env!("CARGO_TARGET_TMPDIR"), "absloc-easy")
                .unwrap();
        let mut cfg = SimConfig {
            seed: 20261122,
            ..Default::default()
        };
        cfg.trajectory.length_m = 8.0;
        cfg.trajectory.rate_hz = 1.0;
        generate_dataset(&cfg, dir.path(), &mut |_, _, _| {}).unwrap();
        dir
    })
    .path()
}

/// The same flight over a medium-difficulty map (12.5 cm/px, 2.5 times coarser than the easy
/// one, other sun), generated once per test binary.
pub fn sim_dataset_medium() -> &'static Path {
    static DIR: OnceLock<jointloc_sim::scratch::ProcessScratch> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = jointloc_sim::scratch::ProcessScratch::new(
            env!("CARGO_TARGET_TMPDIR"),
            "absloc-medium",
        )
        .unwrap();
        let mut cfg = SimConfig {
            seed: 20261123,
            difficulty: jointloc_sim::Difficulty::Medium,
            ..Default::default()
        };
        cfg.trajectory.length_m = 8.0;
        cfg.trajectory.rate_hz = 1.0;
        generate_dataset(&cfg, dir.path(), &mut |_, _, _| {}).unwrap();
        dir
    })
    .path()
}
