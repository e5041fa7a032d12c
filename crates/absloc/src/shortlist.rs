//! Shortlist for the whole-map search: which (view, tile) pairs to match first when there is
//! no prior position (the first fix, the search after a loss).
//!
//! Matching every tile of a map under every rotation hypothesis costs one LightGlue run per
//! pair: 72 pairs on a 60 m map, thousands on a 2 km one. Each tile and each rotated view is
//! summarised by one global descriptor, a VLAD vector (Jégou et al., "Aggregating local
//! descriptors into a compact image representation", CVPR 2010) over the local features the
//! search already has: the residuals of its descriptors to their nearest visual word, summed
//! per word, each word's block L2-normalised ("intra-normalisation", Arandjelović and
//! Zisserman, CVPR 2013), signed square roots, then L2-normalised. The pairs are ranked by the
//! dot product of their VLADs and only the best [`ShortlistConfig::candidates`] are matched.
//!
//! The vocabulary is trained on the map itself (k-means++ seeding and Lloyd iterations over a
//! strided sample of the tiles' descriptors, seeded), when the first whole-map search needs
//! it: nothing is shipped, and the words follow whatever detector and terrain the map has.
//! The descriptors are not rotation-invariant, so a view turned to the wrong heading
//! summarises differently: the ranking chooses the heading as well as the tile.

use jointloc_features::Features;
use rand::{Rng, SeedableRng};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::tile_store::TileStore;
use crate::tiles::MapTiles;

/// Settings of the shortlist.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ShortlistConfig {
    /// (view, tile) pairs matched by a whole-map search, best-ranked first; 0 matches every
    /// pair (the paper's exhaustive search). A search with fewer pairs is not ranked.
    pub candidates: usize,
    /// Pairs matched when the coarse places ([`crate::AbsLocConfig::coarse_places_first`])
    /// were tried first and gave no fix, at most `candidates`. 0 (the default): none; in
    /// flight the next search comes a second or two later, and a failing search paid for
    /// both (docs/absloc.md §"A failing whole-map search").
    pub after_coarse_places: usize,
    /// Visual words of the vocabulary.
    pub words: usize,
    /// Tile descriptors sampled (evenly, in tile order) to train the vocabulary.
    pub training_descriptors: usize,
    /// Lloyd iterations of the k-means.
    pub iterations: usize,
    /// Seed of the k-means++ initialisation.
    pub seed: u64,
}

impl Default for ShortlistConfig {
    fn default() -> Self {
        Self {
            candidates: 48,
            after_coarse_places: 0,
            words: 64,
            training_descriptors: 40_000,
            iterations: 12,
            seed: 0,
        }
    }
}

/// A vocabulary and the visual word of every tile keypoint.
#[derive(Debug)]
pub(crate) struct TileIndex {
    dim: usize,
    /// `words × dim`, row-major.
    centroids: Vec<f32>,
    /// Per tile, the word of each keypoint.
    tile_words: Vec<Vec<u16>>,
}

impl TileIndex {
    /// Trains the vocabulary on the tiles' descriptors and assigns every tile keypoint its
    /// word; `None` when the tiles have fewer descriptors than words or differ in descriptor
    /// length. Two passes over the tiles of `store`, one tile in memory per thread at a time
    /// beyond the store's own budget.
    pub(crate) fn build(
        store: &TileStore,
        map: &MapTiles,
        config: &ShortlistConfig,
    ) -> Result<Option<Self>> {
        let lens: Vec<usize> = (0..store.len()).map(|t| store.keypoints(t)).collect();
        let total: usize = lens.iter().sum();
        let words = config.words.clamp(1, u16::MAX as usize);
        if total < words {
            return Ok(None);
        }
        // Every `stride`-th descriptor in tile order, as if all tiles were one list.
        let stride = total.div_ceil(config.training_descriptors.max(words));
        let starts: Vec<usize> = lens
            .iter()
            .scan(0usize, |acc, &n| {
                let s = *acc;
                *acc += n;
                Some(s)
            })
            .collect();
        let sampled: Vec<Option<(usize, Vec<f32>)>> = (0..store.len())
            .into_par_iter()
            .map(|t| {
                if lens[t] == 0 {
                    return Ok(None);
                }
                let f = store.get(map, t)?;
                let first = (stride - starts[t] % stride) % stride;
                let mut out = Vec::new();
                for i in (first..f.len()).step_by(stride) {
                    out.extend_from_slice(f.descriptor(i));
                }
                Ok(Some((f.descriptor_dim, out)))
            })
            .collect::<Result<_>>()?;
        let Some(dim) = sampled.iter().flatten().map(|(d, _)| *d).next() else {
            return Ok(None);
        };
        if dim == 0 || sampled.iter().flatten().any(|(d, _)| *d != dim) {
            return Ok(None);
        }
        let sample: Vec<&[f32]> = sampled
            .iter()
            .flatten()
            .flat_map(|(_, d)| d.chunks_exact(dim))
            .collect();
        let centroids = kmeans(&sample, dim, words, config.iterations, config.seed);
        let tile_words = (0..store.len())
            .into_par_iter()
            .map(|t| {
                if lens[t] == 0 {
                    return Ok(Vec::new());
                }
                let f = store.get(map, t)?;
                Ok((0..f.len())
                    .map(|i| nearest(&centroids, dim, f.descriptor(i)) as u16)
                    .collect())
            })
            .collect::<Result<_>>()?;
        Ok(Some(Self {
            dim,
            centroids,
            tile_words,
        }))
    }

