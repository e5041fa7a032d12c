//! Acceptance tests of robust homography estimation on synthetic planar scenes.

use jointloc_geometry::GeometryError;
use jointloc_geometry::homography::{
    HomographyConfig, corner_error, estimate_homography, transfer_point,
};
use nalgebra::{Matrix3, Point2, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

const SIZE: f64 = 500.0;

/// The corner error extrapolates H to the image corners, so it grows as the matched region
/// shrinks: at ~50 % overlap even a least-squares fit on the known inliers exceeds 0.5 px for some
/// scenes (σ = 0.5 px). The accuracy target is stated for the intended use (a UAV image inside
/// its satellite tile, large overlap); [`matches_oracle_at_any_overlap`] covers the rest.
const MIN_OVERLAP: f64 = 0.7;

/// Homography of a random plane seen by two 500×500 pinhole cameras (f = 500 px), the second
/// one rotated by up to ~11° and translated by up to 30 % of the plane distance.
fn random_plane_homography(rng: &mut ChaCha8Rng) -> Matrix3<f64> {
    let k = Matrix3::new(500.0, 0.0, 249.5, 0.0, 500.0, 249.5, 0.0, 0.0, 1.0);
    let mut v = || {
        Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        )
    };
    let r = UnitQuaternion::from_scaled_axis(v() * 0.2);
    let t = v() * 0.3;
    let n = (Vector3::z() + v() * 0.3).normalize();
    let e = r.to_rotation_matrix().into_inner() + t * n.transpose();
    let h = k * e * k.try_inverse().unwrap();
    h / h[(2, 2)]
}

struct Scene {
    h: Matrix3<f64>,
    src: Vec<Point2<f64>>,
    dst: Vec<Point2<f64>>,
}

/// Fraction of the source image that `h` maps inside the target image (25×25 grid).
fn overlap(h: &Matrix3<f64>) -> f64 {
    let step = SIZE / 25.0;
    let inside = (0..25 * 25)
        .filter(|k| {
            let s = Point2::new(
                (k % 25) as f64 * step + step / 2.0,
                (k / 25) as f64 * step + step / 2.0,
            );
            let d = transfer_point(h, &s);
            d.x >= 0.0 && d.y >= 0.0 && d.x <= SIZE - 1.0 && d.y <= SIZE - 1.0
        })
        .count();
    inside as f64 / 625.0
}

/// `n` matches, `outlier_ratio` of them uniform in the image, Gaussian noise `sigma` on both sides;
/// the homography is redrawn until at least `min_overlap` of the source image lands in the target.
fn scene(seed: u64, n: usize, outlier_ratio: f64, sigma: f64, min_overlap: f64) -> Scene {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let h = loop {
        let h = random_plane_homography(&mut rng);
        if overlap(&h) >= min_overlap {
            break h;
        }
    };
    let noise = Normal::new(0.0, sigma).unwrap();
    let n_out = (n as f64 * outlier_ratio).round() as usize;
    let inside =
        |p: &Point2<f64>| p.x >= 0.0 && p.y >= 0.0 && p.x <= SIZE - 1.0 && p.y <= SIZE - 1.0;
    let mut src = Vec::with_capacity(n);
    let mut dst = Vec::with_capacity(n);
    while src.len() < n - n_out {
        let s = Point2::new(
            rng.random_range(0.0..SIZE - 1.0),
            rng.random_range(0.0..SIZE - 1.0),
        );
        let d = transfer_point(&h, &s);
        if inside(&d) {
            src.push(s + Vector2Noise::draw(&noise, &mut rng));
            dst.push(d + Vector2Noise::draw(&noise, &mut rng));
        }
    }
    for _ in 0..n_out {
        src.push(Point2::new(
            rng.random_range(0.0..SIZE - 1.0),
            rng.random_range(0.0..SIZE - 1.0),
        ));
        dst.push(Point2::new(
            rng.random_range(0.0..SIZE - 1.0),
            rng.random_range(0.0..SIZE - 1.0),
        ));
    }
    // Shuffle so that outliers are not a contiguous block.
    for i in (1..n).rev() {
        let j = rng.random_range(0..=i);
        src.swap(i, j);
        dst.swap(i, j);
    }
    Scene { h, src, dst }
}

