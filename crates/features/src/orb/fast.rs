//! FAST-9 corners (Rosten & Drummond): a pixel is a corner at threshold `t` when 9 contiguous
//! pixels of the radius-3 Bresenham circle are all brighter than centre + t or all darker than
//! centre − t. Detection in cells as ORB-SLAM2: each cell keeps its corners at the initial
//! threshold, or, when it has none, those at the minimum threshold.
//!
//! The score of a corner is the largest `t` for which it is still a corner, plus one
//! (`max over arcs of the smallest |difference| on the arc`), so a corner at `t` has score > t.
//! One pass at the minimum threshold therefore serves both thresholds, and a 3×3 non-maximum
//! suppression on that score picks the same corners at either threshold.

/// The 16 circle offsets (dx, dy), clockwise from 12 o'clock (y down).
pub const CIRCLE: [(isize, isize); 16] = [
    (0, -3),
    (1, -3),
    (2, -2),
    (3, -1),
    (3, 0),
    (3, 1),
    (2, 2),
    (1, 3),
    (0, 3),
    (-1, 3),
    (-2, 2),
    (-3, 1),
    (-3, 0),
    (-3, -1),
    (-2, -2),
    (-1, -3),
];

/// A corner after non-maximum suppression, in level pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Corner {
    pub x: u32,
    pub y: u32,
    /// FAST score (> threshold it was accepted at).
    pub score: u8,
}

/// True when the 16-bit circular mask has 9 contiguous set bits (FAST-9).
#[inline]
fn has_arc(mask: u32) -> bool {
    let m = mask | (mask << 16);
    let r2 = m & (m >> 1);
    let r4 = r2 & (r2 >> 2);
    let r8 = r4 & (r4 >> 4);
    let r9 = r8 & (m >> 8);
    r9 & 0xFFFF != 0
}

/// FAST score of a pixel known to be a corner: max over arcs and both polarities of the
/// smallest signed difference along the arc. Sliding minima/maxima over the doubled circle
/// (windows of 2, 4, 8, then 9) in fixed-size arrays, which the compiler vectorises.
#[inline]
fn score_of(d: &[i16; 16]) -> u8 {
    let mut e = [0i16; 32];
    e[..16].copy_from_slice(d);
    e[16..].copy_from_slice(d);
    let (mut mn2, mut mx2) = ([0i16; 24], [0i16; 24]);
    for i in 0..24 {
        mn2[i] = e[i].min(e[i + 1]);
        mx2[i] = e[i].max(e[i + 1]);
    }
    let (mut mn4, mut mx4) = ([0i16; 20], [0i16; 20]);
    for i in 0..20 {
        mn4[i] = mn2[i].min(mn2[i + 2]);
        mx4[i] = mx2[i].max(mx2[i + 2]);
    }
    let (mut bright, mut dark) = (i16::MIN, i16::MAX);
    for i in 0..16 {
        let mn9 = mn4[i].min(mn4[i + 4]).min(e[i + 8]);
        let mx9 = mx4[i].max(mx4[i + 4]).max(e[i + 8]);
        bright = bright.max(mn9);
        dark = dark.min(mx9);
    }
    bright.max(-dark).clamp(0, 255) as u8
}

/// Score map of FAST-9 corners at threshold `t` for centres in `[border, w - border)` ×
/// `[border, h - border)`; 0 elsewhere and at non-corners. `border` must be ≥ 3.
pub fn score_map(img: &[u8], w: usize, h: usize, border: usize, t: u8) -> Vec<u8> {
    debug_assert!(border >= 3);
    let mut scores = vec![0u8; w * h];
    if w <= 2 * border || h <= 2 * border {
        return scores;
    }
    let rect = Rect {
        x0: border,
        x1: w - border,
        y0: border,
        y1: h - border,
    };
    score_rect(img, w, rect, t, &mut scores);
    scores
}

/// A pixel rectangle, end-exclusive.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Rect {
    x0: usize,
    x1: usize,
    y0: usize,
    y1: usize,
}

