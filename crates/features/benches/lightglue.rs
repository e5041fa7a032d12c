//! LightGlue (ALIKED weights) at 256 / 512 / 1024 keypoints per image, full depth and width
//! against the adaptive defaults, and LighterGlue at 1024, on 1 thread. Inputs are the golden
//! ALIKED (and XFeat) features of the Mars pair, the top-k by detection score. Criterion's
//! throughput for the full-depth cases is in FLOP/s ("elem/s"); a plain ONNX Runtime GEMM of
//! LightGlue's commonest shape gives the machine's single-core reference.

use std::path::PathBuf;
use std::time::Duration;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use jointloc_features::Features;
use jointloc_features::engine::{Engine, EngineConfig, NetTensor, OrtEngine};
use jointloc_features::lightglue::{LightGlue, LightGlueConfig, LightGlueFeatures};
use jointloc_features::models::ready_store;
use jointloc_features::onnx::{Dim, GraphBuilder};

fn golden(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/golden")
        .join(name)
}

fn f32s(st: &safetensors::SafeTensors, key: &str) -> (Vec<usize>, Vec<f32>) {
    let t = st.tensor(key).expect(key);
    let v = t
        .data()
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect();
    (t.shape().to_vec(), v)
}

/// The `k` highest-scoring golden features of image `side`.
fn top_k(file: &str, scores_key: &str, side: &str, k: usize) -> Features {
    let bytes = std::fs::read(golden(file)).expect("golden file");
    let st = safetensors::SafeTensors::deserialize(&bytes).expect("safetensors");
    let (_, kp) = f32s(&st, &format!("{side}.keypoints"));
    let (ds, d) = f32s(&st, &format!("{side}.descriptors"));
    let (_, s) = f32s(&st, &format!("{side}.{scores_key}"));
    let dim = ds[1];
    let mut order: Vec<usize> = (0..s.len()).collect();
    order.sort_by(|&a, &b| s[b].total_cmp(&s[a]));
    order.truncate(k);
    order.sort_unstable();
    Features {
        keypoints: order.iter().map(|&i| [kp[2 * i], kp[2 * i + 1]]).collect(),
        scores: order.iter().map(|&i| s[i]).collect(),
        descriptors: order
            .iter()
            .flat_map(|&i| d[i * dim..(i + 1) * dim].iter().copied())
            .collect(),
        descriptor_dim: dim,
        image_size: (500, 500),
    }
}

fn lightglue(c: &mut Criterion) {
    let store = ready_store().expect("models (run `jointloc models fetch`)");
    let t0 = std::time::Instant::now();
    let full = LightGlue::new(
        &store,
        LightGlueConfig::lightglue(LightGlueFeatures::Aliked).full(),
    )
    .expect("LightGlue");
    eprintln!(
        "LightGlue::new (graphs cached): {:.0} ms",
        t0.elapsed().as_secs_f64() * 1e3
    );
    let adaptive = LightGlue::new(
        &store,
        LightGlueConfig::lightglue(LightGlueFeatures::Aliked),
    )
    .expect("LightGlue");
    let mut group = c.benchmark_group("lightglue_aliked");
    group
        .sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(10));
    for k in [256, 512, 1024] {
        let a = top_k("aliked_sparse.safetensors", "keypoint_scores", "a", k);
        let b = top_k("aliked_sparse.safetensors", "keypoint_scores", "b", k);
        let flops = full.full_flops(k, k);
        let run = adaptive.match_pair(&a, &b).expect("match");
        eprintln!(
            "{k} keypoints: full depth {:.2} GFLOP; adaptive stops after {} layers keeping {:?}, \
             {} matches",
            flops / 1e9,
            run.layers_run,
            run.kept,
            run.matches.pairs.len()
        );
        group.throughput(Throughput::Elements(flops as u64));
        group.bench_with_input(BenchmarkId::new("full", k), &k, |bench, _| {
            bench.iter(|| full.match_pair(&a, &b).expect("match"))
        });
        group.throughput(Throughput::Elements(1));
        group.bench_with_input(BenchmarkId::new("adaptive", k), &k, |bench, _| {
            bench.iter(|| adaptive.match_pair(&a, &b).expect("match"))
        });
    }
    group.finish();

    let lighter = LightGlue::new(&store, LightGlueConfig::lighterglue()).expect("LighterGlue");
    let mut group = c.benchmark_group("lighterglue_xfeat");
    group
        .sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(5));
    let a = top_k("xfeat_sparse.safetensors", "scores", "a", 1024);
    let b = top_k("xfeat_sparse.safetensors", "scores", "b", 1024);
    eprintln!(
        "LighterGlue 1024 keypoints: full depth {:.2} GFLOP",
        lighter.full_flops(1024, 1024) / 1e9
    );
    group.bench_function("default_1024", |bench| {
        bench.iter(|| lighter.match_pair(&a, &b).expect("match"))
    });
    group.finish();
}

/// `[1024, 256] × [256, 768]` (the qkv projection at 1024 points) on ONNX Runtime, 1 thread:
/// the single-core GEMM rate LightGlue's GFLOP/s compares with.
fn gemm_reference(c: &mut Criterion) {
    let store = ready_store().expect("models");
    let (m, k, n) = (1024usize, 256usize, 768usize);
    let mut g = GraphBuilder::new("gemm");
    let x = g.input_f32("x", &[Dim::from(m), Dim::from(k)]);
    let w: Vec<f32> = (0..k * n)
        .map(|i| ((i % 97) as f32 - 48.0) / 97.0)
        .collect();
    let wv = g.tensor_f32(&[k, n], &w);
    let y = g.op("MatMul", &[&x, &wv], &[]);
    g.output_f32(&y, "y", &[Dim::from(m), Dim::from(n)]);
    let engine = OrtEngine::new(
        &store.onnxruntime_library(),
        &g.to_bytes(),
        "gemm",
        &EngineConfig::default(),
    )
    .expect("engine");
    let input: Vec<f32> = (0..m * k)
        .map(|i| ((i % 89) as f32 - 44.0) / 89.0)
        .collect();
    let mut group = c.benchmark_group("gemm_reference");
    group.throughput(Throughput::Elements((2 * m * k * n) as u64));
    group.bench_function("1024x256x768", |bench| {
        bench.iter(|| {
            engine
                .run(vec![("x", NetTensor::f32(&[m, k], input.clone()))])
                .expect("run")
        })
    });
    group.finish();
}

criterion_group!(benches, gemm_reference, lightglue);
criterion_main!(benches);
