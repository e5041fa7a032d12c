//! Two-view speed: essential matrix + relative pose, and the fundamental matrix, on 500
//! correspondences (30 % outliers, σ = 0.5 px, 5–20 m depth, 1 m baseline, 10° rotation,
//! f = 500 px, 500×500 image); the bare five-point solver; two-view point triangulation.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use jointloc_geometry::pose::so3_exp;
use jointloc_geometry::triangulation::{TriangulationConfig, triangulate};
use jointloc_geometry::two_view::{
    FundamentalConfig, RelativePoseConfig, essential_five_point, estimate_fundamental,
    estimate_relative_pose,
};
use jointloc_geometry::{PinholeCamera, WorldToCamera};
use nalgebra::{Point2, Point3, Vector2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

struct Scene {
    camera: PinholeCamera,
    pose2: WorldToCamera,
    x1: Vec<Point2<f64>>,
    x2: Vec<Point2<f64>>,
}

fn scene(seed: u64) -> Scene {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let camera = PinholeCamera::ideal(500.0, 500, 500);
    let rotation = so3_exp(&(Vector3::new(0.2, 1.0, 0.1).normalize() * 10f64.to_radians()));
    let translation = -(rotation * Vector3::new(0.9, 0.4, 0.1).normalize());
    let pose2 = WorldToCamera::from_rotation_translation(rotation, translation);
    let noise = Normal::new(0.0, 0.5).unwrap();
    let (mut x1, mut x2) = (Vec::new(), Vec::new());
    while x1.len() < 500 {
        let uv = Point2::new(rng.random_range(0.0..500.0), rng.random_range(0.0..500.0));
        let p = Point3::from(camera.unproject(&uv).unwrap() * rng.random_range(5.0..20.0));
        let Some(uv2) = camera.project(&pose2.transform_point(&p)) else {
            continue;
        };
        if !camera.contains(&uv2, 0.0) {
            continue;
        }
        let uv2 = if rng.random_bool(0.3) {
            Point2::new(rng.random_range(0.0..500.0), rng.random_range(0.0..500.0))
        } else {
            uv2 + Vector2::new(noise.sample(&mut rng), noise.sample(&mut rng))
        };
        x1.push(uv + Vector2::new(noise.sample(&mut rng), noise.sample(&mut rng)));
        x2.push(uv2);
    }
    Scene {
        camera,
        pose2,
        x1,
        x2,
    }
}

fn bench(c: &mut Criterion) {
    let s = scene(1);
    let rp_cfg = RelativePoseConfig::default();
    c.bench_function("relative_pose_500", |b| {
        b.iter(|| estimate_relative_pose(black_box(&s.x1), &s.x2, &s.camera, &rp_cfg).unwrap())
    });
    let f_cfg = FundamentalConfig::default();
    c.bench_function("fundamental_500", |b| {
        b.iter(|| estimate_fundamental(black_box(&s.x1), &s.x2, &f_cfg).unwrap())
    });
    let rays1: Vec<Vector3<f64>> = s.x1[..5]
        .iter()
        .map(|p| s.camera.unproject(p).unwrap())
        .collect();
    let rays2: Vec<Vector3<f64>> = s.x2[..5]
        .iter()
        .map(|p| s.camera.unproject(p).unwrap())
        .collect();
    c.bench_function("five_point", |b| {
        b.iter(|| essential_five_point(black_box(&rays1), &rays2))
    });
    let poses = [WorldToCamera::identity(), s.pose2];
    let pixels = [s.x1[1], s.x2[1]];
    let t_cfg = TriangulationConfig::default();
    c.bench_function("triangulate_two_views", |b| {
        b.iter(|| triangulate(black_box(&poses), &pixels, &s.camera, &t_cfg))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
