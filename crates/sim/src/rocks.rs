//! Rock fields: the Golombek & Rapp (1997) size-frequency model and rocks stamped as rounded,
//! irregular 3-D bumps (height ≈ 0.5 D); rocks smaller than a cell only darken or brighten the
//! albedo of the cell they fall in.
//!
//! Model: the cumulative fractional area covered by rocks of diameter ≥ D is
//! F_k(D) = k · exp(−q D) with q = 1.79 + 0.152 / k (k = total rock abundance, 0.02–0.2 on Mars).

use rand::Rng;
use rand_chacha::ChaCha8Rng;

use crate::craters::{Crater, poisson};
use crate::terrain::Terrain;

/// Golombek rock size-frequency distribution.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GolombekSfd {
    /// Total fractional area covered by rocks.
    pub k: f64,
    /// Exponential decay (1/m), 1.79 + 0.152 / k.
    pub q: f64,
}

impl GolombekSfd {
    /// The distribution for rock abundance `k`.
    pub fn new(k: f64) -> Self {
        Self {
            k,
            q: 1.79 + 0.152 / k,
        }
    }

    /// Fraction of the area covered by rocks with diameter ≥ `d` (m).
    pub fn cumulative_area(&self, d: f64) -> f64 {
        self.k * (-self.q * d).exp()
    }

    /// Number of rocks per m² per metre of diameter at `d`: −dF/dD / (π D² / 4).
    pub fn number_density(&self, d: f64) -> f64 {
        self.k * self.q * (-self.q * d).exp() / (std::f64::consts::FRAC_PI_4 * d * d)
    }
}

/// Inverse-CDF sampler of rock diameters in [d_min, d_max], tabulated on a log grid.
#[derive(Debug, Clone)]
pub struct RockSampler {
    sfd: GolombekSfd,
    /// ln D at the table nodes.
    ln_d: Vec<f64>,
    /// Rocks per m² with diameter ≥ D at the nodes (decreasing; last is 0).
    cum: Vec<f64>,
}

impl RockSampler {
    /// Tabulates N(≥D) by integrating the number density in ln D (trapezoid, 1024 nodes).
    pub fn new(sfd: GolombekSfd, d_min: f64, d_max: f64) -> Self {
        const NODES: usize = 1024;
        let (l0, l1) = (d_min.ln(), d_max.max(d_min * 1.0001).ln());
        let ln_d: Vec<f64> = (0..NODES)
            .map(|i| l0 + (l1 - l0) * i as f64 / (NODES - 1) as f64)
            .collect();
        // Integrand in ln D: n(D) · D.
        let f: Vec<f64> = ln_d
            .iter()
            .map(|&l| {
                let d = l.exp();
                sfd.number_density(d) * d
            })
            .collect();
        let mut cum = vec![0.0; NODES];
        for i in (0..NODES - 1).rev() {
            cum[i] = cum[i + 1] + 0.5 * (f[i] + f[i + 1]) * (ln_d[i + 1] - ln_d[i]);
        }
        Self { sfd, ln_d, cum }
    }

    /// The distribution sampled.
    pub fn sfd(&self) -> GolombekSfd {
        self.sfd
    }

    /// Rocks per m² in the tabulated diameter range.
    pub fn total_density(&self) -> f64 {
        self.cum[0]
    }

    /// A diameter for a uniform `u` in [0, 1).
    pub fn diameter(&self, u: f64) -> f64 {
        let target = (1.0 - u) * self.cum[0];
        // cum is decreasing: find i with cum[i] ≥ target > cum[i + 1].
        let i = self
            .cum
            .partition_point(|&c| c >= target)
            .saturating_sub(1)
            .min(self.cum.len() - 2);
        let (c0, c1) = (self.cum[i], self.cum[i + 1]);
        let t = if c0 > c1 {
            (c0 - target) / (c0 - c1)
        } else {
            0.0
        };
        (self.ln_d[i] + t * (self.ln_d[i + 1] - self.ln_d[i])).exp()
    }
}

/// Number of side facets of a rock.
pub const FACETS: usize = 6;

