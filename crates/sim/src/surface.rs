//! Base surface of each terrain kind: relief from noise (fBm hills; for mountains also a
//! domain-warped ridged multifractal) and the albedo pattern (bright dust with soft darker
//! patches of sand or bedrock, mid-scale mottling, per-cell grain, darker steep slopes).

use rayon::prelude::*;

use crate::craters::smoothstep;
use crate::noise::{Fbm, derive_seed, unit_hash};
use crate::terrain::{Terrain, TerrainConfig, TerrainKind};

/// Domain-warped ridged relief of mountains.
#[derive(Debug, Clone)]
struct Ridges {
    ridged: Fbm,
    warp_x: Fbm,
    warp_y: Fbm,
    /// Octaves evaluated on warped coordinates (wavelengths ≥ 4 m).
    n_warped: usize,
    amp_m: f32,
    warp_m: f64,
}

/// Aeolian ripples in sand patches: asymmetric crests, sinuous and broken up by noise.
#[derive(Debug, Clone)]
struct Ripples {
    amp_m: f32,
    inv_wavelength: f64,
    dir: (f64, f64),
    bend: Fbm,
    breakup: Fbm,
}

/// Noise fields and amplitudes of one kind's base surface.
#[derive(Debug, Clone)]
pub struct SurfaceModel {
    kind: TerrainKind,
    cell_m: f64,
    /// Broad hills.
    hills: Fbm,
    hills_m: f32,
    ridges: Option<Ridges>,
    /// Decimetre-scale regolith roughness.
    rough: Fbm,
    rough_m: f32,
    ripples: Ripples,
    /// Albedo: large soft patches (dark sand / bedrock where high), mid-scale mottling,
    /// per-cell grain.
    patches: Fbm,
    mottle: Fbm,
    grain_seed: u64,
    albedo_mean: f32,
    contrast: f32,
    dark_depth: f32,
    dark_threshold: f32,
    steep_darkening: f32,
    rock_clustering: f64,
}

impl SurfaceModel {
    /// The model of `kind` under `cfg`, its noise seeded from `seed`.
    pub fn new(kind: TerrainKind, cfg: &TerrainConfig, seed: u64) -> Self {
        let cell = cfg.cell_m;
        let fine = 2.0 * cell;
        let relief = cfg.relief_scale as f32;
        let s = |i| derive_seed(seed, i);
        let (hills, hills_m) = match kind {
            TerrainKind::Crater => (Fbm::new(s(1), 40.0, 0.5, 0.5, 2.0), 0.5),
            TerrainKind::Gravel => (Fbm::new(s(1), 30.0, 0.5, 0.48, 2.0), 0.35),
            TerrainKind::Mountain => (Fbm::new(s(1), 120.0, 4.0, 0.5, 2.0), 3.0),
        };
        let ridges = (kind == TerrainKind::Mountain).then(|| {
            let ridged = Fbm::new(s(2), 60.0, fine, 0.5, 2.0);
            Ridges {
                n_warped: ridged.octaves_above(4.0),
                ridged,
                warp_x: Fbm::new(s(3), 60.0, 4.0, 0.5, 2.0),
                warp_y: Fbm::new(s(4), 60.0, 4.0, 0.5, 2.0),
                amp_m: 6.0 * relief,
                warp_m: 10.0,
            }
        });
        let (rough_m, ripple_m, dark_depth, dark_threshold, steep) = match kind {
            TerrainKind::Crater => (0.012, 0.03, 0.35, 0.15, 0.15),
            TerrainKind::Gravel => (0.008, 0.025, 0.22, 0.1, 0.1),
            TerrainKind::Mountain => (0.02, 0.02, 0.3, 0.1, 0.35),
        };
        // Per-seed ripple wavelength (0.5–0.9 m) and crest direction.
        let u = |i| (derive_seed(seed, i) >> 11) as f64 / (1u64 << 53) as f64;
        let angle = std::f64::consts::PI * u(20);
        Self {
            kind,
            cell_m: cell,
            hills,
            hills_m: hills_m * relief,
            ridges,
            rough: Fbm::new(s(8), 1.0, fine, 0.6, 2.0),
            rough_m: rough_m * relief,
            ripples: Ripples {
                amp_m: ripple_m * relief,
                inv_wavelength: 1.0 / (0.5 + 0.4 * u(21)),
                dir: (angle.cos(), angle.sin()),
                bend: Fbm::new(s(9), 6.0, 0.5, 0.5, 2.0),
                breakup: Fbm::new(s(10), 2.0, 0.3, 0.5, 2.0),
            },
            patches: Fbm::new(s(5), 30.0, 1.0, 0.55, 2.0),
            mottle: Fbm::new(s(6), 2.0, fine, 0.6, 2.0),
            grain_seed: s(7),
            albedo_mean: cfg.albedo_mean as f32,
            contrast: cfg.albedo_contrast as f32,
            dark_depth,
            dark_threshold,
            steep_darkening: steep,
            rock_clustering: cfg.rock_clustering,
        }
    }

    /// The kind modelled.
    pub fn kind(&self) -> TerrainKind {
        self.kind
    }

