//! SDDH, ALIKED's sparse deformable descriptor head, per keypoint in Rust.
//!
//! For each keypoint the reference takes the 3×3 patch of the normalised feature map at the
//! keypoint's integer pixel, predicts `M` sample offsets from it (3×3 convolution, SELU, 1×1
//! convolution, clamp to ±max(h, w)/4), samples the map bilinearly there (zeros outside),
//! applies a 1×1 convolution and SELU to each sample and aggregates the `M` samples with one
//! `dim × dim` matrix per position; the result is L2-normalised.
//!
//! Why Rust and not an ONNX graph: the head needs the 128-channel normalised map, which the
//! reference forms at full resolution (512 MB at 1024×1024) although only ~73 pixels per
//! keypoint are read. Here the map is evaluated only at those pixels, from the backbone's
//! block-1 output and its three low-resolution projections (bilinear upsampling with
//! `align_corners=True` recomputed exactly per pixel; the projections come channels-last so a
//! pixel's channels are contiguous), one keypoint's pixels at a time so the working set stays
//! in cache. The dense products (offset estimation, sample
//! convolution, aggregation: ~1.1 GFLOP for 1024 keypoints) run as matrix products through
//! nalgebra's `matrixmultiply` GEMM.

use nalgebra::DMatrixView;

use super::graph::Dims;
use super::prep::Padding;
use crate::error::Result;
use crate::pth::StateDict;

const SELU_ALPHA: f32 = 1.673_263_2;
const SELU_SCALE: f32 = 1.050_701;

fn selu(v: &mut [f32]) {
    for x in v {
        *x = if *x > 0.0 {
            SELU_SCALE * *x
        } else {
            SELU_SCALE * SELU_ALPHA * (x.exp() - 1.0)
        };
    }
}

/// `F.normalize(rows, p=2, dim=1)`: each row divided by max(‖row‖, 1e-12).
pub(crate) fn normalize_rows(v: &mut [f32], dim: usize) {
    for row in v.chunks_exact_mut(dim) {
        let n = row.iter().map(|x| x * x).sum::<f32>().sqrt().max(1e-12);
        row.iter_mut().for_each(|x| *x /= n);
    }
}

/// Row-major `a (m×k) · b (k×n)`.
fn matmul(a: &[f32], m: usize, k: usize, b: &[f32], n: usize) -> Vec<f32> {
    if m == 0 || n == 0 {
        return Vec::new();
    }
    // Row-major A is column-major Aᵀ: C = A·B  ⇔  Cᵀ = Bᵀ·Aᵀ, whose column-major storage is C's
    // row-major storage.
    let at = DMatrixView::from_slice(a, k, m);
    let bt = DMatrixView::from_slice(b, n, k);
    (bt * at).as_slice().to_vec()
}

/// Row-major transpose of a `rows × cols` matrix.
fn transpose(v: &[f32], rows: usize, cols: usize) -> Vec<f32> {
    let mut t = vec![0.0f32; v.len()];
    for r in 0..rows {
        for c in 0..cols {
            t[c * rows + r] = v[r * cols + c];
        }
    }
    t
}

/// Weights of the descriptor head and of the block-1 projection it re-evaluates.
#[derive(Debug, Clone)]
pub(crate) struct SddhWeights {
    dims: Dims,
    /// `conv1` (block-1 projection), transposed: `[c1, dim/4]`.
    conv1_t: Vec<f32>,
    /// Offset convolution, transposed: `[dim·K², 2M]`, input index `c·K² + ky·K + kx`.
    offset0_t: Vec<f32>,
    offset0_b: Vec<f32>,
    /// Offset 1×1 convolution, transposed: `[2M, 2M]`.
    offset1_t: Vec<f32>,
    offset1_b: Vec<f32>,
    /// Sample 1×1 convolution, transposed: `[dim, dim]`.
    sf_t: Vec<f32>,
    /// Aggregation `[M·dim, dim]` (the checkpoint's `[M, dim, dim]` as is).
    agg: Vec<f32>,
}

impl SddhWeights {
    /// Reads the head from a checkpoint already checked by [`super::graph::validate`].
    pub(crate) fn new(sd: &StateDict, dims: Dims) -> Result<Self> {
        let (dim, q, m2) = (dims.dim, dims.quarter(), 2 * dims.positions);
        let kk = dims.kernel * dims.kernel;
        let get = |k: &str| -> Result<Vec<f32>> { Ok(sd.get(k)?.data.clone()) };
        Ok(Self {
            dims,
            conv1_t: transpose(&get("conv1.weight")?, q, dims.c1),
            offset0_t: transpose(&get("desc_head.offset_conv.0.weight")?, m2, dim * kk),
            offset0_b: get("desc_head.offset_conv.0.bias")?,
            offset1_t: transpose(&get("desc_head.offset_conv.2.weight")?, m2, m2),
            offset1_b: get("desc_head.offset_conv.2.bias")?,
            sf_t: transpose(&get("desc_head.sf_conv.weight")?, dim, dim),
            agg: get("desc_head.agg_weights")?,
        })
    }
}

