//! The map relit from the sun it was taken under to the flight's sun, with its elevation
//! model: each map pixel is multiplied by the ratio of the two suns' Lambert shading (plus
//! the sky's diffuse light) of the DEM's surface there.
//!
//! Why: under a change of sun azimuth of 90–180° at low flight sun, which slopes are lit
//! flips, and no learned matcher pairs a mountain's frame with its map (0 of 20 pairs within
//! 10 px at 100 m over mountains under 90°, `docs/absloc.md` §"The map relit to the flight's
//! sun"). The DEM knows the slopes, so their shading can be moved to the flight's sun; what it
//! cannot resolve (relief below its posts, albedo) is left as it is.
//!
//! A stereo DTM's slopes at one post are mostly noise (HiRISE: 1 m posts, σ ≈ 0.25 m), and
//! relighting with noise paints false shading onto flat ground. The heights are first
//! denoised by a Wiener filter: per spatial frequency, the power the DEM holds beyond its
//! stated noise's power ([`ElevationInfo::sigma_m`] correlated over
//! [`RelightConfig::noise_correlation_posts`]) over the power it holds. Over gravel (relief
//! below the DTM's noise) this smooths the DEM to a few posts' wavelength of 20 posts and the
//! map is nearly unchanged; over mountains it keeps their slopes down to about 10 posts.
//! Cast shadows are left out: with them the relit mountains matched no better.
//!
//! [`ElevationInfo::sigma_m`]: jointloc_formats::ElevationInfo

use image::GrayImage;
use jointloc_formats::map_toml::SunInfo;
use jointloc_formats::{ElevationModel, Grid};
use rayon::prelude::*;
use rustfft::FftPlanner;
use rustfft::num_complex::Complex32;
use serde::{Deserialize, Serialize};

use crate::error::{AbslocError, Result};
use crate::tiles::MapTiles;

/// How the map is relit to the flight's sun.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RelightConfig {
    /// The sun during the flight (azimuth clockwise from north, elevation above the horizon,
    /// degrees), from the ephemeris at the flight's time and place. `None`: the map is
    /// matched as it was taken. The map's own sun is `map.toml`'s `[sun]`.
    pub flight_sun: Option<SunInfo>,
    /// Relight when both suns and an elevation model are known.
    pub enabled: bool,
    /// Distance in DEM posts over which its errors are correlated (a stereo correlator's
    /// window makes neighbouring posts' errors alike); sets the spectrum of the noise the
    /// Wiener filter removes.
    pub noise_correlation_posts: f64,
    /// Diffuse sky light on a horizontal surface as a fraction of the direct sun at normal
    /// incidence (Mars: 0.15–0.3): what lights the slopes turned away from the sun.
    pub sky_fraction: f64,
}

impl Default for RelightConfig {
    fn default() -> Self {
        Self {
            flight_sun: None,
            enabled: true,
            noise_correlation_posts: 1.0,
            sky_fraction: 0.2,
        }
    }
}

impl RelightConfig {
    /// Checks ranges.
    pub fn validate(&self) -> Result<()> {
        let bad = |field: &'static str, value: f64, reason: &str| AbslocError::InvalidConfig {
            field,
            value: value.to_string(),
            reason: reason.into(),
        };
        if !(self.noise_correlation_posts.is_finite() && self.noise_correlation_posts >= 0.0) {
            return Err(bad(
                "relight.noise_correlation_posts",
                self.noise_correlation_posts,
                "must be >= 0",
            ));
        }
        if !(self.sky_fraction.is_finite() && self.sky_fraction > 0.0) {
            return Err(bad(
                "relight.sky_fraction",
                self.sky_fraction,
                "must be > 0",
            ));
        }
        if let Some(sun) = &self.flight_sun {
            check_sun("relight.flight_sun", sun)?;
        }
        Ok(())
    }
}

/// Errors unless `sun` has a finite azimuth and an elevation in (0, 90].
pub fn check_sun(field: &'static str, sun: &SunInfo) -> Result<()> {
    if !sun.is_valid() {
        return Err(AbslocError::InvalidConfig {
            field,
            value: format!("{} / {}", sun.azimuth_deg, sun.elevation_deg),
            reason: "azimuth must be finite and elevation in (0, 90] degrees".into(),
        });
    }
    Ok(())
}

