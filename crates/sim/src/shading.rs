//! Shading of a terrain under the sun: albedo × (direct sun × cast shadow × (lunar-)Lambert)
//! + diffuse sky light. Mars shadows are lit by the dusty sky, so they are never black.
//!
//! Cast shadows come from one horizon sweep over the grid along the sun's azimuth (O(N)):
//! lines perpendicular to the dominant axis of the sun direction are processed from the sun
//! side, each cell inheriting the "shadow top" of the line before, interpolated at the point
//! one step towards the sun and lowered by the sun's elevation over that step.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::terrain::Terrain;
use jointloc_formats::Grid;

/// Sun position seen from the terrain.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Sun {
    /// Clockwise from north (+y) towards east (+x), degrees.
    pub azimuth_deg: f64,
    /// Above the horizon, degrees; ≤ 0 leaves only sky light.
    pub elevation_deg: f64,
}

impl Sun {
    /// Unit vector towards the sun in the world frame (x east, y north, z up).
    pub fn direction(&self) -> [f64; 3] {
        let (sa, ca) = self.azimuth_deg.to_radians().sin_cos();
        let (se, ce) = self.elevation_deg.to_radians().sin_cos();
        [sa * ce, ca * ce, se]
    }
}

/// Photometric knobs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ShadingConfig {
    /// Diffuse sky irradiance on a horizontal surface as a fraction of the direct irradiance
    /// at normal incidence (Mars: 0.15–0.3, higher when dusty).
    pub sky_fraction: f64,
    /// Lunar-Lambert weight L: 0 is Lambert, 1 is Lommel-Seeliger (viewer assumed at nadir).
    pub lunar_lambert_l: f64,
    /// Width of the shadow edge in cells along the sun direction (anti-aliasing).
    pub shadow_softness_cells: f64,
    /// Cast shadows on (off leaves only self-shadowing by the surface orientation).
    pub cast_shadows: bool,
    /// Radius (m) over which hollows hide part of the sky: a cell Δ below the local mean
    /// height sees the sky over a horizon of tan α ≈ 2Δ / radius, so its sky light is scaled
    /// by cos² α (at least 0.3). 0 turns sky occlusion off.
    pub sky_occlusion_radius_m: f64,
}

impl Default for ShadingConfig {
    fn default() -> Self {
        Self {
            sky_fraction: 0.2,
            lunar_lambert_l: 0.3,
            shadow_softness_cells: 1.0,
            cast_shadows: true,
            sky_occlusion_radius_m: 0.5,
        }
    }
}

