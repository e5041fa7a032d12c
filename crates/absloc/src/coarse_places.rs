//! Where on the whole map a virtual frame may lie: two coarse signals, then a rescoring at
//! twice their resolution (issue #29, the first fix with no prior).
//!
//! [`crate::whole_map`] correlates a view with the whole map at cells of `factor` map pixels
//! (2 m on a 25 cm map). A first version used the gradient magnitude alone and kept the 8 best
//! placements over all headings; under a sun 150–180° from the map's, the true place was
//! never among them on three fresh 2 km flights (rims' shadows fall on the other side, so the
//! gradient moves). The grey levels pooled into the same cells (the ground's albedo, which
//! does not move with the sun) placed it far better, but a view early in a flight covers only
//! 25–50 cells of either, too few to single out one place among a million. So:
//!
//! 1. both signals, gradient magnitude and grey level, are correlated with the whole map at
//!    `factor` through the FFT, and the best [`WholeMapConfig::per_heading`] placements of
//!    each heading and each signal are kept (a few thousand);
//! 2. each is rescored at cells of `factor / 2` (four times as many cells in the view) by the
//!    sum of both signals' masked NCC, moved by up to [`WholeMapConfig::rescore_cells`]
//!    half-cells and turned to the neighbouring headings, directly (a few thousand small
//!    sums, not another FFT);
//! 3. the best distinct places go to the fine correlation.
//!
//! On four 2 km flights at 10 m (suns 31–173° apart) the true place was among the 8 places of
//! the gradient alone in 3 of 109 whole-map searches, all on the flight under the close sun;
//! rescored, it was among the 8 in 20 of the 33 searches logged on the two flights under
//! suns 160° and 156° apart, first in 15 (`docs/absloc.md` §"With no prior").

use rayon::prelude::*;

use crate::correlate::Grid;
use crate::whole_map::{CoarseMap, WholeMapConfig, distinct, peaks, pool, pool_map};

/// The map prepared for [`CoarsePlaces::search`]: both signals at `factor` (with their
/// spectra) and at `factor / 2`.
#[derive(Debug)]
pub struct CoarsePlaces {
    factor: usize,
    gradient: CoarseMap,
    intensity: CoarseMap,
    half_gradient: Grid,
    half_intensity: Grid,
}

/// One view to place, in map pixels at one heading: its gradient magnitude, its grey levels,
/// the pixels it covers and where in it the place to report lies (the principal point).
#[derive(Debug, Clone)]
pub struct ViewSignals {
    pub gradient: Grid,
    pub intensity: Grid,
    pub valid: Vec<bool>,
    pub principal: [f64; 2],
}

/// A place found for view `view`: its top-left at map pixel `(x, y)`, its principal point
/// at map pixel `at`, its rescored `score` (sum of two NCCs, up to 2).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CoarsePlace {
    pub view: usize,
    pub x: usize,
    pub y: usize,
    pub at: [f64; 2],
    pub score: f64,
}

impl CoarsePlaces {
    /// Pools `map` for cells of `factor` pixels (even, at least 2; rounded up to that), the
    /// gradient magnitude after a Gaussian of `smoothing_px`. `None` when the map is smaller
    /// than 2 × 2 cells.
    pub fn new(map: &image::GrayImage, factor: usize, smoothing_px: f64) -> Option<Self> {
        let half = factor.div_ceil(2).max(1);
        let half_gradient = pool_map(map, half, Some(smoothing_px))?;
        let half_intensity = pool_map(map, half, None)?;
        let coarse = |g: &Grid| {
            let grid = g.halved();
            (grid.width >= 2 && grid.height >= 2).then(|| CoarseMap::from_grid(grid, 2 * half))
        };
        Some(Self {
            factor: 2 * half,
            gradient: coarse(&half_gradient)?,
            intensity: coarse(&half_intensity)?,
            half_gradient,
            half_intensity,
        })
    }

    /// Map pixels per coarse cell.
    pub fn factor(&self) -> usize {
        self.factor
    }

