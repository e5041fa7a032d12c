//! Terrain synthesis: heightfield + albedo for the three Martian terrain kinds (crater, gravel,
//! mountain).
//!
//! Each kind has a dominant feature and mixes in the others at lower density, as real terrain
//! does: crater = gentle fBm plains saturated with craters at equilibrium density; gravel =
//! low-relief plains covered by a Golombek rock field (the weak-texture case); mountain = fBm
//! plus domain-warped ridged multifractal relief with darker rocky slopes. Generation order:
//! base relief and albedo (noise, row-parallel), craters oldest first, slope-dependent albedo,
//! rocks. All random parameters come from seeded ChaCha8 streams drawn sequentially and all
//! noise is a pure function of (seed, world x, y), so the result is bit-identical for a seed
//! whatever the thread count.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::craters::{Crater, CraterPopulation, stamp_crater};
use crate::error::{Result, SimError};
use crate::noise::derive_seed;
use crate::rocks::{GolombekSfd, RockField, RockSampler, ejecta_blocks, stamp_rock};
use crate::surface::{SurfaceModel, apply_slope_albedo};
use crate::world_features::{Rect, WorldRockField, craters_over, world_ejecta_blocks};
use jointloc_formats::Grid;

/// The three terrain kinds of the paper's dataset.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TerrainKind {
    Crater,
    Gravel,
    Mountain,
}

/// A terrain patch in the world frame (x east, y north, z up, metres).
///
/// Cell `(col, row)` has its centre at world
/// `(origin_x + col · cell_m, origin_y − row · cell_m)`: rows run south, like map pixels.
#[derive(Debug, Clone)]
pub struct Terrain {
    /// Side of one cell in metres (≤ 0.025).
    pub cell_m: f64,
    /// World x of the centre of cell (0, 0).
    pub origin_x: f64,
    /// World y of the centre of cell (0, 0).
    pub origin_y: f64,
    /// Height above the datum in metres.
    pub height: Grid<f32>,
    /// Albedo in [0, 1].
    pub albedo: Grid<f32>,
}

impl Terrain {
    /// Fractional (col, row) of a world (x, y).
    #[inline]
    pub fn world_to_cell(&self, x: f64, y: f64) -> (f64, f64) {
        (
            (x - self.origin_x) / self.cell_m,
            (self.origin_y - y) / self.cell_m,
        )
    }

    /// World (x, y) of a fractional (col, row).
    #[inline]
    pub fn cell_to_world(&self, col: f64, row: f64) -> (f64, f64) {
        (
            self.origin_x + col * self.cell_m,
            self.origin_y - row * self.cell_m,
        )
    }

    /// Bilinear height at world (x, y), clamped at the border.
    #[inline]
    pub fn height_at(&self, x: f64, y: f64) -> f64 {
        let (c, r) = self.world_to_cell(x, y);
        self.height.bilinear(c, r) as f64
    }
}

/// Knobs of terrain synthesis. `None` means "the kind's default" (see [`KindDefaults`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct TerrainConfig {
    /// Cell side in metres. The datasets use ≤ 0.025 (the UAV's ground sample distance is
    /// 0.02 m at 10 m); coarser cells are allowed for previews and tests.
    pub cell_m: f64,
    /// Multiplies every relief amplitude of the base surface (hills, ridges).
    pub relief_scale: f64,
    /// Crater density as a fraction of the equilibrium density 10^-1.1 D^-2 per m².
    pub crater_density: Option<f64>,
    /// Smallest crater diameter (m): about 6 cells at 2.5 cm.
    pub crater_min_diameter_m: f64,
    /// Largest crater diameter (m).
    pub crater_max_diameter_m: f64,
    /// Golombek rock abundance k (fraction of area covered by rocks, 0.02–0.2 on Mars).
    pub rock_abundance: Option<f64>,
    /// Smallest rock drawn (m); rocks narrower than 1.5 cells only tint the albedo.
    pub rock_min_diameter_m: f64,
    /// Largest rock drawn (m).
    pub rock_max_diameter_m: f64,
    /// Mean rock height over diameter.
    pub rock_height_ratio: f64,
    /// Patchiness of rock fields, 0 (uniform) to 1 (strong clusters).
    pub rock_clustering: f64,
    /// Multiplies the density of each kind's secondary features (craters on gravel and
    /// mountain, rocks on crater plains and mountains); 0 gives pure terrains.
    pub feature_mixing: f64,
    /// Mean albedo of the dust-covered surface.
    pub albedo_mean: f64,
    /// Multiplies every albedo variation (patches, grain, slopes, crater tones).
    pub albedo_contrast: f64,
}

