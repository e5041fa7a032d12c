//! `map.toml`: the georeference of the satellite map and its tiles, the single place where
//! map pixels meet world metres. The absolute localisation reads it; the simulator writes it.
//!
//! Convention: world x east, y north, z up, metres; the world origin is the centre of the
//! map's top-left pixel, and map pixel `(u, v)` (OpenCV: integer coordinates are pixel centres)
//! is at world `(u · gsd, −v · gsd)`. Tiles are windows of the map of the UAV image's size,
//! laid out row-major with a stride of `size · (1 − overlap)`; tile files are named
//! `<idx>_<x>_<y>.png` where `(x, y)` is the tile's top-left pixel in `satellite.png`. The
//! optional `[elevation]` section describes the elevation model ([`crate::elevation`]), the
//! optional `[scene]` section how a simulated map was made.
//!
//! Reading validates everything (version, GSD, tile layout, elevation section): a bad file is
//! an error naming it (and the line, for a TOML syntax or type error).

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::elevation::ElevationInfo;
use crate::error::{FormatError, Result};
use crate::outputs::{read_text, write_text};

/// Version of the `map.toml` layout written by this crate.
pub const MAP_FORMAT_VERSION: u32 = 1;

/// Georeference of an orthographic map and its tiles.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MapInfo {
    /// Layout version ([`MAP_FORMAT_VERSION`]).
    pub format_version: u32,
    /// The map image, relative to the dataset folder.
    pub image: String,
    /// Ground sampling distance, metres per pixel (square pixels).
    pub gsd_m: f64,
    /// Map size in pixels.
    pub width_px: u32,
    pub height_px: u32,
    /// Always `"pixel-center"`: world (0, 0) is the centre of pixel (0, 0).
    pub origin: String,
    pub tiles: TileGrid,
    /// The terrain's elevation model, when the map has one: fixes then get
    /// z = DEM(x, y) + altimeter instead of assuming flat ground at z = 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub elevation: Option<ElevationInfo>,
    /// How the map was made (absent for maps not from the simulator).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scene: Option<SceneInfo>,
    /// The map's coordinate reference system and where world (0, 0) lies in it (maps
    /// imported from GeoTIFF; absent: the map has only its local frame).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub crs: Option<MapCrs>,
    /// The sun when the map was taken (a HiRISE label's sub-solar azimuth and incidence
    /// angle give it): the localiser relights the map to the flight's sun with the elevation
    /// model. Simulated maps record it as `[scene.satellite_sun]` instead.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sun: Option<SunInfo>,
}

/// The CRS of an imported map. The world frame is the CRS translated: easting
/// `= easting_m + x`, northing `= northing_m + y`, both metres (x east, y north).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MapCrs {
    /// EPSG code, when the source names one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub epsg: Option<u32>,
    /// The CRS's description as the source gave it (GeoTIFF citation), when present.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub citation: Option<String>,
    /// The projection's GeoKeys as `name=value` text: the CRS's definition when it has no
    /// EPSG code (Mars CRSs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub geokeys: Option<String>,
    /// Easting and northing of world (0, 0): the centre of map pixel (0, 0).
    pub easting_m: f64,
    pub northing_m: f64,
    /// The file the map was imported from (its name only).
    pub source: String,
}

impl MapCrs {
    /// Map coordinates (easting, northing) of world `(x, y)`.
    pub fn world_to_map(&self, x: f64, y: f64) -> (f64, f64) {
        (self.easting_m + x, self.northing_m + y)
    }
}

/// Layout of the tiles.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TileGrid {
    /// Folder of the tile images, relative to the dataset folder.
    pub dir: String,
    /// Tile size in pixels (the UAV image size).
    pub width_px: u32,
    pub height_px: u32,
    /// Overlap ratio of neighbouring tiles.
    pub overlap: f64,
    /// Distance between neighbouring tiles' top-left pixels.
    pub stride_x_px: u32,
    pub stride_y_px: u32,
    /// Tiles per row and per column.
    pub cols: u32,
    pub rows: u32,
}

/// Scene parameters of a simulated map: informative, so the names are kept as written.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneInfo {
    pub generator: String,
    /// Terrain kind (the simulator's: `crater`, `gravel`, `mountain`).
    pub terrain: String,
    /// Difficulty preset (the simulator's: `easy`, `medium`, `hard`).
    pub difficulty: String,
    pub seed: u64,
    /// Terrain cell size, metres.
    pub terrain_cell_m: f64,
    /// Sun during the UAV flight and when the map was taken.
    pub uav_sun: SunInfo,
    pub satellite_sun: SunInfo,
    /// In a map larger than the flight, the pixel rectangle `[x, y, width, height]` whose
    /// terrain has the UAV's detail (the flight is inside it); elsewhere the map was rendered
    /// from a terrain with one cell per pixel.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub detailed_region_px: Option<[u32; 4]>,
}

