//! XFeat's sparse extraction (`detectAndCompute`) on the dense network outputs, in Rust.
//!
//! Steps as in the reference: softmax over the 65 logits of each 8×8 cell, dustbin dropped,
//! pixel-shuffled to a full-resolution keypoint heatmap; 5×5 non-maximum suppression above the
//! detection threshold; score = keypoint heatmap (nearest) × reliability map (bilinear); top-k;
//! descriptors sampled bicubically from the L2-normalised dense features and normalised again;
//! positions scaled back to the original image. Sampling follows `InterpolateSparse2d`: a
//! position `x` on the network input is normalised with `2x / (W − 1) − 1` and then read by
//! `grid_sample(align_corners=False)` on the map, so it lands on map coordinate
//! `x / (W − 1) · w_map − 1/2`. The same f32 operations are used, so keypoints on the last row
//! or column drop out exactly as in the reference (their nearest read falls off the map: 0).

use crate::types::Features;

/// Dense outputs of the network on one input.
#[derive(Debug, Clone, PartialEq)]
pub struct XFeatDense {
    /// `64 × rows × cols` local features (not normalised), channel-major.
    pub feats: Vec<f32>,
    /// `65 × rows × cols` keypoint logits (64 cell positions + dustbin).
    pub keypoint_logits: Vec<f32>,
    /// `rows × cols` reliability map in (0, 1).
    pub heatmap: Vec<f32>,
    /// Columns of the maps (network input width / 8).
    pub cols: usize,
    /// Rows of the maps (network input height / 8).
    pub rows: usize,
}

/// Settings of the sparse extraction (a subset of [`super::XFeatConfig`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SparseParams {
    pub top_k: usize,
    pub detection_threshold: f32,
    pub nms_size: usize,
    /// Original width / network width.
    pub scale_x: f32,
    /// Original height / network height.
    pub scale_y: f32,
    /// `(width, height)` of the original image.
    pub image_size: (u32, u32),
}

/// Descriptor length.
pub const DIM: usize = 64;

/// Keypoints, scores and descriptors from the dense maps (see the module doc).
pub fn sparse(dense: &XFeatDense, p: &SparseParams) -> Features {
    let (cols, rows) = (dense.cols, dense.rows);
    let (width, height) = (cols * 8, rows * 8);
    let heat = keypoint_heatmap(&dense.keypoint_logits, cols, rows);
    let candidates = nms(&heat, width, height, p.detection_threshold, p.nms_size);

    let gx = Grid::new(width, cols);
    let gy = Grid::new(height, rows);
    let gx_full = Grid::new(width, width);
    let gy_full = Grid::new(height, height);
    let mut scored: Vec<(f32, usize, usize)> = candidates
        .into_iter()
        .map(|(x, y)| {
            let score = if x == 0 && y == 0 {
                // The reference pads its batch with (0, 0) and marks those invalid.
                -1.0
            } else {
                let k = nearest(&heat, width, height, gx_full.map(x), gy_full.map(y));
                let r = bilinear(&dense.heatmap, cols, rows, gx.map(x), gy.map(y));
                k * r
            };
            (score, x, y)
        })
        .collect();
    // Descending score; stable, so ties keep the raster order of the candidates.
    scored.sort_by(|a, b| b.0.total_cmp(&a.0));
    scored.truncate(p.top_k);
    scored.retain(|s| s.0 > 0.0);

    let normalised = normalised_pixels(&dense.feats, cols * rows);
    let mut descriptors = Vec::with_capacity(scored.len() * DIM);
    let mut keypoints = Vec::with_capacity(scored.len());
    let mut scores = Vec::with_capacity(scored.len());
    for &(score, x, y) in &scored {
        let start = descriptors.len();
        descriptors.resize(start + DIM, 0.0);
        bicubic(
            &normalised,
            cols,
            rows,
            gx.map(x),
            gy.map(y),
            &mut descriptors[start..],
        );
        l2_normalise(&mut descriptors[start..]);
        keypoints.push([x as f32 * p.scale_x, y as f32 * p.scale_y]);
        scores.push(score);
    }
    Features {
        keypoints,
        scores,
        descriptors,
        descriptor_dim: DIM,
        image_size: p.image_size,
    }
}

