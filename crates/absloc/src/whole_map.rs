//! Whole-map registration of a virtual frame with no prior (issue #29 item 2): the take-off
//! position unknown, a 10 m flight over a 2 km HiRISE-class map.
//!
//! [`crate::correlate`] places a virtual frame within 25 m of a prior by exhaustive
//! correlation; over a whole 8000² map that would be 10⁵ times the work. Here the map's and
//! the view's gradient magnitudes (the same signal the fine correlation uses, so rims and rocks
//! under any sun) are pooled into coarse cells of `factor` map pixels, where the view spans
//! about [`WholeMapConfig::coarse_view_px`] cells, and the view is correlated against the
//! whole coarse map at once through the FFT: normalised cross-correlation under the view's
//! validity mask (Padfield, "Masked object registration in the Fourier domain", IEEE TIP
//! 2012), three 2-D FFTs per heading. [`crate::coarse_places`] does this for the grey levels
//! too, rescores the best placements at twice the resolution and hands the best few distinct
//! places to the fine correlation with a window of a few cells, which accepts or rejects them
//! as it does any placement.

use std::sync::Arc;

use image::GrayImage;
use rayon::prelude::*;
use rustfft::num_complex::Complex32;
use rustfft::{Fft, FftPlanner};
use serde::{Deserialize, Serialize};

use crate::correlate::Grid;

/// Settings of the whole-map search of a virtual frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WholeMapConfig {
    /// Coarse cells across the view: the pooling factor is the view's width in map pixels
    /// divided by this (8 map pixels, 2 m on a 25 cm map, for a 10 m flight's 200-pixel view
    /// at 24). Fewer cells: a smaller FFT, a blurrier match.
    pub coarse_view_px: usize,
    /// Distinct coarse placements (over all headings) refined at full resolution.
    pub candidates: usize,
    /// Two placements closer than this many coarse cells are one place (the better kept).
    pub exclusion_cells: usize,
    /// Coarse placements kept per heading and per signal before all are rescored at twice the
    /// resolution ([`crate::coarse_places`]). On three 2 km flights the true place was among
    /// the 64 best of its heading where it was not among the 8 best of all headings.
    pub per_heading: usize,
    /// The rescoring moves each placement by up to this many half-size cells either way.
    pub rescore_cells: usize,
    /// A whole-map placement is a fix only with at least this confidence (SSIM ×
    /// correlation), and with at least the local search's `min_confidence`. It is the best of
    /// 10⁵ times more placements than a local search's, so a wrong place scores higher too:
    /// on 2 km maps at 10 m wrong places scored up to w 0.19, right ones under a sun 150–180°
    /// from the map's 0.10–0.15. The fusion makes the difference (JointLoc's
    /// `first_fix_span_m`: weak whole-map fixes make a first alignment only when they lie
    /// far apart), so this gate is the local one by default (`docs/absloc.md`).
    pub min_confidence: f64,
}

impl Default for WholeMapConfig {
    fn default() -> Self {
        Self {
            coarse_view_px: 24,
            candidates: 8,
            exclusion_cells: 3,
            per_heading: 64,
            rescore_cells: 2,
            min_confidence: 0.07,
        }
    }
}

/// A coarse placement: the view's top-left at coarse cell `(x, y)`, its masked NCC `score`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CoarsePeak {
    pub score: f64,
    pub x: usize,
    pub y: usize,
}

/// A map signal (gradient magnitude or grey levels) pooled into `factor`-pixel cells, with the
/// spectra of it and of its square, ready to correlate any view against.
pub struct CoarseMap {
    factor: usize,
    grid: Grid,
    fft_w: usize,
    fft_h: usize,
    /// Spectrum of the (mean-removed) coarse map, and of its square.
    spectrum: Vec<Complex32>,
    spectrum_sq: Vec<Complex32>,
    plans: Plans,
}

