//! `jointloc run` end to end, threaded (absolute localisation on its own thread) on a small
//! simulated dataset with the ORB matcher: every due frame is searched or counted as skipped,
//! as accurate as sequential; real-time replay releases frames at their timestamps, reports the
//! lag and drops none, and is refused with `--sequential`.

mod common;

use common::{base, dataset, jointloc, run_orb, s};

/// Threaded: every due frame (one in `fusion_every`) is either searched or counted as
/// skipped, and the result is as good as the sequential run's.
fn threaded_searches_or_skips_every_due_frame(seed: &str) {
    let frames = base(seed).summary["frames"].as_u64().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let threaded = dir.path().join("threaded");
    let (stdout, t) = run_orb(seed, &threaded, &[]);
    assert_eq!(t["mode"], "threaded", "seed {seed}");
    let every = jointloc_system::JointLocConfig::default().fusion_every as u64;
    let due = frames.div_ceil(every);
    let attempts = t["absolute_attempts"].as_u64().unwrap();
    let skipped = t["skipped_busy"].as_u64().unwrap() + t["skipped_untracked"].as_u64().unwrap();
    assert!(
        attempts + skipped <= due && attempts + skipped + 1 >= due,
        "seed {seed}: {attempts} + {skipped} vs {due}"
    );
    let rmse_t = t["ape_translation"]["rmse"].as_f64().unwrap();
    eprintln!("seed {seed}: rmse threaded {rmse_t:.3}");
    assert!(
        rmse_t < 0.3,
        "seed {seed}: threaded rmse {rmse_t}\n{stdout}"
    );
}

#[test]
fn threaded_searches_or_skips_every_due_frame_seed_31() {
    threaded_searches_or_skips_every_due_frame("31");
}

#[test]
fn threaded_searches_or_skips_every_due_frame_seed_32() {
    threaded_searches_or_skips_every_due_frame("32");
}

/// Real-time replay: frames released at their timestamps (here 3× the 5 Hz camera rate), so
/// 60 frames cannot take less than 59 × 0.2 s / 3; the lag behind the camera is reported and
/// no frame is dropped. `--realtime` is the threaded mode's; with `--sequential` it is refused.
#[test]
fn realtime_replay_keeps_to_the_camera_clock_seed_31() {
    let seed = "31";
    let data = dataset(seed);
    let dir = tempfile::tempdir().unwrap();
    let rt = dir.path().join("realtime");
    let began = std::time::Instant::now();
    let (stdout, r) = run_orb(seed, &rt, &["--realtime", "3", "--max-frames", "60"]);
    let wall = began.elapsed().as_secs_f64();
    assert!(wall >= 59.0 * 0.2 / 3.0, "seed {seed}: {wall} s\n{stdout}");
    assert!(
        stdout.contains("real-time replay at 3× the camera rate"),
        "seed {seed}: {stdout}"
    );
    assert_eq!(r["mode"], "threaded, real-time replay", "seed {seed}");
    assert_eq!(r["frames"], 60, "seed {seed}");
    assert_eq!(r["realtime"]["speed"], 3.0, "seed {seed}");
    let lag = r["realtime"]["lag_max_ms"].as_f64().unwrap();
    assert!(lag.is_finite() && lag >= 0.0, "seed {seed}: {lag}");
    assert!(r["capacity_hz"].as_f64().unwrap() > 0.0, "seed {seed}");
    let t = std::fs::read_to_string(rt.join("trajectory.tum")).unwrap();
    assert_eq!(
        t.lines().filter(|l| !l.starts_with("# timestamp")).count(),
        60,
        "seed {seed}"
    );
    let bad = jointloc(&[
        "run",
        "--dataset",
        s(&data),
        "--out",
        s(&rt),
        "--force",
        "--sequential",
        "--realtime",
    ]);
    assert!(
        !bad.status.success(),
        "seed {seed}: --sequential --realtime accepted"
    );
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(err.contains("--realtime"), "seed {seed}: {err}");
}