/// Full-resolution keypoint probability map (`rows·8 × cols·8`, row-major): softmax over the
/// 65 logits of each cell, the 64 non-dustbin channels laid out as the cell's 8×8 pixels.
pub fn keypoint_heatmap(logits: &[f32], cols: usize, rows: usize) -> Vec<f32> {
    let cells = cols * rows;
    let width = cols * 8;
    // Channel-major passes over contiguous planes (vectorisable), then one scatter.
    let mut max = logits[..cells].to_vec();
    for c in 1..65 {
        for (m, &l) in max.iter_mut().zip(&logits[c * cells..(c + 1) * cells]) {
            *m = m.max(l);
        }
    }
    let mut sum = vec![0.0f32; cells];
    let mut prob = vec![0.0f32; 64 * cells];
    for c in 0..65 {
        let plane = &logits[c * cells..(c + 1) * cells];
        if c < 64 {
            let out = &mut prob[c * cells..(c + 1) * cells];
            for i in 0..cells {
                let e = exp_non_positive(plane[i] - max[i]);
                out[i] = e;
                sum[i] += e;
            }
        } else {
            for i in 0..cells {
                sum[i] += exp_non_positive(plane[i] - max[i]);
            }
        }
    }
    let inv: Vec<f32> = sum.iter().map(|s| 1.0 / s).collect();
    let mut heat = vec![0.0f32; cells * 64];
    for (c, plane) in prob.chunks_exact(cells).enumerate() {
        let (ky, kx) = (c / 8, c % 8);
        for cy in 0..rows {
            let row = &mut heat[(cy * 8 + ky) * width..(cy * 8 + ky + 1) * width];
            for cx in 0..cols {
                let i = cy * cols + cx;
                row[cx * 8 + kx] = plane[i] * inv[i];
            }
        }
    }
    heat
}

/// `e^x` for `x ≤ 0` (softmax exponents after the max is subtracted), within 2 ulp of
/// `f32::exp`; branch-free (Cephes' `expf` polynomial, power of two from the exponent bits) so
/// loops over planes vectorise, where `f32::exp` is a library call per value.
#[inline]
fn exp_non_positive(x: f32) -> f32 {
    // Below −87.3 the result is subnormal or 0; clamping gives ≤ 1.7e−38 instead.
    let x = x.clamp(-87.0, 0.0);
    // Round to nearest by the 1.5·2^23 trick (no rounding instruction needed).
    const SHIFT: f32 = 12_582_912.0;
    let n = (x * std::f32::consts::LOG2_E + SHIFT) - SHIFT;
    let r = x - n * 0.693_359_4 - n * -2.121_944_4e-4;
    let mut p = 1.987_569_1e-4_f32;
    p = p * r + 1.398_199_9e-3;
    p = p * r + 8.333_452e-3;
    p = p * r + 4.166_579_6e-2;
    p = p * r + 1.666_666_5e-1;
    p = p * r + 0.5; // Cephes: 5.0000001201e-1, not representable beyond 0.5 in f32
    let e = p * r * r + r + 1.0;
    e * f32::from_bits(((n as i32 + 127) as u32) << 23)
}

/// Pixels `(x, y)` in raster order that exceed `threshold` and equal the maximum of their
/// `size × size` window (clipped at the border, as max pooling with −∞ padding).
pub fn nms(
    heat: &[f32],
    width: usize,
    height: usize,
    threshold: f32,
    size: usize,
) -> Vec<(usize, usize)> {
    let r = size / 2;
    // Separable: maxima over each pixel's horizontal run first (whole rows, vectorisable), then
    // only candidates look at the runs of the rows around them.
    let mut hmax = heat.to_vec();
    for (out, row) in hmax.chunks_exact_mut(width).zip(heat.chunks_exact(width)) {
        for d in 1..=r.min(width.saturating_sub(1)) {
            for (o, &v) in out[..width - d].iter_mut().zip(&row[d..]) {
                *o = o.max(v);
            }
            for (o, &v) in out[d..].iter_mut().zip(&row[..width - d]) {
                *o = o.max(v);
            }
        }
    }
    let mut out = Vec::new();
    for y in 0..height {
        let row = &heat[y * width..(y + 1) * width];
        let rows = y.saturating_sub(r)..(y + r + 1).min(height);
        for (c, chunk) in row.chunks(8).enumerate() {
            // Most 8-pixel runs hold nothing above the threshold: one max skips them.
            if chunk.iter().fold(f32::NEG_INFINITY, |m, &v| m.max(v)) <= threshold {
                continue;
            }
            for (dx, &v) in chunk.iter().enumerate() {
                let x = c * 8 + dx;
                if v > threshold && rows.clone().all(|yy| hmax[yy * width + x] <= v) {
                    out.push((x, y));
                }
            }
        }
    }
    out
}