    /// The best `cfg.candidates` distinct places of `views` on the map, best first. More than
    /// two views are taken as consecutive headings of a full turn, and each coarse placement
    /// of one is also rescored with its neighbours (the true heading may lie between two).
    pub fn search(&self, views: &[ViewSignals], cfg: &WholeMapConfig) -> Vec<CoarsePlace> {
        let (f, half) = (self.factor, self.factor / 2);
        let n = views.len();
        // Coarse placements of each view, as the map pixel of its principal point.
        let starts: Vec<(usize, [f64; 2])> = views
            .par_iter()
            .enumerate()
            .flat_map_iter(|(i, v)| {
                let (g, ok) = pool(&v.gradient, &v.valid, f);
                let (gray, _) = pool(&v.intensity, &v.valid, f);
                let mut at: Vec<(usize, usize)> = [(&self.gradient, &g), (&self.intensity, &gray)]
                    .into_iter()
                    .filter_map(|(map, cells)| map.ncc(cells, &ok))
                    .flat_map(|(s, w, h)| peaks(&s, w, h, cfg.per_heading, cfg.exclusion_cells))
                    .map(|p| (p.x, p.y))
                    .collect();
                at.sort_unstable();
                at.dedup();
                at.into_iter().map(move |(x, y)| {
                    let p = [
                        (x * f) as f64 + v.principal[0],
                        (y * f) as f64 + v.principal[1],
                    ];
                    (i, p)
                })
            })
            .collect();
        let masked: Vec<Option<(Masked, Masked)>> = views
            .par_iter()
            .map(|v| {
                let (g, ok) = pool(&v.gradient, &v.valid, half);
                let (gray, _) = pool(&v.intensity, &v.valid, half);
                Some((Masked::new(&g, &ok)?, Masked::new(&gray, &ok)?))
            })
            .collect();
        let r = cfg.rescore_cells as i64;
        let mut scored: Vec<CoarsePlace> = starts
            .par_iter()
            .filter_map(|&(i, p)| {
                let turns: &[usize] = if n > 2 { &[n - 1, 0, 1] } else { &[0] };
                let mut best: Option<CoarsePlace> = None;
                for j in turns.iter().map(|t| (i + t) % n) {
                    let Some((gradient, intensity)) = &masked[j] else {
                        continue;
                    };
                    let principal = views[j].principal;
                    let hx0 = ((p[0] - principal[0]) / half as f64).round() as i64;
                    let hy0 = ((p[1] - principal[1]) / half as f64).round() as i64;
                    for (dx, dy) in (-r..=r).flat_map(|dy| (-r..=r).map(move |dx| (dx, dy))) {
                        let (hx, hy) = (hx0 + dx, hy0 + dy);
                        let (Some(a), Some(b)) = (
                            gradient.ncc_at(&self.half_gradient, hx, hy),
                            intensity.ncc_at(&self.half_intensity, hx, hy),
                        ) else {
                            continue;
                        };
                        if best.is_none_or(|b0| a + b > b0.score) {
                            let (x, y) = (hx as usize * half, hy as usize * half);
                            best = Some(CoarsePlace {
                                view: j,
                                x,
                                y,
                                at: [x as f64 + principal[0], y as f64 + principal[1]],
                                score: a + b,
                            });
                        }
                    }
                }
                best
            })
            .collect();
        scored.sort_by(|a, b| {
            b.score
                .total_cmp(&a.score)
                .then((a.view, a.y, a.x).cmp(&(b.view, b.y, b.x)))
        });
        let exclusion = cfg.exclusion_cells * f;
        distinct(scored, cfg.candidates, exclusion, |p| {
            (p.at[0].max(0.0) as usize, p.at[1].max(0.0) as usize)
        })
    }
}

/// Partial sums kept apart in [`Masked::ncc_at`], so that the compiler vectorises it.
const LANES: usize = 4;

/// A view's cells with their mean removed, the valid ones as runs along rows (contiguous
/// in the view and in the map under it), for direct NCC sums.
struct Masked {
    width: usize,
    height: usize,
    /// (row, first column, first value) of each run of valid cells; a run ends where the next
    /// begins in `values`.
    runs: Vec<(usize, usize, usize)>,
    /// Value − mean of each valid cell, row-major.
    values: Vec<f64>,
    norm: f64,
}

impl Masked {
    /// `None` when fewer than 3 cells are valid or they have no variance.
    fn new(grid: &Grid, valid: &[bool]) -> Option<Self> {
        let idx: Vec<usize> = (0..grid.data.len()).filter(|&i| valid[i]).collect();
        if idx.len() < 3 {
            return None;
        }
        let mean = idx.iter().map(|&i| grid.data[i] as f64).sum::<f64>() / idx.len() as f64;
        let values: Vec<f64> = idx.iter().map(|&i| grid.data[i] as f64 - mean).collect();
        let mut runs = Vec::new();
        for (k, &i) in idx.iter().enumerate() {
            let (x, y) = (i % grid.width, i / grid.width);
            let continues = k > 0 && idx[k - 1] + 1 == i && x > 0;
            if !continues {
                runs.push((y, x, k));
            }
        }
        let norm = values.iter().map(|t| t * t).sum::<f64>().sqrt();
        (norm > 1e-9).then_some(Self {
            width: grid.width,
            height: grid.height,
            runs,
            values,
            norm,
        })
    }