/// Linear radiance of every cell under `sun` (same grid as `terrain.height`): albedo times
/// irradiance, so values stay within about [0, 1.3 · albedo].
///
/// Invalid inputs never panic: non-finite angles are treated as a sun at the zenith and
/// negative knobs as 0. Terrain outside the grid casts no shadow, so give the grid a margin
/// towards the sun of at least (relief / tan elevation).
pub fn shade(terrain: &Terrain, sun: &Sun, cfg: &ShadingConfig) -> Grid<f32> {
    let (w, h) = (terrain.height.width, terrain.height.height);
    let mut out = Grid::filled(w, h, 1.0f32);
    if w == 0 || h == 0 {
        return out;
    }
    let sun = if sun.azimuth_deg.is_finite() && sun.elevation_deg.is_finite() {
        *sun
    } else {
        Sun {
            azimuth_deg: 0.0,
            elevation_deg: 90.0,
        }
    };
    let el = sun.elevation_deg.clamp(-90.0, 90.0);
    if el <= 0.0 {
        out.data.fill(0.0);
    } else if cfg.cast_shadows && el < 89.9 {
        cast_shadows(terrain, &sun, cfg.shadow_softness_cells.max(1e-3), &mut out);
    }
    let s = sun.direction();
    let (sx, sy, sz) = (s[0] as f32, s[1] as f32, s[2] as f32);
    let l = cfg.lunar_lambert_l.clamp(0.0, 1.0) as f32;
    let sky = cfg.sky_fraction.max(0.0) as f32;
    let inv2 = (0.5 / terrain.cell_m) as f32;
    let hg = &terrain.height;
    let radius = cfg.sky_occlusion_radius_m;
    let mean = (radius.is_finite() && radius > 0.0).then(|| MeanHeight::new(terrain, radius));
    let inv_half_r = if radius > 0.0 {
        (2.0 / radius) as f32
    } else {
        0.0
    };
    out.data
        .par_chunks_mut(w)
        .zip(terrain.albedo.data.par_chunks(w))
        .enumerate()
        .for_each(|(row, (orow, arow))| {
            let (ru, rd) = (row.saturating_sub(1), (row + 1).min(h - 1));
            let up = &hg.data[ru * w..(ru + 1) * w];
            let down = &hg.data[rd * w..(rd + 1) * w];
            let mid = &hg.data[row * w..(row + 1) * w];
            let ky = inv2 * 2.0 / (rd - ru).max(1) as f32;
            for col in 0..w {
                let (cl, cr) = (col.saturating_sub(1), (col + 1).min(w - 1));
                let kx = inv2 * 2.0 / (cr - cl).max(1) as f32;
                // Height gradient: +x east (columns), +y north (up a row).
                let gx = (mid[cr] - mid[cl]) * kx;
                let gy = (up[col] - down[col]) * ky;
                let nz = 1.0 / (1.0 + gx * gx + gy * gy).sqrt();
                let cos_i = (-gx * sx - gy * sy + sz) * nz;
                let direct = if cos_i > 0.0 {
                    (1.0 - l) * cos_i + l * 2.0 * cos_i / (cos_i + nz)
                } else {
                    0.0
                };
                let mut sky_seen = sky * 0.5 * (1.0 + nz);
                if let Some(m) = &mean {
                    let depth = m.at(col, row) - mid[col];
                    if depth > 0.0 {
                        let t = depth * inv_half_r;
                        sky_seen *= (1.0 / (1.0 + t * t)).max(0.3);
                    }
                }
                let irradiance = orow[col] * direct + sky_seen;
                orow[col] = arow[col] * irradiance;
            }
        });
    out
}

/// Mean height over a square of side ≈ 2 · radius around each cell, computed on a lattice
/// of block means (about 5 blocks per radius) and sampled bilinearly: 1/16 of the grid's
/// memory or less.
struct MeanHeight {
    grid: Grid<f32>,
    step: usize,
}

impl MeanHeight {
    fn new(t: &Terrain, radius_m: f64) -> Self {
        let (w, h) = (t.height.width, t.height.height);
        let step = ((radius_m / t.cell_m / 5.0).round() as usize).clamp(1, 64);
        let (cw, ch) = (w.div_ceil(step), h.div_ceil(step));
        let mut blocks = Grid::filled(cw, ch, 0.0f32);
        blocks
            .data
            .par_chunks_mut(cw)
            .enumerate()
            .for_each(|(j, brow)| {
                let rows = j * step..((j + 1) * step).min(h);
                let n_rows = rows.len();
                for (i, b) in brow.iter_mut().enumerate() {
                    let cols = i * step..((i + 1) * step).min(w);
                    let n = (n_rows * cols.len()) as f32;
                    let mut sum = 0.0f32;
                    for r in rows.clone() {
                        sum += t.height.data[r * w + cols.start..r * w + cols.end]
                            .iter()
                            .sum::<f32>();
                    }
                    *b = sum / n;
                }
            });
        let rc = ((radius_m / (step as f64 * t.cell_m)).round() as usize).max(1);
        let blurred = box_blur(&box_blur(&blocks, rc, true), rc, false);
        Self {
            grid: blurred,
            step,
        }
    }

    #[inline]
    fn at(&self, col: usize, row: usize) -> f32 {
        let s = self.step as f64;
        self.grid
            .bilinear((col as f64 + 0.5) / s - 0.5, (row as f64 + 0.5) / s - 0.5)
    }
}

/// Box mean of radius `r` along rows (`horizontal`) or columns, shrinking at the borders.
fn box_blur(g: &Grid<f32>, r: usize, horizontal: bool) -> Grid<f32> {
    let (w, h) = (g.width, g.height);
    let mut out = Grid::filled(w, h, 0.0f32);
    out.data
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(row, orow)| {
            for (col, o) in orow.iter_mut().enumerate() {
                let (mut sum, mut n) = (0.0f32, 0.0f32);
                if horizontal {
                    for c in col.saturating_sub(r)..(col + r + 1).min(w) {
                        sum += g.data[row * w + c];
                        n += 1.0;
                    }
                } else {
                    for rr in row.saturating_sub(r)..(row + r + 1).min(h) {
                        sum += g.data[rr * w + col];
                        n += 1.0;
                    }
                }
                *o = sum / n;
            }
        });
    out
}

