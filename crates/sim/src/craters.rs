//! Simple impact craters: morphology (bowl, raised rim, ejecta blanket), an equilibrium
//! power-law population, ageing, and stamping onto a terrain in age order.
//!
//! Profile of a fresh simple crater of diameter D (Pike 1977; Melosh 1989): rim crest
//! ≈ 0.04 D above the surroundings, floor d ≈ 0.2 D below the crest, ejecta thinning as
//! (r/R)^-3 outside the rim. Ageing lowers and softens the rim, fills the floor (d/D → 0.05)
//! and fades the ejecta's albedo. Younger craters erase the older relief inside their bowl.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Poisson};
use rayon::prelude::*;

use crate::terrain::Terrain;

/// Equilibrium cumulative crater density: N(>D) = 10^-1.1 · D^-2 per m² (D in metres).
pub const EQUILIBRIUM_COEFFICIENT: f64 = 0.079_432_823_472_428_15;

/// Depth/diameter of a fresh simple crater (rim crest to floor).
pub const FRESH_DEPTH_RATIO: f64 = 0.2;
/// Depth/diameter of the most degraded crater kept.
pub const OLD_DEPTH_RATIO: f64 = 0.05;
/// Rim height/diameter of a fresh crater.
pub const FRESH_RIM_RATIO: f64 = 0.04;
/// Outer end of the ejecta blanket in crater radii (tapered to zero from 2 R).
pub const EJECTA_REACH: f64 = 3.0;

/// One crater, all of its random parameters drawn up front.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Crater {
    /// World x of the centre (m).
    pub x: f64,
    /// World y of the centre (m).
    pub y: f64,
    /// Rim-to-rim diameter (m).
    pub diameter_m: f64,
    /// 0 = fresh, 1 = most degraded.
    pub age: f64,
    /// Rim crest to floor depth over diameter, in [0.05, 0.2].
    pub depth_ratio: f64,
    /// Rim crest height above the pre-impact surface (m).
    pub rim_height_m: f64,
    /// Width of the rounded rim crest as a height (m): the smooth-min blend width.
    pub rim_softness_m: f64,
    /// Radius modulation: cos/sin coefficients of the 2nd, 3rd and 4th angular harmonics.
    pub shape: [f32; 6],
    /// Rim height modulation, same harmonics.
    pub rim_wobble: [f32; 6],
    /// Relative albedo change of walls and ejecta (negative: darker fresh material).
    pub ejecta_tone: f32,
    /// Relative albedo change of the floor (positive: dust fill of old craters).
    pub floor_tone: f32,
}

impl Crater {
    /// An ideal circular crater of the given age (0 fresh … 1 degraded) with no albedo change.
    pub fn ideal(x: f64, y: f64, diameter_m: f64, age: f64) -> Self {
        let age = age.clamp(0.0, 1.0);
        let rim = FRESH_RIM_RATIO * diameter_m * (1.0 - 0.75 * age);
        Self {
            x,
            y,
            diameter_m,
            age,
            depth_ratio: FRESH_DEPTH_RATIO - (FRESH_DEPTH_RATIO - OLD_DEPTH_RATIO) * age,
            rim_height_m: rim,
            rim_softness_m: FRESH_RIM_RATIO * diameter_m * (0.3 + 1.7 * age),
            shape: [0.0; 6],
            rim_wobble: [0.0; 6],
            ejecta_tone: 0.0,
            floor_tone: 0.0,
        }
    }

    /// A crater with random shape, ageing and tones.
    pub fn random(x: f64, y: f64, diameter_m: f64, rng: &mut ChaCha8Rng) -> Self {
        // Most craters in an equilibrium population are degraded.
        let age: f64 = rng.random::<f64>().powf(0.6);
        let mut c = Self::ideal(x, y, diameter_m, age);
        c.depth_ratio = (c.depth_ratio * rng.random_range(0.85..1.0)).max(OLD_DEPTH_RATIO);
        c.rim_height_m *= rng.random_range(0.8..1.0);
        let ell = rng.random_range(0.0..0.08f32);
        let phi = rng.random_range(0.0..std::f32::consts::PI);
        c.shape = [
            ell * (2.0 * phi).cos(),
            ell * (2.0 * phi).sin(),
            rng.random_range(-0.03..0.03),
            rng.random_range(-0.03..0.03),
            rng.random_range(-0.02..0.02),
            rng.random_range(-0.02..0.02),
        ];
        for w in &mut c.rim_wobble {
            *w = rng.random_range(-0.15..0.15);
        }
        let fresh = (1.0 - age) as f32;
        // Fresh ejecta are mostly darker (excavated basaltic material), sometimes brighter.
        let tone = if rng.random::<f32>() < 0.75 {
            -rng.random_range(0.05..0.22f32)
        } else {
            rng.random_range(0.03..0.12f32)
        };
        c.ejecta_tone = tone * fresh * fresh;
        c.floor_tone = rng.random_range(0.0..0.12f32) * age as f32;
        c
    }

