//! The machine's single-core GEMM speed as the limit reference for the networks' GFLOP/s:
//! one 1024×1024×1024 f32 `MatMul` on ONNX Runtime with 1 intra-op thread (the graph built
//! with our `GraphBuilder`). Throughput is in FLOPs ("elem/s" = FLOP/s, 2·n³ per run); wall
//! time (`gemm/…`) and the thread's CPU time (`gemm_cpu/…`, see `cpu_time`).

use std::time::Duration;

use criterion::measurement::{Measurement, WallTime};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use jointloc_features::engine::{Engine, EngineConfig, NetTensor, OrtEngine};
use jointloc_features::models::ready_store;
use jointloc_features::onnx::{Dim, GraphBuilder};

mod cpu_time;
use cpu_time::ThreadCpuTime;

fn gemm<M: Measurement>(c: &mut Criterion<M>, name: &str) {
    let store = ready_store().expect("models (run `jointloc models fetch`)");
    let n = 1024;
    let mut g = GraphBuilder::new("gemm");
    let a = g.input_f32("a", &[Dim::from(n), Dim::from(n)]);
    let b = g.input_f32("b", &[Dim::from(n), Dim::from(n)]);
    let y = g.op("MatMul", &[&a, &b], &[]);
    g.output_f32(&y, "y", &[Dim::from(n), Dim::from(n)]);
    let engine = OrtEngine::new(
        &store.onnxruntime_library(),
        &g.to_bytes(),
        "gemm",
        &EngineConfig::default(),
    )
    .expect("gemm graph");
    let values = |seed: usize| -> Vec<f32> {
        (0..n * n)
            .map(|i| ((i * 7919 + seed) % 1000) as f32 * 1e-3 - 0.5)
            .collect()
    };
    let (va, vb) = (values(1), values(2));

    let mut group = c.benchmark_group(name);
    group.sample_size(20);
    group.measurement_time(Duration::from_secs(10));
    group.throughput(Throughput::Elements(2 * (n * n * n) as u64));
    group.bench_function("onnxruntime matmul 1024 f32 1 thread", |bench| {
        bench.iter(|| {
            engine
                .run(vec![
                    ("a", NetTensor::f32(&[n, n], va.clone())),
                    ("b", NetTensor::f32(&[n, n], vb.clone())),
                ])
                .expect("gemm")
        })
    });
    group.finish();
}

fn wall(c: &mut Criterion<WallTime>) {
    gemm(c, "gemm");
}

fn cpu(c: &mut Criterion<ThreadCpuTime>) {
    gemm(c, "gemm_cpu");
}

criterion_group!(wall_time, wall);
criterion_group! {
    name = cpu_time;
    config = Criterion::default().with_measurement(ThreadCpuTime);
    targets = cpu
}
criterion_main!(wall_time, cpu_time);
