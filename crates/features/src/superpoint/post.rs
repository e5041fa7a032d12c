//! SuperPoint's standard sparse decoding (SuperGlue's / LightGlue's `superpoint.py`):
//! per-cell softmax without the dustbin, cells unfolded to a full-resolution score map,
//! iterated max-pool NMS, border removal, threshold, top-k, and bilinear descriptor sampling.

/// Full-resolution keypoint probabilities `(8·Hc) × (8·Wc)` from `65 × Hc × Wc` logits:
/// softmax over the 65 channels, dustbin dropped, channel `c` of a cell is its pixel
/// `(c / 8, c % 8)`.
pub(crate) fn score_map(logits: &[f32], cells_x: usize, cells_y: usize) -> Vec<f32> {
    let (w, plane) = (cells_x * 8, cells_x * cells_y);
    let mut out = vec![0.0f32; plane * 64];
    let mut e = [0.0f32; 65];
    for cy in 0..cells_y {
        for cx in 0..cells_x {
            let at = cy * cells_x + cx;
            let max = (0..65)
                .map(|c| logits[c * plane + at])
                .fold(f32::NEG_INFINITY, f32::max);
            let mut sum = 0.0f32;
            for (c, ec) in e.iter_mut().enumerate() {
                *ec = (logits[c * plane + at] - max).exp();
                sum += *ec;
            }
            for (c, ec) in e.iter().take(64).enumerate() {
                out[(cy * 8 + c / 8) * w + cx * 8 + c % 8] = ec / sum;
            }
        }
    }
    out
}

/// `max_pool2d(kernel 2r+1, stride 1, padding r)`: the maximum over the window clipped to the
/// map (PyTorch pads with −∞).
fn max_filter(src: &[f32], width: usize, height: usize, r: usize) -> Vec<f32> {
    let mut rows = vec![0.0f32; src.len()];
    for y in 0..height {
        let row = &src[y * width..(y + 1) * width];
        for x in 0..width {
            let (a, b) = (x.saturating_sub(r), (x + r).min(width - 1));
            rows[y * width + x] = row[a..=b].iter().copied().fold(f32::NEG_INFINITY, f32::max);
        }
    }
    // Columns: element-wise maxima of whole rows, which vectorises.
    let mut out = vec![0.0f32; src.len()];
    for y in 0..height {
        let (a, b) = (y.saturating_sub(r), (y + r).min(height - 1));
        let dst = &mut out[y * width..(y + 1) * width];
        dst.copy_from_slice(&rows[a * width..(a + 1) * width]);
        for yy in a + 1..=b {
            for (d, &v) in dst.iter_mut().zip(&rows[yy * width..(yy + 1) * width]) {
                *d = d.max(v);
            }
        }
    }
    out
}

/// SuperPoint's `simple_nms`: local maxima of the window, then twice more the maxima among
/// points not suppressed by an already kept one; other scores become 0.
pub(crate) fn simple_nms(scores: &[f32], width: usize, height: usize, radius: usize) -> Vec<f32> {
    let pooled = max_filter(scores, width, height, radius);
    let mut keep: Vec<bool> = scores.iter().zip(&pooled).map(|(s, m)| s == m).collect();
    for _ in 0..2 {
        let mask: Vec<f32> = keep.iter().map(|&k| if k { 1.0 } else { 0.0 }).collect();
        let suppressed: Vec<bool> = max_filter(&mask, width, height, radius)
            .iter()
            .map(|&v| v > 0.0)
            .collect();
        let rest: Vec<f32> = scores
            .iter()
            .zip(&suppressed)
            .map(|(&s, &sup)| if sup { 0.0 } else { s })
            .collect();
        let rest_max = max_filter(&rest, width, height, radius);
        for i in 0..keep.len() {
            keep[i] |= rest[i] == rest_max[i] && !suppressed[i];
        }
    }
    scores
        .iter()
        .zip(&keep)
        .map(|(&s, &k)| if k { s } else { 0.0 })
        .collect()
}

/// A detection: pixel and probability.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Peak {
    pub x: usize,
    pub y: usize,
    pub score: f32,
}

/// Scores above `threshold` after setting a `border`-pixel frame to −1, in raster order; then,
/// with `max`, the best `max` by descending score (ties in raster order).
pub(crate) fn select(
    nms: &[f32],
    width: usize,
    height: usize,
    border: usize,
    threshold: f32,
    max: Option<usize>,
) -> Vec<Peak> {
    let inside = |x: usize, y: usize| {
        x >= border && y >= border && x + border < width && y + border < height
    };
    let mut peaks: Vec<Peak> = (0..height)
        .flat_map(|y| (0..width).map(move |x| (x, y)))
        .filter_map(|(x, y)| {
            let score = if inside(x, y) {
                nms[y * width + x]
            } else {
                -1.0
            };
            (score > threshold).then_some(Peak { x, y, score })
        })
        .collect();
    if let Some(k) = max
        && k < peaks.len()
    {
        peaks.sort_by(|a, b| b.score.total_cmp(&a.score));
        peaks.truncate(k);
    }
    peaks
}