/// Maps an integer position on the network input to a map coordinate as
/// `InterpolateSparse2d` + `grid_sample(align_corners=False)` do, in the same f32 steps.
#[derive(Debug, Clone, Copy)]
struct Grid {
    input_max: f32,
    half_map: f32,
}

impl Grid {
    fn new(input: usize, map: usize) -> Self {
        Self {
            input_max: (input - 1) as f32,
            half_map: map as f32 / 2.0,
        }
    }

    fn map(&self, v: usize) -> f32 {
        let g = 2.0 * (v as f32 / self.input_max) - 1.0;
        (g + 1.0) * self.half_map - 0.5
    }
}

fn at(map: &[f32], cols: usize, rows: usize, x: i64, y: i64) -> f32 {
    if x < 0 || y < 0 || x >= cols as i64 || y >= rows as i64 {
        0.0
    } else {
        map[y as usize * cols + x as usize]
    }
}

/// `grid_sample(mode='nearest', padding_mode='zeros')`: rounding half to even.
fn nearest(map: &[f32], cols: usize, rows: usize, x: f32, y: f32) -> f32 {
    at(
        map,
        cols,
        rows,
        x.round_ties_even() as i64,
        y.round_ties_even() as i64,
    )
}

/// `grid_sample(mode='bilinear', padding_mode='zeros')`.
fn bilinear(map: &[f32], cols: usize, rows: usize, x: f32, y: f32) -> f32 {
    let (x0, y0) = (x.floor(), y.floor());
    let (x1, y1) = (x0 + 1.0, y0 + 1.0);
    let (nw, ne) = ((x1 - x) * (y1 - y), (x - x0) * (y1 - y));
    let (sw, se) = ((x1 - x) * (y - y0), (x - x0) * (y - y0));
    let (xi, yi) = (x0 as i64, y0 as i64);
    at(map, cols, rows, xi, yi) * nw
        + at(map, cols, rows, xi + 1, yi) * ne
        + at(map, cols, rows, xi, yi + 1) * sw
        + at(map, cols, rows, xi + 1, yi + 1) * se
}

/// Cubic convolution weights (A = −0.75, PyTorch's bicubic) of the taps at −1, 0, 1, 2.
fn cubic_weights(t: f32) -> [f32; 4] {
    const A: f32 = -0.75;
    let outer = |x: f32| ((A * x - 5.0 * A) * x + 8.0 * A) * x - 4.0 * A;
    let inner = |x: f32| ((A + 2.0) * x - (A + 3.0)) * x * x + 1.0;
    [outer(t + 1.0), inner(t), inner(1.0 - t), outer(2.0 - t)]
}

/// `grid_sample(mode='bicubic', padding_mode='zeros')` of a pixel-major `rows × cols × 64`
/// map into `out`.
fn bicubic(map: &[f32], cols: usize, rows: usize, x: f32, y: f32, out: &mut [f32]) {
    let (x0, y0) = (x.floor(), y.floor());
    let wx = cubic_weights(x - x0);
    let wy = cubic_weights(y - y0);
    let (xi, yi) = (x0 as i64 - 1, y0 as i64 - 1);
    for (j, &wyj) in wy.iter().enumerate() {
        let yy = yi + j as i64;
        if yy < 0 || yy >= rows as i64 {
            continue;
        }
        for (i, &wxi) in wx.iter().enumerate() {
            let xx = xi + i as i64;
            if xx < 0 || xx >= cols as i64 {
                continue;
            }
            let w = wxi * wyj;
            let px = (yy as usize * cols + xx as usize) * DIM;
            for (o, &v) in out.iter_mut().zip(&map[px..px + DIM]) {
                *o += w * v;
            }
        }
    }
}

/// Channel-major `64 × pixels` features to pixel-major, each pixel L2-normalised
/// (`F.normalize(dim=1)`, eps 1e-12).
fn normalised_pixels(feats: &[f32], pixels: usize) -> Vec<f32> {
    let mut out = vec![0.0f32; pixels * DIM];
    for (c, plane) in feats.chunks_exact(pixels).enumerate() {
        for (p, &v) in plane.iter().enumerate() {
            out[p * DIM + c] = v;
        }
    }
    for px in out.chunks_exact_mut(DIM) {
        l2_normalise(px);
    }
    out
}

