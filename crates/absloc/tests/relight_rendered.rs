//! The map relit to the flight's sun on rendered terrain: the simulator shades a terrain under
//! the map's sun and under the flight's (cast shadows, lunar-Lambert, sky light), and makes a
//! HiRISE-class DTM of it (1 m posts, 0.25 m correlated noise); the relit map must look more
//! like the flight's rendering than the map as taken over mountains, and no less over gravel,
//! whose relief is below the DTM's noise.

use image::GrayImage;
use jointloc_absloc::relight::{RelightConfig, relight};
use jointloc_formats::map_toml::SunInfo;
use jointloc_formats::{ElevationModel, Grid};
use jointloc_sim::dem::{DemConfig, simulate_dem};
use jointloc_sim::{
    ShadingConfig, Sun, TerrainConfig, TerrainExtent, TerrainKind, generate_terrain, shade,
};

const CELL_M: f64 = 0.25;
const SIDE_CELLS: usize = 400;
const MAP_SUN: SunInfo = SunInfo {
    azimuth_deg: 348.0,
    elevation_deg: 43.0,
};

fn to_sun(s: &SunInfo) -> Sun {
    Sun {
        azimuth_deg: s.azimuth_deg,
        elevation_deg: s.elevation_deg,
    }
}

/// Radiance as an 8-bit image, scaled so its 99.5th percentile is 230.
fn to_image(r: &Grid<f32>) -> GrayImage {
    let mut sorted = r.data.clone();
    sorted.sort_by(f32::total_cmp);
    let top = sorted[sorted.len() * 995 / 1000].max(1e-6);
    GrayImage::from_fn(r.width as u32, r.height as u32, |u, v| {
        let x = r.at(u as usize, v as usize) / top * 230.0;
        image::Luma([x.round().clamp(0.0, 255.0) as u8])
    })
}

/// Normalised cross-correlation over the interior (a 10 % border left out).
fn ncc(a: &GrayImage, b: &GrayImage) -> f64 {
    let (w, h) = a.dimensions();
    let (bx, by) = (w / 10, h / 10);
    let mut pairs = Vec::new();
    for v in by..h - by {
        for u in bx..w - bx {
            pairs.push((
                f64::from(a.get_pixel(u, v).0[0]),
                f64::from(b.get_pixel(u, v).0[0]),
            ));
        }
    }
    let n = pairs.len() as f64;
    let ma = pairs.iter().map(|p| p.0).sum::<f64>() / n;
    let mb = pairs.iter().map(|p| p.1).sum::<f64>() / n;
    let cov: f64 = pairs.iter().map(|p| (p.0 - ma) * (p.1 - mb)).sum();
    let va: f64 = pairs.iter().map(|p| (p.0 - ma).powi(2)).sum();
    let vb: f64 = pairs.iter().map(|p| (p.1 - mb).powi(2)).sum();
    cov / (va * vb).sqrt()
}

/// (NCC of the map as taken, NCC of the relit map) against the flight's rendering.
fn relit_against_flight(kind: TerrainKind, seed: u64, flight_sun: SunInfo) -> (f64, f64) {
    let cfg = TerrainConfig {
        cell_m: CELL_M,
        ..TerrainConfig::default()
    };
    let extent = TerrainExtent {
        origin_x: 0.0,
        origin_y: 0.0,
        width_cells: SIDE_CELLS,
        height_cells: SIDE_CELLS,
    };
    let terrain = generate_terrain(kind, &extent, &cfg, seed).expect("terrain");
    let shading = ShadingConfig::default();
    let map = to_image(&shade(&terrain, &to_sun(&MAP_SUN), &shading));
    let flight = to_image(&shade(&terrain, &to_sun(&flight_sun), &shading));
    let (info, posts) = simulate_dem(
        (&terrain).into(),
        4,
        &DemConfig::hirise(),
        "elevation.png",
        seed,
    )
    .expect("dem");
    let heights = Grid {
        width: posts.width,
        height: posts.height,
        data: posts
            .data
            .iter()
            .map(|&v| (info.offset_m + f64::from(v) * info.scale_m) as f32)
            .collect(),
    };
    let dem = ElevationModel::from_heights(info, heights).expect("dem size");
    let relit = relight(
        &map,
        CELL_M,
        &dem,
        &MAP_SUN,
        &flight_sun,
        &RelightConfig::default(),
    );
    (ncc(&map, &flight), ncc(&relit, &flight))
}

#[test]
fn mountains_relit_look_like_the_flight_and_gravel_is_left_alone() {
    for (azimuth_change, seed) in [(90.0, 11), (180.0, 12)] {
        let flight_sun = SunInfo {
            azimuth_deg: MAP_SUN.azimuth_deg + azimuth_change,
            elevation_deg: 20.0,
        };
        let (taken, relit) = relit_against_flight(TerrainKind::Mountain, seed, flight_sun);
        eprintln!("mountain {azimuth_change}°: as taken {taken:.3}, relit {relit:.3}");
        assert!(
            relit > taken + 0.2,
            "mountain under {azimuth_change}°: relit {relit:.3}, as taken {taken:.3}"
        );
        let (taken, relit) = relit_against_flight(TerrainKind::Gravel, seed, flight_sun);
        eprintln!("gravel {azimuth_change}°: as taken {taken:.3}, relit {relit:.3}");
        assert!(
            relit > taken - 0.02,
            "gravel under {azimuth_change}°: relit {relit:.3}, as taken {taken:.3}"
        );
    }
}
