//! Dense registration of a virtual frame (a [`crate::mosaic::Mosaic`], north-up at the map's
//! GSD) against the map by normalised cross-correlation of gradient magnitudes, the way a
//! lander's vision system correlates its descent images with an orbital map.
//!
//! Why not the learned matchers: on a 10 m flight over a 25 cm map the mosaic is a strip a
//! few tens of map pixels wide, and XFeat + LighterGlue found no match on any of 27 such
//! strips even with the map's sun equal to the flight's (`docs/absloc.md`), while the
//! correlation of the same strips peaks within a map pixel or two of the truth. Gradient
//! magnitudes rather than grey levels: a crater rim is an edge under any sun, while its
//! shading (which side is lit) flips with the sun's azimuth, and albedo patches, which grey
//! levels follow, give broad peaks.
//!
//! The search is exhaustive over a window of the map (the prior ± a radius), coarse to fine:
//! every placement at half resolution, then the best one refined at full resolution, with a
//! parabola through the peak for the sub-pixel shift. A peak is accepted when it is high
//! enough and stands out from the best placement elsewhere (outside an exclusion zone): a
//! repetitive or featureless ground gives several peaks of the same height.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::whole_map::WholeMapConfig;

/// Settings of the correlation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CorrelationConfig {
    /// How far from the prior the view's centre is searched, metres.
    pub search_radius_m: f64,
    /// Smallest accepted correlation at the peak.
    pub min_peak: f64,
    /// Smallest ratio of the peak to the best correlation outside its exclusion zone.
    pub min_peak_ratio: f64,
    /// Gaussian smoothing before the gradient, map pixels (noise of the orbital image).
    pub smoothing_px: f64,
    /// Half-size of the exclusion zone around the peak, map pixels.
    pub exclusion_px: usize,
    /// Fewest valid view pixels (after the erosion) worth correlating.
    pub min_valid_px: usize,
    /// Angles tried when no heading is known: 24 leaves ≤ 7.5° of rotation, which a
    /// 200-pixel view still correlates through.
    pub rotation_hypotheses: usize,
    /// The heading is refined around the given one (or the sweep's best) by halving steps,
    /// starting at this step (given heading), degrees: the prior's heading comes from the
    /// SLAM and earlier fixes, and a few degrees off turn a 50 m view by metres at its end.
    pub heading_step_deg: f64,
    /// The smallest step of that refinement, degrees.
    pub min_heading_step_deg: f64,
    /// A placement whose confidence (SSIM × correlation, the paper's `w`) is below this is
    /// no fix. On six development flights at 10 m (three under suns 41–156° apart) all 20
    /// placements more than 2 m off had w < 0.06 and 416 of the 421 within 1 m had w ≥ 0.08.
    pub min_confidence: f64,
    /// With no prior at all (no take-off position, no fix yet), the whole map is searched
    /// coarse to fine (`[absloc.correlation.whole_map]`; `candidates = 0`: no fix until a
    /// prior exists).
    pub whole_map: WholeMapConfig,
}

impl Default for CorrelationConfig {
    fn default() -> Self {
        Self {
            search_radius_m: 25.0,
            min_peak: 0.25,
            min_peak_ratio: 1.25,
            smoothing_px: 1.0,
            exclusion_px: 4,
            min_valid_px: 1500,
            rotation_hypotheses: 24,
            heading_step_deg: 2.0,
            min_heading_step_deg: 0.5,
            min_confidence: 0.07,
            whole_map: WholeMapConfig::default(),
        }
    }
}

/// A grey-level grid, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Grid {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

impl Grid {
    /// An image's grey levels.
    pub fn from_image(image: &image::GrayImage) -> Grid {
        Grid {
            width: image.width() as usize,
            height: image.height() as usize,
            data: image.as_raw().iter().map(|&p| p as f32).collect(),
        }
    }

    fn at(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }

