//! A dense row-major 2-D grid: the storage of the elevation model here, and of the simulator's
//! heightfields, albedo and radiance.

/// Row-major grid: `data[row * width + col]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Grid<T> {
    pub width: usize,
    pub height: usize,
    pub data: Vec<T>,
}

impl<T: Copy> Grid<T> {
    /// A grid filled with `value`.
    pub fn filled(width: usize, height: usize, value: T) -> Self {
        Self {
            width,
            height,
            data: vec![value; width * height],
        }
    }

    /// Value at column `col`, row `row` (panics when out of range, like slice indexing).
    #[inline]
    pub fn at(&self, col: usize, row: usize) -> T {
        self.data[row * self.width + col]
    }

    /// Mutable reference at column `col`, row `row`.
    #[inline]
    pub fn at_mut(&mut self, col: usize, row: usize) -> &mut T {
        &mut self.data[row * self.width + col]
    }

    /// A copy of the `width × height` window at top-left `(x, y)` (must lie inside).
    pub fn window(&self, x: usize, y: usize, width: usize, height: usize) -> Self {
        let mut data = Vec::with_capacity(width * height);
        for r in y..y + height {
            data.extend_from_slice(&self.data[r * self.width + x..r * self.width + x + width]);
        }
        Self {
            width,
            height,
            data,
        }
    }
}

impl Grid<f32> {
    /// Bilinear sample at fractional (col, row), clamped to the border.
    #[inline]
    pub fn bilinear(&self, col: f64, row: f64) -> f32 {
        let c = col.clamp(0.0, (self.width - 1) as f64);
        let r = row.clamp(0.0, (self.height - 1) as f64);
        let (c0, r0) = (c.floor() as usize, r.floor() as usize);
        let (c1, r1) = ((c0 + 1).min(self.width - 1), (r0 + 1).min(self.height - 1));
        let (fc, fr) = ((c - c0 as f64) as f32, (r - r0 as f64) as f32);
        let top = self.at(c0, r0) * (1.0 - fc) + self.at(c1, r0) * fc;
        let bottom = self.at(c0, r1) * (1.0 - fc) + self.at(c1, r1) * fc;
        top * (1.0 - fr) + bottom * fr
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn window_copies_the_rectangle() {
        let mut g = Grid::filled(5, 4, 0u8);
        for (k, v) in g.data.iter_mut().enumerate() {
            *v = k as u8;
        }
        let c = g.window(1, 2, 3, 2);
        assert_eq!(c.data, vec![11, 12, 13, 16, 17, 18]);
    }
}
