//! `jointloc map import`: a GeoTIFF orthoimage (and optionally its DTM) into jointloc's map
//! folder: `satellite.png`, its tiles, `elevation.png` and `map.toml` with the CRS.
//!
//! - The orthoimage keeps its pixels: 8-bit images as they are; 16-bit and float images are
//!   stretched linearly between their 0.1 % and 99.9 % quantiles (HiRISE products are 10-bit
//!   in 16-bit words). Nodata pixels become 0 and are counted.
//! - The DTM keeps its own grid (its posts need not coincide with the map's pixels): its
//!   georeference is expressed in the map's world frame, which `[elevation]` of `map.toml`
//!   supports, so no resampling is needed. It must be north-up in the same CRS. Nodata posts are
//!   filled from their nearest valid neighbour along the row (then the column) and counted.
//! - World frame: x east, y north, metres, (0, 0) at the centre of map pixel (0, 0); `[crs]`
//!   of `map.toml` gives the map coordinates of that point and the CRS.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::elevation::{ElevationInfo, quantise_heights, write_elevation_png, write_grey_png};
use crate::error::{FormatError, Result};
use crate::geotiff::{GeoRaster, Samples, read_geotiff};
use crate::grid::Grid;
use crate::map_toml::{MapCrs, MapInfo, SunInfo};

/// Settings of the import.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct MapImportConfig {
    /// Tile size in pixels: the UAV image's size (the matcher compares a frame with a tile).
    pub tile_width_px: u32,
    pub tile_height_px: u32,
    /// Overlap of neighbouring tiles (0.5: stride = half a tile).
    pub tile_overlap: f64,
    /// Stated vertical precision of the DTM (1 σ), metres: the weight of the ground
    /// constraints (HiRISE DTMs: a few decimetres).
    pub dem_sigma_m: f64,
    /// The sun when the image was taken, written as `map.toml`'s `[sun]`: with the DTM, the
    /// localiser relights the map to the flight's sun.
    pub sun: Option<SunInfo>,
}

impl Default for MapImportConfig {
    fn default() -> Self {
        Self {
            tile_width_px: 500,
            tile_height_px: 500,
            tile_overlap: 0.5,
            dem_sigma_m: 0.25,
            sun: None,
        }
    }
}

/// What was written.
#[derive(Debug, Clone, PartialEq)]
pub struct ImportReport {
    pub map: MapInfo,
    pub tiles: usize,
    /// Orthoimage pixels that were nodata (written as 0).
    pub nodata_pixels: usize,
    /// DTM posts that were nodata (filled from neighbours).
    pub dem_nodata_posts: usize,
}

/// The files an import writes into `out`.
pub const IMPORT_FILES: [&str; 4] = ["map.toml", "satellite.png", "satellite", "elevation.png"];

/// Imports `image` (and `dem`) into the map folder `out` (created if missing). Existing map
/// files there are an error unless `overwrite`.
pub fn import_map(
    image: &Path,
    dem: Option<&Path>,
    out: &Path,
    cfg: &MapImportConfig,
    overwrite: bool,
) -> Result<ImportReport> {
    check_config(cfg, out)?;
    for name in IMPORT_FILES {
        let p = out.join(name);
        if p.exists() && !overwrite {
            return Err(FormatError::invalid(
                &p,
                "exists: give --force to replace the map in this folder",
            ));
        }
    }
    let ortho = read_geotiff(image)?;
    let (pixels, nodata_pixels) = to_grey(&ortho);
    let (w, h) = (ortho.width as u32, ortho.height as u32);
    if w < cfg.tile_width_px || h < cfg.tile_height_px {
        return Err(FormatError::invalid(
            image,
            format!(
                "{w} × {h} pixels is smaller than one {} × {} tile",
                cfg.tile_width_px, cfg.tile_height_px
            ),
        ));
    }
    let t = ortho.transform;
    let mut map = MapInfo::new(
        t.pixel_m,
        w,
        h,
        cfg.tile_width_px,
        cfg.tile_height_px,
        cfg.tile_overlap,
    )?;
    map.sun = cfg.sun;
    map.crs = Some(MapCrs {
        epsg: ortho.crs.epsg,
        citation: ortho.crs.citation.clone(),
        geokeys: ortho.crs.geokeys.clone(),
        easting_m: t.easting_m,
        northing_m: t.northing_m,
        source: file_name(image),
    });
    let dem = dem
        .map(|p| import_dem(p, &ortho, cfg.dem_sigma_m))
        .transpose()?;
    drop(ortho);

    std::fs::create_dir_all(out).map_err(|e| FormatError::io(out, e))?;
    let tiles_dir = out.join(&map.tiles.dir);
    if tiles_dir.is_dir() {
        std::fs::remove_dir_all(&tiles_dir).map_err(|e| FormatError::io(&tiles_dir, e))?;
    }
    std::fs::create_dir_all(&tiles_dir).map_err(|e| FormatError::io(&tiles_dir, e))?;
    let grid = Grid {
        width: w as usize,
        height: h as usize,
        data: pixels,
    };
    write_grey_png(&out.join(&map.image), &grid)?;
    let tiles = map.tile_list();
    for tile in &tiles {
        let window = grid.window(
            tile.x as usize,
            tile.y as usize,
            tile.width as usize,
            tile.height as usize,
        );
        write_grey_png(&tiles_dir.join(tile.file_name()), &window)?;
    }
    let mut dem_nodata_posts = 0;
    if let Some((info, posts, filled)) = dem {
        write_elevation_png(&out.join(&info.image), &posts)?;
        map.elevation = Some(info);
        dem_nodata_posts = filled;
    }
    map.write(&out.join("map.toml"))?;
    Ok(ImportReport {
        map,
        tiles: tiles.len(),
        nodata_pixels,
        dem_nodata_posts,
    })
}