/// The backbone outputs the descriptor map is made of, and the padding that maps image pixels
/// into them.
#[derive(Debug, Clone, Copy)]
pub(crate) struct FeatureMaps<'a> {
    /// Block-1 output, channels first: `[c1, hp, wp]`.
    pub x1: &'a [f32],
    /// Gated projections, channels last: `[hp/s, wp/s, dim/4]`, s = 2, 8, 32.
    pub x2g: &'a [f32],
    pub x3g: &'a [f32],
    pub x4g: &'a [f32],
    pub pad: Padding,
}

/// Bilinear taps along one axis for `align_corners=True` upsampling from `inp` to `out`
/// samples (PyTorch: source = dst · (in − 1)/(out − 1)).
fn corner_taps(dst: usize, inp: usize, out: usize) -> (usize, usize, f32) {
    let scale = if out > 1 {
        (inp - 1) as f32 / (out - 1) as f32
    } else {
        0.0
    };
    let src = scale * dst as f32;
    let i0 = (src as usize).min(inp - 1);
    let i1 = (i0 + 1).min(inp - 1);
    (i0, i1, (src - i0 as f32).clamp(0.0, 1.0))
}

impl FeatureMaps<'_> {
    /// The normalised `dim`-vectors of the reference's feature map at the given pixels
    /// (`y·w + x` of the unpadded map): `[pixels.len(), dim]`. Row-major output, one pixel at
    /// a time, so callers keep their working set small by asking for nearby pixels together.
    pub(crate) fn features(&self, wts: &SddhWeights, pixels: &[usize]) -> Vec<f32> {
        let d = &wts.dims;
        let (dim, q, c1) = (d.dim, d.quarter(), d.c1);
        let pad = self.pad;
        let (hp, wp) = (pad.hp, pad.wp);
        let n = pixels.len();
        let yx = |i: usize| (i / pad.w + pad.top, i % pad.w + pad.left);

        let mut a = vec![0.0f32; n * c1];
        for (row, &p) in a.chunks_exact_mut(c1).zip(pixels) {
            let (y, x) = yx(p);
            for (c, v) in row.iter_mut().enumerate() {
                *v = self.x1[(c * hp + y) * wp + x];
            }
        }
        let mut g1 = matmul(&a, n, c1, &wts.conv1_t, q);
        selu(&mut g1);

        let mut out = vec![0.0f32; n * dim];
        for ((row, g), &p) in out
            .chunks_exact_mut(dim)
            .zip(g1.chunks_exact(q))
            .zip(pixels)
        {
            let (y, x) = yx(p);
            row[..q].copy_from_slice(g);
            for (part, (map, s)) in [(self.x2g, 2usize), (self.x3g, 8), (self.x4g, 32)]
                .into_iter()
                .enumerate()
            {
                let (hl, wl) = (hp / s, wp / s);
                let (y0, y1, ly) = corner_taps(y, hl, hp);
                let (x0, x1, lx) = corner_taps(x, wl, wp);
                let at = |yy: usize, xx: usize| &map[(yy * wl + xx) * q..][..q];
                let (v00, v01, v10, v11) = (at(y0, x0), at(y0, x1), at(y1, x0), at(y1, x1));
                let (w00, w01) = ((1.0 - ly) * (1.0 - lx), (1.0 - ly) * lx);
                let (w10, w11) = (ly * (1.0 - lx), ly * lx);
                let dst = &mut row[(part + 1) * q..(part + 2) * q];
                for c in 0..q {
                    dst[c] = w00 * v00[c] + w01 * v01[c] + w10 * v10[c] + w11 * v11[c];
                }
            }
        }
        normalize_rows(&mut out, dim);
        out
    }
}

