//! Terrain synthesis: heightfield + albedo for the three Martian terrain kinds (crater, gravel,
//! mountain). (Synthesis in progress; the data contract below is fixed.)

use serde::{Deserialize, Serialize};

use crate::grid::Grid;

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
