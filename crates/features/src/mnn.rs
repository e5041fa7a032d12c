//! Mutual nearest-neighbour matching of float descriptors (the simple baseline next to
//! LightGlue; XFeat's own `match_xfeat` is this with `min_similarity`).
//!
//! Similarity is the dot product, i.e. the cosine for L2-normalised descriptors. The `Na × Nb`
//! similarities are computed in register-sized tiles (4 rows × 16 columns, the descriptor axis
//! innermost over a transposed copy of `b`) and reduced on the fly to each row's best and
//! second best and each column's best, so nothing of size `Na × Nb` is stored.

use serde::{Deserialize, Serialize};

use crate::error::{FeaturesError, Result};
use crate::types::{Features, Matcher, Matches};

/// Matcher settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MnnConfig {
    /// Lowe's ratio test on descriptor distances `‖a − b‖ = sqrt(2 − 2·sim)` (unit descriptors):
    /// keep a match only if best < `ratio` × second best. `None` turns it off.
    pub ratio: Option<f32>,
    /// Keep a match only if its similarity exceeds this (XFeat's `min_cossim`, 0.82 in its
    /// `match`). `None` turns it off.
    pub min_similarity: Option<f32>,
}

impl Default for MnnConfig {
    /// Plain mutual nearest neighbours, as XFeat's `match_xfeat` (`min_cossim = -1`).
    fn default() -> Self {
        Self {
            ratio: None,
            min_similarity: None,
        }
    }
}

/// Mutual nearest-neighbour matcher.
#[derive(Debug, Clone, Default)]
pub struct MnnMatcher {
    config: MnnConfig,
}

impl MnnMatcher {
    /// A matcher with `config` (checked).
    pub fn new(config: MnnConfig) -> Result<Self> {
        if let Some(r) = config.ratio
            && !(r > 0.0 && r <= 1.0)
        {
            return Err(FeaturesError::InvalidConfig {
                field: "ratio",
                value: r.to_string(),
                reason: "in (0, 1]",
            });
        }
        if let Some(s) = config.min_similarity
            && !s.is_finite()
        {
            return Err(FeaturesError::InvalidConfig {
                field: "min_similarity",
                value: s.to_string(),
                reason: "a finite similarity",
            });
        }
        Ok(Self { config })
    }

    /// The settings.
    pub fn config(&self) -> &MnnConfig {
        &self.config
    }
}

impl Matcher for MnnMatcher {
    /// Pairs `(i, j)` where `j` is `i`'s most similar descriptor in `b` and `i` is `j`'s in `a`
    /// (first index on ties), filtered by the ratio and similarity settings. Scores are the
    /// similarities clamped to [0, 1].
    fn match_features(&self, a: &Features, b: &Features) -> Result<Matches> {
        let dim = check(a, "a")?;
        if check(b, "b")? != dim {
            return Err(FeaturesError::InvalidInput(format!(
                "descriptor lengths differ: {} vs {}",
                a.descriptor_dim, b.descriptor_dim
            )));
        }
        let (na, nb) = (a.len(), b.len());
        if na == 0 || nb == 0 {
            return Ok(Matches::default());
        }
        let best = nearest_neighbours(&a.descriptors, &b.descriptors, dim);
        let mut matches = Matches::default();
        for (i, row) in best.rows.iter().enumerate() {
            let j = row.best_index;
            if !row.best.is_finite() || best.cols[j].best_index != i {
                continue;
            }
            if let Some(min) = self.config.min_similarity
                && row.best <= min
            {
                continue;
            }
            if let Some(ratio) = self.config.ratio
                && nb > 1
            {
                let d1 = (2.0 - 2.0 * row.best).max(0.0).sqrt();
                let d2 = (2.0 - 2.0 * row.second).max(0.0).sqrt();
                if d1 >= ratio * d2 {
                    continue;
                }
            }
            matches.pairs.push((i, j));
            matches.scores.push(row.best.clamp(0.0, 1.0));
        }
        Ok(matches)
    }
}

fn check(f: &Features, which: &str) -> Result<usize> {
    if f.descriptors.len() != f.len() * f.descriptor_dim {
        return Err(FeaturesError::InvalidInput(format!(
            "features {which}: {} descriptor values for {} keypoints of length {}",
            f.descriptors.len(),
            f.len(),
            f.descriptor_dim
        )));
    }
    if f.descriptor_dim == 0 && !f.is_empty() {
        return Err(FeaturesError::InvalidInput(format!(
            "features {which}: empty descriptors"
        )));
    }
    Ok(f.descriptor_dim)
}

/// Best (and second best, for rows) similarity and the best's index.
#[derive(Debug, Clone, Copy)]
struct Best {
    best: f32,
    second: f32,
    best_index: usize,
}