    /// Masked NCC with `map` when the view's top-left is at map cell `(x, y)`; `None` when the
    /// view leaves the map or the map under it is flat.
    fn ncc_at(&self, map: &Grid, x: i64, y: i64) -> Option<f64> {
        if x < 0
            || y < 0
            || x as usize + self.width > map.width
            || y as usize + self.height > map.height
        {
            return None;
        }
        let (x, y) = (x as usize, y as usize);
        let n = self.values.len() as f64;
        // Four lanes of partial sums (vectorised), added at the end.
        let (mut sm, mut sm2, mut stm) = ([0.0f64; LANES], [0.0f64; LANES], [0.0f64; LANES]);
        for (r, &(cy, cx, start)) in self.runs.iter().enumerate() {
            let end = self
                .runs
                .get(r + 1)
                .map_or(self.values.len(), |next| next.2);
            let row = (y + cy) * map.width + x + cx;
            let under = &map.data[row..row + (end - start)];
            let values = &self.values[start..end];
            let mut t_chunks = values.chunks_exact(LANES);
            let mut m_chunks = under.chunks_exact(LANES);
            for (t, m) in (&mut t_chunks).zip(&mut m_chunks) {
                for l in 0..LANES {
                    let m = m[l] as f64;
                    sm[l] += m;
                    sm2[l] += m * m;
                    stm[l] += t[l] * m;
                }
            }
            for (&t, &m) in t_chunks.remainder().iter().zip(m_chunks.remainder()) {
                let m = m as f64;
                sm[0] += m;
                sm2[0] += m * m;
                stm[0] += t * m;
            }
        }
        let (sm, sm2, stm) = (
            sm.iter().sum::<f64>(),
            sm2.iter().sum::<f64>(),
            stm.iter().sum::<f64>(),
        );
        let var_m = sm2 - sm * sm / n;
        (var_m > 1e-9).then(|| stm / (var_m.sqrt() * self.norm))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::GrayImage;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A map of smooth blobs (an albedo) with fine speckle on top.
    fn terrain(w: u32, h: u32, seed: u64) -> GrayImage {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let blobs: Vec<(f64, f64, f64, f64)> = (0..w * h / 400)
            .map(|_| {
                (
                    rng.random::<f64>() * w as f64,
                    rng.random::<f64>() * h as f64,
                    3.0 + rng.random::<f64>() * 10.0,
                    rng.random::<f64>() * 2.0 - 1.0,
                )
            })
            .collect();
        GrayImage::from_fn(w, h, |x, y| {
            let mut v = 120.0;
            for &(bx, by, r, a) in &blobs {
                let d2 = (x as f64 - bx).powi(2) + (y as f64 - by).powi(2);
                v += 60.0 * a * (-d2 / (2.0 * r * r)).exp();
            }
            v += rng.random::<f64>() * 30.0 - 15.0;
            image::Luma([v.clamp(0.0, 255.0) as u8])
        })
    }

    fn signals(map: &GrayImage, x0: u32, y0: u32, w: u32, h: u32, valid: &[bool]) -> ViewSignals {
        let cut = image::imageops::crop_imm(map, x0, y0, w, h).to_image();
        let intensity = Grid::from_image(&cut);
        ViewSignals {
            gradient: intensity.gradient_magnitude(1.0),
            intensity,
            valid: valid.to_vec(),
            principal: [w as f64 / 2.0, h as f64 / 2.0],
        }
    }

    #[test]
    fn a_cut_of_the_map_is_found_first_among_other_views() {
        let map = terrain(480, 400, 3);
        let places = CoarsePlaces::new(&map, 8, 1.0).unwrap();
        assert_eq!(places.factor(), 8);
        let (w, h) = (96u32, 64u32);
        // A strip of the view is covered, as early in a flight.
        let valid: Vec<bool> = (0..w * h)
            .map(|i| (i / w) % h >= 16 && (i / w) < 48)
            .collect();
        let cut = signals(&map, 200, 152, w, h, &valid);
        let elsewhere = signals(&terrain(480, 400, 9), 40, 40, w, h, &valid);
        let cfg = WholeMapConfig::default();
        let found = places.search(&[elsewhere, cut], &cfg);
        assert_eq!(found[0].view, 1);
        assert!(
            found[0].x.abs_diff(200) <= 4 && found[0].y.abs_diff(152) <= 4,
            "{found:?}"
        );
        assert!(found[0].score > 1.8, "{found:?}");
        assert!(found.len() <= cfg.candidates);
        for pair in found.windows(2) {
            assert!(pair[0].score >= pair[1].score);
        }
    }

    #[test]
    fn the_rescoring_sum_is_the_masked_ncc() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let map = Grid {
            width: 30,
            height: 20,
            data: (0..600).map(|_| rng.random::<f32>()).collect(),
        };
        let view = Grid {
            width: 6,
            height: 5,
            data: (0..30).map(|_| rng.random::<f32>()).collect(),
        };
        let valid: Vec<bool> = (0..30).map(|i| i % 7 != 3).collect();
        let masked = Masked::new(&view, &valid).unwrap();
        let coarse = CoarseMap::from_grid(map.clone(), 1);
        let (scores, pw, _) = coarse.ncc(&view, &valid).unwrap();
        for (x, y) in [(0, 0), (24, 15), (11, 7)] {
            let direct = masked.ncc_at(&map, x, y).unwrap();
            assert!((direct - scores[y as usize * pw + x as usize]).abs() < 1e-4);
        }
        assert!(masked.ncc_at(&map, 25, 0).is_none());
        assert!(masked.ncc_at(&map, -1, 0).is_none());
        assert!(Masked::new(&view, &[false; 30]).is_none());
    }

    #[test]
    fn a_map_too_small_for_two_cells_is_none() {
        assert!(CoarsePlaces::new(&GrayImage::new(12, 12), 8, 1.0).is_none());
    }
}
