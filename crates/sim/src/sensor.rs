//! Sensor model: optical blur, exposure, shot and read noise, gamma, 8-bit quantisation.
//!
//! Order follows the physics: the lens blurs the radiance, the exposure turns it into a
//! fraction of full scale, the photosite adds Poisson shot noise (Gaussian approximation,
//! σ = √electrons) and read noise, then the camera applies its gamma curve and quantises.
//! Noise is drawn per row from a ChaCha stream keyed by (seed, row), so the output does not
//! depend on how many threads rayon uses.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{Result, SimError};
use jointloc_formats::Grid;

/// Parameters of one camera's sensor.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SensorConfig {
    /// σ of the Gaussian optical blur, pixels (0: none).
    pub blur_sigma_px: f64,
    /// Fixed exposure: signal (fraction of full scale) = exposure · radiance. When absent, the
    /// exposure is chosen once per dataset so the `auto_quantile` of the scene radiance lands at
    /// `auto_level` of full scale (a fixed exposure over the flight, like a locked camera).
    pub exposure: Option<f64>,
    /// Quantile of the scene radiance used by the automatic exposure.
    pub auto_quantile: f64,
    /// Signal level (fraction of full scale) that quantile is mapped to.
    pub auto_level: f64,
    /// Electrons at full scale; shot-noise σ = √electrons (0: no shot noise).
    pub full_well_e: f64,
    /// Read-noise σ in electrons.
    pub read_noise_e: f64,
    /// Output encoding: DN = 255 · signal^gamma (1: linear; < 1 lifts the shadows).
    pub gamma: f64,
}

impl Default for SensorConfig {
    fn default() -> Self {
        Self {
            blur_sigma_px: 0.6,
            exposure: None,
            auto_quantile: 0.995,
            auto_level: 0.92,
            full_well_e: 4000.0,
            read_noise_e: 6.0,
            gamma: 1.0,
        }
    }
}

impl SensorConfig {
    /// A noise-free, blur-free sensor with a fixed exposure and a linear response (tests).
    pub fn ideal(exposure: f64) -> Self {
        Self {
            blur_sigma_px: 0.0,
            exposure: Some(exposure),
            full_well_e: 0.0,
            read_noise_e: 0.0,
            gamma: 1.0,
            ..Self::default()
        }
    }

    /// Checks ranges; `prefix` names the config section in errors.
    pub fn validate(&self, prefix: &'static str) -> Result<()> {
        let check = |ok: bool, value: f64, reason: &str| {
            if ok {
                Ok(())
            } else {
                Err(SimError::InvalidConfig {
                    field: prefix,
                    value: value.to_string(),
                    reason: reason.into(),
                })
            }
        };
        check(
            self.blur_sigma_px.is_finite() && (0.0..=20.0).contains(&self.blur_sigma_px),
            self.blur_sigma_px,
            "blur_sigma_px must be in [0, 20]",
        )?;
        if let Some(e) = self.exposure {
            check(e.is_finite() && e > 0.0, e, "exposure must be positive")?;
        }
        check(
            self.auto_quantile > 0.0 && self.auto_quantile <= 1.0,
            self.auto_quantile,
            "auto_quantile must be in (0, 1]",
        )?;
        check(
            self.auto_level > 0.0 && self.auto_level <= 1.0,
            self.auto_level,
            "auto_level must be in (0, 1]",
        )?;
        check(
            self.full_well_e.is_finite() && self.full_well_e >= 0.0,
            self.full_well_e,
            "full_well_e must be ≥ 0",
        )?;
        check(
            self.read_noise_e.is_finite() && self.read_noise_e >= 0.0,
            self.read_noise_e,
            "read_noise_e must be ≥ 0",
        )?;
        check(
            self.gamma.is_finite() && self.gamma > 0.0 && self.gamma <= 5.0,
            self.gamma,
            "gamma must be in (0, 5]",
        )
    }

    /// The exposure to use for a scene with these radiance values: the fixed one, or the
    /// automatic one (from a regular subsample of at most ~1 M values).
    pub fn exposure_for(&self, radiance: &[f32]) -> f64 {
        if let Some(e) = self.exposure {
            return e;
        }
        let stride = (radiance.len() / 1_000_000).max(1);
        let mut sample: Vec<f32> = radiance
            .iter()
            .step_by(stride)
            .copied()
            .filter(|v| v.is_finite())
            .collect();
        if sample.is_empty() {
            return 1.0;
        }
        let k = ((sample.len() - 1) as f64 * self.auto_quantile).round() as usize;
        let (_, q, _) = sample.select_nth_unstable_by(k, f32::total_cmp);
        let q = *q as f64;
        if q > 1e-12 { self.auto_level / q } else { 1.0 }
    }
}

/// Turns linear radiance into an 8-bit image (row-major, same size).
pub fn expose(radiance: &Grid<f32>, cfg: &SensorConfig, exposure: f64, seed: u64) -> Grid<u8> {
    let blurred = gaussian_blur(radiance, cfg.blur_sigma_px);
    let w = radiance.width;
    let mut out = Grid::filled(w, radiance.height, 0u8);
    let shot = cfg.full_well_e > 0.0;
    let read = if cfg.full_well_e > 0.0 {
        cfg.read_noise_e / cfg.full_well_e
    } else {
        0.0
    };
    let inv_gamma_is_one = cfg.gamma == 1.0;
    out.data
        .par_chunks_mut(w.max(1))
        .zip(blurred.data.par_chunks(w.max(1)))
        .enumerate()
        .for_each(|(row, (dst, src))| {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            rng.set_stream(row as u64);
            for (d, &l) in dst.iter_mut().zip(src) {
                let mut s = (exposure * l as f64).max(0.0);
                if shot {
                    let n: f64 = StandardNormal.sample(&mut rng);
                    s += n * (s / cfg.full_well_e).sqrt();
                }
                if read > 0.0 {
                    let n: f64 = StandardNormal.sample(&mut rng);
                    s += n * read;
                }
                let s = s.clamp(0.0, 1.0);
                let encoded = if inv_gamma_is_one {
                    s
                } else {
                    s.powf(cfg.gamma)
                };
                *d = (encoded * 255.0).round() as u8;
            }
        });
    out
}

