//! DKD, ALIKED's differentiable keypoint detection, at inference: iterated simple NMS, border
//! removal, threshold (or top-k) selection, soft-argmax sub-pixel refinement in the
//! `(2r+1)²` window (temperature 0.1) and scores read bilinearly at the refined positions.

/// Softmax temperature of the sub-pixel refinement (the reference's tuned value).
const TEMPERATURE: f32 = 0.1;
/// Keypoint cap of threshold mode when no maximum is configured (the reference's `n_limit_max`).
pub(crate) const N_LIMIT_MAX: usize = 20_000;

/// How keypoints are selected among the NMS maxima.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Selection {
    /// Scores above `threshold` (or above the map's mean if none is), best `limit` kept.
    Threshold { threshold: f32, limit: usize },
    /// The `k` best NMS values, whatever they are.
    TopK(usize),
}

/// Detected keypoints in the reference's normalised coordinates (`x/(w−1)·2 − 1`), with scores.
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct Detections {
    pub normalised: Vec<[f32; 2]>,
    pub scores: Vec<f32>,
}

/// Sliding-window maximum over `(2r+1)²` with out-of-map cells ignored (`max_pool2d` with its
/// implicit −∞ padding), separable.
fn max_filter(src: &[f32], h: usize, w: usize, r: usize) -> Vec<f32> {
    let mut rows = vec![0.0f32; h * w];
    for y in 0..h {
        let row = &src[y * w..(y + 1) * w];
        for x in 0..w {
            let (a, b) = (x.saturating_sub(r), (x + r).min(w - 1));
            rows[y * w + x] = row[a..=b].iter().copied().fold(f32::NEG_INFINITY, f32::max);
        }
    }
    let mut out = vec![f32::NEG_INFINITY; h * w];
    for y in 0..h {
        let (a, b) = (y.saturating_sub(r), (y + r).min(h - 1));
        for yy in a..=b {
            let (o, s) = (&mut out[y * w..(y + 1) * w], &rows[yy * w..(yy + 1) * w]);
            for (o, &s) in o.iter_mut().zip(s) {
                *o = o.max(s);
            }
        }
    }
    out
}

/// The reference `simple_nms`: maxima, then twice: suppress around them and add the maxima of
/// what is left outside the suppressed zones. Returns the scores at maxima, 0 elsewhere.
fn simple_nms(scores: &[f32], h: usize, w: usize, r: usize) -> Vec<f32> {
    let pooled = max_filter(scores, h, w, r);
    let mut max_mask: Vec<bool> = scores.iter().zip(&pooled).map(|(s, m)| s == m).collect();
    for _ in 0..2 {
        let as_f32: Vec<f32> = max_mask.iter().map(|&m| f32::from(u8::from(m))).collect();
        let supp: Vec<bool> = max_filter(&as_f32, h, w, r)
            .into_iter()
            .map(|v| v > 0.0)
            .collect();
        let supp_scores: Vec<f32> = scores
            .iter()
            .zip(&supp)
            .map(|(&s, &sup)| if sup { 0.0 } else { s })
            .collect();
        let pooled = max_filter(&supp_scores, h, w, r);
        for i in 0..h * w {
            max_mask[i] |= supp_scores[i] == pooled[i] && !supp[i];
        }
    }
    scores
        .iter()
        .zip(&max_mask)
        .map(|(&s, &m)| if m { s } else { 0.0 })
        .collect()
}

/// Bilinear sample at pixel `(x, y)`, zero outside (`grid_sample`, zeros padding).
pub(crate) fn bilinear_zero(map: &[f32], h: usize, w: usize, x: f32, y: f32) -> f32 {
    let (x0, y0) = (x.floor(), y.floor());
    let (lx, ly) = (x - x0, y - y0);
    let (x0, y0) = (x0 as i64, y0 as i64);
    let at = |xi: i64, yi: i64| -> f32 {
        if xi < 0 || yi < 0 || xi >= w as i64 || yi >= h as i64 {
            0.0
        } else {
            map[yi as usize * w + xi as usize]
        }
    };
    at(x0, y0) * (1.0 - lx) * (1.0 - ly)
        + at(x0 + 1, y0) * lx * (1.0 - ly)
        + at(x0, y0 + 1) * (1.0 - lx) * ly
        + at(x0 + 1, y0 + 1) * lx * ly
}

