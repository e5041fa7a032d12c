//! Dataset generation: plan (path, map size, terrain extent), terrain, shading, satellite map
//! and tiles, UAV frames, ground truth and altimeter, written in jointloc's dataset layout
//! (the files through `jointloc_formats`, which reads them back):
//!
//! ```text
//! <out>/uav/images/000000.png …  uav/images.txt   uav/gt.txt   uav/altimeter.txt
//! <out>/camera.yaml   <out>/satellite.png   <out>/satellite/<idx>_<x>_<y>.png   <out>/map.toml
//! <out>/sim.toml      (the full configuration, to reproduce the dataset)
//! ```
//!
//! - `images.txt`: `timestamp filename`, the file name relative to `uav/` (TUM `rgb.txt` style).
//! - `gt.txt`: TUM `timestamp tx ty tz qx qy qz qw`, camera-to-world in the world frame of
//!   `map.toml`, the exact pose each frame was rendered from, printed with round-trip precision.
//! - `altimeter.txt`: `timestamp altitude_m`, the true height of the camera above the terrain
//!   directly below it (vertically, not along the optical axis) plus Gaussian noise of σ
//!   `altimeter_sigma_m`: what a laser or radar altimeter reports, never exact.
//! - Timestamps are `i / rate` seconds with six decimals, identical strings in all three files.
//!
//! Everything random is drawn from sub-seeds of `SimConfig::seed`; rayon only parallelises
//! work whose result does not depend on scheduling, so a seed gives byte-identical files.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use jointloc_geometry::CameraToWorld;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use rayon::prelude::*;
use serde::Serialize;

use jointloc_formats::Grid;
use jointloc_formats::camera_yaml::write_camera_yaml;
use jointloc_formats::elevation::{write_elevation_png, write_grey_png};
use jointloc_formats::geotiff::{GeoTransform, Samples, write_mars_geotiff};
use jointloc_formats::map_toml::{MapInfo, SceneInfo, SunInfo, covered_length, tile_stride};
use jointloc_formats::sequence::{FrameRecord, write_sequence};

use crate::dem::{Heights, simulate_dem};
use crate::error::{Result, SimError};
use crate::regional::{BLEND_BAND_M, Patch, composite, pixel_heights};
use crate::render::UavRenderer;
use crate::satellite::downsample_mean;
use crate::sensor::expose;
use crate::shading::{Sun, shade};
use crate::terrain::{FeatureLayout, Terrain, TerrainConfig, TerrainExtent, generate_terrain_with};
use crate::trajectory::{PlanarPath, fly, plan_path};

use crate::config::stream;
pub use crate::config::{
    ELEVATION_IMAGE, GEOTIFF_ORIGIN_M, MARS_MAP_SIZE_M, MAX_ALTITUDE_M, SimConfig, sub_seed,
};

/// Where things go: computed before any terrain exists.
#[derive(Debug, Clone)]
pub struct DatasetPlan {
    /// The flown path in the world frame.
    pub path: PlanarPath,
    /// Georeference of the map (scene info included).
    pub map: MapInfo,
    /// The (detailed) terrain grid: cell borders coincide with map pixel borders.
    pub extent: TerrainExtent,
    /// Terrain cells per map pixel along each axis.
    pub cells_per_pixel: usize,
    /// The terrain settings in force (the cell adapted to the altitude).
    pub terrain: TerrainConfig,
    /// How the terrain draws its craters and rocks.
    pub layout: FeatureLayout,
    /// Where the detailed terrain lies in a map larger than the flight.
    pub patch: Option<Patch>,
    pub uav_sun: Sun,
    pub satellite_sun: Sun,
}

impl DatasetPlan {
    /// Camera-to-world pose of every frame over `terrain` (the ground truth written).
    pub fn poses(&self, cfg: &SimConfig, terrain: &Terrain) -> Vec<CameraToWorld> {
        let ground = |x: f64, y: f64| terrain.height_at(x, y);
        fly(
            &self.path,
            &ground,
            &cfg.trajectory,
            sub_seed(cfg.seed, stream::FLIGHT),
        )
    }
}