    fn words(&self) -> usize {
        self.centroids.len() / self.dim
    }

    /// The VLAD of one feature set (all zeros without descriptors of the vocabulary's length).
    pub(crate) fn vlad(&self, features: &Features) -> Vec<f32> {
        if features.descriptor_dim != self.dim {
            return vec![0f32; self.words() * self.dim];
        }
        let all: Vec<(usize, u16)> = (0..features.len())
            .map(|i| {
                (
                    i,
                    nearest(&self.centroids, self.dim, features.descriptor(i)) as u16,
                )
            })
            .collect();
        self.aggregate(features, &all)
    }

    /// VLAD over the keypoints `(index, word)` of `features`.
    fn aggregate(&self, features: &Features, keypoints: &[(usize, u16)]) -> Vec<f32> {
        let mut v = vec![0f32; self.words() * self.dim];
        for &(i, w) in keypoints {
            let w = w as usize;
            let c = &self.centroids[w * self.dim..(w + 1) * self.dim];
            let block = &mut v[w * self.dim..(w + 1) * self.dim];
            for ((acc, x), m) in block.iter_mut().zip(features.descriptor(i)).zip(c) {
                *acc += x - m;
            }
        }
        for block in v.chunks_mut(self.dim) {
            normalise(block);
        }
        for x in &mut v {
            *x = x.signum() * x.abs().sqrt();
        }
        normalise(&mut v);
        v
    }

    /// The `keep` best (view, tile) pairs of `views` × `tiles`, best first (ties: the order
    /// of `tiles`, then of `views`). A view sees a frame's footprint, smaller than a tile
    /// when the map is upsampled or the UAV low, so a tile is summarised per window of
    /// `window` = (width, height) tile pixels (at half-window strides) and scores its best
    /// window.
    pub(crate) fn rank(
        &self,
        store: &TileStore,
        map: &MapTiles,
        views: &[(usize, Vec<f32>)],
        window: (f32, f32),
        tiles: &[usize],
        keep: usize,
    ) -> Result<Vec<(usize, usize)>> {
        let per_tile: Vec<Vec<f32>> = tiles
            .par_iter()
            .map(|&t| {
                let mut best = vec![f32::NEG_INFINITY; views.len()];
                if self.tile_words[t].is_empty() {
                    return Ok(best);
                }
                let f = store.get(map, t)?;
                for (x0, y0) in windows(f.image_size, window) {
                    let inside: Vec<(usize, u16)> = self.tile_words[t]
                        .iter()
                        .enumerate()
                        .filter(|&(i, _)| {
                            let [x, y] = f.keypoints[i];
                            x >= x0 && x < x0 + window.0 && y >= y0 && y < y0 + window.1
                        })
                        .map(|(i, &w)| (i, w))
                        .collect();
                    if inside.is_empty() {
                        continue;
                    }
                    let wv = self.aggregate(&f, &inside);
                    for (b, (_, v)) in best.iter_mut().zip(views) {
                        *b = b.max(v.iter().zip(&wv).map(|(a, c)| a * c).sum());
                    }
                }
                Ok(best)
            })
            .collect::<Result<_>>()?;
        let mut scored: Vec<(f32, usize, usize, usize)> = per_tile
            .iter()
            .zip(tiles)
            .enumerate()
            .flat_map(|(order, (best, &t))| {
                views
                    .iter()
                    .zip(best)
                    .enumerate()
                    .map(move |(vi, ((v, _), &s))| (s, order * views.len() + vi, *v, t))
            })
            .collect();
        scored.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        scored.truncate(keep);
        Ok(scored.into_iter().map(|(_, _, v, t)| (v, t)).collect())
    }
}

