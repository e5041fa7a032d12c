//! Learns the steered-BRIEF test pattern (ORB paper §4.3) on simulated Mars frames and writes
//! `crates/features/src/orb/pattern.rs`.
//!
//! ```text
//! cargo run --release -p jointloc-features --example learn_brief_pattern [-- OUT.rs]
//! ```
//!
//! Training data: 3 terrains × seeds 1000–1004 × 2 views, 500 × 500 px; every keypoint the
//! extractor keeps (all levels) gives one oriented patch, at most `MAX_PATCHES` of them drawn
//! with a fixed seed. Deterministic: rerunning writes the same file.

#[path = "../tests/common/sim_frames.rs"]
mod sim_frames;

use std::fmt::Write as _;
use std::path::PathBuf;

use jointloc_features::orb::learn::{LearnConfig, TrainingSet, learn_pattern};
use jointloc_features::orb::{OrbConfig, OrbExtractor};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use sim_frames::{KINDS, View, render_views};

const SEEDS: std::ops::Range<u64> = 1000..1005;
const MAX_PATCHES: usize = 30_000;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = std::env::args()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("src/orb/pattern.rs"));
    let extractor = OrbExtractor::new(OrbConfig::default())?;
    let views = [
        View {
            dx: -1.5,
            dy: 1.0,
            yaw: 0.3,
        },
        View {
            dx: 2.0,
            dy: -1.5,
            yaw: 2.1,
        },
    ];
    // Collect (frame, level, x, y, angle) first, then subsample, then sample patches.
    let mut frames = Vec::new();
    for kind in KINDS {
        for seed in SEEDS {
            frames.extend(render_views(kind, seed, 500, &views));
            eprintln!("rendered {kind:?} seed {seed}");
        }
    }
    let mut all = Vec::new();
    let mut detections = Vec::new();
    for (fi, f) in frames.iter().enumerate() {
        let (pyr, kps) = extractor.detect(f)?;
        for (ki, _) in kps.iter().enumerate() {
            all.push((fi, ki));
        }
        detections.push((pyr, kps));
    }
    let mut rng = ChaCha8Rng::seed_from_u64(1000);
    let chosen: Vec<usize> = if all.len() > MAX_PATCHES {
        let mut idx = rand::seq::index::sample(&mut rng, all.len(), MAX_PATCHES).into_vec();
        idx.sort_unstable();
        idx
    } else {
        (0..all.len()).collect()
    };
    let cfg = LearnConfig::default();
    let mut set = TrainingSet::new(&cfg)?;
    for &i in &chosen {
        let (fi, ki) = all[i];
        let (pyr, kps) = &detections[fi];
        let k = &kps[ki];
        let l = &pyr.levels[k.level as usize];
        set.add_patch(
            &l.blurred,
            l.width,
            l.height,
            k.x as usize,
            k.y as usize,
            k.angle,
        );
    }
    eprintln!("{} keypoints, {} patches; learning…", all.len(), set.len());
    let t = std::time::Instant::now();
    let learned = learn_pattern(&set, &cfg)?;
    eprintln!(
        "threshold {:.3}, mean |bias| {:.4}, mean |corr| {:.4}, {} candidates, {:.1} s",
        learned.threshold,
        learned.mean_bias,
        learned.mean_abs_correlation,
        learned.n_candidates,
        t.elapsed().as_secs_f64()
    );

    let mut s = String::new();
    writeln!(
        s,
        "//! Steered-BRIEF test pattern learned on simulated Mars frames (ORB paper's greedy"
    )?;
    writeln!(
        s,
        "//! procedure, see `learn.rs`). GENERATED, do not edit; regenerate with"
    )?;
    writeln!(
        s,
        "//! `cargo run --release -p jointloc-features --example learn_brief_pattern`."
    )?;
    writeln!(s, "//!")?;
    writeln!(
        s,
        "//! Training: {} frames (crater, gravel, mountain; seeds {}–{}), {} patches, {} candidate",
        frames.len(),
        SEEDS.start,
        SEEDS.end - 1,
        learned.n_patches,
        learned.n_candidates
    )?;
    writeln!(
        s,
        "//! tests; correlation threshold {:.3}, mean |mean − 0.5| {:.4}, mean |correlation| {:.4}.",
        learned.threshold, learned.mean_bias, learned.mean_abs_correlation
    )?;
    writeln!(s)?;
    writeln!(
        s,
        "/// The 256 tests `[x1, y1, x2, y2]`: bit i is `I(p1) < I(p2)` on the blurred level."
    )?;
    writeln!(s, "#[rustfmt::skip]")?;
    writeln!(s, "pub const LEARNED_PATTERN: [[i8; 4]; 256] = [")?;
    for t in learned.pattern.tests() {
        writeln!(s, "    [{}, {}, {}, {}],", t[0], t[1], t[2], t[3])?;
    }
    writeln!(s, "];")?;
    std::fs::write(&out, s)?;
    eprintln!("wrote {}", out.display());
    Ok(())
}