impl Default for TerrainConfig {
    fn default() -> Self {
        Self {
            cell_m: 0.025,
            relief_scale: 1.0,
            crater_density: None,
            crater_min_diameter_m: 0.15,
            crater_max_diameter_m: 30.0,
            rock_abundance: None,
            rock_min_diameter_m: 0.01,
            rock_max_diameter_m: 2.0,
            rock_height_ratio: 0.5,
            rock_clustering: 0.6,
            feature_mixing: 1.0,
            albedo_mean: 0.24,
            albedo_contrast: 1.0,
        }
    }
}

/// Per-kind defaults of the feature densities.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KindDefaults {
    /// Fraction of the equilibrium crater density.
    pub crater_density: f64,
    /// Golombek rock abundance k.
    pub rock_abundance: f64,
}

impl TerrainKind {
    /// Lower-case name, as in files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            TerrainKind::Crater => "crater",
            TerrainKind::Gravel => "gravel",
            TerrainKind::Mountain => "mountain",
        }
    }

    /// Default feature densities; the secondary ones are scaled by `feature_mixing`.
    pub fn defaults(self, feature_mixing: f64) -> KindDefaults {
        let m = feature_mixing.max(0.0);
        match self {
            TerrainKind::Crater => KindDefaults {
                crater_density: 1.0,
                rock_abundance: 0.02 * m,
            },
            TerrainKind::Gravel => KindDefaults {
                crater_density: 0.12 * m,
                rock_abundance: 0.1,
            },
            TerrainKind::Mountain => KindDefaults {
                crater_density: 0.2 * m,
                rock_abundance: 0.08 * m,
            },
        }
    }
}

/// The area to synthesise: a grid of cells whose cell (0, 0) is centred at
/// (origin_x, origin_y); columns run east, rows south.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TerrainExtent {
    pub origin_x: f64,
    pub origin_y: f64,
    pub width_cells: usize,
    pub height_cells: usize,
}

/// Largest grid accepted (cells): 2 × 4 bytes each ≈ 12 GiB, beyond any sensible flight.
const MAX_CELLS: usize = 1_500_000_000;

fn invalid(field: &'static str, value: impl ToString, reason: &str) -> SimError {
    SimError::InvalidConfig {
        field,
        value: value.to_string(),
        reason: reason.to_string(),
    }
}