impl Best {
    const EMPTY: Best = Best {
        best: f32::NEG_INFINITY,
        second: f32::NEG_INFINITY,
        best_index: 0,
    };

    /// Offers similarity `s` of index `k`; candidates must arrive in increasing `k` so the
    /// first index wins ties.
    #[inline]
    fn offer(&mut self, s: f32, k: usize) {
        if s > self.best {
            self.second = self.best;
            self.best = s;
            self.best_index = k;
        } else if s > self.second {
            self.second = s;
        }
    }
}

struct Neighbours {
    rows: Vec<Best>,
    cols: Vec<Best>,
}

const TILE_ROWS: usize = 4;
const TILE_COLS: usize = 16;

/// Row best and second best, and column best, similarities of `a · bᵀ` (`a`: na × dim, `b`: nb × dim, row-major).
fn nearest_neighbours(a: &[f32], b: &[f32], dim: usize) -> Neighbours {
    let (na, nb) = (a.len() / dim, b.len() / dim);
    // bᵀ padded to whole column tiles: tile t holds dim × TILE_COLS values, contiguous.
    let tiles = nb.div_ceil(TILE_COLS);
    let mut bt = vec![0.0f32; tiles * dim * TILE_COLS];
    for j in 0..nb {
        let (t, c) = (j / TILE_COLS, j % TILE_COLS);
        for k in 0..dim {
            bt[(t * dim + k) * TILE_COLS + c] = b[j * dim + k];
        }
    }
    let mut rows = vec![Best::EMPTY; na];
    // Column maxima kept branch-free (vectorisable) in two plain arrays.
    let mut col_best = vec![f32::NEG_INFINITY; nb];
    let mut col_index = vec![0u32; nb];
    let mut a_tile = vec![0.0f32; dim * TILE_ROWS];
    let mut sims = vec![0.0f32; TILE_ROWS * tiles * TILE_COLS];
    let stride = tiles * TILE_COLS;
    for i0 in (0..na).step_by(TILE_ROWS) {
        let nr = TILE_ROWS.min(na - i0);
        // The row tile transposed (k-major) so each k reads TILE_ROWS consecutive values.
        a_tile.fill(0.0);
        for r in 0..nr {
            for k in 0..dim {
                a_tile[k * TILE_ROWS + r] = a[(i0 + r) * dim + k];
            }
        }
        for t in 0..tiles {
            let acc = tile_product(&a_tile, &bt[t * dim * TILE_COLS..(t + 1) * dim * TILE_COLS]);
            for (r, acc_row) in acc.iter().enumerate() {
                sims[r * stride + t * TILE_COLS..r * stride + (t + 1) * TILE_COLS]
                    .copy_from_slice(acc_row);
            }
        }
        for r in 0..nr {
            let i = i0 + r;
            let row = &sims[r * stride..r * stride + nb];
            let best = &mut rows[i];
            for (j, &s) in row.iter().enumerate() {
                if s > best.second {
                    best.offer(s, j);
                }
            }
            for ((cb, ci), &s) in col_best.iter_mut().zip(col_index.iter_mut()).zip(row) {
                let better = s > *cb;
                *cb = if better { s } else { *cb };
                *ci = if better { i as u32 } else { *ci };
            }
        }
    }
    let cols = col_best
        .into_iter()
        .zip(col_index)
        .map(|(best, i)| Best {
            best,
            second: f32::NEG_INFINITY,
            best_index: i as usize,
        })
        .collect();
    Neighbours { rows, cols }
}

/// One 4 × 16 block of similarities; fixed sizes so the accumulators stay in registers.
#[inline]
fn tile_product(a_tile: &[f32], b_tile: &[f32]) -> [[f32; TILE_COLS]; TILE_ROWS] {
    let mut acc = [[0.0f32; TILE_COLS]; TILE_ROWS];
    for (ak, bk) in a_tile
        .chunks_exact(TILE_ROWS)
        .zip(b_tile.chunks_exact(TILE_COLS))
    {
        for r in 0..TILE_ROWS {
            let av = ak[r];
            for c in 0..TILE_COLS {
                acc[r][c] += av * bk[c];
            }
        }
    }
    acc
}

#[cfg(test)]
mod tests {
    use super::*;

    fn features(desc: Vec<f32>, dim: usize) -> Features {
        let n = desc.len() / dim;
        Features {
            keypoints: vec![[0.0, 0.0]; n],
            scores: vec![1.0; n],
            descriptors: desc,
            descriptor_dim: dim,
            image_size: (1, 1),
        }
    }