/// One rock, all of its random parameters drawn up front.
///
/// Shape: the minimum of a slightly tilted top plane and [`FACETS`] steep side planes (an
/// angular, convex block whose footprint is a polygon), blended towards a half-ellipsoid by
/// `roundness` (wind-rounded or partly buried rocks).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rock {
    /// World x of the centre (m).
    pub x: f64,
    /// World y of the centre (m).
    pub y: f64,
    /// Diameter (m, long axis).
    pub diameter_m: f64,
    /// Height above the ground (m).
    pub height_m: f64,
    /// Short/long axis ratio.
    pub aspect: f64,
    /// Long axis direction (rad from +x).
    pub heading: f64,
    /// Side facets in the normalised rock frame: outward direction (cos, sin), footprint
    /// distance from the centre (radii) and steepness (height fractions per radius).
    pub facets: [[f32; 4]; FACETS],
    /// Top tilt (fraction of the height per radius) along the rock's axes.
    pub tilt: [f32; 2],
    /// 0 = angular block, 1 = smooth half-ellipsoid.
    pub roundness: f32,
    /// Albedo multiplier of the rock surface.
    pub albedo_factor: f32,
}

impl Rock {
    /// A random rock of diameter `d` at (x, y), height `height_ratio · D` on average.
    pub fn random(x: f64, y: f64, d: f64, height_ratio: f64, rng: &mut ChaCha8Rng) -> Self {
        let mut facets = [[0.0f32; 4]; FACETS];
        let turn = rng.random_range(0.0..std::f32::consts::TAU);
        for (k, f) in facets.iter_mut().enumerate() {
            let a = turn
                + std::f32::consts::TAU * (k as f32 + rng.random_range(-0.3..0.3)) / FACETS as f32;
            *f = [
                a.cos(),
                a.sin(),
                rng.random_range(0.8..1.05),
                rng.random_range(1.3..4.0),
            ];
        }
        Self {
            x,
            y,
            diameter_m: d,
            height_m: d * height_ratio * rng.random_range(0.7..1.3),
            aspect: rng.random_range(0.6..1.0),
            heading: rng.random_range(0.0..std::f64::consts::PI),
            facets,
            tilt: [rng.random_range(-0.3..0.3), rng.random_range(-0.3..0.3)],
            roundness: rng.random::<f32>().powi(2),
            // Mostly darker basaltic rock, some dust-coated or brighter.
            albedo_factor: rng.random_range(0.6..1.15),
        }
    }

    /// A pebble below the cell size: only its footprint (aspect) and tint matter.
    pub fn pebble(x: f64, y: f64, d: f64, rng: &mut ChaCha8Rng) -> Self {
        Self {
            x,
            y,
            diameter_m: d,
            height_m: 0.5 * d,
            aspect: rng.random_range(0.6..1.0),
            heading: 0.0,
            facets: [[0.0; 4]; FACETS],
            tilt: [0.0; 2],
            roundness: 1.0,
            albedo_factor: rng.random_range(0.6..1.15),
        }
    }

    /// Height of the rock above the ground at rock-frame coordinates normalised by the
    /// semi-axes (0 outside the footprint).
    #[inline]
    pub fn shape(&self, un: f64, vn: f64) -> f64 {
        let mut z = 1.0 + self.tilt[0] as f64 * un + self.tilt[1] as f64 * vn;
        for f in &self.facets {
            let d = un * f[0] as f64 + vn * f[1] as f64;
            z = z.min(f[3] as f64 * (1.0 - d / f[2] as f64));
        }
        let r2 = un * un + vn * vn;
        let round = if r2 < 1.0 { (1.0 - r2).sqrt() } else { 0.0 };
        let t = self.roundness as f64;
        (z.max(0.0) * (1.0 - t) + round * t) * self.height_m
    }
}

