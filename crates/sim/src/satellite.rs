//! The orbital map: an orthographic nadir render of the same terrain under another sun, at a
//! coarser ground sampling distance, through its own sensor (blur, noise, gamma). The gap
//! between this and the UAV frames (sun, resolution, radiometry) is what the absolute
//! localisation has to bridge; the difficulty presets set its size.
//!
//! Each map pixel is the mean radiance of the `f × f` terrain cells it covers (`f = gsd / cell`,
//! an integer): the terrain grid is laid out so cell borders coincide with pixel borders, which
//! makes the map exactly georeferenced (pixel centre = mean of its cell centres).

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::dem::DemConfig;
use crate::error::{Result, SimError};
use crate::sensor::SensorConfig;
use jointloc_formats::Grid;

/// Preset size of the UAV-to-map gap.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Difficulty {
    /// 5 cm/px map (about the paper's), sun 30° away in azimuth, 40° high.
    Easy,
    /// 12.5 cm/px map, sun 45° away in azimuth, 35° high.
    Medium,
    /// 25 cm/px map (HiRISE class), sun 90° away in azimuth and low (25°), softer and noisier,
    /// with a HiRISE-like stereo DTM (1 m posts, 0.25 m noise, smoothed).
    Hard,
    /// The Mars envelope: the `hard` map and DTM over a 2 km map, the map's sun 35–45° high
    /// and 30–180° away in azimuth from the flight's, which is 15–60° high (drawn per seed).
    Mars,
}

impl Difficulty {
    /// All presets, easiest first.
    pub const ALL: [Difficulty; 3] = [Difficulty::Easy, Difficulty::Medium, Difficulty::Hard];

    /// Lower-case name, as in files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Difficulty::Easy => "easy",
            Difficulty::Medium => "medium",
            Difficulty::Hard => "hard",
            Difficulty::Mars => "mars",
        }
    }

    /// The satellite settings of this preset.
    pub fn satellite_config(self) -> SatelliteConfig {
        let base = SatelliteConfig::default();
        match self {
            Difficulty::Easy => base,
            Difficulty::Medium => SatelliteConfig {
                gsd_m: 0.125,
                sun_azimuth_change_deg: 45.0,
                sun_elevation_deg: 35.0,
                sensor: SensorConfig {
                    blur_sigma_px: 0.8,
                    full_well_e: 2000.0,
                    gamma: 0.7,
                    ..base.sensor.clone()
                },
                ..base
            },
            Difficulty::Hard | Difficulty::Mars => SatelliteConfig {
                gsd_m: 0.25,
                sun_azimuth_change_deg: 90.0,
                sun_elevation_deg: 25.0,
                sensor: SensorConfig {
                    blur_sigma_px: 1.0,
                    full_well_e: 1000.0,
                    read_noise_e: 10.0,
                    gamma: 0.6,
                    ..base.sensor.clone()
                },
                dem: DemConfig::hirise(),
                ..base
            },
        }
    }
}

