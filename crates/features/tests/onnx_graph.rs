//! Graphs written by our builder run on ONNX Runtime and compute what the layers mean.

use std::collections::BTreeMap;
use std::path::PathBuf;

use jointloc_features::engine::{Engine, EngineConfig, NetTensor, OrtEngine};
use jointloc_features::onnx::{ConvOpts, Dim, GraphBuilder};
use jointloc_features::pth::{StateDict, Tensor};

fn ort_library() -> PathBuf {
    jointloc_features::models::ready_store()
        .expect("models (fetched once with pip)")
        .onnxruntime_library()
}

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

fn tensor(shape: &[usize], seed: u64) -> Tensor {
    Tensor {
        shape: shape.to_vec(),
        data: lcg(seed, shape.iter().product()),
    }
}

#[test]
fn conv_relu_linear_matches_direct_computation() {
    let (cin, cout, h, w, feat) = (2, 3, 5, 6, 4);
    let mut t = BTreeMap::new();
    t.insert("conv.weight".to_owned(), tensor(&[cout, cin, 3, 3], 1));
    t.insert("conv.bias".to_owned(), tensor(&[cout], 2));
    t.insert("fc.weight".to_owned(), tensor(&[feat, w], 3));
    t.insert("fc.bias".to_owned(), tensor(&[feat], 4));
    let sd = StateDict::from_tensors("synthetic".into(), t);

    let mut g = GraphBuilder::new("test");
    let x = g.input_f32("x", &[1.into(), cin.into(), h.into(), w.into()]);
    let y = g.conv2d(&x, &sd, "conv", ConvOpts::padded(1)).unwrap();
    let y = g.relu(&y);
    let y = g.linear(&y, &sd, "fc").unwrap();
    g.output_f32(&y, "y", &[Dim::from(1), cout.into(), h.into(), feat.into()]);
    let engine = OrtEngine::new(
        &ort_library(),
        &g.to_bytes(),
        "test",
        &EngineConfig::default(),
    )
    .unwrap();
    let input = lcg(5, cin * h * w);
    let out = engine
        .run(vec![("x", NetTensor::f32(&[1, cin, h, w], input.clone()))])
        .unwrap();
    let got = out.get("y").unwrap();
    assert_eq!(got.shape, vec![1, cout, h, feat]);
    let got = got.as_f32("y").unwrap();

    let cw = &sd.get("conv.weight").unwrap().data;
    let cb = &sd.get("conv.bias").unwrap().data;
    let fw = &sd.get("fc.weight").unwrap().data;
    let fb = &sd.get("fc.bias").unwrap().data;
    let mut conv = vec![0.0f32; cout * h * w];
    for o in 0..cout {
        for yy in 0..h {
            for xx in 0..w {
                let mut s = cb[o];
                for i in 0..cin {
                    for ky in 0..3 {
                        for kx in 0..3 {
                            let (sy, sx) = (yy + ky, xx + kx);
                            if sy < 1 || sx < 1 || sy > h || sx > w {
                                continue;
                            }
                            s += cw[((o * cin + i) * 3 + ky) * 3 + kx]
                                * input[(i * h + sy - 1) * w + sx - 1];
                        }
                    }
                }
                conv[(o * h + yy) * w + xx] = s.max(0.0);
            }
        }
    }
    for o in 0..cout {
        for yy in 0..h {
            for f in 0..feat {
                let mut s = fb[f];
                for xx in 0..w {
                    s += fw[f * w + xx] * conv[(o * h + yy) * w + xx];
                }
                let g = got[(o * h + yy) * feat + f];
                assert!((g - s).abs() < 1e-5, "({o},{yy},{f}): {g} vs {s}");
            }
        }
    }
}