/// Top-left corners of `window`-sized windows over an image of `size`, at half-window strides,
/// the last flush with the far edge; one window at the origin where the image is smaller.
fn windows(size: (u32, u32), window: (f32, f32)) -> Vec<(f32, f32)> {
    let starts = |len: f32, win: f32| -> Vec<f32> {
        if win >= len {
            return vec![0.0];
        }
        let step = (win / 2.0).max(1.0);
        let mut s: Vec<f32> = (0..)
            .map(|k| k as f32 * step)
            .take_while(|&x| x + win < len)
            .collect();
        s.push(len - win);
        s
    };
    let xs = starts(size.0 as f32, window.0);
    let ys = starts(size.1 as f32, window.1);
    ys.iter()
        .flat_map(|&y| xs.iter().map(move |&x| (x, y)))
        .collect()
}

fn normalise(v: &mut [f32]) {
    let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    if n > 0.0 {
        for x in v {
            *x /= n;
        }
    }
}

fn sq_dist(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

/// Index of the centroid nearest to `d` (the first of equals).
fn nearest(centroids: &[f32], dim: usize, d: &[f32]) -> usize {
    let mut best = (f32::INFINITY, 0);
    for (w, c) in centroids.chunks_exact(dim).enumerate() {
        let e = sq_dist(c, d);
        if e < best.0 {
            best = (e, w);
        }
    }
    best.1
}

/// k-means with k-means++ seeding; `words × dim` centroids, row-major.
fn kmeans(sample: &[&[f32]], dim: usize, words: usize, iterations: usize, seed: u64) -> Vec<f32> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut centroids: Vec<f32> = Vec::with_capacity(words * dim);
    centroids.extend_from_slice(sample[rng.random_range(0..sample.len())]);
    let mut d2: Vec<f32> = sample
        .par_iter()
        .map(|d| sq_dist(d, &centroids[..dim]))
        .collect();
    while centroids.len() < words * dim {
        let total: f64 = d2.iter().map(|&x| x as f64).sum();
        let pick = if total > 0.0 {
            let mut r = rng.random::<f64>() * total;
            let mut pick = sample.len() - 1;
            for (i, &x) in d2.iter().enumerate() {
                r -= x as f64;
                if r <= 0.0 {
                    pick = i;
                    break;
                }
            }
            pick
        } else {
            rng.random_range(0..sample.len())
        };
        let start = centroids.len();
        centroids.extend_from_slice(sample[pick]);
        let c = &centroids[start..];
        d2.par_iter_mut()
            .zip(sample.par_iter())
            .for_each(|(e, d)| *e = e.min(sq_dist(d, c)));
    }
    for _ in 0..iterations {
        let assign: Vec<usize> = sample
            .par_iter()
            .map(|d| nearest(&centroids, dim, d))
            .collect();
        let mut sums = vec![0f64; words * dim];
        let mut counts = vec![0usize; words];
        for (d, &w) in sample.iter().zip(&assign) {
            counts[w] += 1;
            for (s, &x) in sums[w * dim..(w + 1) * dim].iter_mut().zip(d.iter()) {
                *s += x as f64;
            }
        }
        let mut moved = false;
        for w in 0..words {
            if counts[w] == 0 {
                continue; // an empty word keeps its centroid
            }
            for k in 0..dim {
                let m = (sums[w * dim + k] / counts[w] as f64) as f32;
                moved |= m != centroids[w * dim + k];
                centroids[w * dim + k] = m;
            }
        }
        if !moved {
            break;
        }
    }
    centroids
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand_chacha::ChaCha8Rng;

    const DIM: usize = 16;

    /// A map for the store's signature: in-memory stores never read it.
    fn no_map() -> MapTiles {
        MapTiles::from_image(
            image::GrayImage::new(10, 10),
            1.0,
            (10, 10),
            0.5,
            std::path::Path::new("."),
        )
        .unwrap()
    }

    fn build(tiles: &[Features], config: &ShortlistConfig) -> Option<TileIndex> {
        TileIndex::build(&TileStore::from_features(tiles.to_vec()), &no_map(), config).unwrap()
    }

    fn rank(
        index: &TileIndex,
        tiles: &[Features],
        views: &[(usize, Vec<f32>)],
        window: (f32, f32),
        order: &[usize],
        keep: usize,
    ) -> Vec<(usize, usize)> {
        let store = TileStore::from_features(tiles.to_vec());
        index
            .rank(&store, &no_map(), views, window, order, keep)
            .unwrap()
    }

    /// Random landmarks: a descriptor each, at a random place in a `size` px image.
    fn landmarks(rng: &mut ChaCha8Rng, n: usize, size: f32) -> Features {
        let mut f = Features {
            descriptor_dim: DIM,
            image_size: (size as u32, size as u32),
            ..Default::default()
        };
        for _ in 0..n {
            f.keypoints
                .push([rng.random_range(0.0..size), rng.random_range(0.0..size)]);
            f.scores.push(1.0);
            let mut d: Vec<f32> = (0..DIM).map(|_| rng.random_range(-1.0f32..1.0)).collect();
            normalise(&mut d);
            f.descriptors.extend(d);
        }
        f
    }

    /// What a view sees of `tile`: its landmarks inside `area` (x0, y0, side), re-described
    /// with noise, each kept with probability 2/3, plus `clutter` random ones.
    fn view_of(
        rng: &mut ChaCha8Rng,
        tile: &Features,
        area: (f32, f32, f32),
        clutter: usize,
    ) -> Features {
        let mut v = landmarks(rng, clutter, area.2);
        for i in 0..tile.len() {
            let [x, y] = tile.keypoints[i];
            let inside = x >= area.0 && x < area.0 + area.2 && y >= area.1 && y < area.1 + area.2;
            if inside && rng.random_range(0..3) > 0 {
                v.keypoints.push([x - area.0, y - area.1]);
                v.scores.push(1.0);
                v.descriptors.extend(
                    tile.descriptor(i)
                        .iter()
                        .map(|x| x + rng.random_range(-0.1f32..0.1)),
                );
            }
        }
        v
    }

    #[test]
    fn each_view_ranks_its_own_tile_first() {
        for seed in 0..3 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let tiles: Vec<Features> = (0..20).map(|_| landmarks(&mut rng, 300, 100.0)).collect();
            let config = ShortlistConfig {
                words: 16,
                seed,
                ..Default::default()
            };
            let index = build(&tiles, &config).expect("index");
            let order: Vec<usize> = (0..tiles.len()).collect();
            for (t, tile) in tiles.iter().enumerate() {
                let view = view_of(&mut rng, tile, (0.0, 0.0, 100.0), 50);
                let vlad = index.vlad(&view);
                let ranked = rank(&index, &tiles, &[(7, vlad)], (100.0, 100.0), &order, 3);
                assert_eq!(ranked[0], (7, t), "seed {seed}: view of tile {t}");
                assert_eq!(ranked.len(), 3);
            }
        }
    }

    /// A view of a quarter of a tile finds it through a window, where the tile's summary as a
    /// whole is diluted by the three quarters the view does not see.
    #[test]
    fn a_view_of_part_of_a_tile_finds_it_through_a_window() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let tiles: Vec<Features> = (0..30).map(|_| landmarks(&mut rng, 600, 200.0)).collect();
        let config = ShortlistConfig {
            words: 16,
            ..Default::default()
        };
        let index = build(&tiles, &config).expect("index");
        let order: Vec<usize> = (0..tiles.len()).collect();
        let (mut windowed, mut whole) = (0, 0);
        for (t, tile) in tiles.iter().enumerate() {
            let view = view_of(&mut rng, tile, (100.0, 100.0, 100.0), 40);
            let vlad = index.vlad(&view);
            let w = rank(
                &index,
                &tiles,
                &[(0, vlad.clone())],
                (100.0, 100.0),
                &order,
                1,
            );
            windowed += usize::from(w[0].1 == t);
            let a = rank(&index, &tiles, &[(0, vlad)], (200.0, 200.0), &order, 1);
            whole += usize::from(a[0].1 == t);
        }
        assert!(windowed >= 29, "windows: {windowed} of 30 first");
        assert!(whole < windowed, "whole tiles: {whole} of 30 first");
    }

    /// Streamed from a cache file with room for two tiles, the index and the ranking are those
    /// of the tiles held in memory.
    #[test]
    fn streaming_from_the_cache_gives_the_same_index_and_ranking() {
        let mut rng = ChaCha8Rng::seed_from_u64(21);
        let tiles: Vec<Features> = (0..12).map(|_| landmarks(&mut rng, 150, 100.0)).collect();
        let config = ShortlistConfig {
            words: 8,
            training_descriptors: 500,
            ..Default::default()
        };
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.tiles");
        std::fs::write(&path, crate::cache::encode("k", &tiles)).unwrap();
        let file = crate::cache::CacheFile::open(&path, "k", tiles.len())
            .unwrap()
            .unwrap();
        let one = 150 * (8 + 4 + 4 * DIM);
        let store = TileStore::from_cache_file(file, 2 * one);
        let streamed = TileIndex::build(&store, &no_map(), &config)
            .unwrap()
            .unwrap();
        let held = build(&tiles, &config).unwrap();
        assert_eq!(streamed.centroids, held.centroids);
        assert_eq!(streamed.tile_words, held.tile_words);
        let order: Vec<usize> = (0..tiles.len()).collect();
        let view = view_of(&mut rng, &tiles[4], (0.0, 0.0, 100.0), 30);
        let vlad = held.vlad(&view);
        let a = streamed
            .rank(
                &store,
                &no_map(),
                &[(0, vlad.clone())],
                (100.0, 100.0),
                &order,
                5,
            )
            .unwrap();
        assert_eq!(
            a,
            rank(&held, &tiles, &[(0, vlad)], (100.0, 100.0), &order, 5)
        );
        assert_eq!(a[0], (0, 4));
        assert!(store.resident_bytes() <= 2 * one);
    }

    #[test]
    fn training_is_seeded() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let tiles: Vec<Features> = (0..6).map(|_| landmarks(&mut rng, 100, 50.0)).collect();
        let config = ShortlistConfig {
            words: 8,
            ..Default::default()
        };
        let a = build(&tiles, &config).expect("index");
        let b = build(&tiles, &config).expect("index");
        assert_eq!(a.centroids, b.centroids);
        assert_eq!(a.tile_words, b.tile_words);
        let other = ShortlistConfig { seed: 1, ..config };
        let c = build(&tiles, &other).expect("index");
        assert_ne!(a.centroids, c.centroids);
        for t in &tiles {
            let n: f32 = a.vlad(t).iter().map(|x| x * x).sum();
            assert!((n - 1.0).abs() < 1e-4, "unit length, got {n}");
        }
    }

    #[test]
    fn too_few_or_mixed_descriptors_give_no_index() {
        let one = Features {
            keypoints: vec![[0.0, 0.0]; 3],
            scores: vec![1.0; 3],
            descriptors: vec![0.5; 12],
            descriptor_dim: 4,
            ..Default::default()
        };
        let config = ShortlistConfig::default();
        assert!(build(std::slice::from_ref(&one), &config).is_none());
        assert!(build(&[], &config).is_none());
        let mut other = one.clone();
        other.descriptor_dim = 3;
        other.descriptors = vec![0.5; 9];
        let small = ShortlistConfig {
            words: 2,
            ..Default::default()
        };
        assert!(build(&[one.clone(), other], &small).is_none());
        assert!(build(&[one], &small).is_some());
    }

    #[test]
    fn windows_cover_the_image_at_half_strides() {
        assert_eq!(windows((100, 50), (200.0, 200.0)), vec![(0.0, 0.0)]);
        let w = windows((500, 500), (200.0, 200.0));
        let xs: Vec<f32> = w.iter().filter(|p| p.1 == 0.0).map(|p| p.0).collect();
        assert_eq!(xs, vec![0.0, 100.0, 200.0, 300.0]);
        assert_eq!(w.len(), 16);
        assert_eq!(
            windows((250, 500), (200.0, 500.0)),
            vec![(0.0, 0.0), (50.0, 0.0)]
        );
    }
}
