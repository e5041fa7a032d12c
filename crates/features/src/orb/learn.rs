//! Learning a BRIEF test pattern with the ORB paper's greedy procedure (Rublee et al. 2011,
//! §4.3), on oriented patches around detected keypoints:
//!
//! 1. Candidate tests compare two 5×5 sub-windows of the 31×31 patch (non-overlapping pairs);
//!    a sub-window's value is the blurred level at its centre, which is what the run-time
//!    descriptor reads (the blur plays the role of the sub-window mean). Centres are limited
//!    to the disc of radius [`PATTERN_RADIUS`] so that rotated tests stay inside the patch.
//! 2. Every test is run on every training patch (steered by the patch's orientation) and
//!    the tests are ordered by the distance of their mean from 0.5.
//! 3. Greedy search: a test is kept when its |correlation| with every kept test is below a
//!    threshold; if fewer than 256 are found, the threshold is raised and the search rerun.

use super::descriptor::{BriefPattern, N_TESTS, PATTERN_RADIUS, round_offset};
use crate::error::{FeaturesError, Result};

/// Parameters of the learning.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct LearnConfig {
    /// Side of the patch (ORB: 31).
    pub window: usize,
    /// Side of a sub-window (ORB: 5); two tests' sub-windows must not overlap.
    pub sub_window: usize,
    /// First correlation threshold of the greedy search.
    pub initial_threshold: f64,
    /// Increment of the threshold after a search that found fewer than 256 tests.
    pub threshold_step: f64,
}

impl Default for LearnConfig {
    fn default() -> Self {
        Self {
            window: 31,
            sub_window: 5,
            initial_threshold: 0.15,
            threshold_step: 0.025,
        }
    }
}

/// Oriented training patches, stored position-major (`values[position][patch]`) so that a
/// test's outcomes over all patches are a comparison of two contiguous rows.
#[derive(Debug, Clone)]
pub struct TrainingSet {
    positions: Vec<[i8; 2]>,
    values: Vec<Vec<u8>>,
}

impl TrainingSet {
    /// An empty set whose sample positions are the sub-window centres of `cfg` within the
    /// pattern disc.
    pub fn new(cfg: &LearnConfig) -> Result<Self> {
        if cfg.sub_window == 0 || cfg.sub_window > cfg.window || cfg.window.is_multiple_of(2) {
            return Err(FeaturesError::InvalidConfig {
                field: "window",
                value: format!("{} / {}", cfg.window, cfg.sub_window),
                reason: "window must be odd and at least the sub-window",
            });
        }
        let half = ((cfg.window - cfg.sub_window) / 2).min(PATTERN_RADIUS) as i32;
        let r2 = (PATTERN_RADIUS * PATTERN_RADIUS) as i32;
        let mut positions = Vec::new();
        for y in -half..=half {
            for x in -half..=half {
                if x * x + y * y <= r2 {
                    positions.push([x as i8, y as i8]);
                }
            }
        }
        let values = vec![Vec::new(); positions.len()];
        Ok(Self { positions, values })
    }