/// Unit vector towards `sun` (x east, y north, z up).
fn towards(sun: &SunInfo) -> [f64; 3] {
    let (sa, ca) = sun.azimuth_deg.to_radians().sin_cos();
    let (se, ce) = sun.elevation_deg.to_radians().sin_cos();
    [sa * ce, ca * ce, se]
}

/// `map` (pixel `(u, v)` at world `(u·gsd, −v·gsd)`) relit from `map_sun` to `flight_sun` with
/// the slopes of `dem` after [`wiener_denoise`]; its mean grey level is kept.
pub fn relight(
    map: &GrayImage,
    gsd_m: f64,
    dem: &ElevationModel,
    map_sun: &SunInfo,
    flight_sun: &SunInfo,
    cfg: &RelightConfig,
) -> GrayImage {
    let info = &dem.info;
    let smooth = wiener_denoise(dem.heights(), info.sigma_m, cfg.noise_correlation_posts);
    // Slopes (∂h/∂x east, ∂h/∂y north) at the posts by central differences; rows run south.
    let (w, h) = (smooth.width, smooth.height);
    let slope = |step: f64, lo: usize, hi: usize, a: f32, b: f32| {
        if hi > lo {
            (f64::from(b) - f64::from(a)) / ((hi - lo) as f64 * step)
        } else {
            0.0
        }
    };
    let mut sx = Grid::filled(w, h, 0f32);
    let mut sy = Grid::filled(w, h, 0f32);
    for r in 0..h {
        for c in 0..w {
            let (c0, c1) = (c.saturating_sub(1), (c + 1).min(w - 1));
            let (r0, r1) = (r.saturating_sub(1), (r + 1).min(h - 1));
            *sx.at_mut(c, r) = slope(info.gsd_m, c0, c1, smooth.at(c0, r), smooth.at(c1, r)) as f32;
            // Row r1 is south of r0: ∂h/∂y = (h(r0) − h(r1)) / distance.
            *sy.at_mut(c, r) = slope(info.gsd_m, r0, r1, smooth.at(c, r1), smooth.at(c, r0)) as f32;
        }
    }
    let (fm, ff) = (towards(map_sun), towards(flight_sun));
    let sky = cfg.sky_fraction;
    let shade = |d: &[f64; 3], gx: f64, gy: f64| {
        let n = (gx * gx + gy * gy + 1.0).sqrt();
        sky + ((-gx * d[0] - gy * d[1] + d[2]) / n).max(0.0)
    };
    let (mw, mh) = map.dimensions();
    // Relit grey level of pixel (u, v), before the gain that keeps the mean. Computed twice
    // (the sum, then the pixels) rather than held: 4 bytes a pixel on a km-scale map.
    let relit = |u: u32, v: u32| -> f32 {
        let row = (info.origin_y_m + v as f64 * gsd_m) / info.gsd_m;
        let col = (u as f64 * gsd_m - info.origin_x_m) / info.gsd_m;
        let (gx, gy) = (
            f64::from(sx.bilinear(col, row)),
            f64::from(sy.bilinear(col, row)),
        );
        let ratio = shade(&ff, gx, gy) / shade(&fm, gx, gy);
        (f64::from(map.get_pixel(u, v).0[0]) * ratio) as f32
    };
    // Row sums in parallel, added in row order: the same total on any number of threads.
    let row_sums: Vec<f64> = (0..mh)
        .into_par_iter()
        .map(|v| (0..mw).map(|u| f64::from(relit(u, v))).sum())
        .collect();
    let sum_out: f64 = row_sums.iter().sum();
    let sum_in: f64 = map.as_raw().iter().map(|&p| f64::from(p)).sum();
    let gain = if sum_out > 0.0 { sum_in / sum_out } else { 1.0 };
    let data: Vec<u8> = (0..mh)
        .into_par_iter()
        .flat_map_iter(|v| {
            (0..mw).map(move |u| (f64::from(relit(u, v)) * gain).round().clamp(0.0, 255.0) as u8)
        })
        .collect();
    GrayImage::from_raw(mw, mh, data).expect("one value per pixel")
}

