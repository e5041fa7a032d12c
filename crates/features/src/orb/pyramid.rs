//! Image pyramid: each level is the previous one resized by 1/scale_factor (bilinear, pixel
//! centres aligned, as ORB-SLAM2 builds it), plus a 7×7 Gaussian (σ = 2) blurred copy that the
//! BRIEF tests sample.

use super::GrayImageView;

/// One pyramid level.
#[derive(Debug, Clone)]
pub struct PyramidLevel {
    pub width: usize,
    pub height: usize,
    /// Grey values, row-major.
    pub image: Vec<u8>,
    /// `image` blurred by a 7×7 Gaussian of σ = 2 (reflect-101 borders).
    pub blurred: Vec<u8>,
    /// Nominal scale relative to level 0 (`scale_factor^level`).
    pub scale: f64,
    /// Exact level-0 pixels per level pixel along x and y (sizes are rounded per level).
    pub scale_x: f64,
    pub scale_y: f64,
}

impl PyramidLevel {
    /// Level-0 coordinates of a level pixel (pixel centres at integers).
    pub fn to_level0(&self, x: f64, y: f64) -> (f64, f64) {
        (
            (x + 0.5) * self.scale_x - 0.5,
            (y + 0.5) * self.scale_y - 0.5,
        )
    }
}

/// The levels that are at least `min_side` pixels on each side.
#[derive(Debug, Clone)]
pub struct ImagePyramid {
    pub levels: Vec<PyramidLevel>,
}

impl ImagePyramid {
    /// Builds up to `n_levels` levels; stops early at the first level smaller than
    /// `min_side` on a side. Level 0 must already satisfy it (the caller checks).
    pub fn build(
        image: GrayImageView<'_>,
        scale_factor: f64,
        n_levels: usize,
        min_side: usize,
    ) -> Self {
        let (w0, h0) = (image.width(), image.height());
        let mut levels: Vec<PyramidLevel> = Vec::with_capacity(n_levels);
        let mut scale = 1.0;
        for li in 0..n_levels {
            let level = if li == 0 {
                let data = image.data().to_vec();
                make_level(data, w0, h0, 1.0, 1.0, 1.0)
            } else {
                scale *= scale_factor;
                let w = (w0 as f64 / scale).round() as usize;
                let h = (h0 as f64 / scale).round() as usize;
                if w < min_side || h < min_side {
                    break;
                }
                let prev = &levels[li - 1];
                let data = resize_bilinear(&prev.image, prev.width, prev.height, w, h);
                make_level(
                    data,
                    w,
                    h,
                    scale,
                    w0 as f64 / w as f64,
                    h0 as f64 / h as f64,
                )
            };
            levels.push(level);
        }
        Self { levels }
    }
}

fn make_level(
    image: Vec<u8>,
    width: usize,
    height: usize,
    scale: f64,
    scale_x: f64,
    scale_y: f64,
) -> PyramidLevel {
    let blurred = gaussian_blur_7x7(&image, width, height);
    PyramidLevel {
        width,
        height,
        image,
        blurred,
        scale,
        scale_x,
        scale_y,
    }
}

/// Bilinear resize with pixel centres aligned: destination pixel `d` samples the source at
/// `(d + 0.5) · src/dst − 0.5`, clamped to the image.
pub fn resize_bilinear(src: &[u8], sw: usize, sh: usize, dw: usize, dh: usize) -> Vec<u8> {
    // Fixed point with 11 fractional bits: exact enough for 8-bit data, and integer-only.
    const SHIFT: u32 = 11;
    const ONE: i32 = 1 << SHIFT;
    let axis = |s: usize, d: usize| -> Vec<(usize, usize, i32)> {
        let ratio = s as f64 / d as f64;
        (0..d)
            .map(|i| {
                let f = ((i as f64 + 0.5) * ratio - 0.5).clamp(0.0, (s - 1) as f64);
                let i0 = f.floor() as usize;
                let i1 = (i0 + 1).min(s - 1);
                let w1 = ((f - i0 as f64) * ONE as f64).round() as i32;
                (i0, i1, w1)
            })
            .collect()
    };
    let xs = axis(sw, dw);
    let ys = axis(sh, dh);
    // Horizontal pass once per source row (rows are shared by neighbouring output rows).
    let mut horiz = vec![0i32; sh * dw];
    let mut done = vec![false; sh];
    for &(y0, y1, _) in &ys {
        for y in [y0, y1] {
            if done[y] {
                continue;
            }
            done[y] = true;
            let r = &src[y * sw..(y + 1) * sw];
            for (h, &(x0, x1, wx)) in horiz[y * dw..(y + 1) * dw].iter_mut().zip(&xs) {
                *h = r[x0] as i32 * (ONE - wx) + r[x1] as i32 * wx;
            }
        }
    }
    let mut out = vec![0u8; dw * dh];
    // In i32 (vectorises, unlike i64): a, b ≤ 255 · 2^11, so the sum is ≤ 255 · 2^22 + 2^21
    // < 2^31, and the result is the same.
    let half = 1i32 << (2 * SHIFT - 1);
    for (dy, &(y0, y1, wy)) in ys.iter().enumerate() {
        let row0 = &horiz[y0 * dw..(y0 + 1) * dw];
        let row1 = &horiz[y1 * dw..(y1 + 1) * dw];
        let dst = &mut out[dy * dw..(dy + 1) * dw];
        for (o, (&a, &b)) in dst.iter_mut().zip(row0.iter().zip(row1)) {
            let v = (a * (ONE - wy) + b * wy + half) >> (2 * SHIFT);
            *o = v.clamp(0, 255) as u8;
        }
    }
    out
}