impl TerrainConfig {
    /// Checks every value's range.
    pub fn validate(&self) -> Result<()> {
        let pos = |field, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(invalid(field, v, "must be finite and > 0"))
            }
        };
        let nonneg = |field, v: f64| {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err(invalid(field, v, "must be finite and ≥ 0"))
            }
        };
        pos("cell_m", self.cell_m)?;
        if self.cell_m > 1.0 {
            return Err(invalid("cell_m", self.cell_m, "must be ≤ 1 m"));
        }
        nonneg("relief_scale", self.relief_scale)?;
        pos("crater_min_diameter_m", self.crater_min_diameter_m)?;
        pos("crater_max_diameter_m", self.crater_max_diameter_m)?;
        if self.crater_max_diameter_m < self.crater_min_diameter_m {
            return Err(invalid(
                "crater_max_diameter_m",
                self.crater_max_diameter_m,
                "must be ≥ crater_min_diameter_m",
            ));
        }
        if let Some(d) = self.crater_density {
            nonneg("crater_density", d)?;
        }
        if let Some(k) = self.rock_abundance
            && !(k.is_finite() && (0.0..=0.5).contains(&k))
        {
            return Err(invalid("rock_abundance", k, "must be in [0, 0.5]"));
        }
        pos("rock_min_diameter_m", self.rock_min_diameter_m)?;
        pos("rock_max_diameter_m", self.rock_max_diameter_m)?;
        if self.rock_max_diameter_m < self.rock_min_diameter_m {
            return Err(invalid(
                "rock_max_diameter_m",
                self.rock_max_diameter_m,
                "must be ≥ rock_min_diameter_m",
            ));
        }
        pos("rock_height_ratio", self.rock_height_ratio)?;
        if !(0.0..=1.0).contains(&self.rock_clustering) {
            return Err(invalid(
                "rock_clustering",
                self.rock_clustering,
                "must be in [0, 1]",
            ));
        }
        nonneg("feature_mixing", self.feature_mixing)?;
        if !(self.albedo_mean > 0.0 && self.albedo_mean < 1.0) {
            return Err(invalid(
                "albedo_mean",
                self.albedo_mean,
                "must be in (0, 1)",
            ));
        }
        nonneg("albedo_contrast", self.albedo_contrast)?;
        Ok(())
    }
}

/// Random streams of the generator (one ChaCha8 stream or noise seed per consumer).
mod stream {
    pub const SURFACE: u64 = 1;
    pub const CRATERS: u64 = 2;
    pub const ROCKS: u64 = 3;
    pub const BLOCKS: u64 = 4;
    pub const ROCK_PATCHES: u64 = 5;
}

/// How craters and rocks are drawn.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FeatureLayout {
    /// From one stream over the extent: the datasets whose map is the flight's bounding box.
    Extent,
    /// Per world block ([`crate::world_features`]): any two extents, at any cell size, show
    /// the same features where they overlap. Craters whose diameter bin ends below
    /// `crater_from_m` and rocks whose octave ends below `rock_from_m` are left out (a coarse
    /// grid cannot show them).
    World {
        crater_from_m: f64,
        rock_from_m: f64,
    },
}

impl FeatureLayout {
    /// The world layout for a grid of `cell_m` cells: craters from 2 cells, rocks from half a
    /// cell (smaller ones would only tint single cells).
    pub fn world_for_cell(cell_m: f64) -> Self {
        FeatureLayout::World {
            crater_from_m: 2.0 * cell_m,
            rock_from_m: 0.5 * cell_m,
        }
    }
}

/// Smallest ejecta block drawn in the world layout, whatever the cell (1.5 cells at 2.5 cm).
const WORLD_EJECTA_MIN_M: f64 = 0.0375;

/// Synthesises the heightfield and albedo of `kind` over `extent`.
///
/// Memory: the two f32 grids (8 bytes per cell) plus the crater list (≈ 100 bytes per
/// crater); rocks are drawn and stamped one at a time.
pub fn generate_terrain(
    kind: TerrainKind,
    extent: &TerrainExtent,
    cfg: &TerrainConfig,
    seed: u64,
) -> Result<Terrain> {
    generate_terrain_with(kind, extent, cfg, seed, FeatureLayout::Extent)
}