    /// Gradient magnitude after a Gaussian of `sigma` pixels (central differences).
    pub fn gradient_magnitude(&self, sigma: f64) -> Grid {
        let s = gaussian(self, sigma);
        let (w, h) = (self.width, self.height);
        let mut data = vec![0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let gx = s.at((x + 1).min(w - 1), y) - s.at(x.saturating_sub(1), y);
                let gy = s.at(x, (y + 1).min(h - 1)) - s.at(x, y.saturating_sub(1));
                data[y * w + x] = 0.5 * (gx * gx + gy * gy).sqrt();
            }
        }
        Grid {
            width: w,
            height: h,
            data,
        }
    }

    /// 2 × 2 means (a trailing odd row or column dropped).
    pub(crate) fn halved(&self) -> Grid {
        let (w, h) = (self.width / 2, self.height / 2);
        let data = (0..w * h)
            .map(|i| {
                let (x, y) = (2 * (i % w), 2 * (i / w));
                0.25 * (self.at(x, y)
                    + self.at(x + 1, y)
                    + self.at(x, y + 1)
                    + self.at(x + 1, y + 1))
            })
            .collect();
        Grid {
            width: w,
            height: h,
            data,
        }
    }
}

/// Separable Gaussian blur, borders clamped.
fn gaussian(g: &Grid, sigma: f64) -> Grid {
    if sigma <= 0.0 {
        return g.clone();
    }
    let r = (3.0 * sigma).ceil() as isize;
    let k: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp() as f32)
        .collect();
    let norm: f32 = k.iter().sum();
    let (w, h) = (g.width as isize, g.height as isize);
    let pass = |src: &[f32], horizontal: bool| -> Vec<f32> {
        let mut out = vec![0f32; src.len()];
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0f32;
                for (j, kv) in k.iter().enumerate() {
                    let o = j as isize - r;
                    let (xx, yy) = if horizontal {
                        ((x + o).clamp(0, w - 1), y)
                    } else {
                        (x, (y + o).clamp(0, h - 1))
                    };
                    acc += kv * src[(yy * w + xx) as usize];
                }
                out[(y * w + x) as usize] = acc / norm;
            }
        }
        out
    };
    let data = pass(&pass(&g.data, true), false);
    Grid {
        width: g.width,
        height: g.height,
        data,
    }
}

/// The accepted placement of the view in the window.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Peak {
    /// Window pixel of the view's pixel (0, 0), sub-pixel.
    pub offset: [f64; 2],
    /// Correlation at the peak.
    pub score: f64,
    /// Best correlation outside the exclusion zone.
    pub second: f64,
}

/// Why a correlation gave no placement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum NoPeak {
    /// Too little of the view is valid, or the window is smaller than the view.
    TooSmall { valid_px: usize },
    /// The peak is too low.
    Low { score: f64 },
    /// Another placement is almost as good.
    Ambiguous { score: f64, second: f64 },
    /// The confidence of the best placement is too low.
    LowConfidence { confidence: f64 },
}

/// Masked correlation of `view` (pixels where `valid`) at every placement in `window`.
/// Returns the scores, row-major over placements (`window − view + 1` per axis).
fn scores(view: &Grid, valid: &[bool], window: &Grid) -> (Vec<f64>, usize, usize) {
    let idx: Vec<(usize, f64)> = {
        let pts: Vec<usize> = (0..view.data.len()).filter(|&i| valid[i]).collect();
        let n = pts.len().max(1) as f64;
        let mean = pts.iter().map(|&i| view.data[i] as f64).sum::<f64>() / n;
        pts.iter()
            .map(|&i| {
                let (x, y) = (i % view.width, i / view.width);
                (y * window.width + x, view.data[i] as f64 - mean)
            })
            .collect()
    };
    let var_v: f64 = idx.iter().map(|(_, v)| v * v).sum();
    let n = idx.len() as f64;
    let (pw, ph) = (
        window.width - view.width + 1,
        window.height - view.height + 1,
    );
    let out: Vec<f64> = (0..pw * ph)
        .into_par_iter()
        .map(|p| {
            let base = (p / pw) * window.width + p % pw;
            let (mut s, mut s2, mut cross) = (0.0, 0.0, 0.0);
            for &(o, v) in &idx {
                let m = window.data[base + o] as f64;
                s += m;
                s2 += m * m;
                cross += v * m;
            }
            let var_m = s2 - s * s / n;
            if var_m <= 1e-12 || var_v <= 1e-12 {
                0.0
            } else {
                cross / (var_m * var_v).sqrt()
            }
        })
        .collect();
    (out, pw, ph)
}

