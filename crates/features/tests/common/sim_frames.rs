//! Simulated nadir UAV frames and exact homography pairs for the ORB tests, the ORB bench
//! and the BRIEF pattern generator (included with `#[path]` by the example and the bench, and
//! by the SLAM crate's `tests/init_rendered.rs`, which renders its views the same way).
//!
//! Seeds: the evaluation datasets use seeds 1–9; pattern learning uses 1000+, the tests and
//! the bench 2000+, so that the pattern is never evaluated on the frames it was learned from.
#![allow(dead_code)]

use image::GrayImage;
use jointloc_geometry::{CameraToWorld, PinholeCamera};
use jointloc_sim::render::UavRenderer;
use jointloc_sim::sensor::{SensorConfig, expose};
use jointloc_sim::trajectory::nadir_rotation;
use jointloc_sim::{
    ShadingConfig, Sun, TerrainConfig, TerrainExtent, TerrainKind, generate_terrain, shade,
};
use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Side of the simulated terrain, metres (the camera at 10 m sees 1 m per 50 px).
const TERRAIN_SIDE_M: f64 = 30.0;
/// Flight height above the ground, metres.
const ALTITUDE_M: f64 = 10.0;

/// A nadir view: offset (m) from the terrain centre and heading (radians).
#[derive(Debug, Clone, Copy)]
pub struct View {
    pub dx: f64,
    pub dy: f64,
    pub yaw: f64,
}

/// Renders `size` × `size` frames (fx = fy = 500, principal point at the centre, the default
/// sensor model) of one seeded terrain, one per view.
pub fn render_views(kind: TerrainKind, seed: u64, size: usize, views: &[View]) -> Vec<GrayImage> {
    let cfg = TerrainConfig::default();
    let cells = (TERRAIN_SIDE_M / cfg.cell_m).round() as usize;
    let extent = TerrainExtent {
        origin_x: 0.0,
        origin_y: 0.0,
        width_cells: cells,
        height_cells: cells,
    };
    let terrain = generate_terrain(kind, &extent, &cfg, seed).expect("terrain");
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed);
    let sun = Sun {
        azimuth_deg: rng.random_range(0.0..360.0),
        elevation_deg: rng.random_range(35.0..60.0),
    };
    let radiance = shade(&terrain, &sun, &ShadingConfig::default());
    let camera = PinholeCamera::ideal(500.0, size as u32, size as u32);
    let renderer = UavRenderer::new(&terrain, &radiance, camera).expect("renderer");
    let sensor = SensorConfig::default();
    let exposure = sensor.exposure_for(&radiance.data);
    let (cx, cy) = (TERRAIN_SIDE_M / 2.0, -TERRAIN_SIDE_M / 2.0);
    views
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let (x, y) = (cx + v.dx, cy + v.dy);
            let ground = terrain.height_at(x, y);
            let r = UnitQuaternion::from_rotation_matrix(&nadir_rotation(v.yaw));
            let pose = CameraToWorld::from_rotation_translation(
                r,
                Vector3::new(x, y, ground + ALTITUDE_M),
            );
            let frame = renderer.render(&pose);
            let img = expose(&frame.radiance, &sensor, exposure, seed * 1000 + i as u64);
            GrayImage::from_raw(img.width as u32, img.height as u32, img.data).expect("size")
        })
        .collect()
}

/// One 500 × 500 frame of `kind` and `seed` (straight down over the terrain centre).
pub fn frame_500(kind: TerrainKind, seed: u64) -> GrayImage {
    render_views(
        kind,
        seed,
        500,
        &[View {
            dx: 0.0,
            dy: 0.0,
            yaw: 0.4,
        }],
    )
    .remove(0)
}

/// Bilinear sample of `img` at (x, y); `None` outside.
fn sample(img: &GrayImage, x: f64, y: f64) -> Option<f64> {
    let (w, h) = (img.width() as f64, img.height() as f64);
    if !(x >= 0.0 && y >= 0.0 && x <= w - 1.0 && y <= h - 1.0) {
        return None;
    }
    let (x0, y0) = (x.floor() as u32, y.floor() as u32);
    let (x1, y1) = (
        (x0 + 1).min(img.width() - 1),
        (y0 + 1).min(img.height() - 1),
    );
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    let p = |x, y| img.get_pixel(x, y)[0] as f64;
    let top = p(x0, y0) * (1.0 - fx) + p(x1, y0) * fx;
    let bottom = p(x0, y1) * (1.0 - fx) + p(x1, y1) * fx;
    Some(top * (1.0 - fy) + bottom * fy)
}