/// Rings of the power spectrum averaged over.
const RINGS: usize = 200;
/// Posts of mirrored border around the DEM before the FFT, so that its wrap-around joins
/// heights that meet anyway.
const MIRROR_POSTS: usize = 32;

/// `heights` with the noise of a DEM whose posts err by `sigma_m`, correlated over
/// `correlation_posts` (a Gaussian), filtered out: the Wiener gain per ring of spatial
/// frequency is max(P − N, 0) / P, with P the heights' power in that ring and N the noise's.
pub fn wiener_denoise(heights: &Grid<f32>, sigma_m: f64, correlation_posts: f64) -> Grid<f32> {
    let (w, h) = (heights.width, heights.height);
    if w < 2 || h < 2 || sigma_m.is_nan() || sigma_m <= 0.0 {
        return heights.clone();
    }
    let m = MIRROR_POSTS.min(w - 1).min(h - 1);
    let (pw, ph) = (fft_size(w + 2 * m), fft_size(h + 2 * m));
    let mean = heights.data.iter().map(|&v| f64::from(v)).sum::<f64>() / (w * h) as f64;
    // Mirror beyond each edge, continued by reflection until the padded size.
    let reflect = |i: isize, n: usize| -> usize {
        let period = 2 * n as isize - 2;
        let j = i.rem_euclid(period);
        (if j < n as isize { j } else { period - j }) as usize
    };
    let mut buf = vec![Complex32::default(); pw * ph];
    buf.par_chunks_mut(pw).enumerate().for_each(|(r, out)| {
        let sr = reflect(r as isize - m as isize, h);
        for (c, o) in out.iter_mut().enumerate() {
            let sc = reflect(c as isize - m as isize, w);
            *o = Complex32::new((f64::from(heights.at(sc, sr)) - mean) as f32, 0.0);
        }
    });
    let mut planner = FftPlanner::<f32>::new();
    fft2(&mut planner, &mut buf, pw, ph, false);
    // Ring of each frequency, the power per ring, and the noise's power there.
    let freq = |i: usize, n: usize| {
        let k = if i <= n / 2 {
            i as f64
        } else {
            i as f64 - n as f64
        };
        k / n as f64
    };
    let r_max = 0.5 * std::f64::consts::SQRT_2;
    let ring_of = |r: usize, c: usize| {
        let (fy, fx) = (freq(r, ph), freq(c, pw));
        let f = (fx * fx + fy * fy).sqrt();
        (((f / r_max) * RINGS as f64) as usize).min(RINGS - 1)
    };
    let mut power = [0f64; RINGS];
    let mut count = [0usize; RINGS];
    let mut shape = [0f64; RINGS];
    let four_pi2 = 4.0 * std::f64::consts::PI.powi(2);
    for r in 0..ph {
        for c in 0..pw {
            if r == 0 && c == 0 {
                continue; // the mean, taken out and put back below
            }
            let k = ring_of(r, c);
            let (fy, fx) = (freq(r, ph), freq(c, pw));
            power[k] += f64::from(buf[r * pw + c].norm_sqr());
            shape[k] += (-four_pi2 * (fx * fx + fy * fy) * correlation_posts.powi(2)).exp();
            count[k] += 1;
        }
    }
    let n = (pw * ph) as f64;
    // Parseval: white noise of variance σ² has E|X|² = n σ² per frequency; a Gaussian
    // correlation shapes it by its transfer squared, scaled to keep the variance σ².
    let shape_mean = shape.iter().sum::<f64>() / (n - 1.0);
    let noise_scale = n * sigma_m * sigma_m / shape_mean;
    // Gain per ring, never rising with frequency: the periodogram's scatter above the noise
    // at high frequencies would otherwise let noise through, and slopes are what it spoils.
    let mut gain = [0f64; RINGS];
    let mut ceiling = 1.0f64;
    for k in 0..RINGS {
        if count[k] > 0 {
            let p = power[k] / count[k] as f64;
            let noise = noise_scale * shape[k] / count[k] as f64;
            let g = if p > 0.0 {
                ((p - noise) / p).clamp(0.0, 1.0)
            } else {
                0.0
            };
            ceiling = ceiling.min(g);
        }
        gain[k] = ceiling;
    }
    buf.par_chunks_mut(pw).enumerate().for_each(|(r, out)| {
        for (c, v) in out.iter_mut().enumerate() {
            if r == 0 && c == 0 {
                continue;
            }
            *v *= gain[ring_of(r, c)] as f32;
        }
    });
    fft2(&mut planner, &mut buf, pw, ph, true);
    let mut out = Grid::filled(w, h, 0f32);
    for r in 0..h {
        for c in 0..w {
            *out.at_mut(c, r) = (f64::from(buf[(r + m) * pw + c + m].re) + mean) as f32;
        }
    }
    out
}