/// Places `view` (valid where `valid`) in `window` by correlation, coarse to fine.
pub fn correlate(
    view: &Grid,
    valid: &[bool],
    window: &Grid,
    config: &CorrelationConfig,
) -> Result<Peak, NoPeak> {
    let valid_px = valid.iter().filter(|&&v| v).count();
    if valid_px < config.min_valid_px
        || window.width < view.width
        || window.height < view.height
        || view.width < 4
        || view.height < 4
    {
        return Err(NoPeak::TooSmall { valid_px });
    }
    // Half resolution: every placement.
    let coarse_view = view.halved();
    let coarse_valid: Vec<bool> = (0..coarse_view.data.len())
        .map(|i| {
            let (x, y) = (2 * (i % coarse_view.width), 2 * (i / coarse_view.width));
            let at = |x: usize, y: usize| valid[y * view.width + x];
            at(x, y) && at(x + 1, y) && at(x, y + 1) && at(x + 1, y + 1)
        })
        .collect();
    let coarse_window = window.halved();
    let (cs, cw, _) = scores(&coarse_view, &coarse_valid, &coarse_window);
    let best = argmax(&cs);
    let (bx, by) = (best % cw, best / cw);
    let ex = config.exclusion_px.div_ceil(2);
    let second = cs
        .iter()
        .enumerate()
        .filter(|(i, _)| (i % cw).abs_diff(bx) > ex || (i / cw).abs_diff(by) > ex)
        .map(|(_, &s)| s)
        .fold(f64::NEG_INFINITY, f64::max);
    // Full resolution around the coarse peak.
    let (x0, y0) = ((2 * bx).saturating_sub(3), (2 * by).saturating_sub(3));
    let (pw, ph) = (
        window.width - view.width + 1,
        window.height - view.height + 1,
    );
    let (x1, y1) = ((2 * bx + 4).min(pw), (2 * by + 4).min(ph));
    let sub = Grid {
        width: x1 - x0 + view.width - 1,
        height: y1 - y0 + view.height - 1,
        data: (y0..y1 + view.height - 1)
            .flat_map(|y| (x0..x1 + view.width - 1).map(move |x| (x, y)))
            .map(|(x, y)| window.at(x, y))
            .collect(),
    };
    let (fs, fw, fh) = scores(view, valid, &sub);
    let f = argmax(&fs);
    let (fx, fy) = (f % fw, f / fw);
    let score = fs[f];
    let refine = |i: usize, n: usize, at: &dyn Fn(usize) -> f64| -> f64 {
        if i == 0 || i + 1 >= n {
            return 0.0;
        }
        let (a, b, c) = (at(i - 1), at(i), at(i + 1));
        let d = a - 2.0 * b + c;
        if d.abs() < 1e-12 {
            0.0
        } else {
            (0.5 * (a - c) / d).clamp(-0.5, 0.5)
        }
    };
    let dx = refine(fx, fw, &|x| fs[fy * fw + x]);
    let dy = refine(fy, fh, &|y| fs[y * fw + fx]);
    if score < config.min_peak {
        return Err(NoPeak::Low { score });
    }
    // The coarse level's peak against the coarse level's runner-up.
    let coarse_peak = cs[best];
    if second > 0.0 && coarse_peak < config.min_peak_ratio * second {
        return Err(NoPeak::Ambiguous {
            score: coarse_peak,
            second,
        });
    }
    Ok(Peak {
        offset: [(x0 + fx) as f64 + dx, (y0 + fy) as f64 + dy],
        score,
        second,
    })
}