/// Plans the path, sizes the map and lays the terrain grid under the map: the map is the
/// path's bounding box plus margin (rounded up to whole tile strides), or a square of
/// `map_size_m` with the path placed at a seeded position and a detailed patch under it.
pub fn plan_dataset(cfg: &SimConfig) -> Result<DatasetPlan> {
    cfg.validate()?;
    let sat = cfg.satellite_config();
    let terrain = cfg.effective_terrain();
    let factor = sat.validate(terrain.cell_m)?;
    let mut path = plan_path(&cfg.trajectory, sub_seed(cfg.seed, stream::PATH))?;
    let (lo, hi) = path.bbox();
    let margin = cfg.effective_margin_m();
    let (tw, th) = (cfg.camera.width, cfg.camera.height);
    let (sx, sy) = (
        tile_stride(tw, sat.tile_overlap),
        tile_stride(th, sat.tile_overlap),
    );
    let need = |span: f64, extra: f64| ((span + 2.0 * (margin + extra)) / sat.gsd_m).ceil() as u32;
    let (map_w, map_h, patch) = match cfg.effective_map_size_m() {
        None => {
            let w = covered_length(need(hi[0] - lo[0], 0.0), tw, sx);
            let h = covered_length(need(hi[1] - lo[1], 0.0), th, sy);
            (w, h, None)
        }
        Some(size_m) => {
            let side = (size_m / sat.gsd_m).ceil() as u32;
            let (w, h) = (covered_length(side, tw, sx), covered_length(side, th, sy));
            let (pw, ph) = (
                need(hi[0] - lo[0], BLEND_BAND_M),
                need(hi[1] - lo[1], BLEND_BAND_M),
            );
            if pw > w || ph > h {
                return Err(SimError::InvalidConfig {
                    field: "map_size_m",
                    value: size_m.to_string(),
                    reason: format!(
                        "the map is smaller than the flight: its path, the camera footprint and \
                         a {BLEND_BAND_M} m blend band need {:.0} m × {:.0} m",
                        pw as f64 * sat.gsd_m,
                        ph as f64 * sat.gsd_m
                    ),
                });
            }
            let mut rng = ChaCha8Rng::seed_from_u64(sub_seed(cfg.seed, stream::PLACEMENT));
            let patch = Patch {
                x_px: rng.random_range(0..=w - pw),
                y_px: rng.random_range(0..=h - ph),
                width_px: pw,
                height_px: ph,
                band_px: (BLEND_BAND_M / sat.gsd_m).round() as u32,
            };
            (w, h, Some(patch))
        }
    };
    let mut map = MapInfo::new(sat.gsd_m, map_w, map_h, tw, th, sat.tile_overlap)?;
    // Centre the path in the detailed area (the whole map, or the patch).
    let (px, py, pw, ph) = patch.map_or((0, 0, map_w, map_h), |p| {
        (p.x_px, p.y_px, p.width_px, p.height_px)
    });
    let centre = map.pixel_to_world(
        px as f64 + (pw as f64 - 1.0) / 2.0,
        py as f64 + (ph as f64 - 1.0) / 2.0,
    );
    path.translate(
        centre.0 - 0.5 * (lo[0] + hi[0]),
        centre.1 - 0.5 * (lo[1] + hi[1]),
    );
    let (uav_sun, satellite_sun) = cfg.suns();
    let sun = |s: Sun| SunInfo {
        azimuth_deg: s.azimuth_deg,
        elevation_deg: s.elevation_deg,
    };
    map.scene = Some(SceneInfo {
        generator: format!("jointloc-sim {}", env!("CARGO_PKG_VERSION")),
        terrain: cfg.terrain_kind.name().to_string(),
        difficulty: cfg.difficulty.name().to_string(),
        seed: cfg.seed,
        terrain_cell_m: terrain.cell_m,
        uav_sun: sun(uav_sun),
        satellite_sun: sun(satellite_sun),
        detailed_region_px: patch.map(|p| [p.x_px, p.y_px, p.width_px, p.height_px]),
    });
    // Pixel (px, py) spans gsd around its centre; its first cell's centre is half a cell inside.
    let half = (factor as f64 - 1.0) / 2.0 * terrain.cell_m;
    let (x0, y0) = map.pixel_to_world(px as f64, py as f64);
    let extent = TerrainExtent {
        origin_x: x0 - half,
        origin_y: y0 + half,
        width_cells: pw as usize * factor,
        height_cells: ph as usize * factor,
    };
    let layout = if patch.is_some() {
        FeatureLayout::world_for_cell(terrain.cell_m)
    } else {
        FeatureLayout::Extent
    };
    Ok(DatasetPlan {
        path,
        map,
        extent,
        cells_per_pixel: factor,
        terrain,
        layout,
        patch,
        uav_sun,
        satellite_sun,
    })
}