/// Descriptors at pixel positions from the `dim × Hc × Wc` dense map, as SuperGlue/LightGlue's
/// `sample_descriptors`: position `p` maps to cell coordinate `(p − 3.5)/(8·W − 4.5)·(W − 1)`
/// (its `align_corners=True` normalisation), bilinear with zeros outside, then L2-normalised.
pub(crate) fn sample_descriptors(
    dense: &[f32],
    cells_x: usize,
    cells_y: usize,
    dim: usize,
    points: &[[f32; 2]],
) -> Vec<f32> {
    let s = 8.0f32;
    let plane = cells_x * cells_y;
    let mut out = Vec::with_capacity(points.len() * dim);
    for p in points {
        let to_cell = |v: f32, n: usize| {
            let g = (v - s / 2.0 + 0.5) / (n as f32 * s - s / 2.0 - 0.5) * 2.0 - 1.0;
            (g + 1.0) / 2.0 * (n as f32 - 1.0)
        };
        let (ix, iy) = (to_cell(p[0], cells_x), to_cell(p[1], cells_y));
        let (x0, y0) = (ix.floor(), iy.floor());
        let (fx, fy) = (ix - x0, iy - y0);
        let mut taps = Vec::with_capacity(4);
        for (dy, wy) in [(0, 1.0 - fy), (1, fy)] {
            for (dx, wx) in [(0, 1.0 - fx), (1, fx)] {
                let (x, y) = (x0 as isize + dx, y0 as isize + dy);
                if x >= 0 && y >= 0 && (x as usize) < cells_x && (y as usize) < cells_y {
                    taps.push((y as usize * cells_x + x as usize, wx * wy));
                }
            }
        }
        let start = out.len();
        out.extend((0..dim).map(|c| {
            taps.iter()
                .map(|&(at, w)| w * dense[c * plane + at])
                .sum::<f32>()
        }));
        crate::disk::normalize_l2(&mut out[start..]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_unfold_row_major() {
        // One cell, logit 10 on channel 9 (pixel row 1, column 1).
        let mut logits = vec![0.0f32; 65];
        logits[9] = 10.0;
        let map = score_map(&logits, 1, 1);
        let best = (0..64).max_by(|&a, &b| map[a].total_cmp(&map[b])).unwrap();
        assert_eq!(best, 8 + 1);
        let total: f32 = map.iter().sum();
        let dustbin = 1.0 / (1.0 + 10f32.exp() + 63.0); // softmax share of channel 64
        assert!((total + dustbin - 1.0).abs() < 1e-5);
    }

    #[test]
    fn nms_keeps_separated_maxima_only() {
        let (w, h) = (20, 20);
        let mut s = vec![0.0f32; w * h];
        s[5 * w + 5] = 0.9;
        s[5 * w + 7] = 0.5; // within radius 4 of the stronger peak
        s[15 * w + 15] = 0.4;
        let out = simple_nms(&s, w, h, 4);
        let kept: Vec<usize> = (0..w * h).filter(|&i| out[i] > 0.0).collect();
        assert_eq!(kept, vec![5 * w + 5, 15 * w + 15]);
    }

    #[test]
    fn border_threshold_and_top_k() {
        let (w, h) = (16, 16);
        let mut s = vec![0.0f32; w * h];
        s[2 * w + 8] = 0.9; // in the 4-px border
        s[8 * w + 8] = 0.3;
        s[10 * w + 5] = 0.6;
        s[11 * w + 11] = 0.001; // below threshold
        let all = select(&s, w, h, 4, 0.005, None);
        assert_eq!(
            all.iter().map(|p| (p.x, p.y)).collect::<Vec<_>>(),
            vec![(8, 8), (5, 10)]
        );
        let best = select(&s, w, h, 4, 0.005, Some(1));
        assert_eq!(
            best,
            vec![Peak {
                x: 5,
                y: 10,
                score: 0.6
            }]
        );
    }

    #[test]
    fn sampling_at_a_cell_centre_reads_that_cell() {
        // 2 channels on 4×3 cells; cell (2, 1) holds (3, 4).
        let (cx, cy) = (4, 3);
        let mut dense = vec![0.0f32; 2 * cx * cy];
        dense[cx + 2] = 3.0;
        dense[cx * cy + cx + 2] = 4.0;
        // Pixel whose normalised coordinate lands exactly on cell (2, 1).
        let px = |c: f32, n: usize| c / (n as f32 - 1.0) * (8.0 * n as f32 - 4.5) + 3.5;
        let d = sample_descriptors(&dense, cx, cy, 2, &[[px(2.0, cx), px(1.0, cy)]]);
        assert!(
            (d[0] - 0.6).abs() < 1e-5 && (d[1] - 0.8).abs() < 1e-5,
            "{d:?}"
        );
    }
}
