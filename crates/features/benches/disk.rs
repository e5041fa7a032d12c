//! DISK on the 500×500 golden image, 1 thread: the reference setting (resized to 1024×1024)
//! and the native size (padded to 512×512). Criterion's throughput is the network's FLOPs,
//! so "elem/s" reads as FLOP/s.

use std::path::PathBuf;
use std::time::Duration;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use jointloc_features::Detector;
use jointloc_features::disk::{Disk, DiskConfig};
use jointloc_features::models::ready_store;

fn image() -> image::GrayImage {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/golden/mars_a.png");
    image::open(path).expect("golden image").to_luma8()
}

fn disk(c: &mut Criterion) {
    let store = ready_store().expect("models (run `jointloc models fetch`)");
    let img = image();
    let mut group = c.benchmark_group("disk");
    group.sample_size(10);
    for (label, resize, secs) in [
        ("500x500 native", None, 40),
        ("500x500 resize 1024", Some(1024), 150),
    ] {
        let config = DiskConfig {
            resize,
            ..DiskConfig::default()
        };
        let flops = config.flops(500, 500);
        let disk = Disk::new(&store, config).expect("DISK");
        eprintln!("DISK {label}: {:.1} GFLOP per image", flops as f64 / 1e9);
        group.throughput(Throughput::Elements(flops));
        group.measurement_time(Duration::from_secs(secs));
        group.bench_function(label, |b| b.iter(|| disk.detect(&img).expect("detect")));
    }
    group.finish();
}

criterion_group!(benches, disk);
criterion_main!(benches);