impl std::fmt::Debug for CoarseMap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CoarseMap")
            .field("factor", &self.factor)
            .field("cells", &(self.grid.width, self.grid.height))
            .field("fft", &(self.fft_w, self.fft_h))
            .finish_non_exhaustive()
    }
}

struct Plans {
    row: Arc<dyn Fft<f32>>,
    row_inv: Arc<dyn Fft<f32>>,
    col: Arc<dyn Fft<f32>>,
    col_inv: Arc<dyn Fft<f32>>,
}

impl CoarseMap {
    /// Pools `map`'s gradient magnitude (after a Gaussian of `smoothing_px`) into cells of
    /// `factor` pixels ([`pool_map`]). `None` when the map has fewer than 2 × 2 cells.
    pub fn new(map: &GrayImage, factor: usize, smoothing_px: f64) -> Option<Self> {
        pool_map(map, factor, Some(smoothing_px)).map(|grid| Self::from_grid(grid, factor))
    }

    /// A coarse map from an already pooled grid (`factor` is what each cell stands for).
    pub fn from_grid(grid: Grid, factor: usize) -> Self {
        let (fft_w, fft_h) = (smooth_size(grid.width), smooth_size(grid.height));
        let mut planner = FftPlanner::new();
        let plans = Plans {
            row: planner.plan_fft_forward(fft_w),
            row_inv: planner.plan_fft_inverse(fft_w),
            col: planner.plan_fft_forward(fft_h),
            col_inv: planner.plan_fft_inverse(fft_h),
        };
        // Mean removed: NCC does not change, the sums below lose less to cancellation.
        let mean = grid.data.iter().map(|&v| v as f64).sum::<f64>() / grid.data.len() as f64;
        let padded = |f: &dyn Fn(f64) -> f64| {
            let mut buf = vec![Complex32::default(); fft_w * fft_h];
            for y in 0..grid.height {
                for x in 0..grid.width {
                    buf[y * fft_w + x].re = f(grid.data[y * grid.width + x] as f64 - mean) as f32;
                }
            }
            buf
        };
        let mut spectrum = padded(&|v| v);
        let mut spectrum_sq = padded(&|v| v * v);
        let mut this = Self {
            factor,
            grid,
            fft_w,
            fft_h,
            spectrum: Vec::new(),
            spectrum_sq: Vec::new(),
            plans,
        };
        this.fft2(&mut spectrum, false);
        this.fft2(&mut spectrum_sq, false);
        this.spectrum = spectrum;
        this.spectrum_sq = spectrum_sq;
        this
    }

    /// Map pixels per coarse cell.
    pub fn factor(&self) -> usize {
        self.factor
    }

