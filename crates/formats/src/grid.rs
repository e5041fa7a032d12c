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