    /// Base height (m) and albedo at world (x, y).
    #[inline]
    pub fn sample(&self, x: f64, y: f64) -> (f32, f32) {
        let mut z = self.hills_m * self.hills.eval(x, y) + self.rough_m * self.rough.eval(x, y);
        if let Some(r) = &self.ridges {
            let wx = x + r.warp_m * r.warp_x.eval(x, y) as f64;
            let wy = y + r.warp_m * r.warp_y.eval(x, y) as f64;
            z += r.amp_m * r.ridged.ridged_warped(x, y, wx, wy, r.n_warped);
        }
        // Dark patches: sand or bedrock showing through the dust; sand carries ripples.
        let p = self.patches.eval(x, y);
        let t0 = self.dark_threshold as f64;
        let dark = smoothstep(t0, t0 + 0.12, p as f64) as f32;
        let mut ripple = 0.0f32;
        if dark > 0.0 && self.ripples.amp_m > 0.0 {
            let rp = &self.ripples;
            let phase =
                (x * rp.dir.0 + y * rp.dir.1) * rp.inv_wavelength + 1.5 * rp.bend.eval(x, y) as f64;
            let f = phase - phase.floor();
            // Asymmetric crest: gentle stoss rising over 70 % of the period, steep lee.
            let tri = if f < 0.7 { f / 0.7 } else { (1.0 - f) / 0.3 };
            let crest = (tri * tri * (3.0 - 2.0 * tri)) as f32 - 0.5;
            let keep = smoothstep(-0.15, 0.2, rp.breakup.eval(x, y) as f64) as f32;
            ripple = crest * keep * dark;
            z += rp.amp_m * ripple;
        }
        let ix = (x / self.cell_m).round() as i64;
        let iy = (y / self.cell_m).round() as i64;
        let grain = unit_hash(self.grain_seed, ix, iy) - 0.5;
        let tex = 0.12 * self.mottle.eval(x, y) + 0.2 * grain + 0.05 * p + 0.08 * ripple;
        let a = self.albedo_mean
            * (1.0 - self.contrast * self.dark_depth * dark)
            * (1.0 + self.contrast * tex);
        (z, a.clamp(0.01, 0.99))
    }

    /// Fills the terrain's height and albedo from the base model (row-parallel).
    pub fn fill(&self, t: &mut Terrain) {
        let w = t.height.width;
        let (ox, oy, cell) = (t.origin_x, t.origin_y, t.cell_m);
        t.height
            .data
            .par_chunks_mut(w)
            .zip(t.albedo.data.par_chunks_mut(w))
            .enumerate()
            .for_each(|(row, (hr, ar))| {
                let y = oy - row as f64 * cell;
                for (col, (h, a)) in hr.iter_mut().zip(ar.iter_mut()).enumerate() {
                    (*h, *a) = self.sample(ox + col as f64 * cell, y);
                }
            });
    }

    /// Where rock fields are dense: a smooth acceptance field with mean ≈ 0.5.
    pub fn rock_patches(&self, seed: u64) -> RockPatches {
        RockPatches {
            field: Fbm::new(seed, 12.0, 1.5, 0.5, 2.0),
            strength: 1.6 * self.rock_clustering as f32,
        }
    }
}

/// Acceptance field of rock placement (see [`crate::rocks::RockField::for_each_rock`]).
#[derive(Debug, Clone)]
pub struct RockPatches {
    field: Fbm,
    strength: f32,
}

impl RockPatches {
    /// Probability of keeping a rock drawn at (x, y).
    #[inline]
    pub fn keep(&self, x: f64, y: f64) -> f64 {
        (0.5 + self.strength * self.field.eval(x, y)).clamp(0.0, 1.0) as f64
    }
}

/// Darkens steep slopes (exposed rock, dust slides off) in proportion to the slope.
pub fn apply_slope_albedo(t: &mut Terrain, model: &SurfaceModel) {
    let amount = model.steep_darkening * model.contrast;
    if amount <= 0.0 {
        return;
    }
    let (w, h) = (t.height.width, t.height.height);
    let inv2 = (0.5 / t.cell_m) as f32;
    let height = &t.height;
    t.albedo
        .data
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(row, ar)| {
            let (ru, rd) = (row.saturating_sub(1), (row + 1).min(h - 1));
            let up = &height.data[ru * w..(ru + 1) * w];
            let down = &height.data[rd * w..(rd + 1) * w];
            let mid = &height.data[row * w..(row + 1) * w];
            let ry = inv2 * 2.0 / (rd - ru).max(1) as f32;
            for col in 0..w {
                let (cl, cr) = (col.saturating_sub(1), (col + 1).min(w - 1));
                let gx = (mid[cr] - mid[cl]) * inv2 * 2.0 / (cr - cl).max(1) as f32;
                let gy = (up[col] - down[col]) * ry;
                let s = (gx * gx + gy * gy).sqrt();
                let f = smoothstep(0.25, 0.9, s as f64) as f32;
                ar[col] = (ar[col] * (1.0 - amount * f)).max(0.01);
            }
        });
}