/// [`generate_terrain`] with the features drawn as `layout` says.
pub fn generate_terrain_with(
    kind: TerrainKind,
    extent: &TerrainExtent,
    cfg: &TerrainConfig,
    seed: u64,
    layout: FeatureLayout,
) -> Result<Terrain> {
    cfg.validate()?;
    let (w, h) = (extent.width_cells, extent.height_cells);
    if w < 3 || h < 3 {
        return Err(invalid(
            "extent",
            format!("{w}×{h}"),
            "needs at least 3×3 cells",
        ));
    }
    if w.checked_mul(h).is_none_or(|n| n > MAX_CELLS) {
        return Err(invalid("extent", format!("{w}×{h}"), "too many cells"));
    }
    if !(extent.origin_x.is_finite() && extent.origin_y.is_finite()) {
        return Err(invalid("extent", "origin", "must be finite"));
    }
    let defaults = kind.defaults(cfg.feature_mixing);
    // Each kind draws from its own streams, so kinds never share crater or rock layouts.
    let seed = derive_seed(seed, 1000 + kind as u64);
    let cell = cfg.cell_m;
    let mut terrain = Terrain {
        cell_m: cell,
        origin_x: extent.origin_x,
        origin_y: extent.origin_y,
        height: Grid::filled(w, h, 0.0),
        albedo: Grid::filled(w, h, 0.0),
    };

    let clock = std::time::Instant::now();
    let surface = SurfaceModel::new(kind, cfg, derive_seed(seed, stream::SURFACE));
    surface.fill(&mut terrain);
    let t_surface = clock.elapsed();

    // World rectangle covered by cell centres.
    let (x0, y1) = (extent.origin_x, extent.origin_y);
    let (x1, y0) = terrain.cell_to_world((w - 1) as f64, (h - 1) as f64);

    let crater_pop = CraterPopulation {
        density: cfg.crater_density.unwrap_or(defaults.crater_density),
        min_diameter_m: cfg.crater_min_diameter_m,
        max_diameter_m: cfg.crater_max_diameter_m,
    };
    let mut craters = match layout {
        FeatureLayout::Extent => {
            let mut rng = ChaCha8Rng::seed_from_u64(derive_seed(seed, stream::CRATERS));
            crater_pop.sample(x0, y0, x1, y1, &mut rng)
        }
        FeatureLayout::World { crater_from_m, .. } => craters_over(
            &crater_pop,
            (x0, y0, x1, y1),
            crater_from_m,
            derive_seed(seed, stream::CRATERS),
        ),
    };
    for c in &mut craters {
        c.ejecta_tone *= cfg.albedo_contrast as f32;
        c.floor_tone *= cfg.albedo_contrast as f32;
    }
    tracing::debug!(kind = ?kind, craters = craters.len(), "stamping craters");
    for c in &craters {
        stamp_crater(&mut terrain, c);
    }

    let t_craters = clock.elapsed();
    apply_slope_albedo(&mut terrain, &surface);

    let min_3d = 1.5 * cell;
    let k = cfg.rock_abundance.unwrap_or(defaults.rock_abundance);
    if let FeatureLayout::World {
        rock_from_m,
        crater_from_m: _,
    } = layout
    {
        stamp_world_rocks(
            &mut terrain,
            (x0, y0, x1, y1),
            cfg,
            k,
            &craters,
            &surface,
            rock_from_m,
            seed,
        );
    } else if k > 0.0 {
        let field = RockField {
            sampler: RockSampler::new(
                GolombekSfd::new(k),
                cfg.rock_min_diameter_m,
                cfg.rock_max_diameter_m,
            ),
            height_ratio: cfg.rock_height_ratio,
            shaped_from_m: min_3d,
        };
        let margin = 0.6 * cfg.rock_max_diameter_m;
        let mut rng = ChaCha8Rng::seed_from_u64(derive_seed(seed, stream::ROCKS));
        let patches = surface.rock_patches(derive_seed(seed, stream::ROCK_PATCHES));
        let mut count = 0usize;
        field.for_each_rock(
            (x0 - margin, y0 - margin, x1 + margin, y1 + margin),
            &mut rng,
            |x, y| patches.keep(x, y),
            |r| {
                count += 1;
                stamp_rock(&mut terrain, r, min_3d);
            },
        );
        tracing::debug!(kind = ?kind, rocks = count, k, "stamped rock field");
    }
    if layout == FeatureLayout::Extent {
        let mut rng = ChaCha8Rng::seed_from_u64(derive_seed(seed, stream::BLOCKS));
        let block_min = cfg.rock_min_diameter_m.max(min_3d);
        for c in craters.iter().rev() {
            ejecta_blocks(c, block_min, cfg.rock_height_ratio, &mut rng, |r| {
                stamp_rock(&mut terrain, r, min_3d)
            });
        }
    }
    tracing::debug!(
        kind = ?kind,
        surface_s = t_surface.as_secs_f64(),
        craters_s = (t_craters - t_surface).as_secs_f64(),
        rocks_s = (clock.elapsed() - t_craters).as_secs_f64(),
        "terrain synthesised"
    );
    Ok(terrain)
}

