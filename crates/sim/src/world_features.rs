//! Craters and rocks drawn per world block, for maps larger than the flight.
//!
//! [`crate::terrain::generate_terrain`] draws its features from one random stream over the
//! rectangle it covers, so two rectangles get unrelated craters. A map much larger than the
//! flight is synthesised twice instead: coarsely over the whole map and finely under the
//! flight. Both must show the same craters and rocks where they overlap, so here every
//! feature is drawn from a stream of its own world block (`BLOCK_M` square) and size class,
//! never from the rectangle: any rectangle, at any cell size, sees the same features. A
//! coarse grid leaves out whole size classes it cannot resolve; the draws of the others do not
//! change (each rock's shape has its own seed, whatever the grid does with it).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::craters::{Crater, CraterPopulation, EJECTA_REACH, EQUILIBRIUM_COEFFICIENT, poisson};
use crate::noise::{derive_seed, hash2};
use crate::rocks::{GolombekSfd, Rock, RockSampler, ejecta_blocks};

/// Side of a world block, metres.
pub const BLOCK_M: f64 = 32.0;
/// Logarithmic diameter bins of the crater population (as in [`CraterPopulation::sample`]).
const CRATER_BINS: usize = 48;

/// A world rectangle `(x0, y0, x1, y1)`, metres.
pub type Rect = (f64, f64, f64, f64);

/// Blocks `(bx, by)` that touch `rect` grown by `margin`.
fn blocks(rect: Rect, margin: f64) -> impl Iterator<Item = (i64, i64)> {
    let (x0, y0, x1, y1) = rect;
    let lo = |v: f64| ((v - margin) / BLOCK_M).floor() as i64;
    let hi = |v: f64| ((v + margin) / BLOCK_M).floor() as i64;
    let (bx0, bx1, by0, by1) = (lo(x0), hi(x1), lo(y0), hi(y1));
    (by0..=by1).flat_map(move |by| (bx0..=bx1).map(move |bx| (bx, by)))
}

fn block_rng(seed: u64, class: u64, (bx, by): (i64, i64)) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(hash2(derive_seed(seed, class), bx, by))
}

/// Craters of `pop` whose rim or ejecta reach `rect`, leaving out the diameter bins that end
/// below `resolved_from_m`; oldest first (ties by position), the order to stamp them in.
pub fn craters_over(
    pop: &CraterPopulation,
    rect: Rect,
    resolved_from_m: f64,
    seed: u64,
) -> Vec<Crater> {
    let mut out = Vec::new();
    if !(pop.density > 0.0 && pop.max_diameter_m > pop.min_diameter_m) {
        return out;
    }
    let ratio = (pop.max_diameter_m / pop.min_diameter_m).powf(1.0 / CRATER_BINS as f64);
    let (x0, y0, x1, y1) = rect;
    let mut lo = pop.min_diameter_m;
    for bin in 0..CRATER_BINS {
        let hi = lo * ratio;
        if hi <= resolved_from_m {
            lo = hi;
            continue;
        }
        let lambda =
            pop.density * EQUILIBRIUM_COEFFICIENT * (lo.powi(-2) - hi.powi(-2)) * BLOCK_M * BLOCK_M;
        let (a, b) = (lo.powi(-2), hi.powi(-2));
        for block in blocks(rect, 0.5 * EJECTA_REACH * hi) {
            let mut rng = block_rng(seed, bin as u64, block);
            for _ in 0..poisson(lambda, &mut rng) {
                let u: f64 = rng.random();
                let d = (a - u * (a - b)).powf(-0.5);
                let x = (block.0 as f64 + rng.random::<f64>()) * BLOCK_M;
                let y = (block.1 as f64 + rng.random::<f64>()) * BLOCK_M;
                let crater = Crater::random(x, y, d, &mut rng);
                let reach = 0.5 * EJECTA_REACH * d;
                if x + reach >= x0 && x - reach <= x1 && y + reach >= y0 && y - reach <= y1 {
                    out.push(crater);
                }
            }
        }
        lo = hi;
    }
    out.sort_by(|p, q| {
        q.age
            .total_cmp(&p.age)
            .then(p.x.total_cmp(&q.x))
            .then(p.y.total_cmp(&q.y))
    });
    out
}

/// A Golombek rock field drawn per block and per octave of diameter.
#[derive(Debug, Clone)]
pub struct WorldRockField {
    /// One sampler per octave `[d_min·2^k, d_min·2^(k+1))`, the last ending at `d_max`.
    classes: Vec<(f64, f64, RockSampler)>,
    /// Mean height over diameter.
    pub height_ratio: f64,
}

impl WorldRockField {
    /// The field of abundance `k` between `d_min` and `d_max` (m).
    pub fn new(k: f64, d_min: f64, d_max: f64, height_ratio: f64) -> Self {
        let sfd = GolombekSfd::new(k);
        let mut classes = Vec::new();
        let mut lo = d_min;
        while lo < d_max {
            let hi = (2.0 * lo).min(d_max);
            classes.push((lo, hi, RockSampler::new(sfd, lo, hi)));
            lo = hi;
        }
        Self {
            classes,
            height_ratio,
        }
    }