/// Sun position seen from the terrain.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SunInfo {
    /// Clockwise from north (+y) towards east (+x), degrees.
    pub azimuth_deg: f64,
    /// Above the horizon, degrees.
    pub elevation_deg: f64,
}

impl SunInfo {
    /// A finite azimuth and an elevation in (0, 90] degrees: a sun that lights the terrain.
    pub fn is_valid(&self) -> bool {
        self.azimuth_deg.is_finite() && self.elevation_deg > 0.0 && self.elevation_deg <= 90.0
    }
}

/// One tile: a window of the map.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Tile {
    /// Row-major index, from 0.
    pub index: usize,
    /// Top-left pixel in the map.
    pub x: u32,
    pub y: u32,
    pub width: u32,
    pub height: u32,
}

impl Tile {
    /// `<idx>_<x>_<y>.png`.
    pub fn file_name(&self) -> String {
        format!("{}_{}_{}.png", self.index, self.x, self.y)
    }

    /// Map pixel of the tile's centre.
    pub fn centre_px(&self) -> (f64, f64) {
        (
            self.x as f64 + (self.width as f64 - 1.0) / 2.0,
            self.y as f64 + (self.height as f64 - 1.0) / 2.0,
        )
    }
}

/// Start offsets of windows of size `tile` with `stride` covering `len`: the last one is
/// moved flush with the end when the stride does not divide.
/// (`tile <= len`, `stride > 0`; in `u64` so that strides near `u32::MAX` cannot overflow.)
fn offsets(len: u32, tile: u32, stride: u32) -> Vec<u32> {
    let mut out = Vec::new();
    let mut x = 0u64;
    while x + u64::from(tile) < u64::from(len) {
        out.push(x as u32);
        x += u64::from(stride);
    }
    out.push(len - tile);
    out.dedup();
    out
}

/// How many offsets [`offsets`] gives, without building them (same preconditions).
fn offset_count(len: u32, tile: u32, stride: u32) -> u64 {
    u64::from(len - tile).div_ceil(u64::from(stride)) + 1
}

/// Most tiles a `map.toml` may declare: checked before any per-tile allocation.
pub const MAX_TILES: u64 = 1 << 20;

/// Most pixels a map may have (65536 × 65536): checked before the map image is allocated.
pub const MAX_MAP_PIXELS: u64 = 1 << 32;

/// Stride of tiles of `size` with `overlap`.
pub fn tile_stride(size: u32, overlap: f64) -> u32 {
    ((size as f64 * (1.0 - overlap)).round() as u32).max(1)
}

/// Smallest map length ≥ `need` that tiles of `size` with `stride` cover exactly.
pub fn covered_length(need: u32, size: u32, stride: u32) -> u32 {
    if need <= size {
        size
    } else {
        size + (need - size).div_ceil(stride) * stride
    }
}

impl MapInfo {
    /// A map of `width × height` pixels at `gsd_m`, tiled with `tile_w × tile_h` windows.
    pub fn new(
        gsd_m: f64,
        width_px: u32,
        height_px: u32,
        tile_w: u32,
        tile_h: u32,
        overlap: f64,
    ) -> Result<Self> {
        let (sx, sy) = (tile_stride(tile_w, overlap), tile_stride(tile_h, overlap));
        let info = Self {
            format_version: MAP_FORMAT_VERSION,
            image: "satellite.png".into(),
            gsd_m,
            width_px,
            height_px,
            origin: "pixel-center".into(),
            tiles: TileGrid {
                dir: "satellite".into(),
                width_px: tile_w,
                height_px: tile_h,
                overlap,
                stride_x_px: sx,
                stride_y_px: sy,
                cols: if width_px >= tile_w {
                    offsets(width_px, tile_w, sx).len() as u32
                } else {
                    0
                },
                rows: if height_px >= tile_h {
                    offsets(height_px, tile_h, sy).len() as u32
                } else {
                    0
                },
            },
            elevation: None,
            scene: None,
            crs: None,
            sun: None,
        };
        info.validate(Path::new("map.toml"))?;
        Ok(info)
    }

    /// The sun the map was taken under: `[sun]`, else a simulated map's
    /// `[scene.satellite_sun]`.
    pub fn acquisition_sun(&self) -> Option<SunInfo> {
        self.sun
            .or_else(|| self.scene.as_ref().map(|s| s.satellite_sun))
    }

    /// World `(x, y)` of map pixel `(u, v)`.
    pub fn pixel_to_world(&self, u: f64, v: f64) -> (f64, f64) {
        (u * self.gsd_m, -v * self.gsd_m)
    }

    /// Map pixel `(u, v)` of world `(x, y)`.
    pub fn world_to_pixel(&self, x: f64, y: f64) -> (f64, f64) {
        (x / self.gsd_m, -y / self.gsd_m)
    }

