//! Base surface of each terrain kind: relief from noise (fBm hills; for mountains also a
//! domain-warped ridged multifractal) and the albedo pattern (bright dust with soft darker
//! patches of sand or bedrock, mid-scale mottling, per-cell grain, darker steep slopes).

use rayon::prelude::*;

use crate::craters::smoothstep;
use crate::noise::{Fbm, RidgedState, derive_seed, fast_floor, unit_hash};
use crate::terrain::{Terrain, TerrainConfig, TerrainKind};

/// Domain-warped ridged relief of mountains.
#[derive(Debug, Clone)]
struct Ridges {
    ridged: Fbm,
    warp_x: Fbm,
    warp_y: Fbm,
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

/// Smooth fields evaluated on a coarse lattice and interpolated (Catmull-Rom) per cell.
const N_COARSE: usize = 6;
const HILLS: usize = 0;
const RIDGE_SUM: usize = 1;
const RIDGE_WEIGHT: usize = 2;
const PATCHES: usize = 3;
const BEND: usize = 4;
const BREAKUP: usize = 5;

/// Octaves with wavelengths at or above this are evaluated on the coarse lattice, at least
/// 10 lattice nodes per wavelength so that cubic interpolation is exact to well below a
/// millimetre and a percent of slope.
const COARSE_WAVELENGTH_M: f64 = 2.0;
/// The same for the ridges, whose domain warp compresses wavelengths up to about twice.
const COARSE_RIDGE_WAVELENGTH_M: f64 = 4.0;
/// Cell size at which the per-cell grain has its full amplitude.
const GRAIN_CELL_M: f64 = 0.025;
/// Grain amplitude standing for the unresolved rocks and craters of a coarse cell: on 25 cm
/// cells it matches the pixel-to-pixel texture of 2.5 cm renders averaged to 25 cm (crater,
/// gravel, mountain within 20 %; `tests/regional.rs`).
const UNRESOLVED_GRAIN: f64 = 0.15;
/// Target lattice spacing.
const LATTICE_M: f64 = 0.2;

/// Noise fields and amplitudes of one kind's base surface.
#[derive(Debug, Clone)]
pub struct SurfaceModel {
    kind: TerrainKind,
    cell_m: f64,
    /// Coarse lattice spacing in cells.
    step: usize,
    /// Broad hills; its first `hills_split` octaves are coarse.
    hills: Fbm,
    hills_split: usize,
    hills_m: f32,
    /// Mountain ridges; the first `ridges_split` octaves are coarse and domain-warped, the
    /// finer ones unwarped (warping them would stretch the detail into streaks).
    ridges: Option<Ridges>,
    ridges_split: usize,
    /// Decimetre-scale regolith roughness.
    rough: Fbm,
    rough_m: f32,
    ripples: Ripples,
    /// Albedo: large soft patches (dark sand / bedrock where high), mid-scale mottling,
    /// per-cell grain.
    patches: Fbm,
    mottle: Fbm,
    grain_seed: u64,
    /// Amplitude of the per-cell grain: 0.2 at 2.5 cm cells; on coarser cells the mean of the
    /// finer cells' grains plus the texture of what such a cell cannot resolve (rocks and
    /// craters under its size), so that a map pixel has the same texture whichever grid it
    /// was rendered from.
    grain_amp: f32,
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
        let ridges = (kind == TerrainKind::Mountain).then(|| Ridges {
            ridged: Fbm::new(s(2), 60.0, fine, 0.5, 2.0),
            warp_x: Fbm::new(s(3), 60.0, 4.0, 0.5, 2.0),
            warp_y: Fbm::new(s(4), 60.0, 4.0, 0.5, 2.0),
            amp_m: 6.0 * relief,
            warp_m: 10.0,
        });
        let (rough_m, ripple_m, dark_depth, dark_threshold, steep) = match kind {
            TerrainKind::Crater => (0.012, 0.03, 0.35, 0.15, 0.15),
            TerrainKind::Gravel => (0.008, 0.025, 0.22, 0.1, 0.1),
            TerrainKind::Mountain => (0.02, 0.02, 0.3, 0.1, 0.35),
        };
        // Per-seed ripple wavelength (0.5–0.9 m) and crest direction.
        let u = |i| (derive_seed(seed, i) >> 11) as f64 / (1u64 << 53) as f64;
        let angle = std::f64::consts::PI * u(20);
        let step = ((LATTICE_M / cell).floor() as usize).clamp(1, 16);
        Self {
            kind,
            cell_m: cell,
            step,
            hills_split: hills.octaves_above(COARSE_WAVELENGTH_M),
            hills,
            hills_m: hills_m * relief,
            ridges_split: ridges
                .as_ref()
                .map_or(0, |r| r.ridged.octaves_above(COARSE_RIDGE_WAVELENGTH_M)),
            ridges,
            rough: Fbm::new(s(8), 1.0, fine, 0.6, 2.0),
            rough_m: rough_m * relief,
            ripples: Ripples {
                amp_m: ripple_m * relief,
                inv_wavelength: 1.0 / (0.5 + 0.4 * u(21)),
                dir: (angle.cos(), angle.sin()),
                bend: Fbm::new(s(9), 6.0, 1.0, 0.5, 2.0),
                breakup: Fbm::new(s(10), 2.0, 0.6, 0.5, 2.0),
            },
            patches: Fbm::new(s(5), 30.0, COARSE_WAVELENGTH_M, 0.55, 2.0),
            mottle: Fbm::new(s(6), 2.0, fine, 0.6, 2.0),
            grain_seed: s(7),
            grain_amp: {
                let f = (GRAIN_CELL_M / cell).min(1.0);
                (0.2 * f + UNRESOLVED_GRAIN * (1.0 - f)) as f32
            },
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

    /// The smooth (coarse-lattice) fields at world (x, y).
    #[inline]
    fn coarse_fields(&self, x: f64, y: f64) -> [f32; N_COARSE] {
        let mut f = [0.0f32; N_COARSE];
        f[HILLS] = self.hills.eval_octaves(x, y, 0..self.hills_split);
        f[RIDGE_WEIGHT] = 1.0;
        if let Some(r) = &self.ridges {
            let wx = x + r.warp_m * r.warp_x.eval(x, y) as f64;
            let wy = y + r.warp_m * r.warp_y.eval(x, y) as f64;
            let st =
                r.ridged
                    .ridged_octaves(wx, wy, 0..self.ridges_split, RidgedState::START, 0.05);
            f[RIDGE_SUM] = st.0;
            f[RIDGE_WEIGHT] = st.1;
        }
        f[PATCHES] = self.patches.eval(x, y);
        f[BEND] = self.ripples.bend.eval(x, y);
        f[BREAKUP] = self.ripples.breakup.eval(x, y);
        f
    }

    /// Height and albedo at world (x, y) given the smooth fields there.
    #[inline]
    fn finish(&self, x: f64, y: f64, f: &[f32; N_COARSE]) -> (f32, f32) {
        let hills = f[HILLS] + self.hills.eval_octaves(x, y, self.hills_split..usize::MAX);
        let mut z = self.hills_m * hills + self.rough_m * self.rough.eval(x, y);
        if let Some(r) = &self.ridges {
            let st = RidgedState(f[RIDGE_SUM], f[RIDGE_WEIGHT].clamp(0.0, 1.0));
            let st = r
                .ridged
                .ridged_octaves(x, y, self.ridges_split..usize::MAX, st, 0.0);
            z += r.amp_m * st.0 / r.ridged.amplitude_sum();
        }
        // Dark patches: sand or bedrock showing through the dust; sand carries ripples.
        let p = f[PATCHES];
        let t0 = self.dark_threshold as f64;
        let dark = smoothstep(t0, t0 + 0.12, p as f64) as f32;
        let mut ripple = 0.0f32;
        if dark > 0.0 && self.ripples.amp_m > 0.0 {
            let rp = &self.ripples;
            let phase = (x * rp.dir.0 + y * rp.dir.1) * rp.inv_wavelength + 1.5 * f[BEND] as f64;
            let fr = phase - fast_floor(phase) as f64;
            // Asymmetric crest: gentle stoss rising over 70 % of the period, steep lee.
            let tri = if fr < 0.7 { fr / 0.7 } else { (1.0 - fr) / 0.3 };
            let crest = (tri * tri * (3.0 - 2.0 * tri)) as f32 - 0.5;
            let keep = smoothstep(-0.15, 0.2, f[BREAKUP] as f64) as f32;
            ripple = crest * keep * dark;
            z += rp.amp_m * ripple;
        }
        let ix = fast_floor(x / self.cell_m + 0.5);
        let iy = fast_floor(y / self.cell_m + 0.5);
        let grain = unit_hash(self.grain_seed, ix, iy) - 0.5;
        let tex = 0.12 * self.mottle.eval(x, y) + self.grain_amp * grain + 0.05 * p + 0.08 * ripple;
        let a = self.albedo_mean
            * (1.0 - self.contrast * self.dark_depth * dark)
            * (1.0 + self.contrast * tex);
        (z, a.clamp(0.01, 0.99))
    }

    /// Base height (m) and albedo at world (x, y), evaluated exactly (no lattice).
    pub fn sample(&self, x: f64, y: f64) -> (f32, f32) {
        self.finish(x, y, &self.coarse_fields(x, y))
    }

    /// Fills the terrain's height and albedo from the base model: the smooth fields on a
    /// lattice every `step` cells (Catmull-Rom interpolated), the rest per cell; both
    /// passes row-parallel and pure functions of position.
    pub fn fill(&self, t: &mut Terrain) {
        let (w, h) = (t.height.width, t.height.height);
        let (ox, oy, cell) = (t.origin_x, t.origin_y, t.cell_m);
        let s = self.step;
        // Node (i, j) sits at cell ((i − 1)·s, (j − 1)·s): one node of margin before, two after.
        let (nx, ny) = ((w - 1) / s + 4, (h - 1) / s + 4);
        let mut lattice = vec![[0.0f32; N_COARSE]; nx * ny];
        lattice.par_chunks_mut(nx).enumerate().for_each(|(j, row)| {
            let y = oy - (j as f64 - 1.0) * (s as f64) * cell;
            for (i, v) in row.iter_mut().enumerate() {
                *v = self.coarse_fields(ox + (i as f64 - 1.0) * (s as f64) * cell, y);
            }
        });
        let weights: Vec<[f32; 4]> = (0..s).map(|k| catmull_rom(k as f32 / s as f32)).collect();
        t.height
            .data
            .par_chunks_mut(w)
            .zip(t.albedo.data.par_chunks_mut(w))
            .enumerate()
            .for_each(|(row, (hr, ar))| {
                let y = oy - row as f64 * cell;
                // Interpolate the lattice vertically once per row.
                let (jb, wv) = (row / s, weights[row % s]);
                let vrow: Vec<[f32; N_COARSE]> = (0..nx)
                    .map(|i| {
                        let mut acc = [0.0f32; N_COARSE];
                        for (k, &wk) in wv.iter().enumerate() {
                            let node = &lattice[(jb + k) * nx + i];
                            for (a, &v) in acc.iter_mut().zip(node) {
                                *a += wk * v;
                            }
                        }
                        acc
                    })
                    .collect();
                for (col, (hc, ac)) in hr.iter_mut().zip(ar.iter_mut()).enumerate() {
                    let (ib, wh) = (col / s, weights[col % s]);
                    let mut f = [0.0f32; N_COARSE];
                    for (k, &wk) in wh.iter().enumerate() {
                        for (a, &v) in f.iter_mut().zip(&vrow[ib + k]) {
                            *a += wk * v;
                        }
                    }
                    (*hc, *ac) = self.finish(ox + col as f64 * cell, y, &f);
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

/// Catmull-Rom weights of the four nodes around fraction `t` ∈ [0, 1) between the middle two.
#[inline]
fn catmull_rom(t: f32) -> [f32; 4] {
    let (t2, t3) = (t * t, t * t * t);
    [
        0.5 * (-t3 + 2.0 * t2 - t),
        0.5 * (3.0 * t3 - 5.0 * t2 + 2.0),
        0.5 * (-3.0 * t3 + 4.0 * t2 + t),
        0.5 * (t3 - t2),
    ]
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

#[cfg(test)]
mod tests {
    use super::*;
    use jointloc_formats::Grid;

    #[test]
    fn lattice_interpolation_matches_exact_evaluation() {
        let cfg = TerrainConfig::default();
        for kind in [
            TerrainKind::Crater,
            TerrainKind::Gravel,
            TerrainKind::Mountain,
        ] {
            for seed in 0..2u64 {
                let model = SurfaceModel::new(kind, &cfg, seed);
                let (w, h) = (90, 70);
                let mut t = Terrain {
                    cell_m: cfg.cell_m,
                    origin_x: -7.3,
                    origin_y: 12.1,
                    height: Grid::filled(w, h, 0.0),
                    albedo: Grid::filled(w, h, 0.0),
                };
                model.fill(&mut t);
                let (mut dz, mut da, mut dslope) = (0.0f32, 0.0f32, 0.0f32);
                for row in 1..h - 1 {
                    for col in 1..w - 1 {
                        let (x, y) = t.cell_to_world(col as f64, row as f64);
                        let (z, a) = model.sample(x, y);
                        dz = dz.max((z - t.height.at(col, row)).abs());
                        da = da.max((a - t.albedo.at(col, row)).abs());
                        // Slope along x, exact vs interpolated.
                        let ze =
                            model.sample(x + cfg.cell_m, y).0 - model.sample(x - cfg.cell_m, y).0;
                        let zi = t.height.at(col + 1, row) - t.height.at(col - 1, row);
                        dslope = dslope.max((ze - zi).abs() / (2.0 * cfg.cell_m as f32));
                    }
                }
                assert!(dz < 2e-3, "{kind:?}: height error {dz}");
                assert!(da < 0.01, "{kind:?}: albedo error {da}");
                assert!(dslope < 0.02, "{kind:?}: slope error {dslope}");
            }
        }
    }
}