    /// The pooled signal.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// Masked NCC of `view` (coarse cells, valid where `valid`) at every placement that keeps
    /// it inside the map, row-major over `(width − view.width + 1) × (height − view.height + 1)`
    /// (returned with that width and height); `None` when the view is larger than the map or
    /// has fewer than 3 valid cells or no variance.
    pub fn ncc(&self, view: &Grid, valid: &[bool]) -> Option<(Vec<f64>, usize, usize)> {
        let (vw, vh) = (view.width, view.height);
        if vw > self.grid.width || vh > self.grid.height || valid.len() != vw * vh {
            return None;
        }
        let (mut n, mut st, mut st2) = (0f64, 0f64, 0f64);
        for (i, &v) in view.data.iter().enumerate() {
            if valid[i] {
                let t = v as f64;
                n += 1.0;
                st += t;
                st2 += t * t;
            }
        }
        let var_t = st2 - st * st / n.max(1.0);
        if n < 3.0 || var_t <= 1e-12 * st2.max(1.0) {
            return None;
        }
        // z = t·m + i·m in one FFT; its two real parts' spectra are separated by symmetry.
        let (fw, fh) = (self.fft_w, self.fft_h);
        let mut z = vec![Complex32::default(); fw * fh];
        for y in 0..vh {
            for x in 0..vw {
                if valid[y * vw + x] {
                    z[y * fw + x] = Complex32::new(view.data[y * vw + x], 1.0);
                }
            }
        }
        self.fft2(&mut z, false);
        let mut cross = vec![Complex32::default(); fw * fh];
        let mut sums_sq = vec![Complex32::default(); fw * fh];
        let i = Complex32::new(0.0, 1.0);
        for ky in 0..fh {
            for kx in 0..fw {
                let k = ky * fw + kx;
                let mirror = ((fh - ky) % fh) * fw + (fw - kx) % fw;
                let (zk, zm) = (z[k], z[mirror].conj());
                let a = (zk + zm) * 0.5;
                let b = (zk - zm) / (2.0 * i);
                // corr(M, a) ↔ M̂ · conj(â); both results real, packed as re + i·im.
                cross[k] = self.spectrum[k] * a.conj() + i * (self.spectrum[k] * b.conj());
                sums_sq[k] = self.spectrum_sq[k] * b.conj();
            }
        }
        self.fft2(&mut cross, true);
        self.fft2(&mut sums_sq, true);
        let (pw, ph) = (self.grid.width - vw + 1, self.grid.height - vh + 1);
        let scores = (0..pw * ph)
            .into_par_iter()
            .map(|p| {
                let k = (p / pw) * fw + p % pw;
                let (x, c1, c2) = (cross[k].re as f64, cross[k].im as f64, sums_sq[k].re as f64);
                // The FFTs run in f32 (twice as fast): a map window with under 3 % of its
                // RMS as spread is taken as flat, not as a ratio of rounding errors.
                let var_m = c2 - c1 * c1 / n;
                if var_m <= 1e-3 * c2.abs().max(1e-9) {
                    return 0.0;
                }
                ((x - st * c1 / n) / (var_m * var_t).sqrt()).clamp(-1.0, 1.0)
            })
            .collect();
        Some((scores, pw, ph))
    }

    /// In-place 2-D FFT of a row-major `fft_h × fft_w` buffer; the inverse is scaled by
    /// 1 / (w·h).
    fn fft2(&self, buf: &mut [Complex32], inverse: bool) {
        let (w, h) = (self.fft_w, self.fft_h);
        let (row, col) = if inverse {
            (&self.plans.row_inv, &self.plans.col_inv)
        } else {
            (&self.plans.row, &self.plans.col)
        };
        buf.par_chunks_mut(w).for_each(|r| row.process(r));
        let mut t = vec![Complex32::default(); w * h];
        transpose(buf, &mut t, w, h);
        t.par_chunks_mut(h).for_each(|c| col.process(c));
        transpose(&t, buf, h, w);
        if inverse {
            let s = 1.0 / (w * h) as f32;
            buf.par_iter_mut().for_each(|v| *v *= s);
        }
    }
}

/// `src` (`h` rows of `w`) into `dst` (`w` rows of `h`), in blocks of 32 × 32 so that both
/// sides are read and written a cache line at a time.
pub(crate) fn transpose(src: &[Complex32], dst: &mut [Complex32], w: usize, h: usize) {
    const B: usize = 32;
    dst.par_chunks_mut(h * B).enumerate().for_each(|(bx, out)| {
        let x0 = bx * B;
        let cols = out.len() / h;
        for y0 in (0..h).step_by(B) {
            for y in y0..(y0 + B).min(h) {
                let row = &src[y * w + x0..][..cols];
                for (dx, v) in row.iter().enumerate() {
                    out[dx * h + y] = *v;
                }
            }
        }
    });
}

/// The smallest n ≥ `len` whose prime factors are 2, 3 and 5 (fast FFT sizes). No padding
/// beyond the map is needed: a placement that keeps the view inside the map never reaches
/// past its edge, so the circular correlation does not wrap there.
pub(crate) fn smooth_size(len: usize) -> usize {
    (len.max(1)..)
        .find(|&n| {
            let mut m = n;
            for p in [2, 3, 5] {
                while m % p == 0 {
                    m /= p;
                }
            }
            m == 1
        })
        .expect("a 5-smooth number exists above any length")
}

