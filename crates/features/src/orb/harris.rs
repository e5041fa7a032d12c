//! Harris corner response at a pixel: det(M) − k·trace(M)² of the structure tensor M summed
//! over a 7×7 block of Sobel gradients. Used to rank FAST corners (OpenCV's ORB ranking).

/// Harris sensitivity (the usual 0.04).
pub const HARRIS_K: f32 = 0.04;

/// Half side of the summation block (7×7).
const HALF_BLOCK: usize = 3;

/// Response at (x, y); the 7×7 block plus the Sobel support (radius 4 in all) must lie inside
/// the image, which keypoint borders of ≥ 4 px guarantee.
pub fn response(img: &[u8], w: usize, x: usize, y: usize, k: f32) -> f32 {
    debug_assert!(x > HALF_BLOCK && y > HALF_BLOCK);
    let (mut sxx, mut syy, mut sxy) = (0i64, 0i64, 0i64);
    for yy in y - HALF_BLOCK..=y + HALF_BLOCK {
        let up = &img[(yy - 1) * w..yy * w];
        let mid = &img[yy * w..(yy + 1) * w];
        let down = &img[(yy + 1) * w..(yy + 2) * w];
        for xx in x - HALF_BLOCK..=x + HALF_BLOCK {
            let p = |r: &[u8], i: usize| r[i] as i32;
            let gx = (p(up, xx + 1) - p(up, xx - 1))
                + 2 * (p(mid, xx + 1) - p(mid, xx - 1))
                + (p(down, xx + 1) - p(down, xx - 1));
            let gy = (p(down, xx - 1) - p(up, xx - 1))
                + 2 * (p(down, xx) - p(up, xx))
                + (p(down, xx + 1) - p(up, xx + 1));
            sxx += (gx * gx) as i64;
            syy += (gy * gy) as i64;
            sxy += (gx * gy) as i64;
        }
    }
    // Normalise as a mean over the block of gradients scaled to grey levels per pixel.
    let norm = 1.0 / (4.0 * 49.0 * 255.0);
    let (a, b, c) = (sxx as f64 * norm, syy as f64 * norm, sxy as f64 * norm);
    (a * b - c * c - k as f64 * (a + b) * (a + b)) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corner_beats_edge_beats_flat() {
        let w = 30;
        let mut img = vec![50u8; w * w];
        for y in 15..w {
            for x in 15..w {
                img[y * w + x] = 200;
            }
        }
        let corner = response(&img, w, 15, 15, HARRIS_K);
        let edge = response(&img, w, 15, 24, HARRIS_K);
        let flat = response(&img, w, 6, 6, HARRIS_K);
        assert!(corner > 0.0, "corner {corner}");
        assert!(edge < 0.0, "edge {edge}");
        assert_eq!(flat, 0.0);
    }
}