    /// Map size in metres (edge to edge).
    pub fn extent_m(&self) -> (f64, f64) {
        (
            self.width_px as f64 * self.gsd_m,
            self.height_px as f64 * self.gsd_m,
        )
    }

    /// All tiles, row-major.
    pub fn tile_list(&self) -> Vec<Tile> {
        let t = &self.tiles;
        let xs = offsets(self.width_px, t.width_px, t.stride_x_px);
        let ys = offsets(self.height_px, t.height_px, t.stride_y_px);
        let mut out = Vec::with_capacity(xs.len() * ys.len());
        for &y in &ys {
            for &x in &xs {
                out.push(Tile {
                    index: out.len(),
                    x,
                    y,
                    width: t.width_px,
                    height: t.height_px,
                });
            }
        }
        out
    }

    /// Checks the values; `path` is used in error messages.
    pub fn validate(&self, path: &Path) -> Result<()> {
        let err = |message: String| FormatError::invalid(path, message);
        if self.format_version != MAP_FORMAT_VERSION {
            return Err(err(format!(
                "format_version {} is not supported (expected {MAP_FORMAT_VERSION})",
                self.format_version
            )));
        }
        if !(self.gsd_m.is_finite() && self.gsd_m > 0.0) {
            return Err(err(format!("gsd_m must be positive, got {}", self.gsd_m)));
        }
        if let Some(sun) = &self.sun
            && !sun.is_valid()
        {
            return Err(err(format!(
                "[sun] needs a finite azimuth_deg and an elevation_deg in (0, 90], got {} / {}",
                sun.azimuth_deg, sun.elevation_deg
            )));
        }
        if self.origin != "pixel-center" {
            return Err(err(format!(
                "origin `{}` is not supported (expected `pixel-center`)",
                self.origin
            )));
        }
        let t = &self.tiles;
        if t.width_px == 0
            || t.height_px == 0
            || t.width_px > self.width_px
            || t.height_px > self.height_px
        {
            return Err(err(format!(
                "tile size {}x{} must be non-zero and fit the map {}x{}",
                t.width_px, t.height_px, self.width_px, self.height_px
            )));
        }
        if !(0.0..1.0).contains(&t.overlap) || t.stride_x_px == 0 || t.stride_y_px == 0 {
            return Err(err(format!(
                "overlap {} must be in [0, 1) and strides non-zero",
                t.overlap
            )));
        }
        let pixels = u64::from(self.width_px) * u64::from(self.height_px);
        if pixels > MAX_MAP_PIXELS {
            return Err(err(format!(
                "map of {}x{} px is larger than the {MAX_MAP_PIXELS} pixels supported",
                self.width_px, self.height_px
            )));
        }
        // Counted, not listed: a hostile layout (1-px tiles on a huge map) must not allocate.
        let (cols, rows) = (
            offset_count(self.width_px, t.width_px, t.stride_x_px),
            offset_count(self.height_px, t.height_px, t.stride_y_px),
        );
        if (cols, rows) != (u64::from(t.cols), u64::from(t.rows)) {
            return Err(err(format!(
                "tiles.cols/rows = {}/{} disagree with the layout ({cols}/{rows})",
                t.cols, t.rows
            )));
        }
        if cols * rows > MAX_TILES {
            return Err(err(format!(
                "{cols}x{rows} tiles is more than the {MAX_TILES} supported"
            )));
        }
        if let Some(e) = &self.elevation {
            e.validate(path)?;
        }
        Ok(())
    }

    /// The file's text: a comment stating the convention, then the TOML.
    pub fn to_toml_string(&self) -> String {
        let body =
            toml::to_string(self).unwrap_or_else(|e| format!("# serialisation failed: {e}\n"));
        format!(
            "# Georeference of satellite.png (jointloc map format {MAP_FORMAT_VERSION}).\n\
             # World frame: x east, y north, z up, metres. World (0, 0) is the centre of map pixel\n\
             # (0, 0); pixel (u, v) is at world (u * gsd_m, -v * gsd_m).\n\
             # Tiles: satellite/<idx>_<x>_<y>.png, idx row-major from 0, (x, y) = top-left pixel\n\
             # of the tile in satellite.png.\n\n{body}"
        )
    }

    /// Writes `map.toml`.
    pub fn write(&self, path: &Path) -> Result<()> {
        write_text(path, &self.to_toml_string())
    }

    /// Reads and validates `map.toml`.
    pub fn read(path: &Path) -> Result<Self> {
        Self::parse(&read_text(path)?, path)
    }