/// Stage of [`generate_dataset`] reported to the progress callback.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    Terrain,
    Shading,
    Satellite,
    Frames,
}

impl Stage {
    /// Lower-case name for progress displays.
    pub fn name(self) -> &'static str {
        match self {
            Stage::Terrain => "terrain",
            Stage::Shading => "shading",
            Stage::Satellite => "satellite",
            Stage::Frames => "frames",
        }
    }
}

/// What was written, with wall times per stage.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DatasetSummary {
    pub out_dir: PathBuf,
    pub frames: usize,
    pub path_length_m: f64,
    pub map_width_px: u32,
    pub map_height_px: u32,
    pub map_gsd_m: f64,
    pub tiles: usize,
    pub terrain_width_cells: usize,
    pub terrain_height_cells: usize,
    /// UAV pixels whose ray left the terrain (0 unless the margin is too small).
    pub missed_pixels: usize,
    /// A fisheye's pixels beyond the angle the map covers (72° off axis): the background, as
    /// intended (not counted in `missed_pixels`).
    pub beyond_cover_pixels: usize,
    /// Seconds spent per stage: terrain, shading, satellite, frames.
    pub seconds: [f64; 4],
}

/// Progress callback: `(stage, done, total)`.
pub type Progress<'a> = &'a mut dyn FnMut(Stage, usize, usize);

