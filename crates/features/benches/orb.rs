//! ORB extraction on one simulated 500 × 500 frame, 1000 features, single-threaded; and the
//! brute-force mutual matcher on two such frames. Goal: extraction ≤ ~10 ms (tracking has
//! 20 ms per frame in all).
//!
//! `cargo bench -p jointloc-features --bench orb`

#[path = "../tests/common/sim_frames.rs"]
mod sim_frames;

use criterion::{Criterion, criterion_group, criterion_main};
use jointloc_features::orb::{MatcherConfig, OrbConfig, OrbExtractor, Ranking, match_mutual};
use jointloc_sim::TerrainKind;
use sim_frames::{View, render_views};

fn bench(c: &mut Criterion) {
    let frames = render_views(
        TerrainKind::Crater,
        2001,
        500,
        &[
            View {
                dx: 0.0,
                dy: 0.0,
                yaw: 0.4,
            },
            View {
                dx: 0.6,
                dy: 0.3,
                yaw: 0.5,
            },
        ],
    );
    let extractor = OrbExtractor::new(OrbConfig::default()).expect("config");
    let fast_ranked = OrbExtractor::new(OrbConfig {
        ranking: Ranking::Fast,
        ..OrbConfig::default()
    })
    .expect("config");
    let mut group = c.benchmark_group("orb_500x500_1000");
    group.sample_size(30);
    group.bench_function("extract", |b| {
        b.iter(|| extractor.extract(&frames[0]).expect("extract"))
    });
    group.bench_function("extract_fast_ranking", |b| {
        b.iter(|| fast_ranked.extract(&frames[0]).expect("extract"))
    });
    group.bench_function("detect_only", |b| {
        b.iter(|| extractor.detect(&frames[0]).expect("detect"))
    });
    let fa = extractor.extract(&frames[0]).expect("extract");
    let fb = extractor.extract(&frames[1]).expect("extract");
    let cfg = MatcherConfig::default();
    group.bench_function("match_mutual", |b| b.iter(|| match_mutual(&fa, &fb, &cfg)));
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
