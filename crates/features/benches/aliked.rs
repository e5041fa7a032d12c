//! ALIKED-N16 on the 500×500 golden image, 1 thread: the reference setting (resized to
//! 1024×1024, the golden configuration) and the native size (padded to 512×512). Criterion's
//! throughput is the FLOP count of [`AlikedConfig::flops`], so "elem/s" reads as FLOP/s.

use std::path::PathBuf;
use std::time::Duration;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use jointloc_features::Detector;
use jointloc_features::aliked::{Aliked, AlikedConfig};
use jointloc_features::models::ready_store;

fn image() -> image::GrayImage {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/golden/mars_a.png");
    image::open(path).expect("golden image").to_luma8()
}

fn aliked(c: &mut Criterion) {
    let store = ready_store().expect("models (run `jointloc models fetch`)");
    let img = image();
    let mut group = c.benchmark_group("aliked");
    group.sample_size(10);
    for (label, resize, secs) in [
        ("n16 500x500 native", None, 30),
        ("n16 500x500 resize 1024", Some(1024), 90),
    ] {
        let config = AlikedConfig {
            resize,
            ..AlikedConfig::default()
        };
        let flops = config.flops(500, 500);
        let aliked = Aliked::new(&store, config).expect("ALIKED");
        eprintln!("ALIKED {label}: {:.2} GFLOP per image", flops as f64 / 1e9);
        group.throughput(Throughput::Elements(flops));
        group.measurement_time(Duration::from_secs(secs));
        group.bench_function(label, |b| b.iter(|| aliked.detect(&img).expect("detect")));
    }
    group.finish();
}

criterion_group!(benches, aliked);
criterion_main!(benches);