    /// Number of patches.
    pub fn len(&self) -> usize {
        self.values.first().map_or(0, Vec::len)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Adds the patch at level pixel (x, y) of a blurred level, rotated by `angle` as the
    /// descriptor would be. Returns false (and adds nothing) too close to the border.
    pub fn add_patch(
        &mut self,
        blurred: &[u8],
        w: usize,
        h: usize,
        x: usize,
        y: usize,
        angle: f64,
    ) -> bool {
        let r = PATTERN_RADIUS;
        if x < r || y < r || x + r >= w || y + r >= h || blurred.len() != w * h {
            return false;
        }
        let (s, c) = (angle.sin() as f32, angle.cos() as f32);
        for (p, row) in self.positions.iter().zip(self.values.iter_mut()) {
            let (fx, fy) = (p[0] as f32, p[1] as f32);
            let u = round_offset(fx * c - fy * s);
            let v = round_offset(fx * s + fy * c);
            row.push(blurred[(y as isize + v) as usize * w + (x as isize + u) as usize]);
        }
        true
    }
}

/// Outcome of [`learn_pattern`].
#[derive(Debug, Clone)]
pub struct LearnedPattern {
    pub pattern: BriefPattern,
    /// Correlation threshold at which 256 tests were found.
    pub threshold: f64,
    pub n_patches: usize,
    pub n_candidates: usize,
    /// Mean |mean − 0.5| of the selected tests (0 is ideal).
    pub mean_bias: f64,
    /// Mean |correlation| over pairs of selected tests.
    pub mean_abs_correlation: f64,
}

/// Outcomes of one test over all patches as a bit set, and its mean.
fn outcomes(a: &[u8], b: &[u8], words: &mut [u64]) -> u32 {
    words.iter_mut().for_each(|w| *w = 0);
    for (k, (ca, cb)) in a.chunks(64).zip(b.chunks(64)).enumerate() {
        let mut word = 0u64;
        for (bit, (&x, &y)) in ca.iter().zip(cb).enumerate() {
            word |= ((x < y) as u64) << bit;
        }
        words[k] = word;
    }
    words.iter().map(|w| w.count_ones()).sum()
}

/// Pearson correlation of two binary variables from their counts over `n` samples.
fn correlation(n: f64, ones_a: u32, ones_b: u32, both: u32) -> f64 {
    let (pa, pb, pab) = (ones_a as f64 / n, ones_b as f64 / n, both as f64 / n);
    let den = (pa * (1.0 - pa) * pb * (1.0 - pb)).sqrt();
    if den < 1e-12 {
        1.0
    } else {
        (pab - pa * pb) / den
    }
}

/// Runs the greedy selection of the ORB paper on `set`.
pub fn learn_pattern(set: &TrainingSet, cfg: &LearnConfig) -> Result<LearnedPattern> {
    let n = set.len();
    if n < 64 {
        return Err(FeaturesError::PatternLearning {
            reason: format!("needs at least 64 patches, got {n}"),
        });
    }
    let sub = cfg.sub_window as i32;
    let pos = &set.positions;
    let mut candidates: Vec<(u32, u32)> = Vec::new();
    for i in 0..pos.len() {
        for j in i + 1..pos.len() {
            let dx = (pos[i][0] as i32 - pos[j][0] as i32).abs();
            let dy = (pos[i][1] as i32 - pos[j][1] as i32).abs();
            if dx >= sub || dy >= sub {
                candidates.push((i as u32, j as u32));
            }
        }
    }
    let n_words = n.div_ceil(64);
    let mut words = vec![0u64; n_words];
    // Order by closeness of the mean to 0.5 (ties: enumeration order).
    let mut keyed: Vec<(f64, usize)> = candidates
        .iter()
        .enumerate()
        .map(|(k, &(i, j))| {
            let ones = outcomes(&set.values[i as usize], &set.values[j as usize], &mut words);
            ((ones as f64 / n as f64 - 0.5).abs(), k)
        })
        .collect();
    keyed.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    tracing::info!(
        patches = n,
        candidates = candidates.len(),
        "BRIEF test means computed"
    );

    let mut threshold = cfg.initial_threshold;
    while threshold <= 1.0 + 1e-9 {
        let mut kept: Vec<(usize, Vec<u64>, u32)> = Vec::with_capacity(N_TESTS);
        for &(_, k) in &keyed {
            let (i, j) = candidates[k];
            let ones = outcomes(&set.values[i as usize], &set.values[j as usize], &mut words);
            let ok = kept.iter().all(|(_, bits, ones_b)| {
                let both: u32 = bits
                    .iter()
                    .zip(&words)
                    .map(|(a, b)| (a & b).count_ones())
                    .sum();
                correlation(n as f64, ones, *ones_b, both).abs() <= threshold
            });
            if ok {
                kept.push((k, words.clone(), ones));
                if kept.len() == N_TESTS {
                    break;
                }
            }
        }
        tracing::info!(threshold, found = kept.len(), "greedy BRIEF test selection");
        if kept.len() == N_TESTS {
            let tests: Vec<[i8; 4]> = kept
                .iter()
                .map(|(k, _, _)| {
                    let (i, j) = candidates[*k];
                    let (p, q) = (pos[i as usize], pos[j as usize]);
                    [p[0], p[1], q[0], q[1]]
                })
                .collect();
            let mean_bias = kept
                .iter()
                .map(|(_, _, ones)| (*ones as f64 / n as f64 - 0.5).abs())
                .sum::<f64>()
                / N_TESTS as f64;
            let mut corr_sum = 0.0;
            for a in 0..kept.len() {
                for b in a + 1..kept.len() {
                    let both: u32 = kept[a]
                        .1
                        .iter()
                        .zip(&kept[b].1)
                        .map(|(x, y)| (x & y).count_ones())
                        .sum();
                    corr_sum += correlation(n as f64, kept[a].2, kept[b].2, both).abs();
                }
            }
            let pairs = (N_TESTS * (N_TESTS - 1) / 2) as f64;
            return Ok(LearnedPattern {
                pattern: BriefPattern::new(tests)?,
                threshold,
                n_patches: n,
                n_candidates: candidates.len(),
                mean_bias,
                mean_abs_correlation: corr_sum / pairs,
            });
        }
        threshold += cfg.threshold_step;
    }
    Err(FeaturesError::PatternLearning {
        reason: "could not select 256 BRIEF tests at any correlation threshold".into(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Smooth random images: sums of a few blobs, so tests are correlated as in real patches.
    fn random_patches(seed: u64, n: usize) -> TrainingSet {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut set = TrainingSet::new(&LearnConfig::default()).unwrap();
        let (w, h) = (41, 41);
        for _ in 0..n {
            let blobs: Vec<(f64, f64, f64, f64)> = (0..6)
                .map(|_| {
                    (
                        rng.random_range(0.0..41.0),
                        rng.random_range(0.0..41.0),
                        rng.random_range(3.0..10.0),
                        rng.random_range(-100.0..100.0),
                    )
                })
                .collect();
            let img: Vec<u8> = (0..w * h)
                .map(|i| {
                    let (x, y) = ((i % w) as f64, (i / w) as f64);
                    let v: f64 = blobs
                        .iter()
                        .map(|&(bx, by, s, a)| {
                            a * (-((x - bx).powi(2) + (y - by).powi(2)) / (2.0 * s * s)).exp()
                        })
                        .sum();
                    (128.0 + v).clamp(0.0, 255.0) as u8
                })
                .collect();
            let angle = rng.random_range(0.0..std::f64::consts::TAU);
            assert!(set.add_patch(&img, w, h, 20, 20, angle));
        }
        set
    }

    #[test]
    fn learned_tests_are_valid_unbiased_and_less_correlated_than_random() {
        for seed in [1u64, 2] {
            let set = random_patches(seed, 600);
            let learned = learn_pattern(&set, &LearnConfig::default()).unwrap();
            assert_eq!(learned.pattern.tests().len(), 256);
            assert!(learned.mean_bias < 0.1, "bias {}", learned.mean_bias);
            // The same statistics for the random Gaussian pattern on the same patches.
            let index = |x: i8, y: i8| set.positions.iter().position(|p| *p == [x, y]);
            let random = BriefPattern::random_gaussian(seed);
            let mut words = vec![0u64; set.len().div_ceil(64)];
            let mut bits = Vec::new();
            for t in random.tests() {
                if let (Some(i), Some(j)) = (index(t[0], t[1]), index(t[2], t[3])) {
                    let ones = outcomes(&set.values[i], &set.values[j], &mut words);
                    bits.push((words.clone(), ones));
                }
            }
            let n = set.len() as f64;
            let (mut sum, mut count) = (0.0, 0);
            for a in 0..bits.len() {
                for b in a + 1..bits.len() {
                    let both: u32 = bits[a]
                        .0
                        .iter()
                        .zip(&bits[b].0)
                        .map(|(x, y)| (x & y).count_ones())
                        .sum();
                    sum += correlation(n, bits[a].1, bits[b].1, both).abs();
                    count += 1;
                }
            }
            let random_corr = sum / count as f64;
            assert!(
                learned.mean_abs_correlation < random_corr,
                "learned {} vs random {random_corr}",
                learned.mean_abs_correlation
            );
        }
    }

    #[test]
    fn too_few_patches_is_an_error() {
        let set = random_patches(3, 10);
        assert!(learn_pattern(&set, &LearnConfig::default()).is_err());
    }
}