fn l2_normalise(v: &mut [f32]) {
    let norm = v.iter().map(|x| x * x).sum::<f32>().sqrt().max(1e-12);
    for x in v {
        *x /= norm;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn heatmap_puts_channel_ky_kx_at_pixel_ky_kx_of_its_cell() {
        let (cols, rows) = (2, 1);
        let mut logits = vec![0.0f32; 65 * cols * rows];
        // Cell (0, 1): channel 8 * 3 + 5 dominant → pixel (x = 8 + 5, y = 3).
        logits[(3 * 8 + 5) * 2 + 1] = 20.0;
        let heat = keypoint_heatmap(&logits, cols, rows);
        let width = 16;
        let (mx, at) = heat
            .iter()
            .enumerate()
            .fold((0.0, 0), |m, (i, &v)| if v > m.0 { (v, i) } else { m });
        assert_eq!((at % width, at / width), (13, 3));
        assert!(mx > 0.99);
        // Each cell's 64 probabilities plus the dustbin's sum to one.
        let cell0: f32 = (0..8)
            .flat_map(|y| (0..8).map(move |x| (x, y)))
            .map(|(x, y)| heat[y * width + x])
            .sum();
        assert!((cell0 - 64.0 / 65.0).abs() < 1e-5);
    }

    #[test]
    fn fast_exp_matches_the_library_exp() {
        let mut worst = 0.0f32;
        for i in 0..=200_000 {
            let x = -87.0 * i as f32 / 200_000.0;
            let (got, want) = (exp_non_positive(x), x.exp());
            worst = worst.max((got - want).abs() / want);
        }
        assert!(worst < 3e-7, "relative error {worst}");
        assert_eq!(exp_non_positive(0.0), 1.0);
        assert!(exp_non_positive(-1000.0) < 1e-37);
    }

    #[test]
    fn nms_keeps_window_maxima_above_threshold() {
        let (w, h) = (12, 10);
        let mut heat = vec![0.0f32; w * h];
        heat[2 * w + 2] = 0.5;
        heat[2 * w + 4] = 0.4; // within 2 px of a stronger one
        heat[2 * w + 8] = 0.3; // 4 px away: kept
        heat[9 * w + 11] = 0.04; // below threshold
        heat[7 * w] = 0.2; // on the border
        assert_eq!(nms(&heat, w, h, 0.05, 5), vec![(2, 2), (8, 2), (0, 7)]);
    }

    #[test]
    fn samplers_reproduce_grid_sample_on_simple_maps() {
        // A 4×4 map sampled at integer pixel centres returns the pixel; zeros outside.
        let map: Vec<f32> = (0..16).map(|v| v as f32).collect();
        assert_eq!(bilinear(&map, 4, 4, 1.0, 2.0), 9.0);
        assert_eq!(bilinear(&map, 4, 4, 1.5, 2.0), 9.5);
        assert_eq!(bilinear(&map, 4, 4, -0.5, 0.0), 0.0 * 0.5);
        assert_eq!(nearest(&map, 4, 4, 2.5, 0.0), 2.0);
        assert_eq!(nearest(&map, 4, 4, 3.5, 0.0), 0.0);
        // Cubic weights interpolate (1 at t = 0) and sum to one.
        assert_eq!(cubic_weights(0.0), [0.0, 1.0, 0.0, 0.0]);
        let s: f32 = cubic_weights(0.3).iter().sum();
        assert!((s - 1.0).abs() < 1e-6);
        // Symmetric at half a pixel (A = −0.75 gives −3/32 and 19/32).
        assert_eq!(cubic_weights(0.5), [-0.09375, 0.59375, 0.59375, -0.09375]);
        // Bicubic of a constant map is the constant inside and falls off outside (zeros).
        let ones = vec![1.0f32; 36 * DIM];
        let mut out = vec![0.0; DIM];
        bicubic(&ones, 6, 6, 2.25, 2.5, &mut out);
        assert!((out[0] - 1.0).abs() < 1e-6 && (out[63] - 1.0).abs() < 1e-6);
        let mut edge = vec![0.0; DIM];
        bicubic(&ones, 6, 6, -0.5, 2.0, &mut edge);
        assert!((edge[0] - 0.5).abs() < 1e-6, "{}", edge[0]);
    }

    #[test]
    fn last_row_and_column_fall_outside_as_in_the_reference() {
        let g = Grid::new(480, 480);
        assert_eq!(g.map(479).round_ties_even(), 480.0);
        assert_eq!(g.map(0).round_ties_even(), 0.0);
        assert_eq!(g.map(300).round_ties_even(), 300.0);
        let g8 = Grid::new(480, 60);
        assert!((g8.map(479) - 59.5).abs() < 1e-6);
    }
}