/// Runs DKD on an `h × w` score map (row-major).
pub(crate) fn detect(scores: &[f32], h: usize, w: usize, r: usize, sel: Selection) -> Detections {
    let mut nms = simple_nms(scores, h, w, r);
    for y in 0..h {
        for x in 0..w {
            if y < r || x < r || y + r >= h || x + r >= w {
                nms[y * w + x] = 0.0;
            }
        }
    }
    let indices: Vec<usize> = match sel {
        Selection::Threshold { threshold, limit } => {
            let above = |th: f32| -> Vec<usize> { (0..h * w).filter(|&i| nms[i] > th).collect() };
            let mut idx = if threshold > 0.0 {
                above(threshold)
            } else {
                Vec::new()
            };
            if idx.is_empty() {
                let mean = (scores.iter().map(|&v| f64::from(v)).sum::<f64>() / scores.len() as f64)
                    as f32;
                idx = above(mean);
            }
            if idx.len() > limit {
                idx.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]));
                idx.truncate(limit);
            }
            idx
        }
        Selection::TopK(k) => {
            let mut idx: Vec<usize> = (0..h * w).collect();
            idx.sort_by(|&a, &b| nms[b].total_cmp(&nms[a]));
            idx.truncate(k.min(h * w));
            idx
        }
    };

    let (wm1, hm1) = ((w - 1) as f32, (h - 1) as f32);
    let side = 2 * r + 1;
    let mut out = Detections::default();
    let mut window = vec![0.0f32; side * side];
    for &i in &indices {
        let (cx, cy) = ((i % w) as i64, (i / w) as i64);
        for (k, v) in window.iter_mut().enumerate() {
            let (yy, xx) = (
                cy + (k / side) as i64 - r as i64,
                cx + (k % side) as i64 - r as i64,
            );
            *v = if yy < 0 || xx < 0 || yy >= h as i64 || xx >= w as i64 {
                0.0
            } else {
                scores[yy as usize * w + xx as usize]
            };
        }
        let max = window.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        let (mut sum, mut sx, mut sy) = (0.0f32, 0.0f32, 0.0f32);
        for (k, &v) in window.iter().enumerate() {
            let e = ((v - max) / TEMPERATURE).exp();
            sum += e;
            sx += e * ((k % side) as f32 - r as f32);
            sy += e * ((k / side) as f32 - r as f32);
        }
        let kx = cx as f32 + sx / sum;
        let ky = cy as f32 + sy / sum;
        let n = [kx / wm1 * 2.0 - 1.0, ky / hm1 * 2.0 - 1.0];
        let (px, py) = ((n[0] + 1.0) / 2.0 * wm1, (n[1] + 1.0) / 2.0 * hm1);
        out.scores.push(bilinear_zero(scores, h, w, px, py));
        out.normalised.push(n);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn blob(h: usize, w: usize, peaks: &[(f32, f32, f32)]) -> Vec<f32> {
        let mut m = vec![0.0f32; h * w];
        for y in 0..h {
            for x in 0..w {
                for &(px, py, a) in peaks {
                    let d2 = (x as f32 - px).powi(2) + (y as f32 - py).powi(2);
                    m[y * w + x] = m[y * w + x].max(a * (-d2 / 2.0).exp());
                }
            }
        }
        m
    }

    fn to_px(d: &Detections, h: usize, w: usize) -> Vec<[f32; 2]> {
        d.normalised
            .iter()
            .map(|n| {
                [
                    (n[0] + 1.0) / 2.0 * (w - 1) as f32,
                    (n[1] + 1.0) / 2.0 * (h - 1) as f32,
                ]
            })
            .collect()
    }

    #[test]
    fn symmetric_peaks_are_found_at_their_centres_with_their_scores() {
        let (h, w) = (40, 50);
        let map = blob(h, w, &[(10.0, 12.0, 0.9), (30.0, 25.0, 0.6)]);
        let sel = Selection::Threshold {
            threshold: 0.2,
            limit: 100,
        };
        let d = detect(&map, h, w, 2, sel);
        let px = to_px(&d, h, w);
        assert_eq!(px.len(), 2);
        // Raster order when under the limit.
        assert!((px[0][0] - 10.0).abs() < 1e-4 && (px[0][1] - 12.0).abs() < 1e-4);
        assert!((px[1][0] - 30.0).abs() < 1e-4 && (px[1][1] - 25.0).abs() < 1e-4);
        assert!((d.scores[0] - 0.9).abs() < 1e-4 && (d.scores[1] - 0.6).abs() < 1e-4);
    }

    #[test]
    fn off_grid_peak_is_refined_towards_its_true_position() {
        let (h, w) = (30, 30);
        for (tx, ty) in [(12.3f32, 14.6f32), (15.8, 9.2), (7.4, 20.1)] {
            let map = blob(h, w, &[(tx, ty, 0.8)]);
            let sel = Selection::Threshold {
                threshold: 0.2,
                limit: 10,
            };
            let px = to_px(&detect(&map, h, w, 2, sel), h, w);
            assert_eq!(px.len(), 1);
            let (ix, iy) = (tx.round(), ty.round());
            // Soft-argmax moves from the integer maximum towards the true centre.
            assert!(
                (px[0][0] - tx).abs() < (ix - tx).abs() + 1e-3,
                "{px:?} vs {tx}"
            );
            assert!(
                (px[0][1] - ty).abs() < (iy - ty).abs() + 1e-3,
                "{px:?} vs {ty}"
            );
        }
    }

    #[test]
    fn close_maxima_are_suppressed_and_limit_keeps_the_best() {
        let (h, w) = (20, 40);
        let mut map = vec![0.0f32; h * w];
        map[10 * w + 10] = 0.9;
        map[10 * w + 12] = 0.8; // within radius 2 of a better one: suppressed
        map[10 * w + 20] = 0.5;
        map[10 * w + 30] = 0.7;
        map[w + 5] = 0.95; // in the removed border
        let d = detect(
            &map,
            h,
            w,
            2,
            Selection::Threshold {
                threshold: 0.2,
                limit: 2,
            },
        );
        // The 0.9 peak is pulled towards its suppressed 0.8 neighbour by the soft-argmax.
        let px = to_px(&d, h, w);
        assert_eq!(px.len(), 2);
        // Window: 0.9 at 0, 0.8 at +2, 23 zeros (weights e^0, e^-1, e^-9).
        let (e1, e9) = ((-1.0f32).exp(), (-9.0f32).exp());
        let expected = 10.0 + 2.0 * e1 / (1.0 + e1 + 23.0 * e9);
        assert!((px[0][0] - expected).abs() < 1e-3, "{px:?}");
        assert!((px[1][0] - 30.0).abs() < 1e-3, "{px:?}");
        let top = detect(&map, h, w, 2, Selection::TopK(1));
        assert_eq!(top.normalised.len(), 1);
        assert!((to_px(&top, h, w)[0][0] - expected).abs() < 1e-3);
    }

    #[test]
    fn empty_threshold_falls_back_to_the_mean() {
        let (h, w) = (20, 20);
        let map = blob(h, w, &[(10.0, 10.0, 0.1)]);
        let d = detect(
            &map,
            h,
            w,
            2,
            Selection::Threshold {
                threshold: 0.2,
                limit: 10,
            },
        );
        assert_eq!(d.normalised.len(), 1);
    }
}
