//! Keypoint orientation by the intensity centroid (Rosin; ORB paper §3.2): the angle of the
//! vector from the keypoint to the centroid (m10, m01) of the grey values in a disc.

use std::f64::consts::TAU;

/// The disc `u² + v² ≤ r(r + 1)` (about radius r + ½), as half-widths per row.
#[derive(Debug, Clone, PartialEq)]
pub struct Circle {
    radius: usize,
    /// `u_max[|v|]`: largest |u| in row v.
    u_max: Vec<usize>,
}

impl Circle {
    pub fn new(radius: usize) -> Self {
        let r2 = (radius * (radius + 1)) as f64;
        let u_max = (0..=radius)
            .map(|v| (r2 - (v * v) as f64).max(0.0).sqrt().floor() as usize)
            .collect();
        Self { radius, u_max }
    }

    pub fn radius(&self) -> usize {
        self.radius
    }

    /// Orientation in [0, 2π) of the disc centred at (x, y); the disc must fit in the image.
    /// A flat patch (no centroid offset) gives 0. Moments fit in i32 for any radius ≤ 31
    /// (|m| ≤ 255 · Σ|u| < 2^31), which lets the row sums vectorise.
    pub fn angle(&self, img: &[u8], w: usize, x: usize, y: usize) -> f64 {
        let r = self.radius as isize;
        let (mut m10, mut m01) = (0i32, 0i32);
        for v in -r..=r {
            let um = self.u_max[v.unsigned_abs()] as isize;
            let row = (y as isize + v) as usize * w;
            let start = (row as isize + x as isize - um) as usize;
            let pixels = &img[start..start + 2 * um as usize + 1];
            let mut sum_row = 0i32;
            for (u, &p) in (-um as i32..).zip(pixels) {
                let p = p as i32;
                m10 += u * p;
                sum_row += p;
            }
            m01 += v as i32 * sum_row;
        }
        if m10 == 0 && m01 == 0 {
            return 0.0;
        }
        let a = (m01 as f64).atan2(m10 as f64);
        if a < 0.0 { a + TAU } else { a }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 41×41 patch with a bright blob at `angle` from the centre (radians, y down).
    fn blob_patch(angle: f64) -> Vec<u8> {
        let n = 41;
        let (bx, by) = (20.0 + 8.0 * angle.cos(), 20.0 + 8.0 * angle.sin());
        (0..n * n)
            .map(|i| {
                let (x, y) = ((i % n) as f64, (i / n) as f64);
                let d2 = (x - bx).powi(2) + (y - by).powi(2);
                (30.0 + 200.0 * (-d2 / 18.0).exp()) as u8
            })
            .collect()
    }

    #[test]
    fn angle_points_at_the_bright_side() {
        let c = Circle::new(15);
        for k in 0..16 {
            let want = k as f64 * TAU / 16.0 + 0.1;
            let got = c.angle(&blob_patch(want), 41, 20, 20);
            let err = (got - want + TAU / 2.0).rem_euclid(TAU) - TAU / 2.0;
            assert!(err.abs() < 0.03, "want {want} got {got}");
        }
    }

    #[test]
    fn disc_is_symmetric_and_flat_patches_give_zero() {
        let c = Circle::new(15);
        assert_eq!(c.u_max[0], 15);
        assert_eq!(c.u_max[15], 3);
        assert_eq!(c.angle(&[77u8; 41 * 41], 41, 20, 20), 0.0);
    }
}
