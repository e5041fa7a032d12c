//! The map's elevation model (DEM/DTM): terrain height on a regular grid in the map's world
//! frame. The altimeter measures height above the ground, so without it an absolute fix's z
//! can only assume flat ground at z = 0; with it, z = DEM(x, y) + altimeter.
//!
//! Stored as a 16-bit grey PNG beside `satellite.png` (16 bits keep millimetre steps over
//! 65 m of relief, losslessly) and described by the optional `[elevation]` section of
//! `map.toml`: height = `offset_m + value · scale_m`; post `(i, j)`
//! (column, row) is at world `(origin_x_m + i · gsd_m, origin_y_m − j · gsd_m)`, rows run south
//! like map pixels. Orbital DTMs are coarser than their ortho-images (HiRISE: 1 m posts under
//! 25 cm images), which is why the DEM has its own grid.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::{FormatError, Result};
use crate::grid::Grid;

/// The `[elevation]` section of `map.toml`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ElevationInfo {
    /// 16-bit grey PNG, relative to the dataset folder.
    pub image: String,
    /// Post spacing, metres.
    pub gsd_m: f64,
    /// Grid size in posts.
    pub width_px: u32,
    pub height_px: u32,
    /// World (x, y) of post (0, 0), metres.
    pub origin_x_m: f64,
    pub origin_y_m: f64,
    /// Height of value 0, metres.
    pub offset_m: f64,
    /// Metres per unit of the 16-bit value.
    pub scale_m: f64,
    /// Stated vertical precision (1 σ), metres; informative.
    #[serde(default)]
    pub sigma_m: f64,
}

impl ElevationInfo {
    /// Checks the values; `path` (the `map.toml`) is used in error messages.
    pub fn validate(&self, path: &Path) -> Result<()> {
        let err = |message: String| FormatError::invalid(path, format!("[elevation] {message}"));
        for (name, v) in [("gsd_m", self.gsd_m), ("scale_m", self.scale_m)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(err(format!("{name} must be positive, got {v}")));
            }
        }
        for (name, v) in [
            ("origin_x_m", self.origin_x_m),
            ("origin_y_m", self.origin_y_m),
            ("offset_m", self.offset_m),
            ("sigma_m", self.sigma_m),
        ] {
            if !v.is_finite() {
                return Err(err(format!("{name} must be finite, got {v}")));
            }
        }
        if self.width_px == 0 || self.height_px == 0 {
            return Err(err(format!(
                "grid {}x{} must not be empty",
                self.width_px, self.height_px
            )));
        }
        if self.image.is_empty() {
            return Err(err("image must name a file".into()));
        }
        Ok(())
    }
}

/// A loaded elevation model.
#[derive(Debug, Clone)]
pub struct ElevationModel {
    pub info: ElevationInfo,
    heights: Grid<f32>,
}

impl ElevationModel {
    /// Reads `root/info.image` and checks it against `info`.
    pub fn read(info: &ElevationInfo, root: &Path) -> Result<Self> {
        let path = root.join(&info.image);
        let bad = |message: String| FormatError::invalid(&path, message);
        let image = image::open(&path)
            .map_err(|e| match e {
                image::ImageError::IoError(source) => FormatError::io(&path, source),
                other => bad(other.to_string()),
            })?
            .into_luma16();
        if image.dimensions() != (info.width_px, info.height_px) {
            return Err(bad(format!(
                "elevation image is {}x{} but map.toml says {}x{}",
                image.width(),
                image.height(),
                info.width_px,
                info.height_px
            )));
        }
        let data = image
            .as_raw()
            .iter()
            .map(|&v| (info.offset_m + v as f64 * info.scale_m) as f32)
            .collect();
        Ok(Self {
            info: info.clone(),
            heights: Grid {
                width: info.width_px as usize,
                height: info.height_px as usize,
                data,
            },
        })
    }

    /// A model from heights in metres already in memory, one per post (row-major, rows run
    /// south); `None` when the grid's size is not the one `info` states.
    pub fn from_heights(info: ElevationInfo, heights: Grid<f32>) -> Option<Self> {
        let fits = heights.width == info.width_px as usize
            && heights.height == info.height_px as usize
            && heights.data.len() == heights.width * heights.height;
        fits.then_some(Self { info, heights })
    }

    /// The heights, metres, one per post (row-major, rows run south).
    pub fn heights(&self) -> &Grid<f32> {
        &self.heights
    }

    /// Bilinear height at world (x, y), clamped at the border of the grid.
    pub fn height_at(&self, x: f64, y: f64) -> f64 {
        let i = &self.info;
        let col = (x - i.origin_x_m) / i.gsd_m;
        let row = (i.origin_y_m - y) / i.gsd_m;
        self.heights.bilinear(col, row) as f64
    }
}