fn argmax(v: &[f64]) -> usize {
    let mut best = 0;
    for (i, &s) in v.iter().enumerate() {
        if s > v[best] {
            best = i;
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A textured map: blobs of random size and brightness on noise.
    fn map(w: usize, h: usize, seed: u64) -> Grid {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let blobs: Vec<(f64, f64, f64, f64)> = (0..w * h / 150)
            .map(|_| {
                (
                    rng.random_range(0.0..w as f64),
                    rng.random_range(0.0..h as f64),
                    rng.random_range(1.5..6.0),
                    rng.random_range(-60.0..60.0),
                )
            })
            .collect();
        let data = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                let mut v = 128.0;
                for &(bx, by, r, a) in &blobs {
                    let d2 = (x - bx).powi(2) + (y - by).powi(2);
                    if d2 < 9.0 * r * r {
                        v += a * (-d2 / (2.0 * r * r)).exp();
                    }
                }
                v as f32
            })
            .collect();
        Grid {
            width: w,
            height: h,
            data,
        }
    }

    #[test]
    fn a_strip_of_the_map_is_found_where_it_was_cut_to_a_tenth_of_a_pixel() {
        let m = map(160, 160, 7).gradient_magnitude(1.0);
        // The view: a 60 × 60 window of the map at (47.3, 81.6) (bilinear), valid on a
        // diagonal strip 20 pixels wide, with noise.
        let (ox, oy) = (47.3, 81.6);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let (vw, vh) = (60, 60);
        let mut data = Vec::new();
        let mut valid = Vec::new();
        for y in 0..vh {
            for x in 0..vw {
                let (sx, sy) = (x as f64 + ox, y as f64 + oy);
                let (x0, y0) = (sx.floor() as usize, sy.floor() as usize);
                let (fx, fy) = ((sx - x0 as f64) as f32, (sy - y0 as f64) as f32);
                let v = m.at(x0, y0) * (1.0 - fx) * (1.0 - fy)
                    + m.at(x0 + 1, y0) * fx * (1.0 - fy)
                    + m.at(x0, y0 + 1) * (1.0 - fx) * fy
                    + m.at(x0 + 1, y0 + 1) * fx * fy;
                data.push(v + rng.random_range(-1.0..1.0));
                valid.push((x as i64 - y as i64).abs() < 20);
            }
        }
        let view = Grid {
            width: vw,
            height: vh,
            data,
        };
        let config = CorrelationConfig {
            min_valid_px: 500,
            ..Default::default()
        };
        let p = correlate(&view, &valid, &m, &config).unwrap();
        assert!(
            (p.offset[0] - ox).abs() < 0.15 && (p.offset[1] - oy).abs() < 0.15,
            "{p:?}"
        );
        assert!(p.score > 0.9 && p.second < 0.8 * p.score, "{p:?}");
    }

    #[test]
    fn a_flat_map_gives_no_placement() {
        let flat = Grid {
            width: 100,
            height: 100,
            data: vec![100.0; 10_000],
        };
        let view = map(40, 40, 1);
        let valid = vec![true; 1600];
        let config = CorrelationConfig {
            min_valid_px: 500,
            ..Default::default()
        };
        assert!(matches!(
            correlate(&view, &valid, &flat, &config),
            Err(NoPeak::Low { .. })
        ));
        // Too few valid pixels.
        assert!(matches!(
            correlate(&view, &vec![false; 1600], &flat, &config),
            Err(NoPeak::TooSmall { valid_px: 0 })
        ));
    }
}
