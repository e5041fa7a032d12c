//! Pre-processing as LightGlue's extractor does it for ALIKED: kornia `resize` (long side to a
//! target, Gaussian blur first when shrinking, bilinear with PyTorch's half-pixel convention),
//! then the reference `InputPadder` (replicate padding to a multiple of 32, split evenly with
//! the odd pixel at the bottom/right).

/// Output `(height, width)` with the long side equal to `side` (kornia `side="long"`, the other
/// side truncated like Python's `int()`).
pub(crate) fn target_size(height: usize, width: usize, side: usize) -> (usize, usize) {
    let aspect = width as f64 / height as f64;
    if aspect < 1.0 {
        (side, (side as f64 * aspect) as usize)
    } else {
        ((side as f64 / aspect) as usize, side)
    }
}

/// Resizes a row-major plane to `out_h × out_w`; `antialias` blurs before shrinking.
pub(crate) fn resize(
    src: &[f32],
    h: usize,
    w: usize,
    out_h: usize,
    out_w: usize,
    antialias: bool,
) -> Vec<f32> {
    if (out_h, out_w) == (h, w) {
        return src.to_vec();
    }
    let (fy, fx) = (h as f64 / out_h as f64, w as f64 / out_w as f64);
    let blurred;
    let src = if antialias && fy.max(fx) > 1.0 {
        blurred = blur(src, h, w, fy, fx);
        &blurred[..]
    } else {
        src
    };
    let ys = taps(h, out_h);
    let xs = taps(w, out_w);
    let mut out = Vec::with_capacity(out_h * out_w);
    for &(y0, y1, ly) in &ys {
        let (r0, r1) = (&src[y0 * w..(y0 + 1) * w], &src[y1 * w..(y1 + 1) * w]);
        for &(x0, x1, lx) in &xs {
            let top = (1.0 - lx) * r0[x0] + lx * r0[x1];
            let bottom = (1.0 - lx) * r1[x0] + lx * r1[x1];
            out.push((1.0 - ly) * top + ly * bottom);
        }
    }
    out
}

/// `(i0, i1, weight of i1)` per output index, `align_corners=False` (source clamped at 0).
fn taps(input: usize, output: usize) -> Vec<(usize, usize, f32)> {
    let scale = input as f32 / output as f32;
    (0..output)
        .map(|o| {
            let s = (scale * (o as f32 + 0.5) - 0.5).max(0.0);
            let i0 = (s as usize).min(input - 1);
            let i1 = (i0 + 1).min(input - 1);
            (i0, i1, s - i0 as f32)
        })
        .collect()
}

/// kornia's anti-aliasing blur: σ = max((factor − 1)/2, 0.001) per axis, kernel size
/// int(max(4σ, 3)) made odd, normalised Gaussian, reflect borders, separable.
fn blur(src: &[f32], h: usize, w: usize, fy: f64, fx: f64) -> Vec<f32> {
    let kernel = |f: f64| {
        let sigma = ((f - 1.0) / 2.0).max(0.001);
        let mut ks = (4.0 * sigma).max(3.0) as usize;
        if ks.is_multiple_of(2) {
            ks += 1;
        }
        let half = (ks / 2) as f64;
        let g: Vec<f64> = (0..ks)
            .map(|i| (-(i as f64 - half).powi(2) / (2.0 * sigma * sigma)).exp())
            .collect();
        let sum: f64 = g.iter().sum();
        g.into_iter()
            .map(|v| (v / sum) as f32)
            .collect::<Vec<f32>>()
    };
    let reflect = |i: isize, n: usize| -> usize {
        let n = n as isize;
        let mut i = i;
        if n == 1 {
            return 0;
        }
        // Mirror without repeating the edge, folded until inside (kernels may exceed n).
        loop {
            if i < 0 {
                i = -i;
            } else if i >= n {
                i = 2 * (n - 1) - i;
            } else {
                return i as usize;
            }
        }
    };
    let (ky, kx) = (kernel(fy), kernel(fx));
    let (ry, rx) = ((ky.len() / 2) as isize, (kx.len() / 2) as isize);
    let mut tmp = vec![0.0f32; h * w];
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for (j, &k) in kx.iter().enumerate() {
                s += k * src[y * w + reflect(x as isize + j as isize - rx, w)];
            }
            tmp[y * w + x] = s;
        }
    }
    let mut out = vec![0.0f32; h * w];
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for (j, &k) in ky.iter().enumerate() {
                s += k * tmp[reflect(y as isize + j as isize - ry, h) * w + x];
            }
            out[y * w + x] = s;
        }
    }
    out
}