/// Writes the FAST-9 scores at threshold `t` of the centres in `r` (at least 3 px inside the
/// image) into `scores` (0 at non-corners); pixels outside `r` are left alone.
fn score_rect(img: &[u8], w: usize, r: Rect, t: u8, scores: &mut [u8]) {
    if r.x1 <= r.x0 || r.y1 <= r.y0 {
        return;
    }
    let offs: [isize; 16] = std::array::from_fn(|k| CIRCLE[k].1 * w as isize + CIRCLE[k].0);
    let n = r.x1 - r.x0;
    let mut flags = vec![0u8; n];
    let t8 = t;
    for y in r.y0..r.y1 {
        let start = y * w + r.x0;
        scores[start..start + n].fill(0);
        // Branch-free pre-test over the whole row (vectorised): an arc of 9 contains two
        // consecutive compass points (0, 4, 8, 12), both brighter or both darker.
        {
            let centre = &img[start..start + n];
            let ring = |k: usize| {
                let o = (start as isize + offs[k]) as usize;
                &img[o..o + n]
            };
            let (r0, r4, r8, r12) = (ring(0), ring(4), ring(8), ring(12));
            for x in 0..n {
                let c = centre[x];
                let (hi, lo) = (c.saturating_add(t8), c.saturating_sub(t8));
                let (p0, p4, p8, p12) = (r0[x], r4[x], r8[x], r12[x]);
                let (b0, b4, b8, b12) = (p0 > hi, p4 > hi, p8 > hi, p12 > hi);
                let (d0, d4, d8, d12) = (p0 < lo, p4 < lo, p8 < lo, p12 < lo);
                let bright = (b0 & b4) | (b4 & b8) | (b8 & b12) | (b12 & b0);
                let dark = (d0 & d4) | (d4 & d8) | (d8 & d12) | (d12 & d0);
                flags[x] = (bright | dark) as u8;
            }
        }
        for (xo, &f) in flags.iter().enumerate() {
            if f == 0 {
                continue;
            }
            let i = start + xo;
            let c = img[i] as i16;
            let d: [i16; 16] =
                std::array::from_fn(|k| img[(i as isize + offs[k]) as usize] as i16 - c);
            let t = t8 as i16;
            let (mut mb, mut md) = (0u32, 0u32);
            for (k, &v) in d.iter().enumerate() {
                mb |= ((v > t) as u32) << k;
                md |= ((v < -t) as u32) << k;
            }
            if has_arc(mb) || has_arc(md) {
                scores[i] = score_of(&d).max(1);
            }
        }
    }
}

/// Non-maximum suppression in 3×3: keeps a non-zero score that is strictly greater than its
/// earlier (raster-order) neighbours and not smaller than its later ones, so plateaus keep
/// exactly their first pixel.
fn is_local_max(scores: &[u8], w: usize, x: usize, y: usize) -> bool {
    let i = y * w + x;
    let s = scores[i];
    if s == 0 {
        return false;
    }
    let before = [i - w - 1, i - w, i - w + 1, i - 1];
    let after = [i + 1, i + w - 1, i + w, i + w + 1];
    before.iter().all(|&j| s > scores[j]) && after.iter().all(|&j| s >= scores[j])
}

/// Corners of one level detected per cell: cells of about `cell_size` px tile the region
/// `[border, w - border)` × `[border, h - border)`; a cell keeps its local maxima scoring
/// above `ini_th`, or, if it has none, those above `min_th`.
///
/// Scores are computed at `ini_th` over the whole region, and at `min_th` only in (and one
/// pixel around) the cells that need the fallback: most pixels of a textured image pass the
/// low threshold's pre-test, few pass the high one's. The result equals one pass at `min_th`
/// (a score above `ini_th` beats any neighbour at or below it under either map).
pub fn detect_in_cells(
    img: &[u8],
    w: usize,
    h: usize,
    border: usize,
    cell_size: usize,
    ini_th: u8,
    min_th: u8,
) -> Vec<Corner> {
    if w <= 2 * border + 2 || h <= 2 * border + 2 {
        return Vec::new();
    }
    let scores = score_map(img, w, h, border, ini_th);
    let mut fallback: Vec<u8> = Vec::new();
    let (rw, rh) = (w - 2 * border, h - 2 * border);
    let n_cols = (rw / cell_size).max(1);
    let n_rows = (rh / cell_size).max(1);
    let cw = rw.div_ceil(n_cols);
    let ch = rh.div_ceil(n_rows);
    let mut out = Vec::new();
    for r in 0..n_rows {
        let y0 = border + r * ch;
        let y1 = (y0 + ch).min(h - border);
        for c in 0..n_cols {
            let x0 = border + c * cw;
            let x1 = (x0 + cw).min(w - border);
            let before = out.len();
            collect_maxima(&scores, w, x0..x1, y0..y1, &mut out);
            if out.len() > before || ini_th == min_th {
                continue;
            }
            if fallback.is_empty() {
                fallback = vec![0u8; w * h];
            }
            let rect = Rect {
                x0: x0.saturating_sub(1).max(border),
                x1: (x1 + 1).min(w - border),
                y0: y0.saturating_sub(1).max(border),
                y1: (y1 + 1).min(h - border),
            };
            score_rect(img, w, rect, min_th, &mut fallback);
            collect_maxima(&fallback, w, x0..x1, y0..y1, &mut out);
        }
    }
    out
}