    /// Hands every rock over `rect` (grown by the largest rock) to `sink`, leaving out the
    /// octaves that end below `resolved_from_m`. `keep(x, y)` ∈ [0, 1] thins the field into
    /// patches (the draw is doubled so that a `keep` averaging 0.5 keeps the density).
    pub fn for_each_rock(
        &self,
        rect: Rect,
        resolved_from_m: f64,
        seed: u64,
        keep: impl Fn(f64, f64) -> f64,
        mut sink: impl FnMut(&Rock),
    ) {
        let (x0, y0, x1, y1) = rect;
        for (class, (_, hi, sampler)) in self.classes.iter().enumerate() {
            if *hi <= resolved_from_m {
                continue;
            }
            let reach = 0.65 * hi;
            let expected = 2.0 * sampler.total_density() * BLOCK_M * BLOCK_M;
            for block in blocks(rect, reach) {
                let mut rng = block_rng(seed, 1000 + class as u64, block);
                for _ in 0..poisson(expected, &mut rng) {
                    let d = sampler.diameter(rng.random());
                    let x = (block.0 as f64 + rng.random::<f64>()) * BLOCK_M;
                    let y = (block.1 as f64 + rng.random::<f64>()) * BLOCK_M;
                    let kept = rng.random::<f64>() < keep(x, y);
                    let shape_seed: u64 = rng.random();
                    let inside =
                        x + reach >= x0 && x - reach <= x1 && y + reach >= y0 && y - reach <= y1;
                    if kept && inside {
                        let mut shape = ChaCha8Rng::seed_from_u64(shape_seed);
                        sink(&Rock::random(x, y, d, self.height_ratio, &mut shape));
                    }
                }
            }
        }
    }
}

/// The blocks thrown out by `crater` (see [`ejecta_blocks`]), drawn from the crater's own
/// seed so that every grid sees the same ones; blocks below `resolved_from_m` are left out.
pub fn world_ejecta_blocks(
    crater: &Crater,
    min_d: f64,
    height_ratio: f64,
    resolved_from_m: f64,
    seed: u64,
    mut sink: impl FnMut(&Rock),
) {
    let key = hash2(seed, crater.x.to_bits() as i64, crater.y.to_bits() as i64);
    let mut rng = ChaCha8Rng::seed_from_u64(key);
    ejecta_blocks(crater, min_d, height_ratio, &mut rng, |r| {
        if r.diameter_m >= resolved_from_m {
            sink(r)
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pop() -> CraterPopulation {
        CraterPopulation {
            density: 1.0,
            min_diameter_m: 0.15,
            max_diameter_m: 30.0,
        }
    }

    #[test]
    fn overlapping_rectangles_see_the_same_craters() {
        let big = craters_over(&pop(), (0.0, 0.0, 100.0, 80.0), 0.5, 3);
        let small = craters_over(&pop(), (40.0, 30.0, 60.0, 50.0), 0.0, 3);
        // Every crater of the small, fine rectangle above the cut is in the big, coarse one.
        let resolved: Vec<_> = small.iter().filter(|c| c.diameter_m > 0.6).collect();
        assert!(resolved.len() > 20, "{}", resolved.len());
        for c in resolved {
            assert!(big.contains(c), "{c:?} missing from the coarse draw");
        }
        // The fine one keeps the small craters the coarse one leaves out.
        assert!(small.iter().any(|c| c.diameter_m < 0.3));
        assert!(big.iter().all(|c| c.diameter_m > 0.3));
        // Oldest first.
        assert!(big.windows(2).all(|w| w[0].age >= w[1].age));
        // Another seed, other craters.
        let other = craters_over(&pop(), (40.0, 30.0, 60.0, 50.0), 0.0, 4);
        assert_ne!(other, small);
    }

    #[test]
    fn crater_density_follows_the_equilibrium_law() {
        let (w, h) = (200.0, 200.0);
        let got = craters_over(&pop(), (0.0, 0.0, w, h), 0.0, 11)
            .iter()
            .filter(|c| c.diameter_m >= 1.0 && c.x >= 0.0 && c.x < w && c.y >= 0.0 && c.y < h)
            .count() as f64;
        let want = pop().cumulative_density(1.0) * w * h;
        assert!((got - want).abs() < 4.0 * want.sqrt(), "{got} vs {want}");
    }

    #[test]
    fn rocks_are_the_same_whatever_the_rectangle_and_cut() {
        let field = WorldRockField::new(0.1, 0.01, 2.0, 0.5);
        let collect = |rect, cut| {
            let mut v = Vec::new();
            field.for_each_rock(rect, cut, 9, |_, _| 0.5, |r| v.push(*r));
            v
        };
        let coarse = collect((0.0, 0.0, 40.0, 40.0), 0.12);
        let fine = collect((10.0, 10.0, 20.0, 20.0), 0.0);
        let inner = |r: &&Rock| r.x > 12.0 && r.x < 18.0 && r.y > 12.0 && r.y < 18.0;
        let fine_big: Vec<_> = fine
            .iter()
            .filter(inner)
            .filter(|r| r.diameter_m >= 0.16)
            .collect();
        assert!(!fine_big.is_empty());
        for r in fine_big {
            assert!(coarse.contains(r), "{r:?} missing from the coarse draw");
        }
        assert!(coarse.iter().all(|r| r.diameter_m >= 0.06));
        assert!(fine.iter().any(|r| r.diameter_m < 0.02));
    }
}