/// Reflect-101 index (…, 2, 1, 0, 1, 2, …) for offsets up to the image size.
#[inline]
fn reflect101(i: isize, n: usize) -> usize {
    let n = n as isize;
    if n == 1 {
        return 0;
    }
    let mut i = i;
    if i < 0 {
        i = -i;
    }
    if i >= n {
        i = 2 * n - 2 - i;
    }
    i.clamp(0, n - 1) as usize
}

/// The 7-tap Gaussian of σ = 2, normalised.
fn gaussian_taps() -> [f32; 7] {
    let w: [f64; 7] = std::array::from_fn(|i| {
        let d = i as f64 - 3.0;
        (-d * d / 8.0).exp()
    });
    let s: f64 = w.iter().sum();
    std::array::from_fn(|i| (w[i] / s) as f32)
}

/// Separable 7×7 Gaussian blur (σ = 2), reflect-101 borders, rounded to u8. Whole-row f32
/// multiply-adds, which vectorise on any x86-64.
pub fn gaussian_blur_7x7(src: &[u8], w: usize, h: usize) -> Vec<u8> {
    let taps = gaussian_taps();
    let mut tmp = vec![0f32; w * h];
    let mut padded = vec![0f32; w + 6];
    for y in 0..h {
        let row = &src[y * w..(y + 1) * w];
        for (i, p) in padded.iter_mut().enumerate() {
            *p = row[reflect101(i as isize - 3, w)] as f32;
        }
        let out = &mut tmp[y * w..(y + 1) * w];
        out.iter_mut().for_each(|o| *o = 0.0);
        for (k, &tap) in taps.iter().enumerate() {
            for (o, &p) in out.iter_mut().zip(&padded[k..k + w]) {
                *o += tap * p;
            }
        }
    }
    let mut out = vec![0u8; w * h];
    let mut acc = vec![0f32; w];
    for y in 0..h {
        acc.iter_mut().for_each(|a| *a = 0.0);
        for (k, &tap) in taps.iter().enumerate() {
            let r = reflect101(y as isize + k as isize - 3, h);
            for (a, &v) in acc.iter_mut().zip(&tmp[r * w..(r + 1) * w]) {
                *a += tap * v;
            }
        }
        for (d, &a) in out[y * w..(y + 1) * w].iter_mut().zip(&acc) {
            // Values are ≥ 0; adding 0.5 and truncating rounds half up.
            *d = (a + 0.5).min(255.0) as u8;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blur_keeps_constant_images_and_smooths_an_impulse() {
        let (w, h) = (20, 15);
        let flat = vec![123u8; w * h];
        assert!(gaussian_blur_7x7(&flat, w, h).iter().all(|&v| v == 123));
        let mut imp = vec![0u8; w * h];
        imp[7 * w + 10] = 255;
        let b = gaussian_blur_7x7(&imp, w, h);
        // Peak is the squared centre tap (≈ 0.2^2 · 255 ≈ 10), symmetric around the impulse.
        let c = b[7 * w + 10];
        assert!((8..=13).contains(&c), "centre {c}");
        assert_eq!(b[7 * w + 9], b[7 * w + 11]);
        assert_eq!(b[6 * w + 10], b[8 * w + 10]);
        assert_eq!(b[7 * w + 14], 0);
    }

    #[test]
    fn resize_of_a_ramp_is_a_ramp_at_aligned_centres() {
        let (sw, sh) = (120, 10);
        let src: Vec<u8> = (0..sh)
            .flat_map(|_| (0..sw).map(|x| (x * 2) as u8))
            .collect();
        let (dw, dh) = (100, 8);
        let dst = resize_bilinear(&src, sw, sh, dw, dh);
        for x in 5..dw - 5 {
            let f = (x as f64 + 0.5) * 1.2 - 0.5;
            let want = 2.0 * f;
            let got = dst[3 * dw + x] as f64;
            assert!((got - want).abs() <= 0.51, "x {x}: {got} vs {want}");
        }
    }

    #[test]
    fn pyramid_levels_shrink_by_the_scale_factor() {
        let data = vec![50u8; 500 * 400];
        let img = GrayImageView::new(500, 400, &data).unwrap();
        let p = ImagePyramid::build(img, 1.2, 8, 33);
        assert_eq!(p.levels.len(), 8);
        assert_eq!((p.levels[1].width, p.levels[1].height), (417, 333));
        assert_eq!((p.levels[7].width, p.levels[7].height), (140, 112));
        let (x, y) = p.levels[7].to_level0(69.5, 55.5);
        assert!((x - 249.5).abs() < 1e-9 && (y - 199.5).abs() < 1e-9);
        // Too small levels are dropped.
        let p = ImagePyramid::build(img, 1.2, 8, 300);
        assert_eq!(p.levels.len(), 2);
    }
}
