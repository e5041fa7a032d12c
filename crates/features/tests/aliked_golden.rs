//! ALIKED against the reference extractor (LightGlue's ALIKED n16, 1024 keypoints, threshold
//! 0.2, NMS radius 2, image resized to a long side of 1024) on both golden images; the other
//! variants; clear errors for wrong weights, bad images and bad settings.

use std::path::{Path, PathBuf};

use jointloc_features::aliked::{Aliked, AlikedConfig, AlikedModel};
use jointloc_features::models::{ModelStore, WeightsFile, ready_store};
use jointloc_features::{Detector, Features, FeaturesError};

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

/// `(shape, values)` of an f32 tensor of `aliked_sparse.safetensors`.
fn read_f32(name: &str) -> (Vec<usize>, Vec<f32>) {
    let bytes = std::fs::read(golden("aliked_sparse.safetensors")).expect("golden file");
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

/// Parity figures of one image.
#[derive(Debug)]
struct Parity {
    /// Golden keypoints with one of ours (nearest neighbour) within 0.5 px.
    within_half_px: f64,
    /// Golden keypoints with one of ours within 0.01 px (the same detection).
    same: f64,
    /// Over the same detections: smallest descriptor cosine, largest score difference.
    min_cosine: f32,
    max_score_diff: f32,
    /// Over all pairs within 0.5 px: smallest descriptor cosine.
    min_cosine_half_px: f32,
}

fn compare(ours: &Features, tag: &str) -> Parity {
    let (kshape, kp) = read_f32(&format!("{tag}.keypoints"));
    let (_, scores) = read_f32(&format!("{tag}.keypoint_scores"));
    let (dshape, desc) = read_f32(&format!("{tag}.descriptors"));
    let (n, dim) = (kshape[0], dshape[1]);
    assert_eq!(dim, ours.descriptor_dim);
    let mut p = Parity {
        within_half_px: 0.0,
        same: 0.0,
        min_cosine: 1.0,
        max_score_diff: 0.0,
        min_cosine_half_px: 1.0,
    };
    for i in 0..n {
        let g = [kp[2 * i], kp[2 * i + 1]];
        let dist = |k: [f32; 2]| (k[0] - g[0]).hypot(k[1] - g[1]);
        let nearest = (0..ours.len())
            .min_by(|&a, &b| dist(ours.keypoints[a]).total_cmp(&dist(ours.keypoints[b])));
        let Some(j) = nearest else { continue };
        let d = dist(ours.keypoints[j]);
        if d > 0.5 {
            continue;
        }
        p.within_half_px += 1.0 / n as f64;
        let cos: f32 = ours
            .descriptor(j)
            .iter()
            .zip(&desc[i * dim..(i + 1) * dim])
            .map(|(a, b)| a * b)
            .sum();
        p.min_cosine_half_px = p.min_cosine_half_px.min(cos);
        if d <= 0.01 {
            p.same += 1.0 / n as f64;
            p.min_cosine = p.min_cosine.min(cos);
            p.max_score_diff = p.max_score_diff.max((ours.scores[j] - scores[i]).abs());
        }
    }
    p
}

#[test]
fn keypoints_descriptors_and_scores_match_golden() {
    let aliked = Aliked::new(&store(), AlikedConfig::default()).expect("ALIKED");
    for tag in ["a", "b"] {
        let f = aliked.detect(&grey(&format!("mars_{tag}.png"))).unwrap();
        assert_eq!(f.image_size, (500, 500));
        assert_eq!(f.len(), 1024, "image {tag}");
        assert_eq!(f.descriptors.len(), 1024 * 128);
        let p = compare(&f, tag);
        eprintln!("ALIKED {tag}: {p:?}");
        assert!(p.within_half_px >= 0.99, "image {tag}: {p:?}");
        assert!(p.same >= 0.99, "image {tag}: {p:?}");
        assert!(p.min_cosine >= 0.9999, "image {tag}: {p:?}");
        assert!(p.max_score_diff < 1e-4, "image {tag}: {p:?}");
    }
}

/// Mutual nearest neighbours by descriptor similarity.
fn mutual_nn(a: &Features, b: &Features) -> Vec<(usize, usize)> {
    let best = |x: &Features, y: &Features, i: usize| -> usize {
        (0..y.len())
            .max_by(|&p, &q| {
                let s = |j: usize| -> f32 {
                    x.descriptor(i)
                        .iter()
                        .zip(y.descriptor(j))
                        .map(|(u, v)| u * v)
                        .sum()
                };
                s(p).total_cmp(&s(q))
            })
            .expect("non-empty")
    };
    (0..a.len())
        .filter_map(|i| {
            let j = best(a, b, i);
            (best(b, a, j) == i).then_some((i, j))
        })
        .collect()
}

/// Every variant loads with the same code, and at the native size (not the reference's
/// setting) its mutual matches between the golden pair follow the true homography.
#[test]
fn all_variants_match_the_golden_pair_at_native_size() {
    let h: Vec<f64> = std::fs::read_to_string(golden("H_a_to_b.txt"))
        .unwrap()
        .split_whitespace()
        .map(|v| v.parse().unwrap())
        .collect();
    let (ia, ib) = (grey("mars_a.png"), grey("mars_b.png"));
    let store = store();
    for model in [
        AlikedModel::N16,
        AlikedModel::N16Rot,
        AlikedModel::N32,
        AlikedModel::T16,
    ] {
        let config = AlikedConfig {
            model,
            resize: None,
            ..AlikedConfig::default()
        };
        let aliked = Aliked::new(&store, config).unwrap();
        let (fa, fb) = (aliked.detect(&ia).unwrap(), aliked.detect(&ib).unwrap());
        let dim = model.dims().dim;
        for f in [&fa, &fb] {
            assert!(f.len() > 200, "{model:?}: {} keypoints", f.len());
            assert_eq!(f.descriptor_dim, dim);
            assert!(f.scores.iter().all(|&s| s > 0.0 && s <= 1.0));
            for i in 0..f.len() {
                let n: f32 = f.descriptor(i).iter().map(|v| v * v).sum();
                assert!((n - 1.0).abs() < 1e-4);
            }
        }
        let matches = mutual_nn(&fa, &fb);
        let good = matches
            .iter()
            .filter(|&&(i, j)| {
                let [x, y] = fa.keypoints[i].map(f64::from);
                let w = h[6] * x + h[7] * y + h[8];
                let (px, py) = (
                    (h[0] * x + h[1] * y + h[2]) / w,
                    (h[3] * x + h[4] * y + h[5]) / w,
                );
                let [bx, by] = fb.keypoints[j].map(f64::from);
                (px - bx).hypot(py - by) < 3.0
            })
            .count();
        let ratio = good as f64 / matches.len() as f64;
        eprintln!(
            "{model:?}: {} matches, {ratio:.3} within 3 px",
            matches.len()
        );
        assert!(
            matches.len() > 100 && ratio > 0.8,
            "{model:?}: {good}/{}",
            matches.len()
        );
    }
}

#[test]
fn wrong_weights_bad_images_and_bad_settings_are_errors() {
    let store = store();
    let lib = store.onnxruntime_library();
    // Another variant's checkpoint: a shape error naming the weight, no panic.
    for (model, wrong) in [
        (AlikedModel::N16, WeightsFile::AlikedT16),
        (AlikedModel::T16, WeightsFile::AlikedN16),
        (AlikedModel::N16, WeightsFile::AlikedN32),
    ] {
        let config = AlikedConfig {
            model,
            ..AlikedConfig::default()
        };
        let err = Aliked::from_files(&store.weights(wrong), &lib, None, config).unwrap_err();
        assert!(matches!(err, FeaturesError::WeightShape { .. }), "{err}");
    }
    // Another network's checkpoint: a missing weight.
    let err = Aliked::from_files(
        &store.weights(WeightsFile::XFeat),
        &lib,
        None,
        AlikedConfig::default(),
    )
    .unwrap_err();
    assert!(matches!(err, FeaturesError::MissingWeight { .. }), "{err}");

    let aliked = Aliked::new(&store, AlikedConfig::default()).unwrap();
    // Too small, before or after resizing to a long side of 1024.
    for (w, h) in [(0, 0), (15, 200), (200, 3), (16, 2000)] {
        let err = aliked.detect(&image::GrayImage::new(w, h)).unwrap_err();
        assert!(
            matches!(err, FeaturesError::InvalidInput(_)),
            "{w}×{h}: {err}"
        );
    }
    // A constant image of odd size (padded) is valid; keypoints stay inside it.
    let native = Aliked::new(
        &store,
        AlikedConfig {
            resize: None,
            ..AlikedConfig::default()
        },
    )
    .unwrap();
    let flat = image::GrayImage::from_pixel(61, 37, image::Luma([90]));
    let f = native.detect(&flat).unwrap();
    assert_eq!(f.descriptors.len(), f.len() * 128);
    assert!(f.keypoints.iter().all(|k| k[0] < 61.0 && k[1] < 37.0));

    for bad in [
        AlikedConfig {
            max_keypoints: Some(0),
            ..AlikedConfig::default()
        },
        AlikedConfig {
            nms_radius: 0,
            ..AlikedConfig::default()
        },
        AlikedConfig {
            resize: Some(8),
            ..AlikedConfig::default()
        },
        AlikedConfig {
            detection_threshold: f32::NAN,
            ..AlikedConfig::default()
        },
    ] {
        assert!(matches!(
            Aliked::new(&store, bad).unwrap_err(),
            FeaturesError::InvalidConfig { .. }
        ));
    }
}
