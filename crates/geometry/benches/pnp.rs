//! PnP speed: RANSAC + refinement on 500 correspondences (30 % outliers, σ = 0.5 px) at 8–12 m
//! depth, f = 500 px, 500×500 image; and the bare P3P minimal solver.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use jointloc_geometry::pnp::{PnpConfig, p3p, solve_pnp_ransac};
use jointloc_geometry::{PinholeCamera, WorldToCamera};
use nalgebra::{Point2, Point3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

fn truth() -> WorldToCamera {
    WorldToCamera::from_rotation_translation(
        UnitQuaternion::from_scaled_axis(Vector3::new(0.3, -1.2, 0.4)),
        Vector3::new(5.0, -3.0, 20.0),
    )
}

fn scene(seed: u64, camera: &PinholeCamera) -> (Vec<Point3<f64>>, Vec<Point2<f64>>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let to_world = truth().inverse();
    let noise = Normal::new(0.0, 0.5).unwrap();
    let (w, h) = (camera.width as f64, camera.height as f64);
    (0..500)
        .map(|_| {
            let uv = Point2::new(
                rng.random_range(-0.5..w - 0.5),
                rng.random_range(-0.5..h - 0.5),
            );
            let ray = camera.unproject(&uv).unwrap();
            let p = to_world.transform_point(&Point3::from(ray * rng.random_range(8.0..12.0)));
            let observed = if rng.random_bool(0.3) {
                Point2::new(
                    rng.random_range(-0.5..w - 0.5),
                    rng.random_range(-0.5..h - 0.5),
                )
            } else {
                Point2::new(uv.x + noise.sample(&mut rng), uv.y + noise.sample(&mut rng))
            };
            (p, observed)
        })
        .unzip()
}

fn bench_pnp(c: &mut Criterion) {
    let camera = PinholeCamera::ideal(500.0, 500, 500);
    let (world, pixels) = scene(1, &camera);
    let config = PnpConfig::default();
    c.bench_function("pnp_ransac_refine_500pts_30pct_outliers", |b| {
        b.iter(|| {
            solve_pnp_ransac(black_box(&world), black_box(&pixels), &camera, &config).unwrap()
        })
    });

    // Noise-free bearings of the first three world points.
    let triple = [world[0], world[1], world[2]];
    let bearings = triple.map(|p| truth().transform_point(&p).coords);
    c.bench_function("p3p_lambda_twist", |b| {
        b.iter(|| p3p(black_box(&bearings), black_box(&triple)))
    });
}

criterion_group!(benches, bench_pnp);
criterion_main!(benches);
