//! Descriptor matching by Hamming distance: brute-force mutual nearest neighbours (absolute
//! localisation, initialisation) and a windowed search around predicted positions (SLAM
//! tracking), both with a distance cap, a ratio test and, optionally, ORB-SLAM's
//! rotation-consistency histogram.

use std::f64::consts::TAU;
use std::ops::RangeInclusive;

use serde::{Deserialize, Serialize};

use super::descriptor::{Descriptor, hamming};
use super::{KeyPoint, OrbFeatures};

/// Matching thresholds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MatcherConfig {
    /// Largest accepted Hamming distance (ORB-SLAM2: 50 for tracking, 100 for loose searches).
    pub max_distance: u32,
    /// Best distance must be below `ratio` × second best (Lowe's test); 1 disables it.
    pub ratio: f64,
    /// Brute force: keep a match only if each side is the other's nearest neighbour.
    pub mutual: bool,
    /// Keep only matches whose orientation change falls in the dominant bins of a histogram.
    pub check_orientation: bool,
    /// Bins of that histogram over 360° (ORB-SLAM2: 30).
    pub orientation_bins: usize,
}

impl Default for MatcherConfig {
    fn default() -> Self {
        Self {
            max_distance: 64,
            ratio: 0.9,
            mutual: true,
            check_orientation: false,
            orientation_bins: 30,
        }
    }
}

/// A correspondence: `query` and `train` index their feature lists.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Match {
    pub query: usize,
    pub train: usize,
    pub distance: u32,
}

/// Best and second-best distances with the best index.
fn two_nearest(
    d: &Descriptor,
    others: impl Iterator<Item = (usize, Descriptor)>,
) -> Option<(usize, u32, u32)> {
    let (mut best, mut bi, mut second) = (u32::MAX, usize::MAX, u32::MAX);
    for (i, o) in others {
        let dist = hamming(d, &o);
        if dist < best {
            second = best;
            best = dist;
            bi = i;
        } else if dist < second {
            second = dist;
        }
    }
    (bi != usize::MAX).then_some((bi, best, second))
}

fn passes(best: u32, second: u32, cfg: &MatcherConfig) -> bool {
    best <= cfg.max_distance
        && (second == u32::MAX || (best as f64) < cfg.ratio * second as f64 || cfg.ratio >= 1.0)
}

/// Brute-force matching of every query descriptor against every train descriptor.
/// Sorted by query index.
pub fn match_mutual(query: &OrbFeatures, train: &OrbFeatures, cfg: &MatcherConfig) -> Vec<Match> {
    let q = &query.descriptors;
    let t = &train.descriptors;
    let back: Vec<Option<usize>> = if cfg.mutual {
        t.iter()
            .map(|d| two_nearest(d, q.iter().copied().enumerate()).map(|(i, _, _)| i))
            .collect()
    } else {
        Vec::new()
    };
    let mut out = Vec::new();
    for (qi, d) in q.iter().enumerate() {
        let Some((ti, best, second)) = two_nearest(d, t.iter().copied().enumerate()) else {
            continue;
        };
        if !passes(best, second, cfg) {
            continue;
        }
        if cfg.mutual && back[ti] != Some(qi) {
            continue;
        }
        out.push(Match {
            query: qi,
            train: ti,
            distance: best,
        });
    }
    if cfg.check_orientation {
        let diffs: Vec<f64> = out
            .iter()
            .map(|m| query.keypoints[m.query].angle - train.keypoints[m.train].angle)
            .collect();
        let keep = orientation_consistent(&diffs, cfg.orientation_bins);
        out = out
            .into_iter()
            .zip(keep)
            .filter(|(_, k)| *k)
            .map(|(m, _)| m)
            .collect();
    }
    out
}