/// Descriptors `[N, dim]` for keypoints in the reference's normalised coordinates.
pub(crate) fn describe(
    wts: &SddhWeights,
    maps: &FeatureMaps<'_>,
    normalised: &[[f32; 2]],
) -> Vec<f32> {
    let d = &wts.dims;
    let (dim, m, k) = (d.dim, d.positions, d.kernel);
    let (kk, m2) = (k * k, 2 * m);
    let n = normalised.len();
    if n == 0 {
        return Vec::new();
    }
    let (h, w) = (maps.pad.h, maps.pad.w);
    let wh = [(w - 1) as f32, (h - 1) as f32];
    let kp: Vec<[f32; 2]> = normalised
        .iter()
        .map(|p| [(p[0] / 2.0 + 0.5) * wh[0], (p[1] / 2.0 + 0.5) * wh[1]])
        .collect();

    // Patches as the reference's get_patches: corner (⌊kp⌋ − K/2 + 1) truncated, clamped.
    let corner = |v: f32, size: usize| -> usize {
        let c = ((v as i64) as f32 - k as f32 / 2.0 + 1.0) as i64;
        c.clamp(0, (size as i64 - 1 - k as i64).max(0)) as usize
    };
    let patch_pixels: Vec<usize> = kp
        .iter()
        .flat_map(|p| {
            let (cx, cy) = (corner(p[0], w), corner(p[1], h));
            (0..kk).map(move |t| (cy + t / k) * w + cx + t % k)
        })
        .collect();
    let feats = maps.features(wts, &patch_pixels);
    // [N, dim·K²] with input index c·K² + tap, as the convolution weights are laid out.
    let mut patches = vec![0.0f32; n * dim * kk];
    for (i, row) in patches.chunks_exact_mut(dim * kk).enumerate() {
        for t in 0..kk {
            let f = &feats[(i * kk + t) * dim..][..dim];
            for (ch, &v) in f.iter().enumerate() {
                row[ch * kk + t] = v;
            }
        }
    }

    // Offsets: conv K×K + bias, SELU, 1×1 + bias, clamp.
    let mut o = matmul(&patches, n, dim * kk, &wts.offset0_t, m2);
    for row in o.chunks_exact_mut(m2) {
        row.iter_mut()
            .zip(&wts.offset0_b)
            .for_each(|(v, b)| *v += b);
    }
    selu(&mut o);
    let mut o = matmul(&o, n, m2, &wts.offset1_t, m2);
    let max_offset = h.max(w) as f32 / 4.0;
    for row in o.chunks_exact_mut(m2) {
        for (v, b) in row.iter_mut().zip(&wts.offset1_b) {
            *v = (*v + b).clamp(-max_offset, max_offset);
        }
    }

    // Bilinear samples (zeros outside), one keypoint at a time: its corner pixels are evaluated
    // together (deduplicated) so the work stays in cache.
    let mut sampled = vec![0.0f32; n * m * dim];
    let mut corners: Vec<(usize, f32)> = Vec::with_capacity(4 * m);
    let mut pixels: Vec<usize> = Vec::with_capacity(4 * m);
    for (i, p) in kp.iter().enumerate() {
        corners.clear();
        for j in 0..m {
            // The reference's normalise/unnormalise round trip, then grid_sample's corners.
            let pos = [p[0] + o[i * m2 + j], p[1] + o[i * m2 + m + j]];
            let px: [f32; 2] = std::array::from_fn(|a| {
                let g = 2.0 * pos[a] / wh[a] - 1.0;
                (g + 1.0) / 2.0 * wh[a]
            });
            let (x0, y0) = (px[0].floor(), px[1].floor());
            let (lx, ly) = (px[0] - x0, px[1] - y0);
            for (dx, dy, weight) in [
                (0i64, 0i64, (1.0 - lx) * (1.0 - ly)),
                (1, 0, lx * (1.0 - ly)),
                (0, 1, (1.0 - lx) * ly),
                (1, 1, lx * ly),
            ] {
                let (xi, yi) = (x0 as i64 + dx, y0 as i64 + dy);
                let inside = xi >= 0 && yi >= 0 && (xi as usize) < w && (yi as usize) < h;
                let pixel = if inside {
                    yi as usize * w + xi as usize
                } else {
                    usize::MAX
                };
                corners.push((pixel, weight));
            }
        }
        pixels.clear();
        pixels.extend(corners.iter().map(|c| c.0).filter(|&c| c != usize::MAX));
        pixels.sort_unstable();
        pixels.dedup();
        let feats = maps.features(wts, &pixels);
        for (j, cs) in corners.chunks_exact(4).enumerate() {
            let out = &mut sampled[(i * m + j) * dim..][..dim];
            for &(pixel, weight) in cs {
                if pixel == usize::MAX {
                    continue;
                }
                let r = pixels.binary_search(&pixel).expect("collected corner");
                let f = &feats[r * dim..][..dim];
                out.iter_mut().zip(f).for_each(|(o, &v)| *o += weight * v);
            }
        }
    }

    // 1×1 convolution + SELU per sample, then aggregation over positions and channels.
    let mut g = matmul(&sampled, n * m, dim, &wts.sf_t, dim);
    selu(&mut g);
    let mut desc = matmul(&g, n, m * dim, &wts.agg, dim);
    normalize_rows(&mut desc, dim);
    desc
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lcg(seed: u64, n: usize) -> Vec<f32> {
        let mut s = seed;
        (0..n)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((s >> 40) as f32 / (1u64 << 24) as f32) - 0.5
            })
            .collect()
    }

    #[test]
    fn matmul_matches_naive_product() {
        let (m, k, n) = (13, 37, 9);
        let (a, b) = (lcg(1, m * k), lcg(2, k * n));
        let c = matmul(&a, m, k, &b, n);
        for i in 0..m {
            for j in 0..n {
                let want: f32 = (0..k).map(|t| a[i * k + t] * b[t * n + j]).sum();
                assert!((c[i * n + j] - want).abs() < 1e-5);
            }
        }
    }

    /// The per-pixel evaluation equals the reference's dense construction: projections
    /// upsampled to full resolution (align_corners=True), concatenated, L2-normalised.
    #[test]
    fn sparse_feature_evaluation_matches_dense_map() {
        let dims = Dims {
            c1: 3,
            c2: 4,
            c3: 4,
            c4: 8,
            dim: 8,
            kernel: 3,
            positions: 2,
        };
        let q = dims.quarter();
        for seed in 0..3u64 {
            let pad = Padding::new(60, 50, 32);
            let (hp, wp) = (pad.hp, pad.wp);
            let x1 = lcg(seed, dims.c1 * hp * wp);
            // Channels last, as the graph outputs them.
            let x2 = lcg(seed + 1, q * hp * wp / 4);
            let x3 = lcg(seed + 2, q * hp * wp / 64);
            let x4 = lcg(seed + 3, q * hp * wp / 1024);
            let conv1 = lcg(seed + 4, q * dims.c1);
            let wts = SddhWeights {
                dims,
                conv1_t: transpose(&conv1, q, dims.c1),
                offset0_t: Vec::new(),
                offset0_b: Vec::new(),
                offset1_t: Vec::new(),
                offset1_b: Vec::new(),
                sf_t: Vec::new(),
                agg: Vec::new(),
            };
            let maps = FeatureMaps {
                x1: &x1,
                x2g: &x2,
                x3g: &x3,
                x4g: &x4,
                pad,
            };
            let pixels = vec![50 * 17 + 33, 0, 7, 49, 50 * 59 + 49, 7];
            let got = maps.features(&wts, &pixels);
            // Dense reference with f64 bilinear upsampling (PyTorch's align_corners=True rule).
            let up = |map: &[f32], s: usize, c: usize, y: usize, x: usize| -> f64 {
                let (hl, wl) = (hp / s, wp / s);
                let sy = (hl - 1) as f64 / (hp - 1) as f64 * y as f64;
                let sx = (wl - 1) as f64 / (wp - 1) as f64 * x as f64;
                let (y0, x0) = (sy.floor() as usize, sx.floor() as usize);
                let (y1, x1) = ((y0 + 1).min(hl - 1), (x0 + 1).min(wl - 1));
                let (ly, lx) = (sy - y0 as f64, sx - x0 as f64);
                let v = |yy: usize, xx: usize| f64::from(map[(yy * wl + xx) * q + c]);
                (1.0 - ly) * ((1.0 - lx) * v(y0, x0) + lx * v(y0, x1))
                    + ly * ((1.0 - lx) * v(y1, x0) + lx * v(y1, x1))
            };
            for (r, &p) in pixels.iter().enumerate() {
                let (y, x) = (p / 50 + pad.top, p % 50 + pad.left);
                let mut v = vec![0.0f64; dims.dim];
                for o in 0..q {
                    let s: f64 = (0..dims.c1)
                        .map(|c| f64::from(conv1[o * dims.c1 + c] * x1[(c * hp + y) * wp + x]))
                        .sum();
                    let a = f64::from(SELU_ALPHA) * f64::from(SELU_SCALE);
                    v[o] = if s > 0.0 {
                        f64::from(SELU_SCALE) * s
                    } else {
                        a * (s.exp() - 1.0)
                    };
                    v[q + o] = up(&x2, 2, o, y, x);
                    v[2 * q + o] = up(&x3, 8, o, y, x);
                    v[3 * q + o] = up(&x4, 32, o, y, x);
                }
                let norm = v.iter().map(|a| a * a).sum::<f64>().sqrt();
                for c in 0..dims.dim {
                    let want = v[c] / norm;
                    let g = f64::from(got[r * dims.dim + c]);
                    assert!(
                        (g - want).abs() < 1e-5,
                        "seed {seed} pixel {p} ch {c}: {g} vs {want}"
                    );
                }
            }
        }
    }
}