/// Makes `dir` ready for a dataset: creates it if missing; if it holds anything, fails unless
/// `overwrite`, in which case only the dataset's own entries are removed (other files stay).
pub fn prepare_output_dir(dir: &Path, overwrite: bool) -> Result<()> {
    let io = |source| SimError::Io {
        path: dir.to_path_buf(),
        source,
    };
    if dir.exists() {
        if !dir.is_dir() {
            return Err(io(std::io::Error::new(
                std::io::ErrorKind::AlreadyExists,
                "exists and is not a directory",
            )));
        }
        let non_empty = std::fs::read_dir(dir).map_err(io)?.next().is_some();
        if non_empty {
            if !overwrite {
                return Err(SimError::OutputNotEmpty {
                    path: dir.to_path_buf(),
                });
            }
            for name in ["uav", "satellite"] {
                let p = dir.join(name);
                if p.is_dir() {
                    std::fs::remove_dir_all(&p)
                        .map_err(|source| SimError::Io { path: p, source })?;
                }
            }
            for name in [
                "satellite.png",
                "satellite.tif",
                "elevation.png",
                "elevation.tif",
                "camera.yaml",
                "map.toml",
                "sim.toml",
            ] {
                let p = dir.join(name);
                if p.is_file() {
                    std::fs::remove_file(&p).map_err(|source| SimError::Io { path: p, source })?;
                }
            }
        }
    }
    std::fs::create_dir_all(dir).map_err(io)?;
    // Fail early, with a clear message, when the folder is not writable.
    let probe = dir.join(".jointloc-write-test");
    std::fs::write(&probe, b"").map_err(|source| SimError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    std::fs::remove_file(&probe).map_err(|source| SimError::Io {
        path: probe,
        source,
    })?;
    Ok(())
}

/// Generates the whole dataset into `out_dir` (created if missing; existing dataset files are
/// overwritten, see [`prepare_output_dir`] for the safe policy).
pub fn generate_dataset(
    cfg: &SimConfig,
    out_dir: &Path,
    progress: Progress,
) -> Result<DatasetSummary> {
    let plan = plan_dataset(cfg)?;
    let start = Instant::now();
    progress(Stage::Terrain, 0, 1);
    let terrain = generate_terrain_with(
        cfg.terrain_kind,
        &plan.extent,
        &plan.terrain,
        sub_seed(cfg.seed, stream::TERRAIN),
        plan.layout,
    )?;
    progress(Stage::Terrain, 1, 1);
    let terrain_s = start.elapsed().as_secs_f64();
    tracing::info!(
        cells = plan.extent.width_cells * plan.extent.height_cells,
        seconds = terrain_s,
        "terrain synthesised"
    );
    let mut summary = write_dataset(cfg, &plan, &terrain, out_dir, progress)?;
    summary.seconds[0] = terrain_s;
    Ok(summary)
}

/// Writes every dataset file for `terrain`, which must cover `plan.extent` (tests paint
/// markers into a terrain and call this directly).
pub fn write_dataset(
    cfg: &SimConfig,
    plan: &DatasetPlan,
    terrain: &Terrain,
    out_dir: &Path,
    progress: Progress,
) -> Result<DatasetSummary> {
    cfg.validate()?;
    check_terrain(plan, terrain)?;
    let uav_dir = out_dir.join("uav");
    let images_dir = uav_dir.join("images");
    let tiles_dir = out_dir.join(&plan.map.tiles.dir);
    for d in [&images_dir, &tiles_dir] {
        std::fs::create_dir_all(d).map_err(|source| SimError::Io {
            path: d.clone(),
            source,
        })?;
    }
    let mut seconds = [0.0; 4];

    // Satellite map first, so its radiance grid is freed before the UAV one is made.
    let t = Instant::now();
    progress(Stage::Satellite, 0, 1);
    let sat = cfg.satellite_config();
    let tiles = plan.map.tile_list();
    let (radiance, heights) = map_radiance_and_heights(cfg, plan, terrain)?;
    {
        let exposure = sat.sensor.exposure_for(&radiance.data);
        let image = expose(
            &radiance,
            &sat.sensor,
            exposure,
            sub_seed(cfg.seed, stream::SATELLITE_NOISE),
        );
        drop(radiance);
        write_png(&out_dir.join(&plan.map.image), &image)?;
        if cfg.geotiff {
            write_mars_geotiff(
                &out_dir.join(SATELLITE_GEOTIFF),
                image.width,
                image.height,
                &Samples::U8(image.data.clone()),
                &geotiff_transform(0.0, 0.0, plan.map.gsd_m),
            )?;
        }
        tiles.par_iter().try_for_each(|tile| {
            let window = image.window(
                tile.x as usize,
                tile.y as usize,
                tile.width as usize,
                tile.height as usize,
            );
            write_png(&tiles_dir.join(tile.file_name()), &window)
        })?;
    }
    let mut map = plan.map.clone();
    if sat.dem.post_px > 0 {
        let dem_seed = sub_seed(cfg.seed, stream::DEM);
        let (info, dem) = match &heights {
            // The whole map on its pixel grid (coarse terrain, detailed patch blended in).
            Some(h) => simulate_dem(
                Heights {
                    grid: h,
                    cell_m: plan.map.gsd_m,
                    origin_x: 0.0,
                    origin_y: 0.0,
                },
                sat.dem.post_px as usize,
                &sat.dem,
                ELEVATION_IMAGE,
                dem_seed,
            )?,
            None => simulate_dem(
                terrain.into(),
                sat.dem.post_px as usize * plan.cells_per_pixel,
                &sat.dem,
                ELEVATION_IMAGE,
                dem_seed,
            )?,
        };
        write_elevation_png(&out_dir.join(&info.image), &dem)?;
        if cfg.geotiff {
            let heights = dem
                .data
                .iter()
                .map(|&v| (info.offset_m + v as f64 * info.scale_m) as f32)
                .collect();
            write_mars_geotiff(
                &out_dir.join(ELEVATION_GEOTIFF),
                dem.width,
                dem.height,
                &Samples::F32(heights),
                &geotiff_transform(info.origin_x_m, info.origin_y_m, info.gsd_m),
            )?;
        }
        map.elevation = Some(info);
    }
    map.write(&out_dir.join("map.toml"))?;
    progress(Stage::Satellite, 1, 1);
    seconds[2] = t.elapsed().as_secs_f64();

    let t = Instant::now();
    progress(Stage::Shading, 0, 1);
    let radiance = shade(terrain, &plan.uav_sun, &cfg.shading);
    progress(Stage::Shading, 1, 1);
    seconds[1] = t.elapsed().as_secs_f64();

    // Poses, ground truth, altimeter, camera.
    let poses = plan.poses(cfg, terrain);
    write_text_files(cfg, plan, terrain, &poses, &uav_dir)?;
    write_camera_yaml(
        &out_dir.join("camera.yaml"),
        &cfg.camera,
        cfg.trajectory.rate_hz,
    )?;
    let sim_toml = cfg.to_toml_string()?;
    write_file(&out_dir.join("sim.toml"), sim_toml.as_bytes())?;

    // Frames: several in flight at once (each also parallel over rows).
    let t = Instant::now();
    let renderer = UavRenderer::new(terrain, &radiance, cfg.camera)?;
    let exposure = cfg.sensor.exposure_for(&radiance.data);
    let n = poses.len();
    let chunk = 4 * rayon::current_num_threads().max(1);
    let (mut missed, mut beyond_cover) = (0usize, 0usize);
    progress(Stage::Frames, 0, n);
    for start in (0..n).step_by(chunk) {
        let end = (start + chunk).min(n);
        let counts: Vec<(usize, usize)> = (start..end)
            .into_par_iter()
            .map(|i| -> Result<(usize, usize)> {
                let frame = renderer.render(&poses[i]);
                let seed = sub_seed(sub_seed(cfg.seed, stream::FRAME_NOISE), i as u64);
                let image = expose(&frame.radiance, &cfg.sensor, exposure, seed);
                write_png(&images_dir.join(frame_name(i)), &image)?;
                Ok((frame.misses, frame.beyond_cover))
            })
            .collect::<Result<_>>()?;
        for (m, b) in counts {
            missed += m;
            beyond_cover += b;
        }
        progress(Stage::Frames, end, n);
    }
    seconds[3] = t.elapsed().as_secs_f64();
    if missed > 0 {
        tracing::warn!(
            missed,
            "UAV pixels saw past the terrain edge (margin too small?)"
        );
    }
    if beyond_cover > 0 {
        tracing::info!(
            pixels = beyond_cover,
            "fisheye pixels beyond the map's covered angle show the background, as intended"
        );
    }
    Ok(DatasetSummary {
        out_dir: out_dir.to_path_buf(),
        frames: n,
        path_length_m: plan.path.samples.last().map_or(0.0, |s| s.s),
        map_width_px: plan.map.width_px,
        map_height_px: plan.map.height_px,
        map_gsd_m: plan.map.gsd_m,
        tiles: tiles.len(),
        terrain_width_cells: terrain.height.width,
        terrain_height_cells: terrain.height.height,
        missed_pixels: missed,
        beyond_cover_pixels: beyond_cover,
        seconds,
    })
}

/// The map's radiance under the map's sun, on its pixel grid; for a map larger than the
/// flight also its heights (coarse terrain over the map, the detailed patch blended in).
fn map_radiance_and_heights(
    cfg: &SimConfig,
    plan: &DatasetPlan,
    terrain: &Terrain,
) -> Result<(Grid<f32>, Option<Grid<f32>>)> {
    let detail = {
        let radiance = shade(terrain, &plan.satellite_sun, &cfg.shading);
        downsample_mean(&radiance, plan.cells_per_pixel)?
    };
    let Some(patch) = plan.patch else {
        return Ok((detail, None));
    };
    let gsd = plan.map.gsd_m;
    let coarse_cfg = TerrainConfig {
        cell_m: gsd,
        ..plan.terrain.clone()
    };
    let extent = TerrainExtent {
        origin_x: 0.0,
        origin_y: 0.0,
        width_cells: plan.map.width_px as usize,
        height_cells: plan.map.height_px as usize,
    };
    let t = Instant::now();
    let coarse = generate_terrain_with(
        cfg.terrain_kind,
        &extent,
        &coarse_cfg,
        sub_seed(cfg.seed, stream::TERRAIN),
        FeatureLayout::world_for_cell(gsd),
    )?;
    tracing::info!(
        cells = extent.width_cells * extent.height_cells,
        seconds = t.elapsed().as_secs_f64(),
        "coarse terrain of the whole map synthesised"
    );
    let mut radiance = shade(&coarse, &plan.satellite_sun, &cfg.shading);
    composite(&mut radiance, &detail, &patch)?;
    drop(detail);
    let mut heights = coarse.height;
    composite(
        &mut heights,
        &pixel_heights(terrain, plan.cells_per_pixel)?,
        &patch,
    )?;
    Ok((radiance, Some(heights)))
}

/// Names of the GeoTIFFs written with `geotiff`.
pub const SATELLITE_GEOTIFF: &str = "satellite.tif";
pub const ELEVATION_GEOTIFF: &str = "elevation.tif";

/// The GeoTIFF georeference of a grid whose first cell is centred on world `(x, y)`.
fn geotiff_transform(x: f64, y: f64, pixel_m: f64) -> GeoTransform {
    GeoTransform {
        easting_m: GEOTIFF_ORIGIN_M.0 + x,
        northing_m: GEOTIFF_ORIGIN_M.1 + y,
        pixel_m,
    }
}

fn check_terrain(plan: &DatasetPlan, terrain: &Terrain) -> Result<()> {
    let e = &plan.extent;
    let same = terrain.height.width == e.width_cells
        && terrain.height.height == e.height_cells
        && terrain.albedo.width == e.width_cells
        && terrain.albedo.height == e.height_cells
        && (terrain.origin_x - e.origin_x).abs() < 1e-9
        && (terrain.origin_y - e.origin_y).abs() < 1e-9;
    if same {
        Ok(())
    } else {
        Err(SimError::InvalidConfig {
            field: "terrain",
            value: format!(
                "{}x{} at ({}, {})",
                terrain.height.width, terrain.height.height, terrain.origin_x, terrain.origin_y
            ),
            reason: format!(
                "must match the planned extent {}x{} at ({}, {})",
                e.width_cells, e.height_cells, e.origin_x, e.origin_y
            ),
        })
    }
}

/// `000000.png`.
pub fn frame_name(i: usize) -> String {
    format!("{i:06}.png")
}

fn write_text_files(
    cfg: &SimConfig,
    plan: &DatasetPlan,
    terrain: &Terrain,
    poses: &[CameraToWorld],
    uav_dir: &Path,
) -> Result<()> {
    let rate = cfg.trajectory.rate_hz;
    let mut rng = ChaCha8Rng::seed_from_u64(sub_seed(cfg.seed, stream::ALTIMETER));
    let sigma = cfg.altimeter_noise_m();
    let noise = Normal::new(0.0, sigma).map_err(|e| SimError::InvalidConfig {
        field: "altimeter_sigma_m",
        value: sigma.to_string(),
        reason: e.to_string(),
    })?;
    let frames: Vec<FrameRecord> = poses
        .iter()
        .enumerate()
        .map(|(i, pose)| {
            let (t, _) = pose.to_translation_quaternion();
            let truth = t[2] - terrain.height_at(t[0], t[1]);
            FrameRecord {
                timestamp: i as f64 / rate,
                image: format!("images/{}", frame_name(i)),
                altitude: Some(truth + noise.sample(&mut rng)),
                ground_truth: Some(*pose),
            }
        })
        .collect();
    debug_assert_eq!(poses.len(), plan.path.samples.len());
    Ok(write_sequence(uav_dir, &frames)?)
}

fn write_file(path: &Path, bytes: &[u8]) -> Result<()> {
    let io = |source| SimError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).map_err(io)?);
    f.write_all(bytes).map_err(io)?;
    f.flush().map_err(io)
}