/// Adds one rock to the terrain. Rocks narrower than `min_3d_m` only change the albedo of
/// the cell under their centre, in proportion to the area they cover.
pub fn stamp_rock(terrain: &mut Terrain, rock: &Rock, min_3d_m: f64) {
    let cell = terrain.cell_m;
    let (w, h) = (terrain.height.width, terrain.height.height);
    if rock.diameter_m < min_3d_m {
        let (c, r) = terrain.world_to_cell(rock.x, rock.y);
        let (c, r) = (c.round(), r.round());
        if c < 0.0 || r < 0.0 || c > (w - 1) as f64 || r > (h - 1) as f64 {
            return;
        }
        let cover = (std::f64::consts::FRAC_PI_4 * rock.diameter_m * rock.diameter_m * rock.aspect
            / (cell * cell))
            .min(1.0) as f32;
        let a = terrain.albedo.at_mut(c as usize, r as usize);
        *a = (*a * (1.0 + (rock.albedo_factor - 1.0) * cover)).clamp(0.0, 1.0);
        return;
    }
    let ra = 0.5 * rock.diameter_m;
    let rb = ra * rock.aspect;
    // Polygon corners reach at most 1.05 / cos(π/6 + jitter) ≈ 1.3 radii.
    let reach = ra * 1.3;
    let (c0f, r0f) = terrain.world_to_cell(rock.x - reach, rock.y + reach);
    let (c1f, r1f) = terrain.world_to_cell(rock.x + reach, rock.y - reach);
    if c1f < 0.0 || r1f < 0.0 || c0f > (w - 1) as f64 || r0f > (h - 1) as f64 {
        return;
    }
    let col0 = c0f.ceil().max(0.0) as usize;
    let row0 = r0f.ceil().max(0.0) as usize;
    let col1 = (c1f.floor() as usize).min(w - 1);
    let row1 = (r1f.floor() as usize).min(h - 1);
    let (sh, ch) = rock.heading.sin_cos();
    let edge = 0.12 * rock.height_m;
    for row in row0..=row1 {
        let dy = terrain.origin_y - row as f64 * cell - rock.y;
        for col in col0..=col1 {
            let dx = terrain.origin_x + col as f64 * cell - rock.x;
            // Rock frame: u along the long axis.
            let un = (dx * ch + dy * sh) / ra;
            let vn = (-dx * sh + dy * ch) / rb;
            if un * un + vn * vn >= 1.7 {
                continue;
            }
            let z = rock.shape(un, vn);
            if z <= 0.0 {
                continue;
            }
            *terrain.height.at_mut(col, row) += z as f32;
            let cover = (z / edge).min(1.0) as f32;
            let a = terrain.albedo.at_mut(col, row);
            *a = (*a * (1.0 + (rock.albedo_factor - 1.0) * cover)).clamp(0.0, 1.0);
        }
    }
}

/// A rock field over a rectangle of world space.
#[derive(Debug, Clone)]
pub struct RockField {
    /// Diameter sampler (Golombek model).
    pub sampler: RockSampler,
    /// Mean height over diameter.
    pub height_ratio: f64,
    /// Rocks narrower than this only tint the albedo ([`stamp_rock`]'s `min_3d_m`), so
    /// only their tint and footprint are drawn.
    pub shaped_from_m: f64,
}

impl RockField {
    /// Expected number of rocks over `area_m2`.
    pub fn expected_count(&self, area_m2: f64) -> f64 {
        self.sampler.total_density() * area_m2
    }

    /// Draws rocks over [x0, x1] × [y0, y1] one at a time and hands each to `sink`, keeping
    /// memory flat however many there are. `keep(x, y)` ∈ [0, 1] thins the field into
    /// patches; the draw is doubled so that a `keep` averaging 0.5 preserves the density.
    pub fn for_each_rock(
        &self,
        (x0, y0, x1, y1): (f64, f64, f64, f64),
        rng: &mut ChaCha8Rng,
        keep: impl Fn(f64, f64) -> f64,
        mut sink: impl FnMut(&Rock),
    ) {
        let area = (x1 - x0).max(0.0) * (y1 - y0).max(0.0);
        let n = poisson(2.0 * self.expected_count(area), rng);
        for _ in 0..n {
            let d = self.sampler.diameter(rng.random());
            let x = rng.random_range(x0..x1);
            let y = rng.random_range(y0..y1);
            if rng.random::<f64>() >= keep(x, y) {
                continue;
            }
            let rock = if d < self.shaped_from_m {
                Rock::pebble(x, y, d, rng)
            } else {
                Rock::random(x, y, d, self.height_ratio, rng)
            };
            sink(&rock);
        }
    }
}

