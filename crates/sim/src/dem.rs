//! The simulated elevation model: the terrain's heights averaged over coarser posts, with
//! seeded noise, quantised for the 16-bit PNG of [`jointloc_formats::elevation`].
//!
//! Optionally a stereo DTM's error model (the `hard` and `mars` presets, after HiRISE DTMs:
//! 1 m posts, decimetres of vertical precision, an effective resolution of a few posts because
//! the correlator's window smooths the relief): the post means are smoothed with a Gaussian of
//! `smoothing_posts`, and the noise, correlated over `noise_correlation_posts` like matching
//! errors of neighbouring windows, is scaled to keep its σ equal to `sigma_m`.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use crate::error::{Result, SimError};
use crate::sensor::{gaussian_blur, gaussian_kernel};
use crate::terrain::Terrain;
use jointloc_formats::ElevationInfo;
use jointloc_formats::Grid;
use jointloc_formats::elevation::quantise_heights;

/// Settings of the simulated DEM.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct DemConfig {
    /// Post spacing in map pixels (4: a HiRISE-like DTM at 4× the image's GSD); 0 writes no DEM.
    pub post_px: u32,
    /// σ of the Gaussian error of each post, metres (HiRISE DTMs: a few decimetres).
    pub sigma_m: f64,
    /// σ, in posts, of the Gaussian that smooths the relief (a stereo correlator's window);
    /// 0 keeps the plain post means.
    pub smoothing_posts: f64,
    /// σ, in posts, over which the post errors are correlated; 0 makes them independent.
    pub noise_correlation_posts: f64,
}

impl Default for DemConfig {
    fn default() -> Self {
        Self {
            post_px: 4,
            sigma_m: 0.05,
            smoothing_posts: 0.0,
            noise_correlation_posts: 0.0,
        }
    }
}

impl DemConfig {
    /// A HiRISE stereo DTM: 1 m posts on a 25 cm map, 0.25 m vertical noise correlated over a
    /// post, relief smoothed over a post (effective resolution ≈ 3 m).
    pub fn hirise() -> Self {
        Self {
            post_px: 4,
            sigma_m: 0.25,
            smoothing_posts: 1.0,
            noise_correlation_posts: 1.0,
        }
    }

    pub fn validate(&self) -> Result<()> {
        for (field, v) in [
            ("dem.sigma_m", self.sigma_m),
            ("dem.smoothing_posts", self.smoothing_posts),
            ("dem.noise_correlation_posts", self.noise_correlation_posts),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(SimError::InvalidConfig {
                    field,
                    value: v.to_string(),
                    reason: "must be ≥ 0".into(),
                });
            }
        }
        if self.smoothing_posts > 20.0 || self.noise_correlation_posts > 20.0 {
            return Err(SimError::InvalidConfig {
                field: "dem.smoothing_posts",
                value: format!(
                    "{} / {}",
                    self.smoothing_posts, self.noise_correlation_posts
                ),
                reason: "smoothing and noise correlation must be ≤ 20 posts".into(),
            });
        }
        Ok(())
    }
}

/// A height grid and where it lies: cell `(c, r)` is centred at
/// `(origin_x + c · cell_m, origin_y − r · cell_m)`.
#[derive(Debug, Clone, Copy)]
pub struct Heights<'a> {
    pub grid: &'a Grid<f32>,
    pub cell_m: f64,
    pub origin_x: f64,
    pub origin_y: f64,
}

impl<'a> From<&'a Terrain> for Heights<'a> {
    fn from(t: &'a Terrain) -> Self {
        Self {
            grid: &t.height,
            cell_m: t.cell_m,
            origin_x: t.origin_x,
            origin_y: t.origin_y,
        }
    }
}

