//! XFeat on the 500×500 golden image, 1 thread: whole `detect`, the network alone, the Rust
//! pre- and post-processing alone, and MNN matching of two 1024-keypoint sets. Network
//! throughput is in FLOPs ("elem/s" = FLOP/s); compare with `benches/gemm.rs`.
//!
//! Every case runs twice: wall-clock time (`xfeat/…`) and the benchmark thread's CPU time
//! (`xfeat_cpu/…`, see `cpu_time`).

use std::path::PathBuf;
use std::time::Duration;

use criterion::measurement::{Measurement, WallTime};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use jointloc_features::mnn::MnnMatcher;
use jointloc_features::models::ready_store;
use jointloc_features::xfeat::{SparseParams, XFeat, XFeatConfig, preprocess, sparse};
use jointloc_features::{Detector, Matcher};

mod cpu_time;
use cpu_time::ThreadCpuTime;

fn image(tag: &str) -> image::GrayImage {
    let path =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(format!("tests/golden/mars_{tag}.png"));
    image::open(path).expect("golden image").to_luma8()
}

fn cases<M: Measurement>(c: &mut Criterion<M>, name: &str) {
    let store = ready_store().expect("models (run `jointloc models fetch`)");
    let net = XFeat::from_store(&store, XFeatConfig::default()).expect("XFeat");
    let (img, img_b) = (image("a"), image("b"));
    let flops = XFeat::flops(500, 500);
    eprintln!(
        "XFeat 500x500 (network input 480x480): {:.3} GFLOP per image",
        flops as f64 / 1e9
    );

    let mut group = c.benchmark_group(name);
    group.sample_size(20);
    group.measurement_time(Duration::from_secs(12));
    group.throughput(Throughput::Elements(flops));
    group.bench_function("500x500 detect", |b| {
        b.iter(|| net.detect(&img).expect("detect"))
    });
    let input = preprocess(&img).expect("preprocess");
    group.bench_function("500x500 network", |b| {
        b.iter(|| net.run(&input).expect("run"))
    });

    group.throughput(Throughput::Elements(1));
    group.bench_function("500x500 preprocess", |b| {
        b.iter(|| preprocess(&img).expect("preprocess"))
    });
    let dense = net.run(&input).expect("run");
    let params = SparseParams {
        top_k: 1024,
        detection_threshold: 0.05,
        nms_size: 5,
        scale_x: input.scale_x,
        scale_y: input.scale_y,
        image_size: (500, 500),
    };
    group.bench_function("500x500 postprocess", |b| {
        b.iter(|| sparse(&dense, &params))
    });

    let (fa, fb) = (net.detect(&img).expect("a"), net.detect(&img_b).expect("b"));
    let mnn = MnnMatcher::default();
    group.throughput(Throughput::Elements(2 * (fa.len() * fb.len() * 64) as u64));
    group.bench_function(format!("mnn {}x{}", fa.len(), fb.len()), |b| {
        b.iter(|| mnn.match_features(&fa, &fb).expect("mnn"))
    });
    group.finish();
}

fn wall(c: &mut Criterion<WallTime>) {
    cases(c, "xfeat");
}

fn cpu(c: &mut Criterion<ThreadCpuTime>) {
    cases(c, "xfeat_cpu");
}

criterion_group!(wall_time, wall);
criterion_group! {
    name = cpu_time;
    config = Criterion::default().with_measurement(ThreadCpuTime);
    targets = cpu
}
criterion_main!(wall_time, cpu_time);
