//! End-to-end properties of the ORB extractor on simulated Mars frames: rotation invariance
//! of orientation and descriptors, determinism, robustness to degenerate input, and the
//! learned BRIEF pattern against random Gaussian patterns.

mod common;

use common::metrics::precision;
use common::sim_frames::{frame_500, homography_pairs};
use image::GrayImage;
use jointloc_features::FeaturesError;
use jointloc_features::orb::{
    BriefPattern, GrayImageView, OrbConfig, OrbExtractor, OrbFeatures, hamming,
};
use jointloc_sim::TerrainKind;
use std::f64::consts::{FRAC_PI_2, TAU};

/// Rotation by 90° on screen: (x, y) ↦ (h − 1 − y, x), i.e. `image::imageops::rotate90`.
fn rotate90(img: &GrayImage) -> GrayImage {
    image::imageops::rotate90(img)
}

/// For each keypoint of `a`, the keypoint of `b` at its rotated position (same octave,
/// within 0.5 px), if any.
fn correspondences(a: &OrbFeatures, b: &OrbFeatures, h: f64) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    for (i, k) in a.keypoints.iter().enumerate() {
        let (x, y) = (h - 1.0 - k.y, k.x);
        if let Some(j) = b
            .keypoints
            .iter()
            .position(|o| o.octave == k.octave && (o.x - x).abs() <= 0.5 && (o.y - y).abs() <= 0.5)
        {
            out.push((i, j));
        }
    }
    out
}

#[test]
fn orientation_and_descriptors_follow_a_90_degree_rotation() {
    let ex = OrbExtractor::new(OrbConfig::default()).unwrap();
    for (kind, seed) in [(TerrainKind::Crater, 2101), (TerrainKind::Gravel, 2102)] {
        let img = frame_500(kind, seed);
        let rot = rotate90(&img);
        let (fa, fb) = (ex.extract(&img).unwrap(), ex.extract(&rot).unwrap());
        // FAST, the blur, the centre-aligned resize and the orientation disc are all symmetric
        // under a 90° turn of a square image, so most keypoints reappear exactly (cells and
        // quadtree splits are not symmetric, so not all of them).
        let pairs = correspondences(&fa, &fb, 500.0);
        assert!(
            pairs.len() > 500,
            "{kind:?}: only {} correspondences",
            pairs.len()
        );
        let mut angle_ok = 0;
        let mut dist = Vec::new();
        for &(i, j) in &pairs {
            let d = (fb.keypoints[j].angle - fa.keypoints[i].angle - FRAC_PI_2).rem_euclid(TAU);
            let err = d.min(TAU - d);
            angle_ok += (err < 1e-6) as usize;
            dist.push(hamming(&fa.descriptors[i], &fb.descriptors[j]));
        }
        // Orientation: exactly +90° (the centroid moments are permuted exactly).
        assert_eq!(angle_ok, pairs.len(), "{kind:?}: angles not rotated by 90°");
        // Descriptors: steering makes them nearly identical (rounding of rotated test points
        // can flip a few bits); unrelated keypoints differ in ~128 bits.
        dist.sort_unstable();
        let median = dist[dist.len() / 2];
        assert!(median <= 10, "{kind:?}: median Hamming distance {median}");
    }
}

#[test]
fn extraction_is_deterministic_and_sorted() {
    let img = frame_500(TerrainKind::Mountain, 2103);
    let ex = OrbExtractor::new(OrbConfig::default()).unwrap();
    let a = ex.extract(&img).unwrap();
    let b = OrbExtractor::new(OrbConfig::default())
        .unwrap()
        .extract(&img)
        .unwrap();
    assert_eq!(a, b);
    assert!((900..=1000).contains(&a.len()), "{} keypoints", a.len());
    assert!(
        a.keypoints
            .windows(2)
            .all(|w| w[0].response >= w[1].response)
    );
    assert_eq!(a.descriptors.len(), a.len());
    // Every level holds keypoints, positions are inside the image, sizes follow the octave.
    for k in &a.keypoints {
        assert!(k.x >= 0.0 && k.y >= 0.0 && k.x < 500.0 && k.y < 500.0);
        assert!((k.size - 31.0 * 1.2f64.powi(k.octave as i32)).abs() < 1e-9);
        assert!((0.0..TAU).contains(&k.angle));
    }
    for o in 0..8 {
        assert!(
            a.keypoints.iter().any(|k| k.octave == o),
            "octave {o} empty"
        );
    }
}

#[test]
fn degenerate_images_are_handled_without_panics() {
    let ex = OrbExtractor::new(OrbConfig::default()).unwrap();
    // All black: no keypoints, no error.
    let black = GrayImage::new(500, 500);
    let f = ex.extract(&black).unwrap();
    assert!(f.is_empty());
    // Too small for the 16 px border: an error, not a panic.
    for (w, h) in [(0, 0), (1, 1), (20, 500), (500, 32)] {
        let img = GrayImage::new(w, h);
        assert!(
            matches!(ex.extract(&img), Err(FeaturesError::ImageTooSmall { .. })),
            "{w}x{h}"
        );
    }
    // Smallest accepted size works (only level 0 fits).
    let tiny: Vec<u8> = (0..33 * 33).map(|i| ((i * 97) % 256) as u8).collect();
    let view = GrayImageView::new(33, 33, &tiny).unwrap();
    assert!(ex.extract(view).is_ok());
    // A buffer that does not match its size is rejected.
    assert!(matches!(
        GrayImageView::new(10, 10, &tiny),
        Err(FeaturesError::InvalidImage { .. })
    ));
    // Invalid configurations are rejected.
    for cfg in [
        OrbConfig {
            n_features: 0,
            ..OrbConfig::default()
        },
        OrbConfig {
            scale_factor: 1.0,
            ..OrbConfig::default()
        },
        OrbConfig {
            min_th_fast: 30,
            ..OrbConfig::default()
        },
        OrbConfig {
            edge_threshold: 10,
            ..OrbConfig::default()
        },
        OrbConfig {
            patch_size: 30,
            ..OrbConfig::default()
        },
    ] {
        assert!(OrbExtractor::new(cfg).is_err());
    }
}

/// The learned pattern matches at least as precisely as random Gaussian BRIEF patterns on
/// the same keypoints (pairs from seeds never used for learning).
#[test]
fn learned_pattern_is_not_worse_than_random_gaussian_patterns() {
    let pairs = homography_pairs(&[2201], 2, 0.5);
    let learned = OrbExtractor::new(OrbConfig::default()).unwrap();
    let mean_precision = |ex: &OrbExtractor| -> f64 {
        pairs
            .iter()
            .map(|p| precision(&ex.extract(&p.a).unwrap(), &ex.extract(&p.b).unwrap(), &p.h).1)
            .sum::<f64>()
            / pairs.len() as f64
    };
    let p_learned = mean_precision(&learned);
    let mut randoms = Vec::new();
    for seed in [1u64, 2, 3] {
        let ex =
            OrbExtractor::with_pattern(OrbConfig::default(), BriefPattern::random_gaussian(seed))
                .unwrap();
        randoms.push(mean_precision(&ex));
    }
    let p_random = randoms.iter().sum::<f64>() / randoms.len() as f64;
    eprintln!(
        "precision: learned {p_learned:.4}, random Gaussian {randoms:.4?} (mean {p_random:.4})"
    );
    assert!(
        p_learned >= p_random,
        "learned pattern {p_learned:.4} worse than random patterns {p_random:.4}"
    );
}