/// `map` pooled into cells of `factor` pixels: its gradient magnitude after a Gaussian of
/// `smoothing_px` when given, else its grey levels. In bands of rows, so that the
/// full-resolution gradient of a large map is never held whole. `None` when the map has fewer
/// than 2 × 2 cells.
pub fn pool_map(map: &GrayImage, factor: usize, smoothing_px: Option<f64>) -> Option<Grid> {
    let factor = factor.max(1);
    let (w, h) = (map.width() as usize, map.height() as usize);
    let (cw, ch) = (w / factor, h / factor);
    if cw < 2 || ch < 2 {
        return None;
    }
    // Enough rows of margin for the Gaussian (3σ) and the central difference.
    let margin = smoothing_px.map_or(0, |s| (3.0 * s).ceil() as usize + 1);
    let rows: Vec<Vec<f32>> = (0..ch)
        .into_par_iter()
        .map(|cy| {
            let y0 = (cy * factor).saturating_sub(margin);
            let y1 = ((cy + 1) * factor + margin).min(h);
            let band = Grid {
                width: w,
                height: y1 - y0,
                data: (y0..y1)
                    .flat_map(|y| (0..w).map(move |x| (x, y)))
                    .map(|(x, y)| map.get_pixel(x as u32, y as u32)[0] as f32)
                    .collect(),
            };
            let band = match smoothing_px {
                Some(s) => band.gradient_magnitude(s),
                None => band,
            };
            let top = cy * factor - y0;
            (0..cw)
                .map(|cx| {
                    let mut sum = 0f32;
                    for y in top..top + factor {
                        let row = &band.data[y * w + cx * factor..][..factor];
                        sum += row.iter().sum::<f32>();
                    }
                    sum / (factor * factor) as f32
                })
                .collect()
        })
        .collect();
    Some(Grid {
        width: cw,
        height: ch,
        data: rows.into_iter().flatten().collect(),
    })
}

/// `fine` (a view's signal, valid where `valid`) pooled into `factor`-pixel cells;
/// a cell is valid when every pixel in it is.
pub fn pool(fine: &Grid, valid: &[bool], factor: usize) -> (Grid, Vec<bool>) {
    let f = factor.max(1);
    let (cw, ch) = (fine.width / f, fine.height / f);
    let mut data = vec![0f32; cw * ch];
    let mut ok = vec![false; cw * ch];
    for cy in 0..ch {
        for cx in 0..cw {
            let (mut sum, mut all) = (0f32, true);
            for y in cy * f..(cy + 1) * f {
                for x in cx * f..(cx + 1) * f {
                    let i = y * fine.width + x;
                    all &= valid[i];
                    sum += fine.data[i];
                }
            }
            data[cy * cw + cx] = sum / (f * f) as f32;
            ok[cy * cw + cx] = all;
        }
    }
    (
        Grid {
            width: cw,
            height: ch,
            data,
        },
        ok,
    )
}

/// The `n` best local maxima of `scores` (`w × h`, row-major), best first, no two within
/// `exclusion` cells of each other (Chebyshev). Only the best `256 n` scores are looked at
/// first (a peak and its shoulders take a few dozen of them), the whole grid when those do
/// not hold `n` distinct maxima.
pub fn peaks(scores: &[f64], w: usize, h: usize, n: usize, exclusion: usize) -> Vec<CoarsePeak> {
    let len = (w * h).min(scores.len());
    let shortlist = n.saturating_mul(256).max(1);
    if shortlist < len {
        let mut idx: Vec<usize> = (0..len).collect();
        idx.select_nth_unstable_by(shortlist - 1, |&a, &b| {
            scores[b].total_cmp(&scores[a]).then(a.cmp(&b))
        });
        idx.truncate(shortlist);
        let found = maxima(scores, w, h, idx, n, exclusion);
        if found.len() == n {
            return found;
        }
    }
    maxima(scores, w, h, (0..len).collect(), n, exclusion)
}