/// Appends the local maxima of `scores` in the given pixel ranges.
fn collect_maxima(
    scores: &[u8],
    w: usize,
    xs: std::ops::Range<usize>,
    ys: std::ops::Range<usize>,
    out: &mut Vec<Corner>,
) {
    for y in ys {
        for x in xs.clone() {
            if is_local_max(scores, w, x, y) {
                out.push(Corner {
                    x: x as u32,
                    y: y as u32,
                    score: scores[y * w + x],
                });
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute-force reference: corner at t iff some arc of 9 is all > t or all < −t.
    fn is_corner_reference(img: &[u8], w: usize, x: usize, y: usize, t: i16) -> bool {
        let c = img[y * w + x] as i16;
        let v: Vec<i16> = CIRCLE
            .iter()
            .map(|&(dx, dy)| {
                img[(y as isize + dy) as usize * w + (x as isize + dx) as usize] as i16 - c
            })
            .collect();
        (0..16).any(|s| (0..9).all(|k| v[(s + k) % 16] > t))
            || (0..16).any(|s| (0..9).all(|k| v[(s + k) % 16] < -t))
    }

    fn square_image(w: usize, h: usize) -> Vec<u8> {
        // A bright square on a dark background: its 4 corners are FAST corners.
        let mut img = vec![40u8; w * h];
        for y in 20..40 {
            for x in 20..40 {
                img[y * w + x] = 200;
            }
        }
        img
    }

    #[test]
    fn corners_of_a_square_are_found_and_edges_are_not() {
        let (w, h) = (60, 60);
        let img = square_image(w, h);
        let corners = detect_in_cells(&img, w, h, 4, 30, 20, 7);
        let pos: Vec<(u32, u32)> = corners.iter().map(|c| (c.x, c.y)).collect();
        // One detection within 2 px of each of the four corners (an ideal square gives small
        // plateaus of equal score; the first pixel in raster order is kept), nothing elsewhere.
        for &(cx, cy) in &[(20, 20), (39, 20), (20, 39), (39, 39)] {
            assert!(
                pos.iter()
                    .any(|&(x, y)| (x as i32 - cx).abs() <= 2 && (y as i32 - cy).abs() <= 2),
                "corner ({cx}, {cy}) missing in {pos:?}"
            );
        }
        assert_eq!(corners.len(), 4, "{pos:?}");
        // Straight edges are not corners.
        let scores = score_map(&img, w, h, 4, 7);
        assert_eq!(scores[30 * w + 20], 0);
        assert_eq!(scores[20 * w + 30], 0);
    }

    #[test]
    fn score_map_agrees_with_brute_force_on_noise() {
        // Random texture: every pixel's classification and the score's threshold semantics.
        let (w, h) = (48, 40);
        let mut s = 12345u64;
        let img: Vec<u8> = (0..w * h)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (s >> 56) as u8
            })
            .collect();
        for &t in &[7u8, 20, 40] {
            let scores = score_map(&img, w, h, 3, t);
            for y in 3..h - 3 {
                for x in 3..w - 3 {
                    let want = is_corner_reference(&img, w, x, y, t as i16);
                    let sc = scores[y * w + x];
                    assert_eq!(sc > 0, want, "({x}, {y}) t {t}");
                    if want {
                        // Score s: a corner at s − 1, not at s.
                        assert!(is_corner_reference(&img, w, x, y, sc as i16 - 1));
                        assert!(!is_corner_reference(&img, w, x, y, sc as i16));
                    }
                }
            }
        }
    }

    #[test]
    fn low_contrast_cells_fall_back_to_the_minimum_threshold() {
        // Two squares: a strong one in the left cell, a faint one (contrast 12) in the right.
        let (w, h) = (80, 40);
        let mut img = vec![100u8; w * h];
        for y in 14..26 {
            for x in 10..22 {
                img[y * w + x] = 200;
            }
            for x in 50..62 {
                img[y * w + x] = 112;
            }
        }
        let corners = detect_in_cells(&img, w, h, 4, 36, 20, 7);
        let left = corners.iter().filter(|c| c.x < 40).count();
        let right = corners.iter().filter(|c| c.x >= 40).count();
        assert_eq!(left, 4);
        assert_eq!(right, 4, "faint square found only through the fallback");
        // Without the fallback (min = ini), the faint one is lost.
        let strict = detect_in_cells(&img, w, h, 4, 36, 20, 20);
        assert_eq!(strict.iter().filter(|c| c.x >= 40).count(), 0);
    }

    /// One score pass at `min_th` and the per-cell choice on it (the definition).
    fn detect_in_cells_reference(
        img: &[u8],
        w: usize,
        h: usize,
        border: usize,
        cell_size: usize,
        ini_th: u8,
        min_th: u8,
    ) -> Vec<Corner> {
        let scores = score_map(img, w, h, border, min_th);
        let (rw, rh) = (w - 2 * border, h - 2 * border);
        let (n_cols, n_rows) = ((rw / cell_size).max(1), (rh / cell_size).max(1));
        let (cw, ch) = (rw.div_ceil(n_cols), rh.div_ceil(n_rows));
        let mut out = Vec::new();
        for r in 0..n_rows {
            let y0 = border + r * ch;
            let y1 = (y0 + ch).min(h - border);
            for c in 0..n_cols {
                let x0 = border + c * cw;
                let x1 = (x0 + cw).min(w - border);
                let mut cell = Vec::new();
                collect_maxima(&scores, w, x0..x1, y0..y1, &mut cell);
                if cell.iter().any(|k| k.score > ini_th) {
                    cell.retain(|k| k.score > ini_th);
                }
                out.extend(cell);
            }
        }
        out
    }

    #[test]
    fn two_threshold_detection_equals_one_pass_at_the_minimum() {
        // Smooth blobs plus noise of varying amplitude: some cells have strong corners, some
        // only weak ones, some none.
        for seed in [1u64, 2, 3, 4] {
            let (w, h) = (157, 131);
            let mut s = seed.wrapping_mul(0x9E3779B97F4A7C15) | 1;
            let mut rnd = || {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (s >> 33) as u32
            };
            let img: Vec<u8> = (0..w * h)
                .map(|i| {
                    let (x, y) = ((i % w) as f64, (i / w) as f64);
                    let amp = 4.0 + 60.0 * (x / w as f64) * (y / h as f64);
                    let base = 120.0 + 40.0 * (x * 0.11).sin() * (y * 0.07).cos();
                    (base + amp * ((rnd() % 1000) as f64 / 1000.0 - 0.5)).clamp(0.0, 255.0) as u8
                })
                .collect();
            for &(border, cell, ini, min) in &[(3, 30, 20, 7), (16, 25, 20, 7), (5, 17, 12, 12)] {
                let got = detect_in_cells(&img, w, h, border, cell, ini, min);
                let want = detect_in_cells_reference(&img, w, h, border, cell, ini, min);
                assert_eq!(got, want, "seed {seed} border {border} cell {cell}");
                assert!(!got.is_empty());
            }
        }
    }

    #[test]
    fn flat_and_tiny_images_give_nothing() {
        let img = vec![0u8; 50 * 50];
        assert!(detect_in_cells(&img, 50, 50, 16, 30, 20, 7).is_empty());
        assert!(detect_in_cells(&img[..100], 10, 10, 16, 30, 20, 7).is_empty());
    }
}
