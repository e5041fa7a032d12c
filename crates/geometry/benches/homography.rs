//! Homography RANSAC + refinement on 1000 matches (30 % outliers, σ = 0.5 px on both images),
//! the per-candidate cost of absolute localisation's geometric check.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use jointloc_geometry::homography::{HomographyConfig, estimate_homography, transfer_point};
use nalgebra::{Matrix3, Point2, Vector2};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// A mild perspective warp of a 500×500 image and its noisy, contaminated matches.
fn scene() -> (Vec<Point2<f64>>, Vec<Point2<f64>>) {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let h = Matrix3::new(0.95, 0.08, 12.0, -0.06, 1.02, 20.0, 1.5e-4, -8e-5, 1.0);
    let noise = Normal::new(0.0, 0.5).unwrap();
    let jitter = |rng: &mut ChaCha8Rng| Vector2::new(noise.sample(rng), noise.sample(rng));
    let uniform = |rng: &mut ChaCha8Rng| {
        Point2::new(rng.random_range(0.0..499.0), rng.random_range(0.0..499.0))
    };
    let (mut src, mut dst) = (Vec::new(), Vec::new());
    while src.len() < 700 {
        let s = uniform(&mut rng);
        let d = transfer_point(&h, &s);
        if d.x >= 0.0 && d.y >= 0.0 && d.x <= 499.0 && d.y <= 499.0 {
            src.push(s + jitter(&mut rng));
            dst.push(d + jitter(&mut rng));
        }
    }
    while src.len() < 1000 {
        src.push(uniform(&mut rng));
        dst.push(uniform(&mut rng));
    }
    (src, dst)
}

fn bench(c: &mut Criterion) {
    let (src, dst) = scene();
    let cfg = HomographyConfig::default();
    c.bench_function("homography_ransac_refine_1000", |b| {
        b.iter(|| estimate_homography(black_box(&src), black_box(&dst), &cfg).unwrap())
    });
    let plain = HomographyConfig {
        refine: false,
        ..cfg
    };
    c.bench_function("homography_ransac_dlt_1000", |b| {
        b.iter(|| estimate_homography(black_box(&src), black_box(&dst), &plain).unwrap())
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
