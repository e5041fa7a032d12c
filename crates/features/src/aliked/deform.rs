//! Deformable convolution (torchvision `deform_conv2d` semantics) expressed in ONNX.

use crate::onnx::{Attr, GraphBuilder, Var};

/// Direct deformable 3×3 convolution, stride 1, padding 1, no mask: the reference the ONNX
/// expression is checked against. `offset` is `[2·9, H, W]` with `(dy, dx)` per kernel tap.
#[cfg(test)]
pub(crate) fn deform_conv_direct(
    x: &[f32],
    cin: usize,
    h: usize,
    w: usize,
    offset: &[f32],
    weight: &[f32],
    cout: usize,
) -> Vec<f32> {
    let sample = |c: usize, y: f32, xx: f32| -> f32 {
        if y <= -1.0 || y >= h as f32 || xx <= -1.0 || xx >= w as f32 {
            return 0.0;
        }
        let (y0, x0) = (y.floor(), xx.floor());
        let (ly, lx) = (y - y0, xx - x0);
        let mut v = 0.0;
        for (dy, wy) in [(0i64, 1.0 - ly), (1, ly)] {
            for (dx, wx) in [(0i64, 1.0 - lx), (1, lx)] {
                let (yi, xi) = (y0 as i64 + dy, x0 as i64 + dx);
                if yi >= 0 && xi >= 0 && (yi as usize) < h && (xi as usize) < w {
                    v += wy * wx * x[(c * h + yi as usize) * w + xi as usize];
                }
            }
        }
        v
    };
    let mut out = vec![0.0f32; cout * h * w];
    for oy in 0..h {
        for ox in 0..w {
            for k in 0..9 {
                let (ky, kx) = (k / 3, k % 3);
                let dy = offset[((2 * k) * h + oy) * w + ox];
                let dx = offset[((2 * k + 1) * h + oy) * w + ox];
                let sy = oy as f32 - 1.0 + ky as f32 + dy;
                let sx = ox as f32 - 1.0 + kx as f32 + dx;
                for c in 0..cin {
                    let v = sample(c, sy, sx);
                    for o in 0..cout {
                        out[(o * h + oy) * w + ox] += weight[(o * cin + c) * 9 + k] * v;
                    }
                }
            }
        }
    }
    out
}

/// Native ONNX `DeformConv` (opset 19).
pub(crate) fn deform_conv_native(g: &mut GraphBuilder, x: &Var, offset: &Var, weight: &Var) -> Var {
    g.op(
        "DeformConv",
        &[x, weight, offset],
        &[
            Attr::Ints("kernel_shape", vec![3, 3]),
            Attr::Ints("pads", vec![1, 1, 1, 1]),
            Attr::Ints("strides", vec![1, 1]),
            Attr::Ints("dilations", vec![1, 1]),
            Attr::Int("group", 1),
            Attr::Int("offset_group", 1),
        ],
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::{Engine, EngineConfig, NetTensor, OrtEngine};
    use crate::onnx::Dim;

    fn lcg(seed: u64, n: usize, scale: f32) -> Vec<f32> {
        let mut s = seed;
        (0..n)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (((s >> 40) as f32 / (1u64 << 24) as f32) - 0.5) * scale
            })
            .collect()
    }

    #[test]
    fn native_deform_conv_matches_direct() {
        let store = crate::models::ready_store().unwrap();
        let (cin, cout, h, w) = (3, 4, 5, 7);
        for seed in 0..3u64 {
            let x = lcg(seed, cin * h * w, 2.0);
            let off = lcg(seed + 10, 18 * h * w, 6.0);
            let wt = lcg(seed + 20, cout * cin * 9, 1.0);
            let mut g = GraphBuilder::new("t");
            let xv = g.input_f32("x", &[1.into(), cin.into(), h.into(), w.into()]);
            let ov = g.input_f32("off", &[1.into(), 18.into(), h.into(), w.into()]);
            let wv = g.tensor_f32(&[cout, cin, 3, 3], &wt);
            let y = deform_conv_native(&mut g, &xv, &ov, &wv);
            g.output_f32(&y, "y", &[Dim::from(1), cout.into(), h.into(), w.into()]);
            let e = OrtEngine::new(
                &store.onnxruntime_library(),
                &g.to_bytes(),
                "t",
                &EngineConfig::default(),
            )
            .unwrap();
            let out = e
                .run(vec![
                    ("x", NetTensor::f32(&[1, cin, h, w], x.clone())),
                    ("off", NetTensor::f32(&[1, 18, h, w], off.clone())),
                ])
                .unwrap();
            let got = out.get("y").unwrap().as_f32("y").unwrap().to_vec();
            let want = deform_conv_direct(&x, cin, h, w, &off, &wt, cout);
            let err = got
                .iter()
                .zip(&want)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0f32, f32::max);
            assert!(err < 1e-5, "seed {seed}: max err {err}");
        }
    }
}