fn check_config(cfg: &MapImportConfig, out: &Path) -> Result<()> {
    let bad = |m: String| FormatError::invalid(out, m);
    if cfg.tile_width_px < 16 || cfg.tile_height_px < 16 {
        return Err(bad("tiles must be at least 16 × 16 pixels".into()));
    }
    if !(0.0..0.95).contains(&cfg.tile_overlap) {
        return Err(bad(format!(
            "tile overlap {} must be in [0, 0.95)",
            cfg.tile_overlap
        )));
    }
    if !(cfg.dem_sigma_m.is_finite() && cfg.dem_sigma_m > 0.0) {
        return Err(bad(format!(
            "DEM σ {} must be a positive number of metres",
            cfg.dem_sigma_m
        )));
    }
    Ok(())
}

fn file_name(p: &Path) -> String {
    p.file_name().map_or_else(
        || p.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

fn is_nodata(v: f64, nodata: Option<f64>) -> bool {
    !v.is_finite() || nodata.is_some_and(|n| v == n)
}

/// 8-bit grey pixels of the orthoimage and the count of nodata pixels.
fn to_grey(r: &GeoRaster) -> (Vec<u8>, usize) {
    if let Samples::U8(v) = &r.samples
        && r.nodata.is_none()
    {
        return (v.clone(), 0);
    }
    let n = r.width * r.height;
    let nodata = (0..n)
        .filter(|&i| is_nodata(r.samples.get(i), r.nodata))
        .count();
    // Linear stretch between the 0.1 % and 99.9 % quantiles of the valid pixels (a sample
    // of at most 1 M of them).
    let step = (n / 1_000_000).max(1);
    let mut sample: Vec<f64> = (0..n)
        .step_by(step)
        .map(|i| r.samples.get(i))
        .filter(|&v| !is_nodata(v, r.nodata))
        .collect();
    sample.sort_by(f64::total_cmp);
    let q = |f: f64| {
        sample
            .get(((sample.len() as f64 - 1.0) * f).round() as usize)
            .copied()
            .unwrap_or(0.0)
    };
    let (lo, hi) = match &r.samples {
        Samples::U8(_) => (0.0, 255.0),
        _ => (q(0.001), q(0.999)),
    };
    let span = (hi - lo).max(f64::MIN_POSITIVE);
    let pixels = (0..n)
        .map(|i| {
            let v = r.samples.get(i);
            if is_nodata(v, r.nodata) {
                0
            } else {
                ((v - lo) / span * 255.0).round().clamp(0.0, 255.0) as u8
            }
        })
        .collect();
    (pixels, nodata)
}

/// The DTM's section of `map.toml`, its 16-bit posts and the number of filled nodata posts.
fn import_dem(
    path: &Path,
    ortho: &GeoRaster,
    sigma_m: f64,
) -> Result<(ElevationInfo, Grid<u16>, usize)> {
    let dem = read_geotiff(path)?;
    if let (Some(a), Some(b)) = (dem.crs.epsg, ortho.crs.epsg)
        && a != b
    {
        return Err(FormatError::invalid(
            path,
            format!("the DTM is in EPSG:{a}, the orthoimage in EPSG:{b}: reproject one of them"),
        ));
    }
    let (w, h) = (dem.width, dem.height);
    let mut metres: Vec<f64> = (0..w * h).map(|i| dem.samples.get(i)).collect();
    let mut valid: Vec<bool> = metres.iter().map(|&v| !is_nodata(v, dem.nodata)).collect();
    let missing = valid.iter().filter(|v| !**v).count();
    if missing == w * h {
        return Err(FormatError::invalid(
            path,
            "every post of the DTM is nodata",
        ));
    }
    fill_nodata(&mut metres, &mut valid, w, h);
    let (offset_m, scale_m, data) = quantise_heights(&metres);
    let (o, d) = (ortho.transform, dem.transform);
    let info = ElevationInfo {
        image: "elevation.png".into(),
        gsd_m: d.pixel_m,
        width_px: w as u32,
        height_px: h as u32,
        origin_x_m: d.easting_m - o.easting_m,
        origin_y_m: d.northing_m - o.northing_m,
        offset_m,
        scale_m,
        sigma_m,
    };
    info.validate(&PathBuf::from(path))?;
    Ok((
        info,
        Grid {
            width: w,
            height: h,
            data,
        },
        missing,
    ))
}

/// Fills invalid posts from the nearest valid one along their row, then along their column
/// (rows with no valid post at all).
fn fill_nodata(v: &mut [f64], valid: &mut [bool], w: usize, h: usize) {
    let pass = |v: &mut [f64],
                valid: &mut [bool],
                len: usize,
                stride: usize,
                lines: usize,
                step: usize| {
        for line in 0..lines {
            let idx = |k: usize| line * step + k * stride;
            let known: Vec<usize> = (0..len).filter(|&k| valid[idx(k)]).collect();
            if known.is_empty() {
                continue;
            }
            let mut next = 0;
            for k in 0..len {
                if valid[idx(k)] {
                    continue;
                }
                while next + 1 < known.len() && known[next + 1] < k {
                    next += 1;
                }
                let a = known[next];
                let nearest = known
                    .get(next + 1)
                    .copied()
                    .filter(|&b| b.abs_diff(k) < a.abs_diff(k))
                    .unwrap_or(a);
                v[idx(k)] = v[idx(nearest)];
            }
            for k in 0..len {
                valid[idx(k)] = true;
            }
        }
    };
    pass(v, valid, w, 1, h, w);
    pass(v, valid, h, w, w, 1);
}
