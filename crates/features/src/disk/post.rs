//! DISK's inference-time detection (kornia `heatmap_to_keypoints`): strict local maxima of the
//! heatmap, a score threshold, and the `n` best kept in raster order.

/// A detection on the network's pixel grid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Peak {
    pub x: usize,
    pub y: usize,
    /// Heatmap value (log-probability of keeping the point).
    pub logp: f32,
}

/// Pixels strictly greater than every other pixel of their `window × window` neighbourhood and
/// above `threshold`, in raster order.
///
/// For windows 3, 5 and 7 the reference compares shifted slices, so pixels closer than
/// `window / 2` to the border are never maxima; for other sizes it pads by replication, which
/// this reproduces by clamping neighbour coordinates.
pub(crate) fn peaks(
    heat: &[f32],
    width: usize,
    height: usize,
    window: usize,
    threshold: f32,
) -> Vec<Peak> {
    let r = window / 2;
    let inner_only = matches!(window, 3 | 5 | 7);
    let mut out = Vec::new();
    for y in 0..height {
        for x in 0..width {
            if inner_only && (x < r || y < r || x + r >= width || y + r >= height) {
                continue;
            }
            let v = heat[y * width + x];
            if v.is_nan() || v <= threshold {
                continue;
            }
            let mut is_max = true;
            'window: for dy in 0..window {
                let yy = (y + dy).saturating_sub(r).min(height - 1);
                for dx in 0..window {
                    if dy == r && dx == r {
                        continue;
                    }
                    let xx = (x + dx).saturating_sub(r).min(width - 1);
                    if v <= heat[yy * width + xx] {
                        is_max = false;
                        break 'window;
                    }
                }
            }
            if is_max {
                out.push(Peak { x, y, logp: v });
            }
        }
    }
    out
}

/// Keeps at most `n` peaks as the reference does: those strictly above the `(n+1)`-th largest
/// score (so ties at the cut are all dropped, and with `n` or fewer candidates the smallest one
/// is dropped too), then the first `n` in raster order.
pub(crate) fn keep_best(mut peaks: Vec<Peak>, n: Option<usize>) -> Vec<Peak> {
    let Some(n) = n else {
        return peaks;
    };
    if peaks.is_empty() {
        return peaks;
    }
    let k = (n + 1).min(peaks.len());
    let mut scores: Vec<f32> = peaks.iter().map(|p| p.logp).collect();
    // k-th largest = element k-1 in descending order.
    let (_, cut, _) = scores.select_nth_unstable_by(k - 1, |a, b| b.total_cmp(a));
    let cut = *cut;
    peaks.retain(|p| p.logp > cut);
    peaks.truncate(n);
    peaks
}

/// L2-normalised descriptors (`F.normalize`, eps 1e-12) read at the peaks' pixels from a
/// channel-major `dim × height × width` map.
pub(crate) fn gather_descriptors(
    dense: &[f32],
    width: usize,
    height: usize,
    dim: usize,
    peaks: &[Peak],
) -> Vec<f32> {
    let plane = width * height;
    let mut out = Vec::with_capacity(peaks.len() * dim);
    for p in peaks {
        let at = p.y * width + p.x;
        let start = out.len();
        out.extend((0..dim).map(|c| dense[c * plane + at]));
        normalize(&mut out[start..]);
    }
    out
}

/// `x / max(‖x‖, 1e-12)`.
pub(crate) fn normalize(v: &mut [f32]) {
    let norm = v.iter().map(|a| a * a).sum::<f32>().sqrt().max(1e-12);
    v.iter_mut().for_each(|a| *a /= norm);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strict_maxima_skip_plateaus_and_borders() {
        let (w, h) = (9, 9);
        let mut heat = vec![0.0f32; w * h];
        heat[4 * w + 4] = 2.0; // a clear peak
        heat[w + 1] = 5.0; // inside the 2-px border: never a 5×5 maximum
        heat[6 * w + 2] = 1.0; // a plateau of two: neither is strict
        heat[6 * w + 3] = 1.0;
        let p = peaks(&heat, w, h, 5, 0.0);
        assert_eq!(
            p,
            vec![Peak {
                x: 4,
                y: 4,
                logp: 2.0
            }]
        );
    }

    #[test]
    fn best_n_follow_the_kthvalue_rule() {
        let mk = |v: &[f32]| -> Vec<Peak> {
            v.iter()
                .enumerate()
                .map(|(i, &logp)| Peak { x: i, y: 0, logp })
                .collect()
        };
        let all = mk(&[3.0, 1.0, 4.0, 1.5, 5.0]);
        let xs = |p: Vec<Peak>| p.iter().map(|p| p.x).collect::<Vec<_>>();
        assert_eq!(xs(keep_best(all.clone(), Some(2))), vec![2, 4]);
        // Fewer candidates than n: the smallest is dropped, as in the reference.
        assert_eq!(xs(keep_best(all.clone(), Some(10))), vec![0, 2, 3, 4]);
        assert_eq!(xs(keep_best(all.clone(), None)), vec![0, 1, 2, 3, 4]);
        assert!(keep_best(Vec::new(), Some(3)).is_empty());
    }
}