    /// Radius (m).
    #[inline]
    pub fn radius(&self) -> f64 {
        0.5 * self.diameter_m
    }

    /// Height relative to the pre-impact surface at normalised radius `rho` = r / R, before
    /// angular modulation: the bowl and the ejecta blended by a smooth minimum that rounds
    /// the rim crest, calibrated so the crest sits exactly at `rim_height_m` and the floor
    /// exactly `depth_ratio · D` below it.
    #[inline]
    pub fn profile(&self, rho: f64) -> f64 {
        self.profile_with_rim(rho, 1.0 / rho, 1.0)
    }

    /// The profile given ρ and 1/ρ (the stamping loop has the reciprocal for free).
    #[inline]
    fn profile_with_rim(&self, rho: f64, inv_rho: f64, rim_scale: f64) -> f64 {
        let k = self.rim_softness_m.max(1e-9);
        let crest = self.rim_height_m * rim_scale;
        let hr = crest + 0.25 * k;
        let depth = self.depth_ratio * self.diameter_m + 0.25 * k;
        let ic = inv_rho.min(5.0);
        let taper = 1.0 - smoothstep(2.0, EJECTA_REACH, rho);
        let outer = hr * ic * ic * ic * taper;
        if rho >= 2.0 {
            // The bowl is above the ejecta by more than the blend width here (depth ≥ 0.05 D,
            // k ≤ 0.08 D): skip the costly power.
            return outer;
        }
        // Bowl: a parabola that flattens its floor with age (ρ² → ρ⁴ blend).
        let a = 0.6 * self.age;
        let r2 = rho * rho;
        let inner = hr - depth * (1.0 - r2 * (1.0 - a + a * r2));
        smin(inner, outer, k)
    }
}

#[inline]
pub(crate) fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    // Multiply by the reciprocal: with constant edges it folds to one multiplication.
    let t = ((x - e0) * (1.0 / (e1 - e0))).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Polynomial smooth minimum: equals min(a, b) when |a − b| ≥ k, lowers the junction by k/4.
#[inline]
fn smin(a: f64, b: f64, k: f64) -> f64 {
    let d = (a - b).abs();
    if d >= k {
        return a.min(b);
    }
    let h = (k - d) / k;
    a.min(b) - h * h * k * 0.25
}

/// cos nθ, sin nθ for n = 2, 3, 4 from the unit direction (c, s).
#[inline]
fn angular_terms(c: f64, s: f64) -> [f64; 6] {
    let (c2, s2) = (c * c - s * s, 2.0 * c * s);
    let (c3, s3) = (c * c2 - s * s2, s * c2 + c * s2);
    let (c4, s4) = (c2 * c2 - s2 * s2, 2.0 * s2 * c2);
    [c2, s2, c3, s3, c4, s4]
}

/// Σ (a_n cos nθ + b_n sin nθ) over the terms of [`angular_terms`].
#[inline]
fn harmonics(coef: &[f32; 6], terms: &[f64; 6]) -> f64 {
    coef.iter().zip(terms).map(|(&a, &t)| a as f64 * t).sum()
}

/// A crater population over a rectangle of world space.
#[derive(Debug, Clone, Copy)]
pub struct CraterPopulation {
    /// Fraction of the equilibrium density 10^-1.1 D^-2 per m².
    pub density: f64,
    /// Smallest diameter drawn (m).
    pub min_diameter_m: f64,
    /// Largest diameter drawn (m).
    pub max_diameter_m: f64,
}

impl CraterPopulation {
    /// Expected cumulative number of craters with diameter ≥ `d` per m².
    pub fn cumulative_density(&self, d: f64) -> f64 {
        let d = d.max(self.min_diameter_m);
        if d >= self.max_diameter_m {
            return 0.0;
        }
        self.density * EQUILIBRIUM_COEFFICIENT * (d.powi(-2) - self.max_diameter_m.powi(-2))
    }