/// ORB-SLAM2's rotation check: histogram of the orientation changes (radians) in `bins` bins
/// over a full turn; keeps the three fullest bins, the second and third only if they hold at
/// least a tenth of the fullest. Returns, per change, whether it falls in a kept bin.
pub fn orientation_consistent(angle_changes: &[f64], bins: usize) -> Vec<bool> {
    let bins = bins.max(1);
    let bin_of = |a: f64| -> usize {
        let a = a.rem_euclid(TAU);
        ((a / TAU * bins as f64) as usize).min(bins - 1)
    };
    let mut hist = vec![0usize; bins];
    let idx: Vec<usize> = angle_changes.iter().map(|&a| bin_of(a)).collect();
    for &b in &idx {
        hist[b] += 1;
    }
    let mut order: Vec<usize> = (0..bins).collect();
    order.sort_by(|&a, &b| hist[b].cmp(&hist[a]).then(a.cmp(&b)));
    let top = hist[order[0]];
    let mut kept = vec![false; bins];
    for (rank, &b) in order.iter().take(3).enumerate() {
        if hist[b] > 0 && (rank == 0 || hist[b] * 10 >= top) {
            kept[b] = true;
        }
    }
    idx.iter().map(|&b| kept[b]).collect()
}

/// Spatial index of a frame's keypoints in square cells, for windowed searches.
#[derive(Debug, Clone)]
pub struct FeatureGrid {
    cell: f64,
    cols: usize,
    rows: usize,
    cells: Vec<Vec<u32>>,
    keypoints: Vec<(f64, f64, u32)>,
}

impl FeatureGrid {
    /// Indexes `keypoints` of a `width` × `height` image in cells of `cell` px (≥ 1).
    pub fn new(keypoints: &[KeyPoint], width: usize, height: usize, cell: f64) -> Self {
        let cell = if cell.is_finite() {
            cell.max(1.0)
        } else {
            10.0
        };
        let cols = ((width as f64 / cell).ceil() as usize).max(1);
        let rows = ((height as f64 / cell).ceil() as usize).max(1);
        let mut cells = vec![Vec::new(); cols * rows];
        let mut pts = Vec::with_capacity(keypoints.len());
        for (i, k) in keypoints.iter().enumerate() {
            pts.push((k.x, k.y, k.octave));
            if !(k.x.is_finite() && k.y.is_finite()) {
                continue;
            }
            let c = ((k.x / cell).floor().max(0.0) as usize).min(cols - 1);
            let r = ((k.y / cell).floor().max(0.0) as usize).min(rows - 1);
            cells[r * cols + c].push(i as u32);
        }
        Self {
            cell,
            cols,
            rows,
            cells,
            keypoints: pts,
        }
    }

    /// Indices of keypoints with |x − kx| ≤ r and |y − ky| ≤ r (a square window, as
    /// ORB-SLAM2) and octave in `octaves`, ascending.
    pub fn in_area(&self, x: f64, y: f64, r: f64, octaves: &RangeInclusive<u32>) -> Vec<usize> {
        let mut out = Vec::new();
        if !(x.is_finite() && y.is_finite() && r.is_finite()) || r < 0.0 {
            return out;
        }
        let lo = |v: f64, n: usize| (((v - r) / self.cell).floor().max(0.0) as usize).min(n);
        let hi = |v: f64, n: usize| {
            let h = ((v + r) / self.cell).floor();
            if h < 0.0 {
                None
            } else {
                Some((h as usize).min(n - 1))
            }
        };
        let (Some(c1), Some(r1)) = (hi(x, self.cols), hi(y, self.rows)) else {
            return out;
        };
        let (c0, r0) = (lo(x, self.cols), lo(y, self.rows));
        for row in r0..=r1 {
            for col in c0..=c1 {
                for &i in &self.cells[row * self.cols + col] {
                    let (kx, ky, o) = self.keypoints[i as usize];
                    if (kx - x).abs() <= r && (ky - y).abs() <= r && octaves.contains(&o) {
                        out.push(i as usize);
                    }
                }
            }
        }
        out.sort_unstable();
        out
    }
}

/// A descriptor looked for around a predicted position (e.g. a projected map point).
#[derive(Debug, Clone, PartialEq)]
pub struct WindowQuery {
    pub descriptor: Descriptor,
    /// Predicted position in the train image (level-0 pixels).
    pub x: f64,
    pub y: f64,
    /// Half side of the square search window, pixels.
    pub radius: f64,
    /// Octaves a match may have (predicted scale ± tolerance).
    pub octaves: RangeInclusive<u32>,
    /// Orientation of the query's keypoint (radians) for the rotation check; queries without
    /// one are never removed by it.
    pub angle: Option<f64>,
}

