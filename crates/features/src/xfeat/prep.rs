//! XFeat's input: the grey image scaled to [0, 1] and resized down to multiples of 32 with
//! PyTorch's `F.interpolate(mode='bilinear', align_corners=False)` (no antialiasing), as the
//! reference `preprocess_tensor` does; arithmetic in f32 in the same order as PyTorch's CPU
//! kernel so the network sees the same input to the last bits.

use crate::error::{FeaturesError, Result};

/// The smallest side XFeat accepts (its coarsest feature map is 1/32 of the input).
pub const MIN_SIDE: u32 = 32;

/// A network input and the factors that map its pixels back to the original image.
#[derive(Debug, Clone, PartialEq)]
pub struct Preprocessed {
    /// Row-major `height × width` grey values in [0, 1].
    pub data: Vec<f32>,
    /// Network input width (a multiple of 32).
    pub width: usize,
    /// Network input height (a multiple of 32).
    pub height: usize,
    /// Original width / network width (the reference's `rw`).
    pub scale_x: f32,
    /// Original height / network height (the reference's `rh`).
    pub scale_y: f32,
}

/// Scales `image` to [0, 1] and resizes it to `(w / 32 * 32, h / 32 * 32)`.
pub fn preprocess(image: &image::GrayImage) -> Result<Preprocessed> {
    let (w, h) = image.dimensions();
    if w < MIN_SIDE || h < MIN_SIDE {
        return Err(FeaturesError::InvalidInput(format!(
            "XFeat needs an image of at least {MIN_SIDE}×{MIN_SIDE} pixels, got {w}×{h}"
        )));
    }
    let (w, h) = (w as usize, h as usize);
    let (nw, nh) = (w / 32 * 32, h / 32 * 32);
    let grey: Vec<f32> = image
        .as_raw()
        .iter()
        .map(|&v| f32::from(v) / 255.0)
        .collect();
    let data = if (nw, nh) == (w, h) {
        grey
    } else {
        let xs = linear_taps(w, nw);
        let ys = linear_taps(h, nh);
        let mut out = Vec::with_capacity(nw * nh);
        for &(y0, y1, wy0, wy1) in &ys {
            let (r0, r1) = (&grey[y0 * w..(y0 + 1) * w], &grey[y1 * w..(y1 + 1) * w]);
            for &(x0, x1, wx0, wx1) in &xs {
                let top = r0[x0] * wx0 + r0[x1] * wx1;
                let bottom = r1[x0] * wx0 + r1[x1] * wx1;
                out.push(top * wy0 + bottom * wy1);
            }
        }
        out
    };
    Ok(Preprocessed {
        data,
        width: nw,
        height: nh,
        scale_x: (w as f64 / nw as f64) as f32,
        scale_y: (h as f64 / nh as f64) as f32,
    })
}

/// Source taps `(i0, i1, w0, w1)` of each output index of a 1-D linear resize, half-pixel
/// centres, negative source positions clamped to 0 (PyTorch's `area_pixel_compute_source_index`).
fn linear_taps(input: usize, output: usize) -> Vec<(usize, usize, f32, f32)> {
    let scale = input as f32 / output as f32;
    (0..output)
        .map(|i| {
            let src = (scale * (i as f32 + 0.5) - 0.5).max(0.0);
            let i0 = (src.floor() as usize).min(input - 1);
            let lambda = (src - i0 as f32).clamp(0.0, 1.0);
            let i1 = if i0 < input - 1 { i0 + 1 } else { i0 };
            (i0, i1, 1.0 - lambda, lambda)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn multiples_of_32_pass_through_and_small_images_are_refused() {
        let img = image::GrayImage::from_fn(64, 32, |x, y| image::Luma([(x + y) as u8]));
        let p = preprocess(&img).unwrap();
        assert_eq!(
            (p.width, p.height, p.scale_x, p.scale_y),
            (64, 32, 1.0, 1.0)
        );
        assert_eq!(p.data[65], 2.0 / 255.0);
        for (w, h) in [(31, 100), (100, 31), (0, 0)] {
            let err = preprocess(&image::GrayImage::new(w, h)).unwrap_err();
            assert!(matches!(err, FeaturesError::InvalidInput(_)), "{err}");
        }
    }

    #[test]
    fn a_linear_ramp_stays_linear_inside() {
        // Bilinear resampling reproduces an affine image exactly away from the clamped border.
        let img = image::GrayImage::from_fn(100, 40, |x, _| image::Luma([(2 * x) as u8]));
        let p = preprocess(&img).unwrap();
        assert_eq!((p.width, p.height), (96, 32));
        for (i, &v) in p.data[..96].iter().enumerate().skip(1).take(94) {
            let src = (100.0 / 96.0) * (i as f32 + 0.5) - 0.5;
            assert!((v - 2.0 * src / 255.0).abs() < 1e-5, "{i}: {v}");
        }
    }
}