struct Vector2Noise;
impl Vector2Noise {
    fn draw(noise: &Normal<f64>, rng: &mut ChaCha8Rng) -> nalgebra::Vector2<f64> {
        nalgebra::Vector2::new(noise.sample(rng), noise.sample(rng))
    }
}

#[test]
fn accurate_under_noise_and_outliers() {
    for seed in 0..6 {
        let sc = scene(seed, 1000, 0.3, 0.5, MIN_OVERLAP);
        let cfg = HomographyConfig {
            ransac: jointloc_geometry::RansacConfig {
                seed,
                ..HomographyConfig::default().ransac
            },
            ..Default::default()
        };
        let r = estimate_homography(&sc.src, &sc.dst, &cfg).unwrap();
        let err = corner_error(&r.h, &sc.h, 500, 500);
        assert!(err < 0.5, "seed {seed}: corner error {err} px");
        // 700 true inliers; outliers falling within 3 px by chance are rare.
        assert!(
            (680..=710).contains(&r.inliers.len()),
            "seed {seed}: {} inliers",
            r.inliers.len()
        );
        assert!(r.inliers.windows(2).all(|w| w[0] < w[1]));
        // σ = 0.5 px per coordinate on both sides: each one-way 2-D transfer error has
        // E‖e‖² ≈ 2·2σ² = 1 px², so the RMS is about 1 px.
        eprintln!(
            "seed {seed}: corner error {err:.4} px, {} inliers, {} iterations, rms {:.3} px",
            r.inliers.len(),
            r.iterations,
            r.rms_error
        );
        assert!(
            r.rms_error > 0.8 && r.rms_error < 1.2,
            "seed {seed}: rms {}",
            r.rms_error
        );
        assert!((r.h[(2, 2)] - 1.0).abs() < 1e-12);
    }
}

#[test]
fn refinement_does_not_hurt() {
    let mut sum_plain = 0.0;
    let mut sum_refined = 0.0;
    for seed in 10..15 {
        let sc = scene(seed, 1000, 0.3, 0.5, MIN_OVERLAP);
        let mut cfg = HomographyConfig::default();
        cfg.ransac.seed = seed;
        let refined = estimate_homography(&sc.src, &sc.dst, &cfg).unwrap();
        cfg.refine = false;
        let plain = estimate_homography(&sc.src, &sc.dst, &cfg).unwrap();
        sum_plain += corner_error(&plain.h, &sc.h, 500, 500);
        sum_refined += corner_error(&refined.h, &sc.h, 500, 500);
    }
    assert!(
        sum_refined <= sum_plain * 1.1,
        "refined {sum_refined} vs DLT {sum_plain}"
    );
}

#[test]
fn same_seed_same_answer() {
    for seed in [3, 17, 99, 1234, 5555] {
        let sc = scene(seed, 1000, 0.3, 0.5, MIN_OVERLAP);
        let mut cfg = HomographyConfig::default();
        cfg.ransac.seed = seed;
        let a = estimate_homography(&sc.src, &sc.dst, &cfg).unwrap();
        let b = estimate_homography(&sc.src, &sc.dst, &cfg).unwrap();
        assert_eq!(a.inliers, b.inliers);
        assert_eq!(a.iterations, b.iterations);
        assert_eq!(a.h, b.h, "bitwise identical H expected");
    }
}