    /// Deterministic pseudo-random unit vectors.
    fn unit_vectors(n: usize, dim: usize, seed: u64) -> Vec<f32> {
        let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        let mut v: Vec<f32> = (0..n * dim)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                (s >> 40) as f32 / (1u64 << 24) as f32 - 0.5
            })
            .collect();
        for row in v.chunks_exact_mut(dim) {
            let n = row.iter().map(|x| x * x).sum::<f32>().sqrt();
            row.iter_mut().for_each(|x| *x /= n);
        }
        v
    }

    fn brute_force(a: &[f32], b: &[f32], dim: usize) -> Vec<(usize, usize)> {
        let (na, nb) = (a.len() / dim, b.len() / dim);
        let sim =
            |i: usize, j: usize| -> f32 { (0..dim).map(|k| a[i * dim + k] * b[j * dim + k]).sum() };
        let argmax = |n: usize, f: &dyn Fn(usize) -> f32| {
            (0..n).fold(0, |m, k| if f(k) > f(m) { k } else { m })
        };
        (0..na)
            .filter_map(|i| {
                let j = argmax(nb, &|j| sim(i, j));
                (argmax(na, &|i2| sim(i2, j)) == i).then_some((i, j))
            })
            .collect()
    }

    #[test]
    fn agrees_with_brute_force_for_odd_sizes() {
        for seed in 0..5 {
            let (na, nb, dim) = (37 + seed as usize, 53 - seed as usize, 24);
            let a = unit_vectors(na, dim, seed);
            let b = unit_vectors(nb, dim, seed + 100);
            let m = MnnMatcher::default()
                .match_features(&features(a.clone(), dim), &features(b.clone(), dim))
                .unwrap();
            assert_eq!(m.pairs, brute_force(&a, &b, dim), "seed {seed}");
            assert!(!m.pairs.is_empty());
        }
    }

    #[test]
    fn recovers_a_permutation_of_noisy_copies() {
        for seed in 0..4 {
            let (n, dim) = (300, 64);
            let a = unit_vectors(n, dim, seed);
            let noise = unit_vectors(n, dim, seed + 7);
            // b[j] = normalise(a[perm(j)] + 0.3 noise), perm(j) = (7j + 3) mod n.
            let perm = |j: usize| (7 * j + 3) % n;
            let mut b = vec![0.0f32; n * dim];
            for j in 0..n {
                let row = &mut b[j * dim..(j + 1) * dim];
                for k in 0..dim {
                    row[k] = a[perm(j) * dim + k] + 0.3 * noise[j * dim + k];
                }
                let norm = row.iter().map(|x| x * x).sum::<f32>().sqrt();
                row.iter_mut().for_each(|x| *x /= norm);
            }
            let m = MnnMatcher::default()
                .match_features(&features(a, dim), &features(b, dim))
                .unwrap();
            assert_eq!(m.pairs.len(), n, "seed {seed}");
            for &(i, j) in &m.pairs {
                assert_eq!(perm(j), i);
            }
            assert!(m.scores.iter().all(|&s| s > 0.8 && s <= 1.0));
        }
    }

    #[test]
    fn ratio_and_similarity_filters() {
        let dim = 3;
        // a0 has two equally good candidates in b (ambiguous), a1 one clear but weaker one.
        let a = vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
        let (s, c) = (0.8f32, 0.6f32);
        let (u, v) = (0.99f32, (1.0f32 - 0.99 * 0.99).sqrt());
        let b = vec![u, v, 0.0, u, -v, 0.0, 0.0, s, c];
        let (fa, fb) = (features(a, dim), features(b, dim));
        let plain = MnnMatcher::default().match_features(&fa, &fb).unwrap();
        assert_eq!(plain.pairs, vec![(0, 0), (1, 2)]);
        let ratio = MnnMatcher::new(MnnConfig {
            ratio: Some(0.8),
            ..MnnConfig::default()
        })
        .unwrap()
        .match_features(&fa, &fb)
        .unwrap();
        assert_eq!(ratio.pairs, vec![(1, 2)]);
        let sim = MnnMatcher::new(MnnConfig {
            min_similarity: Some(0.82),
            ..MnnConfig::default()
        })
        .unwrap()
        .match_features(&fa, &fb)
        .unwrap();
        assert_eq!(sim.pairs, vec![(0, 0)]);
    }

    #[test]
    fn bad_inputs_are_errors_not_panics() {
        let a = features(vec![1.0, 0.0], 2);
        let b = features(vec![1.0, 0.0, 0.0], 3);
        assert!(MnnMatcher::default().match_features(&a, &b).is_err());
        let mut broken = features(vec![1.0, 0.0], 2);
        broken.descriptors.pop();
        assert!(MnnMatcher::default().match_features(&broken, &a).is_err());
        let empty = features(vec![], 2);
        assert!(
            MnnMatcher::default()
                .match_features(&empty, &a)
                .unwrap()
                .pairs
                .is_empty()
        );
        for bad in [Some(0.0), Some(1.5), Some(f32::NAN)] {
            assert!(
                MnnMatcher::new(MnnConfig {
                    ratio: bad,
                    ..MnnConfig::default()
                })
                .is_err()
            );
        }
    }
}