/// Writes an 8-bit grey PNG.
pub fn write_png(path: &Path, image: &Grid<u8>) -> Result<()> {
    Ok(write_grey_png(path, image)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::satellite::Difficulty;
    use crate::terrain::TerrainKind;

    #[test]
    fn plan_lays_the_terrain_under_the_map_pixels() {
        for (d, f) in [
            (Difficulty::Easy, 2),
            (Difficulty::Medium, 5),
            (Difficulty::Hard, 10),
        ] {
            let cfg = SimConfig {
                difficulty: d,
                ..Default::default()
            };
            let plan = plan_dataset(&cfg).unwrap();
            assert_eq!(plan.cells_per_pixel, f);
            let map = &plan.map;
            assert_eq!(plan.extent.width_cells, map.width_px as usize * f);
            // Mean of the first pixel's cell centres is world (0, 0).
            let c = cfg.terrain.cell_m;
            let mean_x = plan.extent.origin_x + (f as f64 - 1.0) / 2.0 * c;
            let mean_y = plan.extent.origin_y - (f as f64 - 1.0) / 2.0 * c;
            assert!(mean_x.abs() < 1e-12 && mean_y.abs() < 1e-12);
            // The path keeps the margin from the map edge.
            let (w, h) = map.extent_m();
            let m = cfg.effective_margin_m();
            let half = map.gsd_m / 2.0;
            for s in &plan.path.samples {
                assert!(s.x >= -half + m - 1e-6 && s.x <= w - half - m + 1e-6);
                assert!(-s.y >= -half + m - 1e-6 && -s.y <= h - half - m + 1e-6);
            }
            // Whole tiles.
            assert_eq!((map.width_px - 500) % 250, 0);
        }
    }

    #[test]
    fn suns_differ_by_the_preset_azimuth_change() {
        for seed in 0..5 {
            for d in Difficulty::ALL {
                let cfg = SimConfig {
                    seed,
                    difficulty: d,
                    ..Default::default()
                };
                let (uav, sat) = cfg.suns();
                let diff = (sat.azimuth_deg - uav.azimuth_deg).rem_euclid(360.0);
                let diff = diff.min(360.0 - diff);
                assert!((diff - d.satellite_config().sun_azimuth_change_deg).abs() < 1e-9);
                assert!((35.0..60.0).contains(&uav.elevation_deg));
            }
        }
    }

    #[test]
    fn a_larger_map_holds_the_flight_at_a_seeded_place() {
        let mut places = Vec::new();
        for seed in 0..3 {
            let cfg = SimConfig {
                seed,
                map_size_m: Some(200.0),
                ..Default::default()
            };
            let plan = plan_dataset(&cfg).unwrap();
            let map = &plan.map;
            assert_eq!((map.width_px, map.height_px), (4000, 4000));
            let p = plan.patch.expect("a patch");
            assert!(p.x_px + p.width_px <= map.width_px && p.y_px + p.height_px <= map.height_px);
            // The path keeps the margin and the blend band from the patch edge.
            let keep = cfg.effective_margin_m() + BLEND_BAND_M - map.gsd_m;
            let (x0, y0) = map.pixel_to_world(p.x_px as f64, p.y_px as f64);
            let (x1, y1) = map.pixel_to_world(
                (p.x_px + p.width_px) as f64 - 1.0,
                (p.y_px + p.height_px) as f64 - 1.0,
            );
            for s in &plan.path.samples {
                assert!(s.x >= x0 + keep && s.x <= x1 - keep, "x {}", s.x);
                assert!(s.y <= y0 - keep && s.y >= y1 + keep, "y {}", s.y);
            }
            assert_eq!(
                plan.extent.width_cells,
                p.width_px as usize * plan.cells_per_pixel
            );
            assert!(matches!(plan.layout, FeatureLayout::World { .. }));
            let scene = map.scene.as_ref().unwrap();
            assert_eq!(
                scene.detailed_region_px,
                Some([p.x_px, p.y_px, p.width_px, p.height_px])
            );
            places.push((p.x_px, p.y_px));
        }
        places.dedup();
        assert_eq!(places.len(), 3, "the place follows the seed");
    }

    #[test]
    fn a_map_smaller_than_the_flight_is_refused_with_the_size_it_needs() {
        let cfg = SimConfig {
            map_size_m: Some(60.0),
            ..Default::default()
        };
        let e = plan_dataset(&cfg).unwrap_err().to_string();
        assert!(
            e.contains("map_size_m") && e.contains("smaller than the flight"),
            "{e}"
        );
    }

    #[test]
    fn envelope_options_out_of_range_are_refused_naming_the_field() {
        let base = SimConfig::default();
        let cases: Vec<(SimConfig, &str)> = vec![
            (
                SimConfig {
                    map_size_m: Some(-5.0),
                    ..base.clone()
                },
                "map_size_m",
            ),
            (
                SimConfig {
                    map_size_m: Some(f64::NAN),
                    ..base.clone()
                },
                "map_size_m",
            ),
            (
                SimConfig {
                    map_size_m: Some(1.0e6),
                    ..base.clone()
                },
                "map_size_m",
            ),
            (
                SimConfig {
                    sun_azimuth_change_deg: Some(181.0),
                    ..base.clone()
                },
                "sun_azimuth_change_deg",
            ),
            (
                SimConfig {
                    sun_azimuth_change_deg: Some(-1.0),
                    ..base.clone()
                },
                "sun_azimuth_change_deg",
            ),
            (
                SimConfig {
                    sun_elevation_deg: Some(0.0),
                    ..base.clone()
                },
                "sun_elevation_deg",
            ),
            (
                SimConfig {
                    flight_sun_elevation_deg: Some(95.0),
                    ..base.clone()
                },
                "flight_sun_elevation_deg",
            ),
            (
                SimConfig {
                    altimeter_range_fraction: -0.1,
                    ..base.clone()
                },
                "altimeter_range_fraction",
            ),
        ];
        for (cfg, field) in cases {
            let e = cfg.validate().unwrap_err().to_string();
            assert!(e.contains(field), "{field}: {e}");
        }
        let mut high = base.clone();
        high.trajectory.altitude_m = 800.0;
        assert!(
            high.validate()
                .unwrap_err()
                .to_string()
                .contains("altitude_m")
        );
    }

    #[test]
    fn the_mars_preset_draws_its_suns_and_obeys_overrides() {
        for seed in 0..20 {
            let cfg = SimConfig {
                seed,
                difficulty: Difficulty::Mars,
                ..Default::default()
            };
            let (uav, sat) = cfg.suns();
            let change = (sat.azimuth_deg - uav.azimuth_deg).rem_euclid(360.0);
            let change = change.min(360.0 - change);
            assert!((30.0 - 1e-9..=180.0 + 1e-9).contains(&change), "{change}");
            assert!((35.0..=45.0).contains(&sat.elevation_deg));
            assert!((15.0..=60.0).contains(&uav.elevation_deg));
            assert_eq!(cfg.effective_map_size_m(), Some(MARS_MAP_SIZE_M));
            let fixed = SimConfig {
                sun_azimuth_change_deg: Some(180.0),
                sun_elevation_deg: Some(40.0),
                flight_sun_elevation_deg: Some(20.0),
                ..cfg
            };
            let (uav, sat) = fixed.suns();
            let change = (sat.azimuth_deg - uav.azimuth_deg).rem_euclid(360.0);
            assert!((change - 180.0).abs() < 1e-9);
            assert_eq!((sat.elevation_deg, uav.elevation_deg), (40.0, 20.0));
        }
    }

    #[test]
    fn terrain_detail_and_altimeter_noise_follow_the_altitude() {
        let at = |difficulty, altitude_m| {
            let mut cfg = SimConfig {
                difficulty,
                ..Default::default()
            };
            cfg.trajectory.altitude_m = altitude_m;
            cfg
        };
        // At 10 m every preset keeps the 2.5 cm cell and the 10 cm altimeter.
        for d in Difficulty::ALL {
            assert_eq!(at(d, 10.0).terrain_cell_m(), 0.025);
            assert_eq!(at(d, 10.0).altimeter_noise_m(), 0.1);
        }
        assert!((at(Difficulty::Hard, 200.0).terrain_cell_m() - 0.25).abs() < 1e-12);
        assert!((at(Difficulty::Hard, 50.0).terrain_cell_m() - 0.125).abs() < 1e-12);
        assert!((at(Difficulty::Easy, 100.0).terrain_cell_m() - 0.05).abs() < 1e-12);
        assert!((at(Difficulty::Hard, 200.0).altimeter_noise_m() - 1.0).abs() < 1e-12);
        for a in [10.0, 25.0, 50.0, 100.0, 200.0] {
            let cfg = at(Difficulty::Hard, a);
            let gsd = cfg.satellite_config().gsd_m;
            let n = gsd / cfg.terrain_cell_m();
            assert!((n - n.round()).abs() < 1e-9, "{a} m: {n}");
            plan_dataset(&cfg).unwrap();
        }
    }

    #[test]
    fn sub_seeds_differ() {
        let a: Vec<u64> = (0..8).map(|s| sub_seed(1, s)).collect();
        let mut b = a.clone();
        b.sort();
        b.dedup();
        assert_eq!(a.len(), b.len());
        assert_ne!(sub_seed(1, 1), sub_seed(2, 1));
    }

    #[test]
    fn config_round_trips_through_toml() {
        let cfg = SimConfig {
            seed: 9,
            terrain_kind: TerrainKind::Gravel,
            difficulty: Difficulty::Hard,
            ..Default::default()
        };
        let text = toml::to_string(&cfg).unwrap();
        let back: SimConfig = toml::from_str(&text).unwrap();
        assert_eq!(back, cfg);
        let partial: SimConfig =
            toml::from_str("seed = 3\n[trajectory]\nlength_m = 20.0\n").unwrap();
        assert_eq!(partial.seed, 3);
        assert_eq!(partial.trajectory.length_m, 20.0);
        assert_eq!(partial.trajectory.rate_hz, 5.0);
    }
}