#[test]
fn exact_data_is_recovered() {
    for seed in 20..25 {
        let sc = scene(seed, 200, 0.0, 0.0, 0.0);
        let r = estimate_homography(&sc.src, &sc.dst, &HomographyConfig::default()).unwrap();
        assert_eq!(r.inliers.len(), 200);
        assert!(corner_error(&r.h, &sc.h, 500, 500) < 1e-8);
        assert!(r.rms_error < 1e-8);
    }
}

#[test]
fn bad_input_gives_errors() {
    let sc = scene(1, 100, 0.3, 0.5, 0.0);
    let cfg = HomographyConfig::default();
    for n in 0..4 {
        assert!(matches!(
            estimate_homography(&sc.src[..n], &sc.dst[..n], &cfg),
            Err(GeometryError::TooFewPoints { required: 4, found }) if found == n
        ));
    }
    assert!(matches!(
        estimate_homography(&sc.src, &sc.dst[..50], &cfg),
        Err(GeometryError::LengthMismatch { .. })
    ));
    for bad in [f64::NAN, f64::INFINITY] {
        let mut src = sc.src.clone();
        src[7].y = bad;
        assert!(matches!(
            estimate_homography(&src, &sc.dst, &cfg),
            Err(GeometryError::NonFinite(_))
        ));
        let mut dst = sc.dst.clone();
        dst[0].x = bad;
        assert!(estimate_homography(&sc.src, &dst, &cfg).is_err());
    }
    // All points on one line: no homography, an error rather than a panic or a garbage H.
    let line: Vec<_> = (0..50)
        .map(|i| Point2::new(i as f64, 3.0 * i as f64))
        .collect();
    let mut small = cfg;
    small.ransac.max_iterations = 100;
    assert!(estimate_homography(&line, &line, &small).is_err());
    let mut bad_cfg = cfg;
    bad_cfg.ransac.threshold = -1.0;
    assert!(matches!(
        estimate_homography(&sc.src, &sc.dst, &bad_cfg),
        Err(GeometryError::InvalidConfig { .. })
    ));
}

#[test]
fn corner_error_metric() {
    let id = Matrix3::identity();
    assert_eq!(corner_error(&id, &id, 500, 500), 0.0);
    let mut shift = id;
    shift[(0, 2)] = 3.0;
    shift[(1, 2)] = 4.0;
    assert!((corner_error(&shift, &id, 500, 500) - 5.0).abs() < 1e-12);
    // A homography sending the corner (512, 0) to infinity.
    let mut inf = id;
    inf[(2, 0)] = -1.0 / 512.0;
    assert_eq!(corner_error(&inf, &id, 513, 513), f64::INFINITY);
}

/// Against a least-squares fit that knows the true inliers (DLT + the same refinement), at any
/// overlap: robust estimation must cost (almost) nothing in accuracy.
#[test]
fn matches_oracle_at_any_overlap() {
    use jointloc_geometry::homography::{dlt, refine_homography};
    for seed in 30..40 {
        let sc = scene(seed, 1000, 0.3, 0.5, 0.3);
        let truth: Vec<usize> = (0..sc.src.len())
            .filter(|&i| (transfer_point(&sc.h, &sc.src[i]) - sc.dst[i]).norm() < 4.0)
            .collect();
        let s: Vec<_> = truth.iter().map(|&i| sc.src[i]).collect();
        let d: Vec<_> = truth.iter().map(|&i| sc.dst[i]).collect();
        let all: Vec<usize> = (0..s.len()).collect();
        let oracle = refine_homography(&dlt(&s, &d).unwrap(), &s, &d, &all, 20)
            .unwrap()
            .h;
        let mut cfg = HomographyConfig::default();
        cfg.ransac.seed = seed;
        let r = estimate_homography(&sc.src, &sc.dst, &cfg).unwrap();
        let (ours, best) = (
            corner_error(&r.h, &sc.h, 500, 500),
            corner_error(&oracle, &sc.h, 500, 500),
        );
        assert!(
            ours < best + 0.05,
            "seed {seed}: ours {ours} px vs oracle {best} px"
        );
    }
}