    /// Parses and validates the text of a `map.toml`.
    pub fn parse(text: &str, path: &Path) -> Result<Self> {
        let info: MapInfo = toml::from_str(text).map_err(|e| {
            FormatError::parse(
                path,
                e.span().map_or(0, |s| {
                    text[..s.start.min(text.len())].lines().count().max(1)
                }),
                e.message(),
            )
        })?;
        info.validate(path)?;
        Ok(info)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_cover_the_map_with_half_overlap() {
        let w = covered_length(1234, 500, 250);
        assert_eq!(w, 1250);
        assert_eq!(covered_length(300, 500, 250), 500);
        let info = MapInfo::new(0.05, 1250, 750, 500, 500, 0.5).unwrap();
        let tiles = info.tile_list();
        assert_eq!((info.tiles.cols, info.tiles.rows), (4, 2));
        assert_eq!(tiles.len(), 8);
        assert_eq!(tiles[5].file_name(), "5_250_250.png");
        assert_eq!(tiles.last().unwrap().x + 500, 1250);
        // Every pixel is in some tile.
        for (u, v) in [(0, 0), (1249, 749), (600, 10), (10, 600)] {
            assert!(
                tiles
                    .iter()
                    .any(|t| u >= t.x && u < t.x + t.width && v >= t.y && v < t.y + t.height)
            );
        }
    }

    #[test]
    fn pixel_world_round_trip() {
        let info = MapInfo::new(0.125, 750, 500, 500, 500, 0.5).unwrap();
        assert_eq!(info.pixel_to_world(0.0, 0.0), (0.0, 0.0));
        assert_eq!(info.pixel_to_world(8.0, 4.0), (1.0, -0.5));
        let (u, v) = info.world_to_pixel(1.0, -0.5);
        assert!((u - 8.0).abs() < 1e-12 && (v - 4.0).abs() < 1e-12);
    }

    #[test]
    fn toml_round_trips_and_rejects_inconsistency() {
        let mut info = MapInfo::new(0.05, 1000, 750, 500, 500, 0.5).unwrap();
        info.scene = Some(SceneInfo {
            generator: "test".into(),
            terrain: "crater".into(),
            difficulty: "medium".into(),
            seed: 7,
            terrain_cell_m: 0.025,
            uav_sun: SunInfo {
                azimuth_deg: 120.0,
                elevation_deg: 45.0,
            },
            satellite_sun: SunInfo {
                azimuth_deg: 75.0,
                elevation_deg: 35.0,
            },
            detailed_region_px: Some([100, 50, 400, 300]),
        });
        let text = info.to_toml_string();
        let back = MapInfo::parse(&text, Path::new("map.toml")).unwrap();
        assert_eq!(back, info);
        let broken = text.replace("cols = 3", "cols = 4");
        assert!(MapInfo::parse(&broken, Path::new("map.toml")).is_err());
        let garbage = text.replace("gsd_m = 0.05", "gsd_m = \"x\"");
        let e = MapInfo::parse(&garbage, Path::new("map.toml")).unwrap_err();
        let line = garbage
            .lines()
            .position(|l| l.starts_with("gsd_m"))
            .unwrap()
            + 1;
        assert!(
            e.to_string().starts_with(&format!("map.toml:{line}:")),
            "{e}"
        );
    }

    #[test]
    fn the_maps_sun_is_read_and_checked() {
        let mut info = MapInfo::new(0.25, 1000, 750, 500, 500, 0.5).unwrap();
        assert_eq!(info.acquisition_sun(), None);
        info.sun = Some(SunInfo {
            azimuth_deg: 348.5,
            elevation_deg: 43.0,
        });
        let text = info.to_toml_string();
        let back = MapInfo::parse(&text, Path::new("map.toml")).unwrap();
        assert_eq!(back.acquisition_sun(), info.sun);
        let below = text.replace("elevation_deg = 43.0", "elevation_deg = -3.0");
        let e = MapInfo::parse(&below, Path::new("map.toml")).unwrap_err();
        assert!(e.to_string().contains("[sun]"), "{e}");
    }

    #[test]
    fn file_round_trips_and_bad_files_name_themselves() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("map.toml");
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
        info.write(&path).unwrap();
        assert_eq!(MapInfo::read(&path).unwrap(), info);
        // Missing file.
        let e = MapInfo::read(&dir.path().join("absent.toml")).unwrap_err();
        assert!(matches!(e, FormatError::Io { .. }), "{e}");
        assert!(e.to_string().contains("absent.toml"), "{e}");
        // A value out of range: the file is named.
        let text = info
            .to_toml_string()
            .replace("gsd_m = 0.05", "gsd_m = -0.05");
        std::fs::write(&path, text).unwrap();
        let e = MapInfo::read(&path).unwrap_err();
        assert!(matches!(e, FormatError::Invalid { .. }), "{e}");
        assert!(
            e.to_string().contains("map.toml") && e.to_string().contains("gsd_m"),
            "{e}"
        );
    }
}