/// Matches each query against the train keypoints inside its window; a train keypoint is
/// given to the query closest to it in descriptor distance (ties: lower query index).
/// Sorted by query index. `grid` must index `train.keypoints`.
pub fn search_in_window(
    queries: &[WindowQuery],
    train: &OrbFeatures,
    grid: &FeatureGrid,
    cfg: &MatcherConfig,
) -> Vec<Match> {
    let mut owner: Vec<Option<Match>> = vec![None; train.len()];
    for (qi, q) in queries.iter().enumerate() {
        let cands = grid.in_area(q.x, q.y, q.radius, &q.octaves);
        let Some((ti, best, second)) = two_nearest(
            &q.descriptor,
            cands
                .into_iter()
                .filter(|&i| i < train.descriptors.len())
                .map(|i| (i, train.descriptors[i])),
        ) else {
            continue;
        };
        if !passes(best, second, cfg) {
            continue;
        }
        let m = Match {
            query: qi,
            train: ti,
            distance: best,
        };
        match owner[ti] {
            Some(prev) if prev.distance <= best => {}
            _ => owner[ti] = Some(m),
        }
    }
    let mut out: Vec<Match> = owner.into_iter().flatten().collect();
    out.sort_by_key(|m| m.query);
    if cfg.check_orientation {
        let with_angle: Vec<usize> = (0..out.len())
            .filter(|&i| queries[out[i].query].angle.is_some())
            .collect();
        let diffs: Vec<f64> = with_angle
            .iter()
            .map(|&i| {
                queries[out[i].query].angle.unwrap_or(0.0) - train.keypoints[out[i].train].angle
            })
            .collect();
        let keep = orientation_consistent(&diffs, cfg.orientation_bins);
        let mut drop = vec![false; out.len()];
        for (&i, k) in with_angle.iter().zip(keep) {
            drop[i] = !k;
        }
        out = out
            .into_iter()
            .zip(drop)
            .filter(|(_, d)| !d)
            .map(|(m, _)| m)
            .collect();
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn kp(x: f64, y: f64, octave: u32, angle: f64) -> KeyPoint {
        KeyPoint {
            x,
            y,
            octave,
            angle,
            response: 1.0,
            size: 31.0,
        }
    }

    fn random_desc(rng: &mut ChaCha8Rng) -> Descriptor {
        std::array::from_fn(|_| rng.random())
    }

    /// Flips `n` distinct bits.
    fn perturb(d: &Descriptor, n: usize, rng: &mut ChaCha8Rng) -> Descriptor {
        let mut out = *d;
        for i in rand::seq::index::sample(rng, 256, n) {
            out[i / 8] ^= 1 << (i % 8);
        }
        out
    }

    fn features(kps: Vec<KeyPoint>, descs: Vec<Descriptor>) -> OrbFeatures {
        OrbFeatures {
            keypoints: kps,
            descriptors: descs,
            level_scales: vec![1.0],
        }
    }

    #[test]
    fn mutual_matching_recovers_a_permutation() {
        for seed in 0..3u64 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let n = 200;
            let a: Vec<Descriptor> = (0..n).map(|_| random_desc(&mut rng)).collect();
            let perm: Vec<usize> = rand::seq::index::sample(&mut rng, n, n).into_vec();
            let mut b = vec![[0u8; 32]; n];
            for (i, &p) in perm.iter().enumerate() {
                b[p] = perturb(&a[i], 20, &mut rng);
            }
            // 50 distractors in b.
            b.extend((0..50).map(|_| random_desc(&mut rng)));
            let kps = |m| {
                (0..m)
                    .map(|i| kp(i as f64, 0.0, 0, 0.0))
                    .collect::<Vec<_>>()
            };
            let fa = features(kps(n), a);
            let fb = features(kps(n + 50), b);
            let m = match_mutual(&fa, &fb, &MatcherConfig::default());
            assert_eq!(m.len(), n);
            assert!(
                m.iter()
                    .all(|m| perm[m.query] == m.train && m.distance == 20)
            );
            // A distance cap below the perturbation rejects everything.
            let strict = MatcherConfig {
                max_distance: 19,
                ..Default::default()
            };
            assert!(match_mutual(&fa, &fb, &strict).is_empty());
        }
    }

    #[test]
    fn ratio_test_rejects_ambiguous_matches() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let d = random_desc(&mut rng);
        let fa = features(vec![kp(0.0, 0.0, 0, 0.0)], vec![d]);
        // Two near-identical candidates: 10 and 11 bits away.
        let fb = features(
            vec![kp(0.0, 0.0, 0, 0.0), kp(1.0, 0.0, 0, 0.0)],
            vec![perturb(&d, 10, &mut rng), perturb(&d, 11, &mut rng)],
        );
        let cfg = MatcherConfig {
            mutual: false,
            ..Default::default()
        };
        assert!(match_mutual(&fa, &fb, &cfg).is_empty());
        let no_ratio = MatcherConfig { ratio: 1.0, ..cfg };
        assert_eq!(match_mutual(&fa, &fb, &no_ratio).len(), 1);
    }

    #[test]
    fn rotation_histogram_keeps_the_dominant_bins() {
        let mut changes = vec![0.5; 50];
        changes.extend(vec![0.52; 10]);
        changes.extend(vec![2.0; 4]); // < 10 % of 50: dropped
        changes.extend(vec![4.0, -1.0]);
        let keep = orientation_consistent(&changes, 30);
        assert!(keep[..60].iter().all(|&k| k));
        assert!(keep[60..].iter().all(|&k| !k));
        // Angle wrap: 2π − 0.01 and −0.01 fall in the same bin.
        let keep = orientation_consistent(&[TAU - 0.01, -0.01, 3.0], 30);
        assert_eq!(keep, vec![true, true, true]);
    }

    #[test]
    fn grid_window_search_respects_window_octave_and_uniqueness() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let kps: Vec<KeyPoint> = (0..400)
            .map(|i| {
                kp(
                    (i % 20) as f64 * 25.0 + 3.0,
                    (i / 20) as f64 * 25.0 + 3.0,
                    (i % 3) as u32,
                    0.3,
                )
            })
            .collect();
        let descs: Vec<Descriptor> = (0..400).map(|_| random_desc(&mut rng)).collect();
        let train = features(kps.clone(), descs.clone());
        let grid = FeatureGrid::new(&kps, 500, 500, 10.0);
        // Grid lookups equal a linear scan.
        for _ in 0..50 {
            let (x, y, r) = (
                rng.random_range(-20.0..520.0),
                rng.random_range(-20.0..520.0),
                rng.random_range(0.0..60.0),
            );
            let oct = 1..=2;
            let want: Vec<usize> = (0..kps.len())
                .filter(|&i| {
                    (kps[i].x - x).abs() <= r
                        && (kps[i].y - y).abs() <= r
                        && oct.contains(&kps[i].octave)
                })
                .collect();
            assert_eq!(grid.in_area(x, y, r, &oct), want);
        }
        // Queries near their true keypoint find it; a query whose window misses it does not.
        let mut queries: Vec<WindowQuery> = (0..100)
            .map(|i| WindowQuery {
                descriptor: perturb(&descs[i], 15, &mut rng),
                x: kps[i].x + 4.0,
                y: kps[i].y - 3.0,
                radius: 8.0,
                octaves: 0..=2,
                angle: Some(0.3),
            })
            .collect();
        queries[5].x += 30.0;
        queries[6].octaves = 3..=5;
        // Two queries for the same keypoint: the closer descriptor wins.
        let mut dup = queries[7].clone();
        dup.descriptor = perturb(&descs[7], 5, &mut rng);
        queries.push(dup);
        let cfg = MatcherConfig {
            check_orientation: true,
            ..Default::default()
        };
        let m = search_in_window(&queries, &train, &grid, &cfg);
        assert!(
            m.iter()
                .all(|m| m.query == m.train || (m.query == 100 && m.train == 7))
        );
        let matched: Vec<usize> = m.iter().map(|m| m.query).collect();
        assert!(!matched.contains(&5) && !matched.contains(&6) && !matched.contains(&7));
        assert!(matched.contains(&100));
        assert_eq!(m.len(), 98);
    }
}