/// The rock field and the craters' ejecta blocks of the world layout.
#[allow(clippy::too_many_arguments)]
fn stamp_world_rocks(
    terrain: &mut Terrain,
    rect: Rect,
    cfg: &TerrainConfig,
    k: f64,
    craters: &[Crater],
    surface: &SurfaceModel,
    rock_from_m: f64,
    seed: u64,
) {
    let min_3d = 1.5 * terrain.cell_m;
    if k > 0.0 {
        let field = WorldRockField::new(
            k,
            cfg.rock_min_diameter_m,
            cfg.rock_max_diameter_m,
            cfg.rock_height_ratio,
        );
        let patches = surface.rock_patches(derive_seed(seed, stream::ROCK_PATCHES));
        field.for_each_rock(
            rect,
            rock_from_m,
            derive_seed(seed, stream::ROCKS),
            |x, y| patches.keep(x, y),
            |r| stamp_rock(terrain, r, min_3d),
        );
    }
    let block_min = cfg.rock_min_diameter_m.max(WORLD_EJECTA_MIN_M);
    for c in craters.iter().rev() {
        world_ejecta_blocks(
            c,
            block_min,
            cfg.rock_height_ratio,
            rock_from_m,
            derive_seed(seed, stream::BLOCKS),
            |r| stamp_rock(terrain, r, min_3d),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn extent(w: usize, h: usize) -> TerrainExtent {
        TerrainExtent {
            origin_x: 3.0,
            origin_y: 50.0,
            width_cells: w,
            height_cells: h,
        }
    }

    const KINDS: [TerrainKind; 3] = [
        TerrainKind::Crater,
        TerrainKind::Gravel,
        TerrainKind::Mountain,
    ];

    fn bits(g: &Grid<f32>) -> Vec<u32> {
        g.data.iter().map(|v| v.to_bits()).collect()
    }

    fn in_pool<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("thread pool")
            .install(f)
    }

    #[test]
    fn same_seed_is_bit_identical_whatever_the_thread_count() {
        // 10 m × 7.5 m at 2.5 cm: large craters take the parallel stamping path.
        let cfg = TerrainConfig::default();
        let ext = extent(400, 300);
        for kind in KINDS {
            let a = in_pool(1, || generate_terrain(kind, &ext, &cfg, 42).unwrap());
            let b = in_pool(3, || generate_terrain(kind, &ext, &cfg, 42).unwrap());
            assert_eq!(bits(&a.height), bits(&b.height), "{kind:?} height");
            assert_eq!(bits(&a.albedo), bits(&b.albedo), "{kind:?} albedo");
            assert!(a.height.data.iter().all(|v| v.is_finite()));
            assert!(a.albedo.data.iter().all(|v| (0.0..=1.0).contains(v)));
        }
    }

    #[test]
    fn different_seeds_and_kinds_differ() {
        let cfg = TerrainConfig {
            cell_m: 0.05,
            ..Default::default()
        };
        let ext = extent(120, 100);
        let mut seen: Vec<Vec<u32>> = Vec::new();
        for kind in KINDS {
            for seed in [1u64, 2] {
                let t = generate_terrain(kind, &ext, &cfg, seed).unwrap();
                let h = bits(&t.height);
                for other in &seen {
                    let same = other.iter().zip(&h).filter(|(a, b)| a == b).count();
                    assert!(
                        same < h.len() / 100,
                        "{kind:?} seed {seed}: {same} equal cells"
                    );
                }
                seen.push(h);
            }
        }
    }

    /// Max − min height over square windows of `win` cells.
    fn max_window_relief(g: &Grid<f32>, win: usize) -> f32 {
        let mut best = 0.0f32;
        for r0 in (0..=g.height - win).step_by(win / 2) {
            for c0 in (0..=g.width - win).step_by(win / 2) {
                let (mut lo, mut hi) = (f32::MAX, f32::MIN);
                for r in r0..r0 + win {
                    for c in c0..c0 + win {
                        lo = lo.min(g.at(c, r));
                        hi = hi.max(g.at(c, r));
                    }
                }
                best = best.max(hi - lo);
            }
        }
        best
    }

    #[test]
    fn relief_suits_a_uav_at_ten_metres() {
        // 60 m × 60 m at 10 cm cells: the terrain is defined at any cell size.
        let cfg = TerrainConfig {
            cell_m: 0.1,
            ..Default::default()
        };
        let ext = extent(600, 600);
        for seed in 0..3u64 {
            for kind in KINDS {
                let t = generate_terrain(kind, &ext, &cfg, seed).unwrap();
                let lo = t.height.data.iter().cloned().fold(f32::MAX, f32::min);
                let hi = t.height.data.iter().cloned().fold(f32::MIN, f32::max);
                let local = max_window_relief(&t.height, 100);
                eprintln!(
                    "{kind:?} seed {seed}: relief {:.2} m, max in 10 m {local:.2} m",
                    hi - lo
                );
                match kind {
                    // Several metres over the area, at most ~5 m under one 10 m footprint.
                    TerrainKind::Mountain => {
                        assert!(hi - lo > 3.0, "{kind:?} seed {seed}: relief {}", hi - lo);
                        assert!(local < 5.5, "{kind:?} seed {seed}: local relief {local}");
                    }
                    // Low relief: rocks and small craters only.
                    TerrainKind::Gravel => assert!(local < 2.0, "seed {seed}: {local}"),
                    TerrainKind::Crater => assert!(local < 5.5, "seed {seed}: {local}"),
                }
            }
        }
    }

    #[test]
    fn bad_configuration_and_extent_are_rejected() {
        let ok = TerrainConfig::default();
        let ext = extent(10, 10);
        assert!(generate_terrain(TerrainKind::Gravel, &ext, &ok, 0).is_ok());
        let bad = [
            TerrainConfig {
                cell_m: 0.0,
                ..ok.clone()
            },
            TerrainConfig {
                cell_m: f64::NAN,
                ..ok.clone()
            },
            TerrainConfig {
                rock_abundance: Some(0.9),
                ..ok.clone()
            },
            TerrainConfig {
                crater_max_diameter_m: 0.1,
                ..ok.clone()
            },
            TerrainConfig {
                albedo_mean: 1.5,
                ..ok.clone()
            },
        ];
        for cfg in &bad {
            assert!(matches!(
                generate_terrain(TerrainKind::Crater, &ext, cfg, 0),
                Err(SimError::InvalidConfig { .. })
            ));
        }
        assert!(generate_terrain(TerrainKind::Crater, &extent(2, 10), &ok, 0).is_err());
        assert!(generate_terrain(TerrainKind::Crater, &extent(usize::MAX, 2), &ok, 0).is_err());
    }

    #[test]
    fn config_round_trips_through_toml_with_defaults_for_missing_fields() {
        let cfg: TerrainConfig = toml::from_str("rock_abundance = 0.15\ncell_m = 0.02").unwrap();
        assert_eq!(cfg.rock_abundance, Some(0.15));
        assert_eq!(cfg.cell_m, 0.02);
        assert_eq!(
            cfg.crater_min_diameter_m,
            TerrainConfig::default().crater_min_diameter_m
        );
        let text = toml::to_string(&cfg).unwrap();
        let back: TerrainConfig = toml::from_str(&text).unwrap();
        assert_eq!(back, cfg);
    }
}