/// Block-mean of the heights over posts of `post_cells × post_cells` cells (partial blocks at
/// the far edges average what they cover), with `cfg`'s error model, quantised to 16 bits.
/// Returns the section for `map.toml` and the 16-bit values.
pub fn simulate_dem(
    heights: Heights,
    post_cells: usize,
    cfg: &DemConfig,
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
    cfg.validate()?;
    let sigma_m = cfg.sigma_m;
    let grid = heights.grid;
    let (w, h) = (grid.width, grid.height);
    let (pw, ph) = (w.div_ceil(post_cells), h.div_ceil(post_cells));
    let noise = Normal::new(0.0, sigma_m).map_err(|e| SimError::InvalidConfig {
        field: "dem.sigma_m",
        value: sigma_m.to_string(),
        reason: e.to_string(),
    })?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut means = Vec::with_capacity(pw * ph);
    let mut errors = Vec::with_capacity(pw * ph);
    for j in 0..ph {
        for i in 0..pw {
            let (c0, r0) = (i * post_cells, j * post_cells);
            let (c1, r1) = ((c0 + post_cells).min(w), (r0 + post_cells).min(h));
            let mut sum = 0.0f64;
            for r in r0..r1 {
                sum += grid.data[r * w + c0..r * w + c1]
                    .iter()
                    .map(|&v| v as f64)
                    .sum::<f64>();
            }
            means.push(sum / ((c1 - c0) * (r1 - r0)) as f64);
            errors.push(noise.sample(&mut rng));
        }
    }
    if cfg.smoothing_posts > 0.0 {
        means = blurred(&means, pw, ph, cfg.smoothing_posts);
    }
    if cfg.noise_correlation_posts > 0.0 {
        // A 2-D blur shrinks the σ of white noise by Σw² of its 1-D kernel: undo that.
        let gain: f64 = gaussian_kernel(cfg.noise_correlation_posts)
            .iter()
            .map(|&k| (k as f64).powi(2))
            .sum();
        errors = blurred(&errors, pw, ph, cfg.noise_correlation_posts)
            .iter()
            .map(|e| e / gain)
            .collect();
    }
    let metres: Vec<f64> = means.iter().zip(&errors).map(|(m, e)| m + e).collect();
    let (offset_m, scale_m, data) = quantise_heights(&metres);
    // Post (0, 0) covers cells [0, post_cells): its centre is half a block inside.
    let half = (post_cells as f64 - 1.0) / 2.0 * heights.cell_m;
    let info = ElevationInfo {
        image: image.to_string(),
        gsd_m: post_cells as f64 * heights.cell_m,
        width_px: pw as u32,
        height_px: ph as u32,
        origin_x_m: heights.origin_x + half,
        origin_y_m: heights.origin_y - half,
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

/// `values` (a `w × h` grid) blurred by a Gaussian of σ samples, edges clamped.
fn blurred(values: &[f64], w: usize, h: usize, sigma: f64) -> Vec<f64> {
    let grid = Grid {
        width: w,
        height: h,
        data: values.iter().map(|&v| v as f32).collect(),
    };
    gaussian_blur(&grid, sigma)
        .data
        .iter()
        .map(|&v| v as f64)
        .collect()
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
        let (info, grid) = simulate_dem(
            (&terrain).into(),
            8,
            &DemConfig {
                sigma_m: 0.0,
                ..Default::default()
            },
            "elevation.png",
            1,
        )
        .unwrap();
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
    fn the_stereo_model_has_its_stated_noise_correlated_over_a_post() {
        let (w, h) = (480, 480);
        let flat = Grid::filled(w, h, 3.0f32);
        let heights = Heights {
            grid: &flat,
            cell_m: 0.25,
            origin_x: 0.0,
            origin_y: 0.0,
        };
        for seed in [1, 2] {
            let (info, grid) =
                simulate_dem(heights, 4, &DemConfig::hirise(), "e.png", seed).unwrap();
            assert_eq!((info.gsd_m, info.width_px), (1.0, 120));
            let m: Vec<f64> = grid
                .data
                .iter()
                .map(|&q| info.offset_m + q as f64 * info.scale_m - 3.0)
                .collect();
            let n = m.len() as f64;
            let mean = m.iter().sum::<f64>() / n;
            let sd = (m.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
            assert!(mean.abs() < 0.05, "bias {mean}");
            assert!((sd - 0.25).abs() < 0.03, "σ {sd}");
            // Neighbouring posts share their error (a stereo matcher's window).
            let (mut c, mut k) = (0.0, 0.0);
            for r in 0..120 {
                for col in 0..119 {
                    c += (m[r * 120 + col] - mean) * (m[r * 120 + col + 1] - mean);
                    k += 1.0;
                }
            }
            let rho = c / k / (sd * sd);
            assert!(rho > 0.5 && rho < 0.95, "neighbour correlation {rho}");
        }
        // Independent noise without the correlation.
        let white = DemConfig {
            noise_correlation_posts: 0.0,
            ..DemConfig::hirise()
        };
        let (info, grid) = simulate_dem(heights, 4, &white, "e.png", 1).unwrap();
        let m: Vec<f64> = grid
            .data
            .iter()
            .map(|&q| info.offset_m + q as f64 * info.scale_m)
            .collect();
        let (mut c, mut v) = (0.0, 0.0);
        let mean = m.iter().sum::<f64>() / m.len() as f64;
        for i in 0..m.len() - 1 {
            c += (m[i] - mean) * (m[i + 1] - mean);
            v += (m[i] - mean).powi(2);
        }
        assert!((c / v).abs() < 0.1, "{}", c / v);
    }

    #[test]
    fn smoothing_blurs_a_step_over_a_few_posts() {
        let (w, h) = (160, 40);
        let mut step = Grid::filled(w, h, 0.0f32);
        for r in 0..h {
            for c in w / 2..w {
                *step.at_mut(c, r) = 1.0;
            }
        }
        let heights = Heights {
            grid: &step,
            cell_m: 0.25,
            origin_x: 0.0,
            origin_y: 0.0,
        };
        let cfg = DemConfig {
            sigma_m: 0.0,
            ..DemConfig::hirise()
        };
        let (info, grid) = simulate_dem(heights, 4, &cfg, "e.png", 1).unwrap();
        let row: Vec<f64> = (0..40)
            .map(|c| info.offset_m + grid.at(c, 5) as f64 * info.scale_m)
            .collect();
        // The step (between posts 19 and 20) spreads over about ±2 posts, monotonically.
        assert!(row[18] > 0.01 && row[18] < 0.2, "{row:?}");
        assert!(row[21] < 0.99 && row[21] > 0.8, "{row:?}");
        assert!(row[10] < 1e-3 && row[30] > 0.999);
        assert!(row.windows(2).all(|p| p[1] >= p[0] - 1e-9));
    }

    #[test]
    fn wrong_size_and_missing_file_are_errors_naming_the_file() {
        let terrain = sloped_terrain();
        let dir = tempfile::tempdir().unwrap();
        let (mut info, grid) = simulate_dem(
            (&terrain).into(),
            8,
            &DemConfig::default(),
            "elevation.png",
            1,
        )
        .unwrap();
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