/// The `n` best distinct local maxima among the positions `at`.
fn maxima(
    scores: &[f64],
    w: usize,
    h: usize,
    at: Vec<usize>,
    n: usize,
    exclusion: usize,
) -> Vec<CoarsePeak> {
    let score = |x: usize, y: usize| scores[y * w + x];
    let mut maxima: Vec<CoarsePeak> = at
        .into_par_iter()
        .filter_map(|p| {
            let (x, y) = (p % w, p / w);
            let s = scores[p];
            let is_max = (y.saturating_sub(1)..(y + 2).min(h))
                .all(|yy| (x.saturating_sub(1)..(x + 2).min(w)).all(|xx| score(xx, yy) <= s));
            (is_max && s > 0.0).then_some(CoarsePeak { score: s, x, y })
        })
        .collect();
    maxima.sort_by(|a, b| {
        b.score
            .total_cmp(&a.score)
            .then((a.y, a.x).cmp(&(b.y, b.x)))
    });
    distinct(maxima, n, exclusion, |p| (p.x, p.y))
}

/// The first `n` of `sorted` (best first) that are more than `exclusion` (Chebyshev) from
/// every one kept before them.
pub fn distinct<T: Copy>(
    sorted: Vec<T>,
    n: usize,
    exclusion: usize,
    at: impl Fn(&T) -> (usize, usize),
) -> Vec<T> {
    let mut kept: Vec<T> = Vec::with_capacity(n);
    for p in sorted {
        if kept.len() == n {
            break;
        }
        let (x, y) = at(&p);
        let far = kept.iter().all(|k| {
            let (kx, ky) = at(k);
            kx.abs_diff(x) > exclusion || ky.abs_diff(y) > exclusion
        });
        if far {
            kept.push(p);
        }
    }
    kept
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_grid(w: usize, h: usize, seed: u64) -> Grid {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        Grid {
            width: w,
            height: h,
            data: (0..w * h).map(|_| rng.random::<f32>() * 10.0).collect(),
        }
    }

    /// The direct masked NCC at one placement, for reference.
    fn direct(map: &Grid, view: &Grid, valid: &[bool], px: usize, py: usize) -> f64 {
        let idx: Vec<usize> = (0..valid.len()).filter(|&i| valid[i]).collect();
        let n = idx.len() as f64;
        let (mut st, mut sm, mut st2, mut sm2, mut stm) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for &i in &idx {
            let (x, y) = (i % view.width, i / view.width);
            let t = view.data[i] as f64;
            let m = map.data[(py + y) * map.width + px + x] as f64;
            st += t;
            sm += m;
            st2 += t * t;
            sm2 += m * m;
            stm += t * m;
        }
        (stm - st * sm / n) / ((st2 - st * st / n) * (sm2 - sm * sm / n)).sqrt()
    }

    #[test]
    fn peaks_from_the_best_scores_are_the_peaks_of_the_whole_grid() {
        let (w, h) = (300, 200);
        let grid = random_grid(w, h, 11);
        let smooth = grid.gradient_magnitude(2.0);
        let scores: Vec<f64> = smooth.data.iter().map(|&v| v as f64).collect();
        for (n, exclusion) in [(1, 3), (8, 3), (64, 2)] {
            let quick = peaks(&scores, w, h, n, exclusion);
            let full = maxima(&scores, w, h, (0..w * h).collect(), n, exclusion);
            assert_eq!(quick, full, "n {n}");
            assert_eq!(quick.len(), n);
        }
    }

    #[test]
    fn the_blocked_transpose_is_a_transpose() {
        for (w, h) in [(1, 1), (70, 33), (33, 70), (64, 64)] {
            let src: Vec<Complex32> = (0..w * h)
                .map(|i| Complex32::new(i as f32, -(i as f32)))
                .collect();
            let mut dst = vec![Complex32::default(); w * h];
            transpose(&src, &mut dst, w, h);
            for y in 0..h {
                for x in 0..w {
                    assert_eq!(dst[x * h + y], src[y * w + x]);
                }
            }
        }
    }

    #[test]
    fn masked_ncc_through_the_fft_equals_the_direct_sum() {
        for seed in 0..3 {
            let map = random_grid(37, 29, seed);
            let coarse = CoarseMap::from_grid(map.clone(), 1);
            let view = random_grid(9, 7, seed + 10);
            let mut rng = ChaCha8Rng::seed_from_u64(seed + 20);
            let valid: Vec<bool> = (0..63).map(|_| rng.random::<f64>() < 0.8).collect();
            let (scores, pw, ph) = coarse.ncc(&view, &valid).unwrap();
            assert_eq!((pw, ph), (29, 23));
            for (px, py) in [(0, 0), (28, 22), (13, 5), (3, 17)] {
                let want = direct(&map, &view, &valid, px, py);
                let got = scores[py * pw + px];
                assert!(
                    (got - want).abs() < 1e-4,
                    "seed {seed} ({px}, {py}): {got} vs {want}"
                );
            }
        }
    }

    #[test]
    fn a_cut_of_the_map_peaks_where_it_was_cut_and_nowhere_else() {
        let map = random_grid(120, 90, 7);
        let coarse = CoarseMap::from_grid(map.clone(), 1);
        let (x0, y0) = (71, 33);
        let view = Grid {
            width: 20,
            height: 16,
            data: (0..16)
                .flat_map(|y| (0..20).map(move |x| (x, y)))
                .map(|(x, y)| map.data[(y0 + y) * 120 + x0 + x])
                .collect(),
        };
        // A disc of the cut is valid, as a rotated view's mask would be.
        let valid: Vec<bool> = (0..320)
            .map(|i| {
                let (x, y) = ((i % 20) as f64 - 9.5, (i / 20) as f64 - 7.5);
                x * x + y * y < 64.0
            })
            .collect();
        let (scores, pw, ph) = coarse.ncc(&view, &valid).unwrap();
        let found = peaks(&scores, pw, ph, 2, 3);
        assert_eq!((found[0].x, found[0].y), (x0, y0));
        assert!((found[0].score - 1.0).abs() < 1e-4);
        assert!(found[1].score < 0.6, "{found:?}");
    }

    #[test]
    fn pooling_the_map_in_bands_equals_pooling_its_whole_gradient() {
        let grid = random_grid(64, 48, 3);
        let image = GrayImage::from_fn(64, 48, |x, y| {
            image::Luma([(grid.data[(y * 64 + x) as usize] * 25.0) as u8])
        });
        let whole = Grid::from_image(&image).gradient_magnitude(1.0);
        let (pooled, _) = pool(&whole, &vec![true; 64 * 48], 4);
        let coarse = CoarseMap::new(&image, 4, 1.0).unwrap();
        assert_eq!((coarse.grid().width, coarse.grid().height), (16, 12));
        for (a, b) in coarse.grid().data.iter().zip(&pooled.data) {
            assert!((a - b).abs() < 1e-4, "{a} vs {b}");
        }
    }

    #[test]
    fn too_small_or_flat_views_give_no_scores() {
        let coarse = CoarseMap::from_grid(random_grid(10, 10, 1), 1);
        assert!(coarse.ncc(&random_grid(11, 3, 2), &[true; 33]).is_none());
        let flat = Grid {
            width: 4,
            height: 4,
            data: vec![2.0; 16],
        };
        assert!(coarse.ncc(&flat, &[true; 16]).is_none());
        assert!(coarse.ncc(&random_grid(4, 4, 2), &[false; 16]).is_none());
        assert_eq!(smooth_size(1334), 1350);
        assert_eq!(smooth_size(1024), 1024);
        assert!(CoarseMap::new(&GrayImage::new(7, 7), 4, 1.0).is_none());
    }
}