    /// Draws craters whose effect (rim and ejecta) can reach the rectangle
    /// [x0, x1] × [y0, y1]; returned oldest first, the order in which to stamp them.
    pub fn sample(&self, x0: f64, y0: f64, x1: f64, y1: f64, rng: &mut ChaCha8Rng) -> Vec<Crater> {
        let mut out = Vec::new();
        if self.density.is_nan()
            || self.density <= 0.0
            || self.max_diameter_m.is_nan()
            || self.max_diameter_m <= self.min_diameter_m
        {
            return out;
        }
        const BINS: usize = 48;
        let ratio = (self.max_diameter_m / self.min_diameter_m).powf(1.0 / BINS as f64);
        let mut lo = self.min_diameter_m;
        for _ in 0..BINS {
            let hi = lo * ratio;
            // A crater reaches EJECTA_REACH radii from its centre.
            let margin = 0.5 * EJECTA_REACH * hi;
            let area = (x1 - x0 + 2.0 * margin) * (y1 - y0 + 2.0 * margin);
            let lambda =
                self.density * EQUILIBRIUM_COEFFICIENT * (lo.powi(-2) - hi.powi(-2)) * area;
            let n = poisson(lambda, rng);
            let (a, b) = (lo.powi(-2), hi.powi(-2));
            for _ in 0..n {
                // Inverse CDF of the truncated power law N(>D) ∝ D^-2.
                let u: f64 = rng.random();
                let d = (a - u * (a - b)).powf(-0.5);
                let x = rng.random_range(x0 - margin..x1 + margin);
                let y = rng.random_range(y0 - margin..y1 + margin);
                out.push(Crater::random(x, y, d, rng));
            }
            lo = hi;
        }
        // Oldest first; stable sort on a total order keeps this deterministic.
        out.sort_by(|p, q| q.age.total_cmp(&p.age));
        out
    }
}

/// Poisson draw that stays exact for small means and avoids the sampler's limits for huge ones.
pub(crate) fn poisson(lambda: f64, rng: &mut ChaCha8Rng) -> u64 {
    if lambda.is_nan() || lambda <= 0.0 {
        return 0;
    }
    match Poisson::new(lambda) {
        Ok(p) => p.sample(rng) as u64,
        Err(_) => lambda.round() as u64,
    }
}