/// The normalised 1-D Gaussian kernel of σ > 0 samples, 3σ to each side.
pub fn gaussian_kernel(sigma: f64) -> Vec<f32> {
    let radius = (3.0 * sigma).ceil() as isize;
    let mut kernel: Vec<f32> = (-radius..=radius)
        .map(|k| (-0.5 * (k as f64 / sigma).powi(2)).exp() as f32)
        .collect();
    let sum: f32 = kernel.iter().sum();
    kernel.iter_mut().for_each(|k| *k /= sum);
    kernel
}

/// Separable Gaussian blur with clamped borders; σ ≤ 0 returns a copy.
pub fn gaussian_blur(image: &Grid<f32>, sigma: f64) -> Grid<f32> {
    if sigma <= 0.0 || image.width == 0 || image.height == 0 {
        return image.clone();
    }
    let kernel = gaussian_kernel(sigma);
    let radius = (kernel.len() / 2) as isize;
    let (w, h) = (image.width, image.height);
    let clamp = |i: isize, n: usize| i.clamp(0, n as isize - 1) as usize;
    let mut tmp = Grid::filled(w, h, 0.0f32);
    tmp.data
        .par_chunks_mut(w)
        .zip(image.data.par_chunks(w))
        .for_each(|(dst, src)| {
            for (x, d) in dst.iter_mut().enumerate() {
                *d = kernel
                    .iter()
                    .enumerate()
                    .map(|(k, &wt)| wt * src[clamp(x as isize + k as isize - radius, w)])
                    .sum();
            }
        });
    let mut out = Grid::filled(w, h, 0.0f32);
    out.data.par_chunks_mut(w).enumerate().for_each(|(y, dst)| {
        for (k, &wt) in kernel.iter().enumerate() {
            let src = clamp(y as isize + k as isize - radius, h);
            let row = &tmp.data[src * w..(src + 1) * w];
            for (d, &s) in dst.iter_mut().zip(row) {
                *d += wt * s;
            }
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(w: usize, h: usize) -> Grid<f32> {
        let mut g = Grid::filled(w, h, 0.0f32);
        for (k, v) in g.data.iter_mut().enumerate() {
            *v = ((k % w) as f32 / w as f32) * 0.8 + 0.1;
        }
        g
    }

    #[test]
    fn output_does_not_depend_on_thread_count() {
        let image = ramp(97, 61);
        let cfg = SensorConfig::default();
        let run = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| expose(&image, &cfg, 1.0, 42))
        };
        let a = run(1);
        assert_eq!(a, run(3));
        assert_ne!(a, expose(&image, &cfg, 1.0, 43));
    }

    #[test]
    fn ideal_sensor_quantises_linearly() {
        let image = ramp(50, 3);
        let out = expose(&image, &SensorConfig::ideal(1.0), 1.0, 0);
        for (o, i) in out.data.iter().zip(&image.data) {
            assert_eq!(*o, (i * 255.0).round() as u8);
        }
    }

    #[test]
    fn noise_has_the_modelled_strength() {
        let image = Grid::filled(200, 200, 0.5f32);
        let cfg = SensorConfig {
            blur_sigma_px: 0.0,
            gamma: 1.0,
            ..SensorConfig::default()
        };
        let out = expose(&image, &cfg, 1.0, 7);
        let vals: Vec<f64> = out.data.iter().map(|&v| v as f64 / 255.0).collect();
        let mean = vals.iter().sum::<f64>() / vals.len() as f64;
        let std = (vals.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / vals.len() as f64).sqrt();
        let expected =
            (0.5 / cfg.full_well_e + (cfg.read_noise_e / cfg.full_well_e).powi(2)).sqrt();
        assert!((mean - 0.5).abs() < 0.002, "mean {mean}");
        // Quantisation adds 1/(255·√12) in quadrature.
        let expected = (expected.powi(2) + (1.0 / 255.0f64).powi(2) / 12.0).sqrt();
        assert!(
            (std / expected - 1.0).abs() < 0.1,
            "std {std} vs {expected}"
        );
    }

    #[test]
    fn blur_keeps_the_mean_and_the_centroid() {
        let mut g = Grid::filled(31, 31, 0.0f32);
        *g.at_mut(12, 17) = 1.0;
        let b = gaussian_blur(&g, 1.2);
        let total: f32 = b.data.iter().sum();
        assert!((total - 1.0).abs() < 1e-5);
        let (mut cx, mut cy) = (0.0, 0.0);
        for (k, v) in b.data.iter().enumerate() {
            cx += (k % 31) as f32 * v;
            cy += (k / 31) as f32 * v;
        }
        assert!((cx - 12.0).abs() < 1e-4 && (cy - 17.0).abs() < 1e-4);
    }

    #[test]
    fn auto_exposure_maps_the_quantile_to_the_level() {
        let values: Vec<f32> = (0..1001).map(|k| k as f32 / 1000.0).collect();
        let cfg = SensorConfig {
            auto_quantile: 0.5,
            auto_level: 0.25,
            ..SensorConfig::default()
        };
        assert!((cfg.exposure_for(&values) - 0.5).abs() < 1e-6);
        assert_eq!(SensorConfig::ideal(2.0).exposure_for(&values), 2.0);
    }
}