/// Replicate padding to multiples of `div`, as the reference `InputPadder`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Padding {
    /// Unpadded size.
    pub h: usize,
    pub w: usize,
    /// Padded size.
    pub hp: usize,
    pub wp: usize,
    /// Rows added above and columns added to the left.
    pub top: usize,
    pub left: usize,
}

impl Padding {
    pub(crate) fn new(h: usize, w: usize, div: usize) -> Self {
        let (hp, wp) = (h.next_multiple_of(div), w.next_multiple_of(div));
        Self {
            h,
            w,
            hp,
            wp,
            top: (hp - h) / 2,
            left: (wp - w) / 2,
        }
    }

    /// The padded plane (edge pixels repeated).
    pub(crate) fn pad(&self, src: &[f32]) -> Vec<f32> {
        let mut out = Vec::with_capacity(self.hp * self.wp);
        for yp in 0..self.hp {
            let y = yp.saturating_sub(self.top).min(self.h - 1);
            let row = &src[y * self.w..(y + 1) * self.w];
            for xp in 0..self.wp {
                out.push(row[xp.saturating_sub(self.left).min(self.w - 1)]);
            }
        }
        out
    }

    /// The unpadded window of a padded plane.
    pub(crate) fn crop(&self, padded: &[f32]) -> Vec<f32> {
        let mut out = Vec::with_capacity(self.h * self.w);
        for y in 0..self.h {
            let start = (y + self.top) * self.wp + self.left;
            out.extend_from_slice(&padded[start..start + self.w]);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_side_sizes_truncate_like_python() {
        assert_eq!(target_size(500, 500, 1024), (1024, 1024));
        assert_eq!(target_size(480, 640, 1024), (768, 1024));
        assert_eq!(target_size(700, 300, 1024), (1024, 438));
    }

    #[test]
    fn upscaling_keeps_constants_and_ramps() {
        let (h, w) = (5, 7);
        let ramp: Vec<f32> = (0..h * w).map(|i| (i % w) as f32).collect();
        let out = resize(&ramp, h, w, 10, 14, true);
        // Interior samples of a linear ramp stay on the ramp: x_src = (x + 0.5)/2 − 0.5.
        for x in 1..13 {
            let want = ((x as f32 + 0.5) / 2.0 - 0.5).clamp(0.0, 6.0);
            assert!((out[3 * 14 + x] - want).abs() < 1e-5, "x {x}");
        }
        let flat = resize(&[0.25; 35], h, w, 3, 4, true);
        assert!(flat.iter().all(|v| (v - 0.25).abs() < 1e-6));
    }

    #[test]
    fn padding_is_centred_and_replicates_edges() {
        let p = Padding::new(30, 33, 32);
        assert_eq!((p.hp, p.wp, p.top, p.left), (32, 64, 1, 15));
        let src: Vec<f32> = (0..30 * 33).map(|i| i as f32).collect();
        let padded = p.pad(&src);
        assert_eq!(padded[0], 0.0);
        assert_eq!(padded[63], 32.0);
        assert_eq!(padded[31 * 64 + 20], src[29 * 33 + 5]);
        assert_eq!(p.crop(&padded), src);
    }
}
