//! The simulated elevation model: the terrain's heights averaged over coarser posts, with
//! seeded noise, quantised for the 16-bit PNG of [`jointloc_formats::elevation`].

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use crate::error::{Result, SimError};
use crate::terrain::Terrain;
use jointloc_formats::ElevationInfo;
use jointloc_formats::Grid;

/// Settings of the simulated DEM.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct DemConfig {
    /// Post spacing in map pixels (4: a HiRISE-like DTM at 4× the image's GSD); 0 writes no DEM.
    pub post_px: u32,
    /// σ of the Gaussian error added to each post, metres (HiRISE DTMs: a few decimetres).
    pub sigma_m: f64,
}

impl Default for DemConfig {
    fn default() -> Self {
        Self {
            post_px: 4,
            sigma_m: 0.05,
        }
    }
}

impl DemConfig {
    pub fn validate(&self) -> Result<()> {
        if !(self.sigma_m.is_finite() && self.sigma_m >= 0.0) {
            return Err(SimError::InvalidConfig {
                field: "dem.sigma_m",
                value: self.sigma_m.to_string(),
                reason: "must be ≥ 0".into(),
            });
        }
        Ok(())
    }
}

/// Block-mean of the terrain heights over posts of `post_cells × post_cells` cells (partial
/// blocks at the far edges average what they cover), plus seeded post noise, quantised to
/// 16 bits. Returns the section for `map.toml` and the 16-bit values.
pub fn simulate_dem(
    terrain: &Terrain,
    post_cells: usize,
    sigma_m: f64,
    image: &str,
    seed: u64,
) -> Result<(ElevationInfo, Grid<u16>)> {
    if post_cells == 0 {
        return Err(SimError::InvalidConfig {
            field: "dem.post_px",
            value: "0".into(),
            reason: "no DEM requested".into(),
        });
    }
    let (w, h) = (terrain.height.width, terrain.height.height);
    let (pw, ph) = (w.div_ceil(post_cells), h.div_ceil(post_cells));
    let noise = Normal::new(0.0, sigma_m).map_err(|e| SimError::InvalidConfig {
        field: "dem.sigma_m",
        value: sigma_m.to_string(),
        reason: e.to_string(),
    })?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut metres = Vec::with_capacity(pw * ph);
    for j in 0..ph {
        for i in 0..pw {
            let (c0, r0) = (i * post_cells, j * post_cells);
            let (c1, r1) = ((c0 + post_cells).min(w), (r0 + post_cells).min(h));
            let mut sum = 0.0f64;
            for r in r0..r1 {
                sum += terrain.height.data[r * w + c0..r * w + c1]
                    .iter()
                    .map(|&v| v as f64)
                    .sum::<f64>();
            }
            let mean = sum / ((c1 - c0) * (r1 - r0)) as f64;
            metres.push(mean + noise.sample(&mut rng));
        }
    }
    let lo = metres.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = metres.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    // Millimetre steps unless the relief needs coarser ones to fit 16 bits.
    let scale_m = ((hi - lo) / 65535.0).max(0.001);
    let offset_m = (lo / 0.001).floor() * 0.001;
    let data = metres
        .iter()
        .map(|&m| ((m - offset_m) / scale_m).round().clamp(0.0, 65535.0) as u16)
        .collect();
    // Post (0, 0) covers cells [0, post_cells): its centre is half a block inside.
    let half = (post_cells as f64 - 1.0) / 2.0 * terrain.cell_m;
    let info = ElevationInfo {
        image: image.to_string(),
        gsd_m: post_cells as f64 * terrain.cell_m,
        width_px: pw as u32,
        height_px: ph as u32,
        origin_x_m: terrain.origin_x + half,
        origin_y_m: terrain.origin_y - half,
        offset_m,
        scale_m,
        sigma_m,
    };
    Ok((
        info,
        Grid {
            width: pw,
            height: ph,
            data,
        },
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use jointloc_formats::ElevationModel;
    use jointloc_formats::elevation::write_elevation_png;
    use std::path::Path;

    fn sloped_terrain() -> Terrain {
        let (w, h) = (40, 30);
        let mut height = Grid::filled(w, h, 0.0f32);
        let cell = 0.025;
        let (ox, oy) = (-0.0125, 0.0125);
        for r in 0..h {
            for c in 0..w {
                let (x, y) = (ox + c as f64 * cell, oy - r as f64 * cell);
                *height.at_mut(c, r) = (2.0 + 0.5 * x - 0.25 * y) as f32;
            }
        }
        Terrain {
            cell_m: cell,
            origin_x: ox,
            origin_y: oy,
            albedo: Grid::filled(w, h, 0.5),
            height,
        }
    }

    #[test]
    fn dem_round_trips_a_plane_through_png() {
        let terrain = sloped_terrain();
        let dir = tempfile::tempdir().unwrap();
        let (info, grid) = simulate_dem(&terrain, 8, 0.0, "elevation.png", 1).unwrap();
        assert_eq!((info.width_px, info.height_px), (5, 4));
        write_elevation_png(&dir.path().join("elevation.png"), &grid).unwrap();
        let dem = ElevationModel::read(&info, dir.path()).unwrap();
        // Inside full blocks a block mean of a plane is the plane at the block centre.
        for (x, y) in [(0.1, -0.1), (0.55, -0.3), (0.3, -0.45)] {
            let want = 2.0 + 0.5 * x - 0.25 * y;
            assert!(
                (dem.height_at(x, y) - want).abs() < 2e-3,
                "{x} {y}: {} vs {want}",
                dem.height_at(x, y)
            );
        }
    }

    #[test]
    fn wrong_size_and_missing_file_are_errors_naming_the_file() {
        let terrain = sloped_terrain();
        let dir = tempfile::tempdir().unwrap();
        let (mut info, grid) = simulate_dem(&terrain, 8, 0.05, "elevation.png", 1).unwrap();
        write_elevation_png(&dir.path().join("elevation.png"), &grid).unwrap();
        info.width_px += 1;
        let e = ElevationModel::read(&info, dir.path()).unwrap_err();
        assert!(e.to_string().contains("elevation.png"), "{e}");
        info.image = "absent.png".into();
        let e = ElevationModel::read(&info, dir.path()).unwrap_err();
        assert!(e.to_string().contains("absent.png"), "{e}");
        info.gsd_m = f64::NAN;
        assert!(info.validate(Path::new("map.toml")).is_err());
    }
}