/// Stamps one crater onto the terrain (height and albedo).
///
/// Inside the bowl the old surface is replaced by a plane fitted to the old heights on the
/// rim circle plus the crater profile (so younger craters erase older relief); outside, the
/// ejecta drape the old surface.
pub fn stamp_crater(terrain: &mut Terrain, crater: &Crater) {
    let r = crater.radius();
    if r.is_nan() || r <= 0.0 {
        return;
    }
    let max_mod = 1.0 + crater.shape.iter().map(|v| v.abs() as f64).sum::<f64>();
    let reach = EJECTA_REACH * r * max_mod;
    let cell = terrain.cell_m;
    let (w, h) = (terrain.height.width, terrain.height.height);
    let (c0f, r0f) = terrain.world_to_cell(crater.x - reach, crater.y + reach);
    let (c1f, r1f) = terrain.world_to_cell(crater.x + reach, crater.y - reach);
    if c1f < 0.0 || r1f < 0.0 || c0f > (w - 1) as f64 || r0f > (h - 1) as f64 {
        return;
    }
    let col0 = c0f.ceil().max(0.0) as usize;
    let row0 = r0f.ceil().max(0.0) as usize;
    let col1 = (c1f.floor() as usize).min(w - 1);
    let row1 = (r1f.floor() as usize).min(h - 1);
    if col0 > col1 || row0 > row1 {
        return;
    }

    // Reference plane of the pre-impact surface from the old heights on the rim circle.
    const RING: usize = 16;
    let (mut mean, mut gx, mut gy) = (0.0, 0.0, 0.0);
    for i in 0..RING {
        let phi = std::f64::consts::TAU * i as f64 / RING as f64;
        let (s, c) = phi.sin_cos();
        let z = terrain.height_at(crater.x + r * c, crater.y + r * s);
        mean += z;
        gx += z * c;
        gy += z * s;
    }
    mean /= RING as f64;
    gx *= 2.0 / (RING as f64 * r);
    gy *= 2.0 / (RING as f64 * r);

    let (ox, oy) = (terrain.origin_x, terrain.origin_y);
    let inv_r = 1.0 / r;
    let reach2 = reach * reach;
    let toned = crater.ejecta_tone != 0.0 || crater.floor_tone != 0.0;
    let row_job = |row: usize, hrow: &mut [f32], arow: &mut [f32]| {
        let dy = oy - row as f64 * cell - crater.y;
        for col in col0..=col1 {
            let dx = ox + col as f64 * cell - crater.x;
            let rr2 = dx * dx + dy * dy;
            if rr2 > reach2 {
                continue;
            }
            let rr = rr2.sqrt();
            let inv_rr = if rr > 1e-12 { 1.0 / rr } else { 1e12 };
            let q = rr * inv_r;
            // Shape harmonics fade towards the centre, where directions converge.
            let (stretch, rim_scale) = if q < 0.15 {
                (1.0, 1.0)
            } else {
                let terms = angular_terms(dx * inv_rr, dy * inv_rr);
                let fade = smoothstep(0.15, 0.8, q);
                (
                    1.0 + fade * harmonics(&crater.shape, &terms),
                    1.0 + fade * harmonics(&crater.rim_wobble, &terms),
                )
            };
            let rho = q / stretch;
            if rho > EJECTA_REACH {
                continue;
            }
            let inv_rho = stretch * r * inv_rr;
            let prof = crater.profile_with_rim(rho, inv_rho, rim_scale);
            let old = hrow[col] as f64;
            hrow[col] = if rho < 1.05 {
                let erase = 1.0 - smoothstep(0.75, 1.05, rho);
                let plane = mean + gx * dx + gy * dy;
                (old + prof + erase * (plane - old)) as f32
            } else {
                (old + prof) as f32
            };
            if toned {
                let (ejecta, floor) = if rho <= 1.0 {
                    (1.0, 1.0 - smoothstep(0.3, 0.85, rho))
                } else {
                    let t = 1.0 - smoothstep(2.0, EJECTA_REACH, rho);
                    (t * inv_rho * inv_rho * inv_rho, 0.0)
                };
                let tone =
                    1.0 + crater.ejecta_tone * ejecta as f32 + crater.floor_tone * floor as f32;
                arow[col] = (arow[col] * tone).clamp(0.0, 1.0);
            }
        }
    };

    let span = row0 * w..(row1 + 1) * w;
    let hs = &mut terrain.height.data[span.clone()];
    let als = &mut terrain.albedo.data[span];
    let cells = (row1 - row0 + 1) * (col1 - col0 + 1);
    if cells > 1 << 12 {
        hs.par_chunks_mut(w)
            .zip(als.par_chunks_mut(w))
            .enumerate()
            .for_each(|(i, (hr, ar))| row_job(row0 + i, hr, ar));
    } else {
        for (i, (hr, ar)) in hs.chunks_mut(w).zip(als.chunks_mut(w)).enumerate() {
            row_job(row0 + i, hr, ar);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use jointloc_formats::Grid;
    use rand::SeedableRng;

    fn flat(n: usize, cell: f64) -> Terrain {
        Terrain {
            cell_m: cell,
            origin_x: 0.0,
            origin_y: (n - 1) as f64 * cell,
            height: Grid::filled(n, n, 0.0),
            albedo: Grid::filled(n, n, 0.25),
        }
    }

    /// Height along the east-west line through the centre, as (distance from centre, h).
    fn radial(t: &Terrain, cx: f64, cy: f64) -> Vec<(f64, f64)> {
        let (_, row) = t.world_to_cell(cx, cy);
        let row = row.round() as usize;
        (0..t.height.width)
            .map(|c| {
                let (x, _) = t.cell_to_world(c as f64, row as f64);
                ((x - cx).abs(), t.height.at(c, row) as f64)
            })
            .collect()
    }

    #[test]
    fn fresh_crater_profile_has_rim_bowl_and_ejecta() {
        for &d in &[0.5, 2.0, 4.0] {
            let cell = d / 100.0;
            let mut t = flat(401, cell);
            let (cx, cy) = (200.0 * cell, 200.0 * cell);
            let c = Crater::ideal(cx, cy, d, 0.0);
            stamp_crater(&mut t, &c);
            let prof = radial(&t, cx, cy);
            let rim = prof.iter().map(|p| p.1).fold(f64::MIN, f64::max);
            let floor = prof.iter().map(|p| p.1).fold(f64::MAX, f64::min);
            // Rim crest ≈ 0.04 D above the flat surroundings.
            assert!((rim / d - 0.04).abs() < 0.004, "D {d}: rim/D {}", rim / d);
            // Depth from crest to floor over D within the simple-crater range, fresh ≈ 0.2.
            let dd = (rim - floor) / d;
            assert!((0.18..=0.21).contains(&dd), "D {d}: d/D {dd}");
            // Crest lies at the rim radius.
            let at_rim = prof.iter().max_by(|a, b| a.1.total_cmp(&b.1)).unwrap().0;
            assert!((at_rim / (0.5 * d) - 1.0).abs() < 0.05, "crest at {at_rim}");
            // Ejecta thin as (r/R)^-3: at 1.5 R expect rim/3.4.
            let h15 = prof
                .iter()
                .min_by(|a, b| (a.0 - 0.75 * d).abs().total_cmp(&(b.0 - 0.75 * d).abs()))
                .unwrap()
                .1;
            let want = FRESH_RIM_RATIO * d / 1.5f64.powi(3);
            assert!((h15 - want).abs() < 0.15 * want, "ejecta {h15} vs {want}");
            // Nothing beyond the ejecta reach.
            let far = prof.iter().filter(|p| p.0 > 1.6 * d).map(|p| p.1.abs());
            assert!(far.fold(0.0, f64::max) < 1e-9);
        }
    }

    #[test]
    fn ageing_makes_craters_shallower_with_lower_rims() {
        let d = 3.0;
        let cell = 0.03;
        let mut prev: Option<(f64, f64)> = None;
        for &age in &[0.0, 0.5, 1.0] {
            let mut t = flat(401, cell);
            let (cx, cy) = (6.0, 6.0);
            stamp_crater(&mut t, &Crater::ideal(cx, cy, d, age));
            let prof = radial(&t, cx, cy);
            let rim = prof.iter().map(|p| p.1).fold(f64::MIN, f64::max);
            let floor = prof.iter().map(|p| p.1).fold(f64::MAX, f64::min);
            let dd = (rim - floor) / d;
            assert!((0.045..=0.21).contains(&dd), "age {age}: d/D {dd}");
            if let Some((prim, pdd)) = prev {
                assert!(rim < prim && dd < pdd, "age {age}");
            }
            prev = Some((rim, dd));
        }
    }

    #[test]
    fn younger_crater_erases_older_relief_inside_its_bowl() {
        let cell = 0.02;
        let mut t = flat(401, cell);
        // A small fresh crater, then a big one centred on it.
        stamp_crater(&mut t, &Crater::ideal(4.0, 4.0, 0.6, 0.0));
        let mut reference = flat(401, cell);
        let big = Crater::ideal(4.0, 4.0, 5.0, 0.0);
        stamp_crater(&mut t, &big);
        stamp_crater(&mut reference, &big);
        let diff = t
            .height
            .data
            .iter()
            .zip(&reference.height.data)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(diff < 1e-4, "old crater still visible: {diff}");
    }

    #[test]
    fn population_follows_equilibrium_power_law() {
        let pop = CraterPopulation {
            density: 1.0,
            min_diameter_m: 0.2,
            max_diameter_m: 20.0,
        };
        for seed in 0..4u64 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let (w, h) = (200.0, 150.0);
            let craters = pop.sample(0.0, 0.0, w, h, &mut rng);
            // Count centres inside the rectangle only (sampling adds a margin).
            let inside: Vec<&Crater> = craters
                .iter()
                .filter(|c| (0.0..w).contains(&c.x) && (0.0..h).contains(&c.y))
                .collect();
            for &d in &[0.2, 0.4, 0.8] {
                let n = inside.iter().filter(|c| c.diameter_m >= d).count() as f64;
                let want = pop.cumulative_density(d) * w * h;
                assert!(
                    (n - want).abs() < 4.0 * want.sqrt() + 0.02 * want,
                    "seed {seed} D {d}: {n} vs {want}"
                );
            }
            // Stamping order: oldest first.
            assert!(craters.windows(2).all(|p| p[0].age >= p[1].age));
            assert!(
                craters
                    .iter()
                    .all(|c| (0.05..=0.2).contains(&c.depth_ratio))
            );
        }
    }
}