/// Writes the lit fraction (0 in shadow … 1 lit) of every cell into `lit`.
fn cast_shadows(terrain: &Terrain, sun: &Sun, softness: f64, lit: &mut Grid<f32>) {
    let (w, h) = (terrain.height.width, terrain.height.height);
    let (sa, ca) = sun.azimuth_deg.to_radians().sin_cos();
    // Towards the sun in grid units: columns grow east, rows grow south.
    let (dc, dr) = (sa, -ca);
    let tan_e = sun.elevation_deg.to_radians().tan();
    let cell = terrain.cell_m;
    // Lines are rows when the sun is mostly north/south, columns otherwise.
    let (lines, len, line_stride, pos_stride, toward, offset, step_m) = if dr.abs() >= dc.abs() {
        (h, w, w, 1, dr.signum(), dc / dr.abs(), cell / dr.abs())
    } else {
        (w, h, 1, w, dc.signum(), dr / dc.abs(), cell / dc.abs())
    };
    let drop = (step_m * tan_e) as f32;
    let eps = (softness as f32 * drop).max(1e-6);
    let hd = &terrain.height.data;
    let mut prev = vec![f32::NEG_INFINITY; len];
    let mut cur = vec![0.0f32; len];
    // Start at the line nearest the sun: the upsun neighbour of line i is line i + toward.
    for k in 0..lines {
        let line = if toward > 0.0 { lines - 1 - k } else { k };
        let base = line * line_stride;
        for pos in 0..len {
            let z = hd[base + pos * pos_stride];
            let p = pos as f64 + offset;
            let top = if k == 0 || p < 0.0 || p > (len - 1) as f64 {
                f32::NEG_INFINITY
            } else {
                let p0 = p.floor() as usize;
                let p1 = (p0 + 1).min(len - 1);
                let f = (p - p0 as f64) as f32;
                prev[p0] + (prev[p1] - prev[p0]) * f - drop
            };
            let occl = top - z;
            lit.data[base + pos * pos_stride] = (0.5 - occl / eps).clamp(0.0, 1.0);
            cur[pos] = z.max(top);
        }
        std::mem::swap(&mut prev, &mut cur);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(w: usize, h: usize, cell: f64, albedo: f32) -> Terrain {
        Terrain {
            cell_m: cell,
            origin_x: 0.0,
            origin_y: 0.0,
            height: Grid::filled(w, h, 0.0),
            albedo: Grid::filled(w, h, albedo),
        }
    }

    #[test]
    fn flat_terrain_is_albedo_times_sin_elevation_plus_sky() {
        for &el in &[10.0, 30.0, 60.0, 90.0] {
            for &l in &[0.0, 1.0] {
                let t = flat(20, 10, 0.025, 0.3);
                let sun = Sun {
                    azimuth_deg: 123.0,
                    elevation_deg: el,
                };
                let cfg = ShadingConfig {
                    lunar_lambert_l: l,
                    ..Default::default()
                };
                let g = shade(&t, &sun, &cfg);
                let mu = el.to_radians().sin();
                let direct = if l == 0.0 { mu } else { 2.0 * mu / (mu + 1.0) };
                let want = 0.3 * (direct + cfg.sky_fraction);
                for &v in &g.data {
                    assert!(
                        (v as f64 - want).abs() < 1e-5,
                        "el {el} L {l}: {v} vs {want}"
                    );
                }
            }
        }
    }

    /// A wall one cell thick across the sun direction; returns the shadow length behind it (m).
    fn wall_shadow(az: f64, el: f64, wall_h: f32) -> f64 {
        let n = 301;
        let cell = 0.02;
        let mut t = flat(n, n, cell, 0.25);
        let c = (n / 2) as f64;
        let (sa, ca) = az.to_radians().sin_cos();
        let (dc, dr) = (sa, -ca);
        // Cells within half a cell of the line through the centre perpendicular to the sun.
        for row in 0..n {
            for col in 0..n {
                let along = (col as f64 - c) * dc + (row as f64 - c) * dr;
                let across = -(col as f64 - c) * dr + (row as f64 - c) * dc;
                if along.abs() <= 0.75 && across.abs() < 100.0 {
                    *t.height.at_mut(col, row) = wall_h;
                }
            }
        }
        let sun = Sun {
            azimuth_deg: az,
            elevation_deg: el,
        };
        let cfg = ShadingConfig::default();
        let g = shade(&t, &sun, &cfg);
        // Walk from the wall away from the sun along the centre line; ground lit level:
        let lit_level = 0.25
            * ((el.to_radians().sin() * (1.0 - cfg.lunar_lambert_l))
                + cfg.lunar_lambert_l * 2.0 * el.to_radians().sin()
                    / (el.to_radians().sin() + 1.0)
                + cfg.sky_fraction);
        let shadow_level = 0.25 * cfg.sky_fraction;
        let mid = 0.5 * (lit_level + shadow_level);
        let mut dist = 3.0;
        loop {
            let col = (c - dist * dc).round();
            let row = (c - dist * dr).round();
            if col < 0.0 || row < 0.0 || col >= n as f64 || row >= n as f64 {
                return f64::INFINITY;
            }
            let v = g.at(col as usize, row as usize) as f64;
            assert!(v >= 0.9 * shadow_level, "shadow too dark: {v}");
            if v > mid {
                return (dist - 0.75) * cell;
            }
            dist += 0.25;
        }
    }

    #[test]
    fn wall_casts_shadow_of_height_over_tan_elevation() {
        for &az in &[0.0, 30.0, 45.0, 90.0, 160.0, 200.0, 270.0, 315.0] {
            for &el in &[20.0, 35.0, 55.0] {
                let wall = 0.5f32;
                let got = wall_shadow(az, el, wall);
                let want = wall as f64 / el.to_radians().tan();
                assert!(
                    (got - want).abs() < 0.05 * want + 0.04,
                    "az {az} el {el}: {got} vs {want}"
                );
            }
        }
    }

    #[test]
    fn hollows_see_less_sky_than_open_ground() {
        // A pit 0.4 m deep and 0.4 m wide in flat ground; sun below the horizon: sky only.
        let mut t = flat(80, 80, 0.025, 0.25);
        for row in 32..48 {
            for col in 32..48 {
                *t.height.at_mut(col, row) = -0.4;
            }
        }
        let sun = Sun {
            azimuth_deg: 0.0,
            elevation_deg: -5.0,
        };
        let cfg = ShadingConfig::default();
        let g = shade(&t, &sun, &cfg);
        let open = 0.25 * cfg.sky_fraction as f32;
        assert!((g.at(5, 5) - open).abs() < 1e-6);
        let bottom = g.at(40, 40);
        assert!(
            bottom < 0.8 * open && bottom >= 0.3 * open - 1e-6,
            "{bottom} vs {open}"
        );
        let off = ShadingConfig {
            sky_occlusion_radius_m: 0.0,
            ..Default::default()
        };
        assert!((shade(&t, &sun, &off).at(40, 40) - open).abs() < 1e-6);
    }

    #[test]
    fn shadows_are_never_black_and_sun_below_horizon_leaves_sky() {
        let mut t = flat(50, 50, 0.05, 0.2);
        for row in 0..50 {
            for col in 0..50 {
                *t.height.at_mut(col, row) =
                    ((col as f32 * 0.7).sin() + (row as f32 * 0.3).cos()) * 0.5;
            }
        }
        let cfg = ShadingConfig::default();
        for &el in &[5.0, 25.0, -10.0] {
            let g = shade(
                &t,
                &Sun {
                    azimuth_deg: 77.0,
                    elevation_deg: el,
                },
                &cfg,
            );
            let min = g.data.iter().cloned().fold(f32::MAX, f32::min);
            // Worst case: a vertical face (half the sky) at the bottom of a deep hollow (0.3).
            assert!(
                min >= 0.2 * 0.5 * 0.3 * cfg.sky_fraction as f32,
                "el {el}: {min}"
            );
            if el < 0.0 {
                let max = g.data.iter().cloned().fold(0.0, f32::max);
                assert!(max <= 0.2 * cfg.sky_fraction as f32 + 1e-6);
            }
        }
    }
}
