//! Local bundle adjustment on a typical ORB-SLAM window: 10 free + 10 fixed keyframes, 3000
//! points, ~20 000 observations (5 % gross outliers), 10 LM iterations.

use criterion::{Criterion, criterion_group, criterion_main};
use jointloc_slam::ba::synthetic::{SyntheticSceneConfig, synthetic_scene};
use jointloc_slam::ba::{BundleAdjustmentConfig, bundle_adjust};

fn local_window(c: &mut Criterion) {
    let scene = synthetic_scene(&SyntheticSceneConfig {
        rows: 2,
        cols: 10,
        spacing_m: 6.0,
        row_spacing_m: 12.0,
        points: 3000,
        observation_probability: 0.57,
        fixed_cameras: 10,
        seed: 7,
        ..Default::default()
    })
    .expect("valid scene");
    // Exactly 10 iterations: no early stop, so the figure is the worst case of the schedule.
    let config = BundleAdjustmentConfig {
        max_iterations: 10,
        function_tolerance: 0.0,
        gradient_tolerance: 0.0,
        step_tolerance: 0.0,
        ..Default::default()
    };
    let r = bundle_adjust(&scene.problem, &config).expect("solves");
    eprintln!(
        "window: {} cameras ({} free), {} points, {} observations; {} iterations ({:?}), cost {:.1} -> {:.1}",
        scene.problem.cameras.len(),
        scene.problem.cameras.iter().filter(|c| !c.fixed).count(),
        scene.problem.points.len(),
        scene.problem.observations.len(),
        r.iterations,
        r.termination,
        r.initial_cost,
        r.final_cost
    );
    c.bench_function("local_ba_10free_10fixed_3000pts_10it", |b| {
        b.iter(|| bundle_adjust(std::hint::black_box(&scene.problem), &config).expect("solves"))
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = local_window
}
criterion_main!(benches);
