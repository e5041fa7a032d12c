//! LightGlue's data-dependent control, in Rust between the layer graphs: the per-layer
//! confidence thresholds, the early-stop test (adaptive depth), the point-pruning mask
//! (adaptive width) and the mutual-match filter on the final assignment.
//!
//! Comparisons are done in `f32` with the thresholds rounded to `f32` first, as the reference
//! does (its thresholds live in a float32 buffer and Python scalars meet float32 tensors), so
//! points on a threshold fall on the same side.

/// Token-confidence threshold of layer `layer` out of `n_layers`:
/// `clip(0.8 + 0.1·exp(-4·layer / n_layers), 0, 1)`, high early and relaxing with depth.
pub fn confidence_threshold(layer: usize, n_layers: usize) -> f32 {
    let t = 0.8 + 0.1 * (-4.0 * layer as f64 / n_layers.max(1) as f64).exp();
    t.clamp(0.0, 1.0) as f32
}

/// Adaptive depth: stop when the fraction of confident points exceeds `depth_confidence`.
///
/// `token0`/`token1` are the confidences of the points still present; `num_points` is the
/// number of points of both images *before* pruning (the reference divides by it, so pruned
/// points count as confident).
pub fn should_stop(
    token0: &[f32],
    token1: &[f32],
    threshold: f32,
    num_points: usize,
    depth_confidence: f64,
) -> bool {
    if num_points == 0 {
        return true;
    }
    let unconfident = token0
        .iter()
        .chain(token1)
        .filter(|&&c| c < threshold)
        .count();
    let ratio_confident = 1.0f32 - unconfident as f32 / num_points as f32;
    ratio_confident > depth_confidence as f32
}

/// Adaptive width: which points to keep after a layer. A point stays when its matchability
/// exceeds `1 - width_confidence`, or (with early stopping on, so `token` is given) when its
/// token confidence is at most the layer's threshold: unsure points are never pruned.
pub fn keep_mask(
    matchability: &[f32],
    token: Option<&[f32]>,
    threshold: f32,
    width_confidence: f64,
) -> Vec<bool> {
    let min_match = (1.0 - width_confidence) as f32;
    matchability
        .iter()
        .enumerate()
        .map(|(i, &s)| s > min_match || token.is_some_and(|t| t[i] <= threshold))
        .collect()
}

/// One accepted correspondence: rows of the final (pruned) sets and its probability.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RawMatch {
    pub i: usize,
    pub j: usize,
    pub score: f32,
}

/// Mutual best matches of the log-assignment matrix whose probability exceeds `threshold`.
///
/// `max0[i]`/`arg0[i]` are the best log score and column of row `i`, `arg1[j]` the best row
/// of column `j` (dustbins excluded). Output is sorted by `i`. Returns `None` when an index is
/// out of range (a malformed engine output).
pub fn filter_matches(
    max0: &[f32],
    arg0: &[i64],
    arg1: &[i64],
    threshold: f64,
) -> Option<Vec<RawMatch>> {
    let (m, n) = (arg0.len(), arg1.len());
    if max0.len() != m {
        return None;
    }
    let th = threshold as f32;
    let mut out = Vec::new();
    for (i, (&j, &v)) in arg0.iter().zip(max0).enumerate() {
        let j = usize::try_from(j).ok().filter(|&j| j < n)?;
        let back = usize::try_from(arg1[j]).ok().filter(|&b| b < m)?;
        if back != i {
            continue;
        }
        let score = v.exp();
        if score > th {
            out.push(RawMatch { i, j, score });
        }
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn threshold_schedule_matches_the_formula() {
        // 0.8 + 0.1·exp(-4i/9) for the 9-layer models.
        let expected = [0.9f32, 0.864_118_8, 0.841_111_2, 0.826_359_6, 0.816_901_2];
        for (i, e) in expected.iter().enumerate() {
            assert!((confidence_threshold(i, 9) - e).abs() < 1e-6, "layer {i}");
        }
        for i in 1..9 {
            assert!(confidence_threshold(i, 9) < confidence_threshold(i - 1, 9));
        }
    }

    #[test]
    fn stop_counts_pruned_points_as_confident() {
        let th = 0.9;
        // 2 of 4 present points are unsure; with 4 points in total that is 50 % confident...
        let t0 = [0.95, 0.5];
        let t1 = [0.99, 0.1];
        assert!(!should_stop(&t0, &t1, th, 4, 0.95));
        // ...but if 36 more points had been pruned before, 38 of 40 are confident (95 %),
        // which is not *more* than 0.95; with 41 it is.
        assert!(!should_stop(&t0, &t1, th, 40, 0.95));
        assert!(should_stop(&t0, &t1, th, 41, 0.95));
    }

    #[test]
    fn pruning_keeps_matchable_or_unsure_points() {
        let matchability = [0.5, 0.001, 0.001, 0.02];
        let token = [0.99, 0.99, 0.5, 0.99];
        assert_eq!(
            keep_mask(&matchability, Some(&token), 0.9, 0.99),
            [true, false, true, true]
        );
        assert_eq!(
            keep_mask(&matchability, None, 0.9, 0.99),
            [true, false, false, true]
        );
    }

    #[test]
    fn filter_keeps_mutual_matches_above_threshold() {
        // Row 0 ↔ col 1 mutual and confident; row 1 → col 1 but col 1 → row 0 (not mutual);
        // row 2 ↔ col 0 mutual but below threshold.
        let max0 = [0.9f32.ln(), 0.8f32.ln(), 0.05f32.ln()];
        let arg0 = [1, 1, 0];
        let arg1 = [2, 0];
        let m = filter_matches(&max0, &arg0, &arg1, 0.1).unwrap();
        assert_eq!(m.len(), 1);
        assert_eq!((m[0].i, m[0].j), (0, 1));
        assert!((m[0].score - 0.9).abs() < 1e-6);
        assert!(filter_matches(&max0, &[5, 1, 0], &arg1, 0.1).is_none());
    }
}