/// In-place 2-D FFT of a row-major `h × w` buffer; the inverse is scaled by 1 / (w·h).
fn fft2(planner: &mut FftPlanner<f32>, buf: &mut [Complex32], w: usize, h: usize, inverse: bool) {
    let (row, col) = if inverse {
        (planner.plan_fft_inverse(w), planner.plan_fft_inverse(h))
    } else {
        (planner.plan_fft_forward(w), planner.plan_fft_forward(h))
    };
    buf.par_chunks_mut(w).for_each(|r| row.process(r));
    let mut t = vec![Complex32::default(); w * h];
    crate::whole_map::transpose(buf, &mut t, w, h);
    t.par_chunks_mut(h).for_each(|c| col.process(c));
    crate::whole_map::transpose(&t, buf, h, w);
    if inverse {
        let s = 1.0 / (w * h) as f32;
        buf.par_iter_mut().for_each(|v| *v *= s);
    }
}

/// The smallest size ≥ `len` with prime factors 2, 3 and 5 only.
fn fft_size(len: usize) -> usize {
    crate::whole_map::smooth_size(len)
}

/// Why a map is matched as it was taken rather than relit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NotRelit {
    /// [`RelightConfig::enabled`] is off.
    Disabled,
    /// No flight sun in the configuration.
    NoFlightSun,
    /// `map.toml` states no sun for the map.
    NoMapSun,
    /// The map has no elevation model.
    NoElevation,
}

impl std::fmt::Display for NotRelit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Disabled => "relighting is off",
            Self::NoFlightSun => "no flight sun given",
            Self::NoMapSun => "map.toml states no [sun] for the map",
            Self::NoElevation => "the map has no elevation model",
        })
    }
}

/// `tiles` relit to the configuration's flight sun (see [`relight`]), or why not.
pub fn relit_tiles(
    tiles: &MapTiles,
    cfg: &RelightConfig,
) -> Result<std::result::Result<MapTiles, NotRelit>> {
    if !cfg.enabled {
        return Ok(Err(NotRelit::Disabled));
    }
    let Some(flight_sun) = cfg.flight_sun else {
        return Ok(Err(NotRelit::NoFlightSun));
    };
    let Some(map_sun) = tiles.sun() else {
        return Ok(Err(NotRelit::NoMapSun));
    };
    let ground = tiles.ground();
    let Some(dem) = ground.model() else {
        return Ok(Err(NotRelit::NoElevation));
    };
    check_sun("map sun", &map_sun)?;
    check_sun("relight.flight_sun", &flight_sun)?;
    let map = relight(tiles.map(), tiles.gsd_m(), dem, &map_sun, &flight_sun, cfg);
    Ok(Ok(tiles.with_pixels(map)?))
}

