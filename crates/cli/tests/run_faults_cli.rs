//! `jointloc run` end to end with injected faults, on a small simulated dataset with the ORB
//! matcher, sequential, compared with the same run without them: wrong fixes are rejected by
//! the alignment; a wrong first fix, before any alignment exists, costs little; a blinded
//! camera loses tracking and a new map starts, geo-referenced again.

mod common;

use common::{base, poses, run_orb, s};

/// Wrong fixes (30 %, 10-50 m off) are rejected by the alignment.
fn wrong_fixes_are_rejected(seed: &str) {
    let rmse = base(seed).summary["ape_translation"]["rmse"]
        .as_f64()
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let faulty = dir.path().join("faulty");
    let (stdout, f) = run_orb(seed, &faulty, &["--sequential", "--wrong-fixes", "0.3"]);
    assert!(
        f["fixes_injected_wrong"].as_u64().unwrap() >= 1,
        "seed {seed}: {stdout}"
    );
    let fixes = std::fs::read_to_string(faulty.join("fixes.txt")).unwrap();
    for line in fixes.lines().filter(|l| !l.starts_with('#')) {
        let v: Vec<&str> = line.split_whitespace().collect();
        // injected => not an inlier of the final alignment
        assert!(!(v[15] == "1" && v[14] == "1"), "seed {seed}: {line}");
    }
    let rmse_f = f["ape_translation"]["rmse"].as_f64().unwrap();
    eprintln!("seed {seed}: rmse sequential {rmse:.3}, wrong fixes {rmse_f:.3}");
    // A short flight has few fixes, so the ones lost to injection matter; an accepted wrong
    // fix would cost metres.
    assert!(
        rmse_f < 2.0 * rmse + 0.1,
        "seed {seed}: {rmse_f} with wrong fixes vs {rmse}\n{stdout}"
    );
}

#[test]
fn wrong_fixes_are_rejected_seed_31() {
    wrong_fixes_are_rejected("31");
}

#[test]
fn wrong_fixes_are_rejected_seed_32() {
    wrong_fixes_are_rejected("32");
}

/// A wrong first fix (position and heading), before any alignment exists to reject it: it
/// steers the next searches and would make a two-fix alignment metres off.
fn a_wrong_first_fix_costs_little(seed: &str) {
    let summary = &base(seed).summary;
    let world = summary["world_poses"].as_u64().unwrap();
    let rmse = summary["ape_translation"]["rmse"].as_f64().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let first = dir.path().join("first-wrong");
    let cfg = dir.path().join("first-wrong.toml");
    std::fs::write(&cfg, "[faults]\nwrong_first_fixes = 1\n").unwrap();
    let (stdout, w) = run_orb(seed, &first, &["--sequential", "--config", s(&cfg)]);
    assert_eq!(
        w["fixes_injected_wrong"].as_u64(),
        Some(1),
        "seed {seed}: {stdout}"
    );
    let fixes = std::fs::read_to_string(first.join("fixes.txt")).unwrap();
    let first_fix: Vec<&str> = fixes
        .lines()
        .find(|l| !l.starts_with('#'))
        .unwrap()
        .split_whitespace()
        .collect();
    assert_eq!(
        (first_fix[15], first_fix[14]),
        ("1", "0"),
        "seed {seed}: {fixes}"
    );
    // Geo-referenced at most two fixes (20 frames) later than without it, as accurate.
    let world_w = w["world_poses"].as_u64().unwrap();
    assert!(world_w + 20 >= world, "seed {seed}: {world_w} vs {world}");
    let rmse_w = w["ape_translation"]["rmse"].as_f64().unwrap();
    assert!(
        rmse_w < 1.5 * rmse + 0.05,
        "seed {seed}: {rmse_w} with a wrong first fix vs {rmse}\n{stdout}"
    );
}

#[test]
fn a_wrong_first_fix_costs_little_seed_31() {
    a_wrong_first_fix_costs_little("31");
}

#[test]
fn a_wrong_first_fix_costs_little_seed_32() {
    a_wrong_first_fix_costs_little("32");
}

/// A blinded camera (6 s of grey from 8 s): tracking is lost, and after 5 s a new map starts,
/// is geo-referenced again by the fixes, the first map is merged into it, and both parts are
/// in the outputs.
fn a_blinded_camera_starts_a_new_map(seed: &str) {
    let rmse = base(seed).summary["ape_translation"]["rmse"]
        .as_f64()
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let blind = dir.path().join("blind");
    let (stdout, b) = run_orb(seed, &blind, &["--sequential", "--blind", "8:6"]);
    assert_eq!(b["new_maps"].as_u64(), Some(1), "seed {seed}: {stdout}");
    // Both maps are tied to the world: the first is merged into the second, one map at the end.
    assert_eq!(b["maps_merged"].as_u64(), Some(1), "seed {seed}: {stdout}");
    assert_eq!(b["maps_at_end"].as_u64(), Some(1), "seed {seed}: {stdout}");
    // (The first map's keyframes may all predate its geo-referencing at 4-6 s.)
    for (file, before) in [
        ("trajectory.tum", true),
        ("trajectory-final.tum", true),
        ("keyframes.tum", false),
    ] {
        let stamps: Vec<i64> = poses(&blind.join(file)).into_keys().collect();
        assert!(
            (!before || stamps.iter().any(|&t| t < 8_000_000))
                && stamps.iter().any(|&t| t >= 24_000_000),
            "seed {seed}: {file} covers {:?}..{:?} µs\n{stdout}",
            stamps.first(),
            stamps.last()
        );
        let blinded = 8_000_000..14_000_000;
        assert!(
            !stamps.iter().any(|t| blinded.contains(t)),
            "seed {seed}: {file}"
        );
    }
    let rmse_b = b["ape_translation"]["rmse"].as_f64().unwrap();
    assert!(
        rmse_b < 1.5 * rmse + 0.05,
        "seed {seed}: {rmse_b} after a new map vs {rmse}\n{stdout}"
    );
}

#[test]
fn a_blinded_camera_starts_a_new_map_seed_31() {
    a_blinded_camera_starts_a_new_map("31");
}

#[test]
fn a_blinded_camera_starts_a_new_map_seed_32() {
    a_blinded_camera_starts_a_new_map("32");
}
