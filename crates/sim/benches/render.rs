//! Rendering one 500 × 500 UAV frame (ray casting + sensor model) over a crater terrain at
//! 10 m, the per-frame cost of `jointloc sim`. Target: ≤ 100 ms median on 2 cores.

use criterion::{Criterion, criterion_group, criterion_main};
use jointloc_geometry::{CameraToWorld, PinholeCamera};
use jointloc_sim::render::UavRenderer;
use jointloc_sim::sensor::{SensorConfig, expose};
use jointloc_sim::trajectory::nadir_rotation;
use jointloc_sim::{
    ShadingConfig, Sun, TerrainConfig, TerrainExtent, TerrainKind, generate_terrain, shade,
};
use nalgebra::{UnitQuaternion, Vector3};

fn bench(c: &mut Criterion) {
    let cfg = TerrainConfig::default();
    // 40 m × 40 m at 2.5 cm.
    let extent = TerrainExtent {
        origin_x: 0.0,
        origin_y: 0.0,
        width_cells: 1600,
        height_cells: 1600,
    };
    let terrain = generate_terrain(TerrainKind::Crater, &extent, &cfg, 1).expect("terrain");
    let sun = Sun {
        azimuth_deg: 135.0,
        elevation_deg: 45.0,
    };
    let radiance = shade(&terrain, &sun, &ShadingConfig::default());
    let camera = PinholeCamera::ideal(500.0, 500, 500);
    let renderer = UavRenderer::new(&terrain, &radiance, camera).expect("renderer");
    let ground = terrain.height_at(20.0, -20.0);
    let r = UnitQuaternion::from_rotation_matrix(&nadir_rotation(0.6))
        * UnitQuaternion::from_scaled_axis(Vector3::new(0.01, -0.008, 0.003));
    let pose =
        CameraToWorld::from_rotation_translation(r, Vector3::new(20.0, -20.0, ground + 10.0));
    let sensor = SensorConfig::default();
    let exposure = sensor.exposure_for(&radiance.data);

    let mut group = c.benchmark_group("uav_frame_500x500");
    group.sample_size(20);
    group.bench_function("render", |b| b.iter(|| renderer.render(&pose)));
    let frame = renderer.render(&pose);
    group.bench_function("sensor", |b| {
        b.iter(|| expose(&frame.radiance, &sensor, exposure, 7))
    });
    group.bench_function("render+sensor", |b| {
        b.iter(|| expose(&renderer.render(&pose).radiance, &sensor, exposure, 7))
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