impl std::fmt::Display for Difficulty {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Settings of the orbital map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SatelliteConfig {
    /// Ground sampling distance, metres per pixel; a whole multiple of the terrain cell.
    pub gsd_m: f64,
    /// Azimuth difference between the map's sun and the UAV flight's sun, degrees (the sign is
    /// drawn from the seed).
    pub sun_azimuth_change_deg: f64,
    /// Elevation of the map's sun, degrees.
    pub sun_elevation_deg: f64,
    /// The orbital camera's sensor.
    pub sensor: SensorConfig,
    /// Overlap ratio of neighbouring tiles (0.5: stride = half a tile).
    pub tile_overlap: f64,
    /// The elevation model written beside the map (`elevation.png`).
    pub dem: DemConfig,
}

impl Default for SatelliteConfig {
    fn default() -> Self {
        Self {
            gsd_m: 0.05,
            sun_azimuth_change_deg: 30.0,
            sun_elevation_deg: 40.0,
            sensor: SensorConfig {
                blur_sigma_px: 0.7,
                full_well_e: 3000.0,
                read_noise_e: 8.0,
                gamma: 0.8,
                ..SensorConfig::default()
            },
            tile_overlap: 0.5,
            dem: DemConfig::default(),
        }
    }
}

impl SatelliteConfig {
    /// Checks ranges and that the GSD is a whole number of terrain cells; returns that number.
    pub fn validate(&self, cell_m: f64) -> Result<usize> {
        let bad = |field: &'static str, value: f64, reason: &str| SimError::InvalidConfig {
            field,
            value: value.to_string(),
            reason: reason.into(),
        };
        if !(self.gsd_m.is_finite() && self.gsd_m > 0.0) {
            return Err(bad("satellite.gsd_m", self.gsd_m, "must be positive"));
        }
        let ratio = self.gsd_m / cell_m;
        let factor = ratio.round();
        if factor < 1.0 || (ratio - factor).abs() > 1e-6 * ratio {
            return Err(bad(
                "satellite.gsd_m",
                self.gsd_m,
                &format!("must be a whole multiple of the terrain cell ({cell_m} m)"),
            ));
        }
        if !self.sun_azimuth_change_deg.is_finite() {
            return Err(bad(
                "satellite.sun_azimuth_change_deg",
                self.sun_azimuth_change_deg,
                "must be finite",
            ));
        }
        if !(self.sun_elevation_deg > 0.0 && self.sun_elevation_deg <= 90.0) {
            return Err(bad(
                "satellite.sun_elevation_deg",
                self.sun_elevation_deg,
                "must be in (0, 90]",
            ));
        }
        if !(self.tile_overlap >= 0.0 && self.tile_overlap < 1.0) {
            return Err(bad(
                "satellite.tile_overlap",
                self.tile_overlap,
                "must be in [0, 1)",
            ));
        }
        self.sensor.validate("satellite.sensor")?;
        self.dem.validate()?;
        Ok(factor as usize)
    }
}

/// Mean over `factor × factor` blocks; the grid's size must be a multiple of `factor`.
pub fn downsample_mean(radiance: &Grid<f32>, factor: usize) -> Result<Grid<f32>> {
    if factor == 0
        || !radiance.width.is_multiple_of(factor)
        || !radiance.height.is_multiple_of(factor)
    {
        return Err(SimError::InvalidConfig {
            field: "satellite downsampling",
            value: format!("{}x{} / {factor}", radiance.width, radiance.height),
            reason: "grid size must be a multiple of the factor".into(),
        });
    }
    let (w, h) = (radiance.width / factor, radiance.height / factor);
    let mut out = Grid::filled(w, h, 0.0f32);
    let norm = 1.0 / (factor * factor) as f64;
    out.data
        .par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(v, row)| {
            let mut acc = vec![0.0f64; w];
            for r in v * factor..(v + 1) * factor {
                let src = &radiance.data[r * radiance.width..(r + 1) * radiance.width];
                for (u, a) in acc.iter_mut().enumerate() {
                    *a += src[u * factor..(u + 1) * factor]
                        .iter()
                        .map(|&x| x as f64)
                        .sum::<f64>();
                }
            }
            for (o, a) in row.iter_mut().zip(acc) {
                *o = (a * norm) as f32;
            }
        });
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_divide_the_terrain_cell() {
        for d in Difficulty::ALL {
            let f = d.satellite_config().validate(0.025).unwrap();
            assert_eq!(f, [2, 5, 10][d as usize]);
        }
        let odd = SatelliteConfig {
            gsd_m: 0.06,
            ..Default::default()
        };
        assert!(odd.validate(0.025).is_err());
    }

    #[test]
    fn downsampling_averages_blocks() {
        let mut g = Grid::filled(6, 4, 0.0f32);
        for (k, v) in g.data.iter_mut().enumerate() {
            *v = k as f32;
        }
        let d = downsample_mean(&g, 2).unwrap();
        assert_eq!((d.width, d.height), (3, 2));
        assert_eq!(d.at(0, 0), (0.0 + 1.0 + 6.0 + 7.0) / 4.0);
        assert_eq!(d.at(2, 1), (16.0 + 17.0 + 22.0 + 23.0) / 4.0);
        assert!(downsample_mean(&g, 4).is_err());
    }
}