/// Heights (m) as 16-bit values with their `(offset_m, scale_m)`: millimetre steps unless the
/// relief needs coarser ones to fit 16 bits.
pub fn quantise_heights(metres: &[f64]) -> (f64, f64, Vec<u16>) {
    let lo = metres.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = metres.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let scale_m = ((hi - lo) / 65535.0).max(0.001);
    let offset_m = (lo / 0.001).floor() * 0.001;
    let data = metres
        .iter()
        .map(|&m| ((m - offset_m) / scale_m).round().clamp(0.0, 65535.0) as u16)
        .collect();
    (offset_m, scale_m, data)
}

/// Writes an 8-bit grey PNG (maps, tiles, frames).
pub fn write_grey_png(path: &Path, grid: &Grid<u8>) -> Result<()> {
    image::save_buffer_with_format(
        path,
        &grid.data,
        grid.width as u32,
        grid.height as u32,
        image::ExtendedColorType::L8,
        image::ImageFormat::Png,
    )
    .map_err(|e| match e {
        image::ImageError::IoError(source) => FormatError::io(path, source),
        other => FormatError::invalid(path, other.to_string()),
    })
}

/// Writes the 16-bit grey PNG of an elevation model (the values, before `offset_m` and
/// `scale_m`).
pub fn write_elevation_png(path: &Path, grid: &Grid<u16>) -> Result<()> {
    let bytes: Vec<u8> = grid.data.iter().flat_map(|v| v.to_ne_bytes()).collect();
    image::save_buffer_with_format(
        path,
        &bytes,
        grid.width as u32,
        grid.height as u32,
        image::ExtendedColorType::L16,
        image::ImageFormat::Png,
    )
    .map_err(|e| match e {
        image::ImageError::IoError(source) => FormatError::io(path, source),
        other => FormatError::invalid(path, other.to_string()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 5 × 4 grid of a plane h = 2 + 0.5 x − 0.25 y, posts 0.2 m apart from (0.1, −0.1).
    fn plane() -> (ElevationInfo, Grid<u16>) {
        let info = ElevationInfo {
            image: "elevation.png".into(),
            gsd_m: 0.2,
            width_px: 5,
            height_px: 4,
            origin_x_m: 0.1,
            origin_y_m: -0.1,
            offset_m: 1.0,
            scale_m: 0.001,
            sigma_m: 0.05,
        };
        let mut grid = Grid::filled(5, 4, 0u16);
        for j in 0..4 {
            for i in 0..5 {
                let (x, y) = (0.1 + 0.2 * i as f64, -0.1 - 0.2 * j as f64);
                let h = 2.0 + 0.5 * x - 0.25 * y;
                *grid.at_mut(i, j) = ((h - 1.0) / 0.001).round() as u16;
            }
        }
        (info, grid)
    }

    #[test]
    fn png_round_trips_a_plane() {
        let dir = tempfile::tempdir().unwrap();
        let (info, grid) = plane();
        write_elevation_png(&dir.path().join("elevation.png"), &grid).unwrap();
        let dem = ElevationModel::read(&info, dir.path()).unwrap();
        for (x, y) in [(0.1, -0.1), (0.55, -0.3), (0.3, -0.45)] {
            let want = 2.0 + 0.5 * x - 0.25 * y;
            assert!((dem.height_at(x, y) - want).abs() < 1e-3, "{x} {y}");
        }
        let heights = Grid {
            width: 5,
            height: 4,
            data: grid
                .data
                .iter()
                .map(|&v| (1.0 + v as f64 * 0.001) as f32)
                .collect(),
        };
        let mem = ElevationModel::from_heights(info.clone(), heights).unwrap();
        assert_eq!(mem.height_at(0.3, -0.3), dem.height_at(0.3, -0.3));
        assert!(ElevationModel::from_heights(info, Grid::filled(4, 4, 0.0)).is_none());
    }

    #[test]
    fn wrong_size_bad_values_and_missing_file_are_errors_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let (mut info, grid) = plane();
        write_elevation_png(&dir.path().join("elevation.png"), &grid).unwrap();
        info.width_px += 1;
        let e = ElevationModel::read(&info, dir.path()).unwrap_err();
        assert!(e.to_string().contains("elevation.png"), "{e}");
        assert!(e.to_string().contains("5x4"), "{e}");
        info.image = "absent.png".into();
        let e = ElevationModel::read(&info, dir.path()).unwrap_err();
        assert!(matches!(e, FormatError::Io { .. }), "{e}");
        assert!(e.to_string().contains("absent.png"), "{e}");
        std::fs::write(dir.path().join("garbage.png"), b"not a png").unwrap();
        info.image = "garbage.png".into();
        let e = ElevationModel::read(&info, dir.path()).unwrap_err();
        assert!(e.to_string().contains("garbage.png"), "{e}");
        info.gsd_m = f64::NAN;
        let e = info.validate(Path::new("map.toml")).unwrap_err();
        assert!(
            e.to_string().contains("map.toml") && e.to_string().contains("gsd_m"),
            "{e}"
        );
    }
}
