//! Maps larger than the flight (`map_size_m`): a coarse terrain over the whole map, a detailed
//! one under the flight, and the map and DEM composited from both.
//!
//! The UAV only ever sees the *detailed patch*: the flown path's bounding box, grown by the
//! camera footprint's margin and by a blend band. There the terrain has its full detail (cells
//! of [`crate::SimConfig::terrain_cell_m`], every rock and small crater). Elsewhere the map is
//! rendered from a terrain with one cell per map pixel. Both are drawn in the world layout
//! ([`crate::terrain::FeatureLayout::World`]), so they share their relief, craters and rocks;
//! the coarse one lacks only what a map pixel cannot show (craters under 2 pixels, rocks under
//! half a pixel, whose sub-pixel texture is matched by a weaker per-cell grain). Across the
//! band (`BLEND_BAND_M` wide) the map radiance and heights fade from the detailed render to the
//! coarse one with a smoothstep, so no seam marks where the detail ends. Memory and time grow
//! with the patch and with the map's pixel count, never with the map area at the fine cell.

use rayon::prelude::*;

use jointloc_formats::Grid;

use crate::craters::smoothstep;
use crate::error::{Result, SimError};
use crate::terrain::Terrain;

/// Width of the band over which the detailed render fades into the coarse one, metres.
pub const BLEND_BAND_M: f64 = 16.0;
/// Largest map side, pixels (a 4 km map at 25 cm, or 800 m at 5 cm).
pub const MAX_MAP_SIDE_PX: u32 = 16_384;

/// Where the detailed patch lies in the map, in map pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Patch {
    /// Top-left pixel.
    pub x_px: u32,
    pub y_px: u32,
    /// Size, pixels.
    pub width_px: u32,
    pub height_px: u32,
    /// Blend band, pixels.
    pub band_px: u32,
}

impl Patch {
    /// Weight of the detailed render at patch pixel `(i, j)`: 0 on the patch border, 1 from
    /// the band's inner edge inwards.
    #[inline]
    pub fn weight(&self, i: usize, j: usize) -> f32 {
        let (w, h) = (self.width_px as f64, self.height_px as f64);
        let (u, v) = (i as f64 + 0.5, j as f64 + 0.5);
        let d = u.min(w - u).min(v).min(h - v);
        smoothstep(0.0, self.band_px.max(1) as f64, d) as f32
    }
}

/// Blends `detail` (the patch's pixels) into `coarse` (the whole map's) in place.
pub fn composite(coarse: &mut Grid<f32>, detail: &Grid<f32>, patch: &Patch) -> Result<()> {
    let fits = detail.width == patch.width_px as usize
        && detail.height == patch.height_px as usize
        && (patch.x_px + patch.width_px) as usize <= coarse.width
        && (patch.y_px + patch.height_px) as usize <= coarse.height;
    if !fits {
        return Err(SimError::InvalidConfig {
            field: "map_size_m",
            value: format!("{patch:?}"),
            reason: format!(
                "the detailed patch ({}x{}) must lie inside the map ({}x{})",
                detail.width, detail.height, coarse.width, coarse.height
            ),
        });
    }
    let (x0, y0, cw) = (patch.x_px as usize, patch.y_px as usize, coarse.width);
    coarse
        .data
        .par_chunks_mut(cw)
        .skip(y0)
        .take(detail.height)
        .enumerate()
        .for_each(|(j, row)| {
            for (i, c) in row[x0..x0 + detail.width].iter_mut().enumerate() {
                let w = patch.weight(i, j);
                *c = w * detail.at(i, j) + (1.0 - w) * *c;
            }
        });
    Ok(())
}

/// Mean height of each `factor × factor` block of the detailed terrain: its heights on the
/// map's pixel grid.
pub fn pixel_heights(terrain: &Terrain, factor: usize) -> Result<Grid<f32>> {
    crate::satellite::downsample_mean(&terrain.height, factor)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_detail_fades_in_across_the_band() {
        let patch = Patch {
            x_px: 10,
            y_px: 5,
            width_px: 40,
            height_px: 30,
            band_px: 8,
        };
        let mut coarse = Grid::filled(80, 60, 1.0f32);
        let detail = Grid::filled(40, 30, 3.0f32);
        composite(&mut coarse, &detail, &patch).unwrap();
        // Outside the patch: coarse; the patch centre: detail; monotone across the band.
        assert_eq!(coarse.at(5, 20), 1.0);
        assert_eq!(coarse.at(30, 20), 3.0);
        let row: Vec<f32> = (10..30).map(|c| coarse.at(c, 20)).collect();
        assert!(row.windows(2).all(|p| p[1] >= p[0]), "{row:?}");
        assert!(row[0] < 1.05 && row[0] >= 1.0);
        assert!(coarse.at(10 + 8, 20) == 3.0);
        let too_big = Grid::filled(41, 30, 0.0f32);
        assert!(composite(&mut coarse, &too_big, &patch).is_err());
    }
}