#[cfg(test)]
mod tests {
    use super::*;
    use jointloc_formats::ElevationInfo;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// `values` (`w × h`, row-major) blurred by a Gaussian of `sigma` samples, clamped edges.
    fn blur(values: &[f64], w: usize, h: usize, sigma: f64) -> Vec<f64> {
        let r = (3.0 * sigma).ceil() as isize;
        let k: Vec<f64> = (-r..=r)
            .map(|i| (-0.5 * (i as f64 / sigma).powi(2)).exp())
            .collect();
        let sum: f64 = k.iter().sum();
        let pass = |src: &[f64], horizontal: bool| -> Vec<f64> {
            let mut out = vec![0.0; w * h];
            for y in 0..h {
                for x in 0..w {
                    out[y * w + x] = (-r..=r)
                        .map(|d| {
                            let (xx, yy) = if horizontal {
                                ((x as isize + d).clamp(0, w as isize - 1) as usize, y)
                            } else {
                                (x, (y as isize + d).clamp(0, h as isize - 1) as usize)
                            };
                            src[yy * w + xx] * k[(d + r) as usize] / sum
                        })
                        .sum();
                }
            }
            out
        };
        pass(&pass(values, true), false)
    }

    /// White noise of σ `sigma` blurred over `corr` posts and rescaled to σ `sigma`.
    fn correlated_noise(w: usize, h: usize, sigma: f64, corr: f64, seed: u64) -> Vec<f64> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let white: Vec<f64> = (0..w * h)
            .map(|_| Normal::new(0.0, 1.0).unwrap().sample(&mut rng))
            .collect();
        let blurred = blur(&white, w, h, corr);
        let std = (blurred.iter().map(|v| v * v).sum::<f64>() / (w * h) as f64).sqrt();
        blurred.iter().map(|v| v * sigma / std).collect()
    }

    fn grid(w: usize, h: usize, f: impl Fn(usize, usize) -> f64) -> Grid<f32> {
        Grid {
            width: w,
            height: h,
            data: (0..w * h).map(|i| f(i % w, i / w) as f32).collect(),
        }
    }

    fn rms(a: &Grid<f32>, b: impl Fn(usize, usize) -> f64) -> f64 {
        let n = a.data.len() as f64;
        (a.data
            .iter()
            .enumerate()
            .map(|(i, &v)| (f64::from(v) - b(i % a.width, i / a.width)).powi(2))
            .sum::<f64>()
            / n)
            .sqrt()
    }

    #[test]
    fn noise_alone_is_smoothed_away() {
        let (w, h) = (160, 120);
        let noise = correlated_noise(w, h, 0.25, 1.0, 3);
        let dem = grid(w, h, |c, r| 5.0 + noise[r * w + c]);
        let out = wiener_denoise(&dem, 0.25, 1.0);
        let left = rms(&out, |_, _| 5.0);
        assert!(left < 0.25 / 5.0, "noise left {left:.4} m of 0.25");
    }

    #[test]
    fn relief_above_the_noise_is_kept() {
        let (w, h) = (160, 120);
        let noise = correlated_noise(w, h, 0.25, 1.0, 4);
        // Hills of 3–8 m, 8–15 posts wide: slopes up to about 0.4, like the mountains.
        let hills = [
            (30.0, 40.0, 8.0, 12.0),
            (90.0, 70.0, -5.0, 15.0),
            (120.0, 30.0, 3.0, 8.0),
            (60.0, 95.0, 6.0, 10.0),
        ];
        let hill = |c: usize, r: usize| {
            hills
                .iter()
                .map(|&(x, y, a, s): &(f64, f64, f64, f64)| {
                    a * (-0.5 * ((c as f64 - x).powi(2) + (r as f64 - y).powi(2)) / (s * s)).exp()
                })
                .sum::<f64>()
        };
        let dem = grid(w, h, |c, r| hill(c, r) + noise[r * w + c]);
        let out = wiener_denoise(&dem, 0.25, 1.0);
        let err = rms(&out, hill);
        // Against the best of fixed Gaussian smoothings, chosen knowing the truth.
        let best_fixed = [1.0, 1.5, 2.0, 3.0, 4.0]
            .iter()
            .map(|&sigma| {
                let raw: Vec<f64> = dem.data.iter().map(|&v| f64::from(v)).collect();
                let smooth = grid(w, h, {
                    let b = blur(&raw, w, h, sigma);
                    move |c, r| b[r * w + c]
                });
                rms(&smooth, hill)
            })
            .fold(f64::INFINITY, f64::min);
        assert!(
            err < 0.6 * 0.25 && err < 1.1 * best_fixed,
            "{err:.3} m from the hills (best fixed smoothing {best_fixed:.3}, noise 0.25 m)"
        );
    }

    fn model(heights: Grid<f32>, sigma_m: f64) -> ElevationModel {
        let info = ElevationInfo {
            image: "elevation.png".into(),
            gsd_m: 1.0,
            width_px: heights.width as u32,
            height_px: heights.height as u32,
            origin_x_m: 0.0,
            origin_y_m: 0.0,
            offset_m: 0.0,
            scale_m: 0.001,
            sigma_m,
        };
        ElevationModel::from_heights(info, heights).unwrap()
    }

    const MAP_SUN: SunInfo = SunInfo {
        azimuth_deg: 348.0,
        elevation_deg: 43.0,
    };
    const FLIGHT_SUN: SunInfo = SunInfo {
        azimuth_deg: 168.0,
        elevation_deg: 20.0,
    };

    #[test]
    fn a_flat_map_keeps_its_pixels() {
        let dem = model(grid(40, 40, |_, _| 3.0), 0.25);
        let map = GrayImage::from_fn(120, 120, |u, v| {
            image::Luma([((u * 7 + v * 3) % 200) as u8])
        });
        let out = relight(
            &map,
            0.25,
            &dem,
            &MAP_SUN,
            &FLIGHT_SUN,
            &RelightConfig::default(),
        );
        assert_eq!(out, map);
    }

    #[test]
    fn a_slope_is_lit_as_under_the_flight_sun() {
        // A Lambert-shaded ridge field under the map's sun, relit, against the same field
        // shaded under the flight's sun: the relit map is that image up to its mean.
        let hill = |x: f64, y: f64| 6.0 * (x / 25.0).sin() * (y / 18.0).cos();
        let dem = model(grid(60, 60, |c, r| hill(c as f64, -(r as f64))), 0.01);
        let cfg = RelightConfig::default();
        let render = |sun: &SunInfo| {
            let d = towards(sun);
            GrayImage::from_fn(200, 200, |u, v| {
                let (x, y) = (u as f64 * 0.25, -(v as f64) * 0.25);
                let e = 1e-3;
                let gx = (hill(x + e, y) - hill(x - e, y)) / (2.0 * e);
                let gy = (hill(x, y + e) - hill(x, y - e)) / (2.0 * e);
                let n = (gx * gx + gy * gy + 1.0).sqrt();
                let s = cfg.sky_fraction + ((-gx * d[0] - gy * d[1] + d[2]) / n).max(0.0);
                image::Luma([(120.0 * s).round() as u8])
            })
        };
        let (under_map, under_flight) = (render(&MAP_SUN), render(&FLIGHT_SUN));
        let out = relight(&under_map, 0.25, &dem, &MAP_SUN, &FLIGHT_SUN, &cfg);
        let ncc = |a: &GrayImage, b: &GrayImage| {
            let (a, b): (Vec<f64>, Vec<f64>) = a
                .pixels()
                .zip(b.pixels())
                .map(|(p, q)| (f64::from(p.0[0]), f64::from(q.0[0])))
                .unzip();
            let (ma, mb) = (
                a.iter().sum::<f64>() / a.len() as f64,
                b.iter().sum::<f64>() / b.len() as f64,
            );
            let cov: f64 = a.iter().zip(&b).map(|(x, y)| (x - ma) * (y - mb)).sum();
            let va: f64 = a.iter().map(|x| (x - ma).powi(2)).sum();
            let vb: f64 = b.iter().map(|y| (y - mb).powi(2)).sum();
            cov / (va * vb).sqrt()
        };
        let before = ncc(&under_map, &under_flight);
        let after = ncc(&out, &under_flight);
        assert!(
            before < 0.5,
            "the suns should light the slopes differently ({before:.3})"
        );
        assert!(after > 0.97, "relit {after:.3}, as taken {before:.3}");
    }
}
