//! Structural similarity (Wang et al., 2004) over a masked region: the global factor of the
//! paper's confidence, computed between the map under the warped frame and the warped frame.
//!
//! Local statistics use the standard 11 × 11 Gaussian window (σ = 1.5) and constants
//! `C1 = (0.01 L)²`, `C2 = (0.03 L)²` with `L = 255`. With a mask, only pixels whose whole
//! window lies inside the mask contribute, so the frame's border (where the warped frame meets
//! no data) never enters a statistic; the result is the mean SSIM over those pixels.

use serde::{Deserialize, Serialize};

/// SSIM parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SsimConfig {
    /// σ of the Gaussian window, pixels.
    pub sigma: f64,
    /// Window half-width, pixels (5: the 11 × 11 window of the reference).
    pub radius: usize,
    /// `C1 = (k1 · range)²`.
    pub k1: f64,
    /// `C2 = (k2 · range)²`.
    pub k2: f64,
    /// Dynamic range of the pixel values.
    pub range: f64,
}

impl Default for SsimConfig {
    fn default() -> Self {
        Self {
            sigma: 1.5,
            radius: 5,
            k1: 0.01,
            k2: 0.03,
            range: 255.0,
        }
    }
}

/// Normalised 1-D Gaussian weights of length `2 radius + 1`.
fn kernel(cfg: &SsimConfig) -> Vec<f64> {
    let r = cfg.radius as i64;
    let w: Vec<f64> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * cfg.sigma * cfg.sigma)).exp())
        .collect();
    let s: f64 = w.iter().sum();
    w.into_iter().map(|v| v / s).collect()
}

/// Number of local statistics: μa, μb, E[a²], E[b²], E[ab].
const STATS: usize = 5;

/// Mean SSIM of `a` and `b` (`width × height`, row-major) over the pixels whose whole window
/// lies in `mask` (everywhere when `None`). `None` when no pixel qualifies (region smaller than
/// the window) or the sizes disagree.
///
/// The separable Gaussian runs row by row: each input row is blurred horizontally into a ring
/// of the last `2r + 1` rows, from which one output row is blurred vertically and scored at
/// once. The working set stays in cache (a frame warped onto a 25 cm map at 200 m covers about
/// 900 × 900 map pixels), and each sum adds its taps in order, as a direct window sum would.
pub fn ssim_masked(
    a: &[f32],
    b: &[f32],
    width: usize,
    height: usize,
    mask: Option<&[bool]>,
    cfg: &SsimConfig,
) -> Option<f64> {
    let n = width.checked_mul(height)?;
    if a.len() != n || b.len() != n || mask.is_some_and(|m| m.len() != n) {
        return None;
    }
    let r = cfg.radius;
    if width <= 2 * r || height <= 2 * r {
        return None;
    }
    let k = kernel(cfg);
    let d = k.len();
    let ow = width - 2 * r;
    // A window is fully inside the mask when the box count of invalid pixels is zero.
    let inside = window_inside(mask, width, height, r);
    let c1 = (cfg.k1 * cfg.range).powi(2);
    let c2 = (cfg.k2 * cfg.range).powi(2);
    // The statistics' inputs of one row, one statistic after the other.
    let mut line = vec![0.0f64; STATS * width];
    // Horizontally blurred rows: row y in slot y mod d, each STATS × ow.
    let mut ring = vec![0.0f64; d * STATS * ow];
    let mut column = vec![0.0f64; STATS * ow];
    let (mut sum, mut count) = (0.0, 0usize);
    for y in 0..height {
        let row = y * width;
        let (va, rest) = line.split_at_mut(width);
        let (vb, rest) = rest.split_at_mut(width);
        let (vaa, rest) = rest.split_at_mut(width);
        let (vbb, vab) = rest.split_at_mut(width);
        for x in 0..width {
            let i = row + x;
            let (p, q) = if mask.is_none_or(|m| m[i]) {
                (a[i] as f64, b[i] as f64)
            } else {
                (0.0, 0.0)
            };
            va[x] = p;
            vb[x] = q;
            vaa[x] = p * p;
            vbb[x] = q * q;
            vab[x] = p * q;
        }
        let slot = &mut ring[(y % d) * STATS * ow..][..STATS * ow];
        slot.fill(0.0);
        for (src, dst) in line.chunks_exact(width).zip(slot.chunks_exact_mut(ow)) {
            for (i, &kv) in k.iter().enumerate() {
                for (o, s) in dst.iter_mut().zip(&src[i..i + ow]) {
                    *o += kv * s;
                }
            }
        }
        if y + 1 < d {
            continue;
        }
        let oy = y + 1 - d;
        column.fill(0.0);
        for (i, &kv) in k.iter().enumerate() {
            let src = &ring[((oy + i) % d) * STATS * ow..][..STATS * ow];
            for (o, s) in column.iter_mut().zip(src) {
                *o += kv * s;
            }
        }
        let (mu_a, rest) = column.split_at(ow);
        let (mu_b, rest) = rest.split_at(ow);
        let (aa, rest) = rest.split_at(ow);
        let (bb, ab) = rest.split_at(ow);
        for (x, &ok) in inside[oy * ow..(oy + 1) * ow].iter().enumerate() {
            if !ok {
                continue;
            }
            let (ma, mb) = (mu_a[x], mu_b[x]);
            let va = aa[x] - ma * ma;
            let vb = bb[x] - mb * mb;
            let cov = ab[x] - ma * mb;
            sum += ((2.0 * ma * mb + c1) * (2.0 * cov + c2))
                / ((ma * ma + mb * mb + c1) * (va + vb + c2));
            count += 1;
        }
    }
    (count > 0).then(|| sum / count as f64)
}

