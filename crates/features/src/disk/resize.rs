//! The reference extractor's resizing (LightGlue `ImagePreprocessor` → kornia `resize`): the
//! long side to a target length, a Gaussian blur first when shrinking, then bilinear
//! interpolation with PyTorch's half-pixel convention, all in f32 as PyTorch computes it.

/// Output `(height, width)` with the long side equal to `side` (kornia `side="long"`; the other
/// side truncated as Python's `int()` does).
pub(crate) fn target_size(height: usize, width: usize, side: usize) -> (usize, usize) {
    let aspect = width as f64 / height as f64;
    if aspect < 1.0 {
        (side, (side as f64 * aspect) as usize)
    } else {
        ((side as f64 / aspect) as usize, side)
    }
}

/// Resizes a row-major `height × width` plane to `out_h × out_w`.
pub(crate) fn resize(
    src: &[f32],
    height: usize,
    width: usize,
    out_h: usize,
    out_w: usize,
    antialias: bool,
) -> Vec<f32> {
    let (fy, fx) = (height as f64 / out_h as f64, width as f64 / out_w as f64);
    let blurred;
    let src = if antialias && fy.max(fx) > 1.0 {
        let sigma = |f: f64| ((f - 1.0) / 2.0).max(0.001);
        blurred = gaussian_blur(src, height, width, sigma(fy), sigma(fx));
        &blurred[..]
    } else {
        src
    };
    let ys = linear_taps(height, out_h);
    let xs = linear_taps(width, out_w);
    let mut out = Vec::with_capacity(out_h * out_w);
    for &(y0, y1, wy) in &ys {
        let (r0, r1) = (
            &src[y0 * width..(y0 + 1) * width],
            &src[y1 * width..(y1 + 1) * width],
        );
        for &(x0, x1, wx) in &xs {
            let top = (1.0 - wx) * r0[x0] + wx * r0[x1];
            let bottom = (1.0 - wx) * r1[x0] + wx * r1[x1];
            out.push((1.0 - wy) * top + wy * bottom);
        }
    }
    out
}

/// Source taps `(i0, i1, weight of i1)` of each output index (`align_corners=False`).
fn linear_taps(input: usize, output: usize) -> Vec<(usize, usize, f32)> {
    let scale = input as f32 / output as f32;
    (0..output)
        .map(|o| {
            let s = (scale * (o as f32 + 0.5) - 0.5).max(0.0);
            let i0 = (s as usize).min(input - 1);
            let i1 = if i0 + 1 < input { i0 + 1 } else { i0 };
            (i0, i1, (s - i0 as f32).clamp(0.0, 1.0))
        })
        .collect()
}

/// kornia's kernel size for a sigma: `int(max(4σ, 3))`, made odd.
fn kernel_size(sigma: f64) -> usize {
    let k = (4.0 * sigma).max(3.0) as usize;
    if k % 2 == 1 { k } else { k + 1 }
}

/// Normalised 1-D Gaussian of `size` taps centred on `size / 2`.
fn gaussian_kernel(size: usize, sigma: f64) -> Vec<f32> {
    let sigma = sigma as f32;
    let c = (size / 2) as f32;
    let g: Vec<f32> = (0..size)
        .map(|i| (-(i as f32 - c).powi(2) / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum: f32 = g.iter().sum();
    g.into_iter().map(|v| v / sum).collect()
}

/// Mirror index without repeating the edge (PyTorch `reflect` padding), for any offset.
fn reflect(i: isize, n: usize) -> usize {
    if n == 1 {
        return 0;
    }
    let period = 2 * (n as isize - 1);
    let m = i.rem_euclid(period);
    (if m < n as isize { m } else { period - m }) as usize
}

/// Separable Gaussian blur with reflected borders (kornia `gaussian_blur2d`).
fn gaussian_blur(src: &[f32], height: usize, width: usize, sigma_y: f64, sigma_x: f64) -> Vec<f32> {
    let kx = gaussian_kernel(kernel_size(sigma_x), sigma_x);
    let ky = gaussian_kernel(kernel_size(sigma_y), sigma_y);
    let (rx, ry) = ((kx.len() / 2) as isize, (ky.len() / 2) as isize);
    let mut tmp = vec![0.0f32; height * width];
    for y in 0..height {
        let row = &src[y * width..(y + 1) * width];
        for x in 0..width {
            tmp[y * width + x] = kx
                .iter()
                .enumerate()
                .map(|(k, w)| w * row[reflect(x as isize + k as isize - rx, width)])
                .sum();
        }
    }
    let mut out = vec![0.0f32; height * width];
    for y in 0..height {
        for (k, w) in ky.iter().enumerate() {
            let sy = reflect(y as isize + k as isize - ry, height);
            for x in 0..width {
                out[y * width + x] += w * tmp[sy * width + x];
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_side_target() {
        assert_eq!(target_size(500, 500, 1024), (1024, 1024));
        assert_eq!(target_size(480, 640, 1024), (768, 1024));
        assert_eq!(target_size(640, 480, 1024), (1024, 768));
    }

    #[test]
    fn doubling_interpolates_half_pixel_centres() {
        let src = [0.0, 1.0, 2.0, 3.0];
        let out = resize(&src, 1, 4, 1, 8, true);
        let expect = [0.0, 0.25, 0.75, 1.25, 1.75, 2.25, 2.75, 3.0];
        for (a, b) in out.iter().zip(expect) {
            assert!((a - b).abs() < 1e-6, "{out:?}");
        }
    }

    #[test]
    fn shrinking_a_constant_keeps_it() {
        let src = vec![0.7f32; 40 * 30];
        let out = resize(&src, 30, 40, 10, 13, true);
        assert!(out.iter().all(|v| (v - 0.7).abs() < 1e-5));
    }

    #[test]
    fn reflect_mirrors_without_edge_repeat() {
        let got: Vec<usize> = (-3..7).map(|i| reflect(i, 4)).collect();
        assert_eq!(got, vec![3, 2, 1, 0, 1, 2, 3, 2, 1, 0]);
    }
}