/// Blocks thrown out by a fresh crater: a few rocks on the rim and near ejecta, sizes up to
/// a few percent of the crater diameter, denser towards the rim.
pub fn ejecta_blocks(
    crater: &Crater,
    min_d: f64,
    height_ratio: f64,
    rng: &mut ChaCha8Rng,
    mut sink: impl FnMut(&Rock),
) {
    let r = crater.radius();
    let freshness = (1.0 - crater.age).max(0.0);
    let dmax = 0.06 * crater.diameter_m;
    if dmax <= min_d * 1.5 || freshness < 0.3 {
        return;
    }
    // Golombek-like: the cumulative number of blocks grows as the size range widens.
    let n = poisson(12.0 * freshness * freshness * (dmax / min_d).min(30.0), rng);
    for _ in 0..n {
        // Size: truncated power law N(>D) ∝ D^-2 between min_d and dmax.
        let (a, b) = (min_d.powi(-2), dmax.powi(-2));
        let d = (a - rng.random::<f64>() * (a - b)).powf(-0.5);
        // Radius: rim to 2.5 R, density ∝ (r/R)^-3.
        let u: f64 = rng.random();
        let rho = (1.0 - u * (1.0 - 2.5f64.powi(-2))).powf(-0.5) * rng.random_range(0.85..1.0);
        let phi = rng.random_range(0.0..std::f64::consts::TAU);
        let (s, c) = phi.sin_cos();
        sink(&Rock::random(
            crater.x + rho * r * c,
            crater.y + rho * r * s,
            d,
            height_ratio,
            rng,
        ));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use jointloc_formats::Grid;
    use rand::SeedableRng;

    #[test]
    fn sampled_rocks_match_golombek_cumulative_area() {
        for (seed, &k) in [0.03, 0.08, 0.15, 0.2].iter().enumerate() {
            let sfd = GolombekSfd::new(k);
            let (dmin, dmax) = (0.02, 3.0);
            let field = RockField {
                sampler: RockSampler::new(sfd, dmin, dmax),
                height_ratio: 0.5,
                shaped_from_m: 0.04,
            };
            let side = 150.0;
            let mut rng = ChaCha8Rng::seed_from_u64(seed as u64 + 11);
            let probes = [0.05, 0.1, 0.2, 0.4];
            let mut area = [0.0f64; 4];
            field.for_each_rock(
                (0.0, 0.0, side, side),
                &mut rng,
                |_, _| 0.5,
                |r| {
                    for (a, &p) in area.iter_mut().zip(&probes) {
                        if r.diameter_m >= p {
                            *a += std::f64::consts::FRAC_PI_4 * r.diameter_m * r.diameter_m;
                        }
                    }
                },
            );
            for (a, &p) in area.iter().zip(&probes) {
                let got = a / (side * side);
                let want = sfd.cumulative_area(p) - sfd.cumulative_area(dmax);
                // Large rocks are rare: allow for counting noise on top of 8 %.
                let n_big = want * side * side / (std::f64::consts::FRAC_PI_4 * (2.0 * p).powi(2));
                let tol = 0.08 + 2.0 / n_big.sqrt();
                assert!(
                    (got / want - 1.0).abs() < tol,
                    "k {k} D≥{p}: {got:.5} vs {want:.5} (tol {tol:.3})"
                );
            }
        }
    }

    #[test]
    fn rock_bump_is_about_half_as_high_as_wide_and_tints_albedo() {
        let cell = 0.01;
        let n = 101;
        let mut t = Terrain {
            cell_m: cell,
            origin_x: 0.0,
            origin_y: 1.0,
            height: Grid::filled(n, n, 0.0),
            albedo: Grid::filled(n, n, 0.25),
        };
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut rock = Rock::random(0.5, 0.5, 0.4, 0.5, &mut rng);
        rock.tilt = [0.0, 0.0];
        rock.roundness = 0.3;
        stamp_rock(&mut t, &rock, 0.02);
        let top = t.height.data.iter().cloned().fold(0.0f32, f32::max) as f64;
        assert!((top - rock.height_m).abs() < 0.02 * rock.height_m, "{top}");
        assert!((0.35 * 0.4..=0.65 * 0.4).contains(&top));
        // Footprint area ≈ π a b (a polygon of about that size).
        let cells = t.height.data.iter().filter(|&&z| z > 0.0).count() as f64;
        let want = std::f64::consts::PI * 0.2 * 0.2 * rock.aspect / (cell * cell);
        assert!((0.7..1.35).contains(&(cells / want)), "{cells} vs {want}");
        let centre = t.albedo.at(50, 50);
        assert!((centre - 0.25 * rock.albedo_factor).abs() < 1e-4);
        // A sub-cell pebble changes only the albedo.
        let before = t.height.clone();
        let mut peb = Rock::random(0.112, 0.899, 0.005, 0.5, &mut rng);
        peb.albedo_factor = 0.5;
        stamp_rock(&mut t, &peb, 0.02);
        assert_eq!(before, t.height);
        assert!(t.albedo.at(11, 10) < 0.25);
    }
}