/// Applies a homography to a point.
pub fn apply(h: &Matrix3<f64>, x: f64, y: f64) -> (f64, f64) {
    let v = h * Vector3::new(x, y, 1.0);
    (v.x / v.z, v.y / v.z)
}

/// A random homography about the centre of a `size` image: rotation within ±`max_rot`,
/// scale in [0.85, 1.2], shift ≤ 20 px, perspective terms ≤ 1e-4 (about ±5 % across).
pub fn random_homography(rng: &mut ChaCha8Rng, size: usize, max_rot: f64) -> Matrix3<f64> {
    let c = (size as f64 - 1.0) / 2.0;
    let a = rng.random_range(-max_rot..max_rot);
    let s = (rng.random_range(0.85f64.ln()..1.2f64.ln())).exp();
    let (sa, ca) = a.sin_cos();
    let (tx, ty) = (rng.random_range(-20.0..20.0), rng.random_range(-20.0..20.0));
    let (p, q) = (rng.random_range(-1e-4..1e-4), rng.random_range(-1e-4..1e-4));
    let to_c = Matrix3::new(1.0, 0.0, -c, 0.0, 1.0, -c, 0.0, 0.0, 1.0);
    let from_c = Matrix3::new(1.0, 0.0, c + tx, 0.0, 1.0, c + ty, 0.0, 0.0, 1.0);
    let m = Matrix3::new(s * ca, -s * sa, 0.0, s * sa, s * ca, 0.0, p, q, 1.0);
    from_c * m * to_c
}

/// An exact pair from a larger `source` frame: A is its central `size` crop, B the crop seen
/// through `h` (B(H·x) = A(x)), resampled bilinearly from the source so that B has no empty
/// corners. Panics if `h` maps B outside the source (choose a big enough source).
pub fn homography_pair(
    source: &GrayImage,
    size: usize,
    h: &Matrix3<f64>,
) -> (GrayImage, GrayImage) {
    let off_x = (source.width() as usize - size) / 2;
    let off_y = (source.height() as usize - size) / 2;
    let a = image::imageops::crop_imm(source, off_x as u32, off_y as u32, size as u32, size as u32)
        .to_image();
    let hinv = h.try_inverse().expect("invertible homography");
    let mut b = GrayImage::new(size as u32, size as u32);
    for y in 0..size {
        for x in 0..size {
            let (ax, ay) = apply(&hinv, x as f64, y as f64);
            let v = sample(source, ax + off_x as f64, ay + off_y as f64)
                .expect("homography maps B inside the source frame");
            b.put_pixel(
                x as u32,
                y as u32,
                image::Luma([v.round().clamp(0.0, 255.0) as u8]),
            );
        }
    }
    (a, b)
}

/// The three terrain kinds.
pub const KINDS: [TerrainKind; 3] = [
    TerrainKind::Crater,
    TerrainKind::Gravel,
    TerrainKind::Mountain,
];

/// An exact test pair: B(H·x) = A(x).
#[derive(Debug, Clone)]
pub struct Pair {
    pub name: String,
    pub a: GrayImage,
    pub b: GrayImage,
    pub h: Matrix3<f64>,
}

/// `per_scene` pairs of 500 × 500 frames for each terrain kind and seed, cut from 960 × 960
/// renders (so that rotations up to `max_rot`, the scales and shifts of
/// [`random_homography`] never leave the source).
pub fn homography_pairs(seeds: &[u64], per_scene: usize, max_rot: f64) -> Vec<Pair> {
    let mut out = Vec::new();
    for kind in KINDS {
        for &seed in seeds {
            let source = render_views(
                kind,
                seed,
                960,
                &[View {
                    dx: 0.0,
                    dy: 0.0,
                    yaw: 0.4,
                }],
            )
            .remove(0);
            let mut rng = ChaCha8Rng::seed_from_u64(seed.wrapping_mul(31) + kind as u64);
            for k in 0..per_scene {
                let h = random_homography(&mut rng, 500, max_rot);
                let (a, b) = homography_pair(&source, 500, &h);
                out.push(Pair {
                    name: format!("{kind:?}-{seed}-{k}").to_lowercase(),
                    a,
                    b,
                    h,
                });
            }
        }
    }
    out
}