/// For each "valid" output pixel: whether its `(2r+1)²` window has no masked-out pixel.
fn window_inside(mask: Option<&[bool]>, w: usize, h: usize, r: usize) -> Vec<bool> {
    let (ow, oh) = (w - 2 * r, h - 2 * r);
    let Some(m) = mask else {
        return vec![true; ow * oh];
    };
    // Summed-area table of invalid pixels.
    let mut sat = vec![0u32; (w + 1) * (h + 1)];
    for y in 0..h {
        let mut row = 0u32;
        for x in 0..w {
            row += u32::from(!m[y * w + x]);
            sat[(y + 1) * (w + 1) + x + 1] = sat[y * (w + 1) + x + 1] + row;
        }
    }
    let d = 2 * r + 1;
    let mut out = vec![false; ow * oh];
    for y in 0..oh {
        for x in 0..ow {
            let s = sat[(y + d) * (w + 1) + x + d] + sat[y * (w + 1) + x]
                - sat[y * (w + 1) + x + d]
                - sat[(y + d) * (w + 1) + x];
            out[y * ow + x] = s == 0;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn noise(w: usize, h: usize, seed: u64) -> Vec<f32> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..w * h).map(|_| rng.random_range(0.0..255.0)).collect()
    }

    /// Direct 2-D window sums at every pixel: an independent reference.
    fn brute(a: &[f32], b: &[f32], w: usize, h: usize, cfg: &SsimConfig) -> f64 {
        let k = kernel(cfg);
        let r = cfg.radius;
        let (c1, c2) = ((cfg.k1 * cfg.range).powi(2), (cfg.k2 * cfg.range).powi(2));
        let (mut sum, mut n) = (0.0, 0);
        for y in r..h - r {
            for x in r..w - r {
                let (mut ma, mut mb, mut aa, mut bb, mut ab) = (0.0, 0.0, 0.0, 0.0, 0.0);
                for dy in 0..=2 * r {
                    for dx in 0..=2 * r {
                        let i = (y + dy - r) * w + x + dx - r;
                        let wt = k[dy] * k[dx];
                        let (p, q) = (a[i] as f64, b[i] as f64);
                        ma += wt * p;
                        mb += wt * q;
                        aa += wt * p * p;
                        bb += wt * q * q;
                        ab += wt * p * q;
                    }
                }
                let (va, vb, cov) = (aa - ma * ma, bb - mb * mb, ab - ma * mb);
                sum += (2.0 * ma * mb + c1) * (2.0 * cov + c2)
                    / ((ma * ma + mb * mb + c1) * (va + vb + c2));
                n += 1;
            }
        }
        sum / n as f64
    }

    #[test]
    fn constant_images_give_the_hand_computed_luminance_term() {
        // Flat images: σ = 0, so SSIM = (2·μa·μb + C1) / (μa² + μb² + C1); C1 = 2.55² = 6.5025.
        let cfg = SsimConfig::default();
        let a = vec![100.0f32; 20 * 20];
        let b = vec![50.0f32; 20 * 20];
        let expected =
            (2.0 * 100.0 * 50.0 + 6.5025) / (100.0f64.powi(2) + 50.0f64.powi(2) + 6.5025);
        let s = ssim_masked(&a, &b, 20, 20, None, &cfg).unwrap();
        assert!((s - expected).abs() < 1e-9, "{s} vs {expected}");
        assert!((expected - 0.800_104_0).abs() < 1e-6);
    }

    #[test]
    fn matches_the_direct_window_computation() {
        let cfg = SsimConfig::default();
        for seed in 0..3 {
            let a = noise(31, 27, seed);
            let b: Vec<f32> = a
                .iter()
                .zip(noise(31, 27, seed + 10))
                .map(|(x, n)| 0.7 * x + 0.3 * n)
                .collect();
            let s = ssim_masked(&a, &b, 31, 27, None, &cfg).unwrap();
            let r = brute(&a, &b, 31, 27, &cfg);
            assert!((s - r).abs() < 1e-9, "seed {seed}: {s} vs {r}");
        }
    }

    #[test]
    fn known_properties() {
        let cfg = SsimConfig::default();
        for seed in 0..3 {
            let a = noise(40, 40, seed);
            let b = noise(40, 40, seed + 100);
            // Identity, symmetry, bounds.
            assert!((ssim_masked(&a, &a, 40, 40, None, &cfg).unwrap() - 1.0).abs() < 1e-12);
            let ab = ssim_masked(&a, &b, 40, 40, None, &cfg).unwrap();
            let ba = ssim_masked(&b, &a, 40, 40, None, &cfg).unwrap();
            assert!((ab - ba).abs() < 1e-12 && ab < 0.2 && ab > -1.0);
            // More noise, less similarity.
            let mix = |t: f32| -> Vec<f32> {
                a.iter()
                    .zip(&b)
                    .map(|(x, y)| (1.0 - t) * x + t * y)
                    .collect()
            };
            let s: Vec<f64> = [0.1, 0.3, 0.6]
                .iter()
                .map(|&t| ssim_masked(&a, &mix(t), 40, 40, None, &cfg).unwrap())
                .collect();
            assert!(s[0] > s[1] && s[1] > s[2], "{s:?}");
            // Inverted contrast is negative.
            let inv: Vec<f32> = a.iter().map(|x| 255.0 - x).collect();
            assert!(ssim_masked(&a, &inv, 40, 40, None, &cfg).unwrap() < -0.5);
        }
    }

    #[test]
    fn mask_excludes_outside_pixels() {
        let cfg = SsimConfig::default();
        let a = noise(40, 40, 1);
        let mut b = a.clone();
        // Garbage outside a 20x20 square; the mask keeps only the square.
        let inside = |i: usize| (10..30).contains(&(i % 40)) && (10..30).contains(&(i / 40));
        for (i, v) in b.iter_mut().enumerate() {
            if !inside(i) {
                *v = 255.0 - *v;
            }
        }
        let mask: Vec<bool> = (0..1600).map(inside).collect();
        let s = ssim_masked(&a, &b, 40, 40, Some(&mask), &cfg).unwrap();
        assert!((s - 1.0).abs() < 1e-12, "{s}");
        assert!(ssim_masked(&a, &b, 40, 40, None, &cfg).unwrap() < 0.5);
        // A region smaller than the window gives no value.
        let tiny: Vec<bool> = (0..1600).map(|i| i % 40 < 8 && i / 40 < 8).collect();
        assert!(ssim_masked(&a, &b, 40, 40, Some(&tiny), &cfg).is_none());
        assert!(ssim_masked(&a, &b[..10], 40, 40, None, &cfg).is_none());
    }
}
