//! `jointloc run` end to end on a small simulated dataset with the ORB matcher (no model files
//! needed): world-frame trajectory without any alignment, fixes, timing, sequential and
//! threaded, with and without the altimeter aid of z, and with injected wrong fixes; outputs
//! are not replaced without `--force`; a bad dataset is a clear error.

use std::path::Path;
use std::process::{Command, Output};

fn jointloc(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_jointloc"))
        .args(args)
        .output()
        .expect("running jointloc")
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Positions of a TUM file by timestamp (µs), comment lines skipped.
fn poses(path: &Path) -> std::collections::BTreeMap<i64, [f64; 3]> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
            ((v[0] * 1e6).round() as i64, [v[1], v[2], v[3]])
        })
        .collect()
}

#[test]
fn fuses_into_the_world_frame_and_refuses_to_overwrite() {
    for seed in ["31", "32"] {
        let dir = tempfile::tempdir().unwrap();
        let data = dir.path().join("data");
        let sim = jointloc(&[
            "sim",
            "--out",
            s(&data),
            "--length-m",
            "30",
            "--seed",
            seed,
            "--terrain",
            "crater",
        ]);
        assert!(
            sim.status.success(),
            "{}",
            String::from_utf8_lossy(&sim.stderr)
        );
        let out = dir.path().join("out");
        let args = [
            "run",
            "--dataset",
            s(&data),
            "--out",
            s(&out),
            "--matcher",
            "orb",
            "--sequential",
        ];
        let run = jointloc(&args);
        let stdout = String::from_utf8_lossy(&run.stdout).into_owned();
        assert!(
            run.status.success(),
            "{stdout}\n{}",
            String::from_utf8_lossy(&run.stderr)
        );
        for f in [
            "trajectory.tum",
            "trajectory-final.tum",
            "keyframes.tum",
            "fixes.txt",
            "timing.json",
            "summary.json",
        ] {
            assert!(out.join(f).exists(), "seed {seed}: {f}\n{stdout}");
        }
        let summary: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap())
                .unwrap();
        let frames = summary["frames"].as_u64().unwrap();
        let world = summary["world_poses"].as_u64().unwrap();
        // Geo-referenced after a few fixes, then every frame.
        assert!(
            world + 40 >= frames,
            "seed {seed}: {world} of {frames}\n{stdout}"
        );
        assert!(summary["fixes_used"].as_u64().unwrap() >= 5, "{stdout}");
        // The map has an elevation model, so the terrain correction ran; on a 5 cm/px map in
        // the flight's light the fixes share no bias worth a decimetre.
        let terrain = &summary["terrain_correction_m"];
        assert!(terrain["updates"].as_u64().unwrap() > 0, "{stdout}");
        let offset = terrain["x"]
            .as_f64()
            .unwrap()
            .hypot(terrain["y"].as_f64().unwrap());
        assert!(
            offset < 0.1,
            "seed {seed}: terrain correction {offset} m\n{stdout}"
        );
        // World frame with no alignment: the simulated map is 5 cm/px and carries an
        // elevation model, so z = DEM + altimeter; a few decimetres at most.
        let rmse = summary["ape_translation"]["rmse"].as_f64().unwrap();
        assert!(rmse < 0.3, "seed {seed}: APE rmse {rmse}\n{stdout}");
        // The trajectory as known at the end: every tracked frame, world frame, as good.
        let fin = &summary["ape_translation_final"];
        assert!(fin["count"].as_u64().unwrap() >= world, "{stdout}");
        let rmse_final = fin["rmse"].as_f64().unwrap();
        assert!(
            rmse_final < 0.3,
            "seed {seed}: final APE rmse {rmse_final}\n{stdout}"
        );
        // ... after a global BA of the whole map with the fixes.
        let ba = &summary["final_ba"];
        assert!(ba["keyframes"].as_u64().unwrap() >= 3, "{stdout}");
        assert!(ba["global_factors"].as_u64().unwrap() >= 10, "{stdout}");
        assert!(stdout.contains("final global BA"), "{stdout}");
        // Frames before the alignment are flagged, not invented.
        let traj = std::fs::read_to_string(out.join("trajectory.tum")).unwrap();
        let flagged = traj
            .lines()
            .filter(|l| l.contains("not geo-referenced"))
            .count() as u64;
        assert_eq!(
            flagged + world + 1,
            frames + 1 - traj.lines().filter(|l| l.contains("not tracked")).count() as u64,
            "{traj}"
        );
        // The altimeter aid moves z only, and towards the truth: the same run without it has
        // identical x, y and a larger z error.
        let no_aid = dir.path().join("no-aid");
        let cfg = dir.path().join("no-aid.toml");
        std::fs::write(&cfg, "altitude_window_s = 0.0\n").unwrap();
        let run = jointloc(&[
            "run",
            "--dataset",
            s(&data),
            "--out",
            s(&no_aid),
            "--matcher",
            "orb",
            "--sequential",
            "--config",
            s(&cfg),
        ]);
        assert!(
            run.status.success(),
            "{}",
            String::from_utf8_lossy(&run.stderr)
        );
        let gt = poses(&data.join("uav/gt.txt"));
        let (with, without) = (
            poses(&out.join("trajectory.tum")),
            poses(&no_aid.join("trajectory.tum")),
        );
        assert_eq!(with.len(), without.len());
        let mut z2 = [0.0, 0.0];
        for (t, p) in &with {
            let q = &without[t];
            assert!(
                (p[0] - q[0]).abs() < 1e-9 && (p[1] - q[1]).abs() < 1e-9,
                "seed {seed}: x, y moved at {t}"
            );
            z2[0] += (p[2] - gt[t][2]).powi(2);
            z2[1] += (q[2] - gt[t][2]).powi(2);
        }
        assert!(
            z2[0] < z2[1],
            "seed {seed}: z error with the altimeter aid {} >= without {}",
            (z2[0] / with.len() as f64).sqrt(),
            (z2[1] / with.len() as f64).sqrt()
        );

        // Without a start position the first search sweeps the whole map (tens of tile and
        // rotation evaluations); with the take-off position (here the first ground-truth x, y,
        // 1 m off) it starts from the nearest tile and stops there.
        let first = gt.values().next().unwrap();
        let start = format!("{},{}", first[0] + 0.7, first[1] - 0.7);
        let started = dir.path().join("started");
        let run = jointloc(&[
            "run",
            "--dataset",
            s(&data),
            "--out",
            s(&started),
            "--matcher",
            "orb",
            "--sequential",
            "--start",
            &start,
        ]);
        assert!(
            run.status.success(),
            "{}",
            String::from_utf8_lossy(&run.stderr)
        );
        let st: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(started.join("summary.json")).unwrap())
                .unwrap();
        let (with_start, without) = (
            st["first_fix_searched_tiles"].as_u64().unwrap(),
            summary["first_fix_searched_tiles"].as_u64().unwrap(),
        );
        assert!(
            with_start * 4 <= without,
            "seed {seed}: {with_start} tiles matched with --start, {without} without"
        );
        let bad = jointloc(&[
            "run",
            "--dataset",
            s(&data),
            "--out",
            s(&dir.path().join("bad")),
            "--start",
            "north",
        ]);
        assert!(!bad.status.success());
        assert!(String::from_utf8_lossy(&bad.stderr).contains("--start north: expected X,Y"));

        let again = jointloc(&args);
        assert!(!again.status.success());
        assert!(String::from_utf8_lossy(&again.stderr).contains("--force"));

        // Threaded: absolute localisation on its own thread; every due frame is either
        // searched or counted as skipped, and the result is as good.
        let threaded = dir.path().join("threaded");
        let run = jointloc(&[
            "run",
            "--dataset",
            s(&data),
            "--out",
            s(&threaded),
            "--matcher",
            "orb",
        ]);
        let stdout = String::from_utf8_lossy(&run.stdout).into_owned();
        assert!(run.status.success(), "{stdout}");
        let t: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(threaded.join("summary.json")).unwrap())
                .unwrap();
        assert_eq!(t["mode"], "threaded");
        let due = frames.div_ceil(10);
        let attempts = t["absolute_attempts"].as_u64().unwrap();
        let skipped =
            t["skipped_busy"].as_u64().unwrap() + t["skipped_untracked"].as_u64().unwrap();
        assert!(
            attempts + skipped <= due && attempts + skipped + 1 >= due,
            "{attempts} + {skipped} vs {due}"
        );
        let rmse_t = t["ape_translation"]["rmse"].as_f64().unwrap();
        assert!(
            rmse_t < 0.3,
            "seed {seed}: threaded rmse {rmse_t}\n{stdout}"
        );

        // Real-time replay: frames released at their timestamps (here 3× the 5 Hz camera
        // rate), so 60 frames cannot take less than 59 × 0.2 s / 3; the lag behind the camera
        // is reported and no frame is dropped.
        if seed == "31" {
            let rt = dir.path().join("realtime");
            let began = std::time::Instant::now();
            let run = jointloc(&[
                "run",
                "--dataset",
                s(&data),
                "--out",
                s(&rt),
                "--matcher",
                "orb",
                "--realtime",
                "3",
                "--max-frames",
                "60",
            ]);
            let wall = began.elapsed().as_secs_f64();
            let stdout = String::from_utf8_lossy(&run.stdout).into_owned();
            assert!(run.status.success(), "{stdout}");
            assert!(wall >= 59.0 * 0.2 / 3.0, "{wall} s\n{stdout}");
            assert!(
                stdout.contains("real-time replay at 3× the camera rate"),
                "{stdout}"
            );
            let r: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(rt.join("summary.json")).unwrap())
                    .unwrap();
            assert_eq!(r["mode"], "threaded, real-time replay");
            assert_eq!(r["frames"], 60);
            assert_eq!(r["realtime"]["speed"], 3.0);
            let lag = r["realtime"]["lag_max_ms"].as_f64().unwrap();
            assert!(lag.is_finite() && lag >= 0.0, "{lag}");
            assert!(r["capacity_hz"].as_f64().unwrap() > 0.0);
            let t = std::fs::read_to_string(rt.join("trajectory.tum")).unwrap();
            assert_eq!(
                t.lines().filter(|l| !l.starts_with("# timestamp")).count(),
                60
            );
            // --realtime is the threaded mode's; with --sequential it is refused.
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
            assert!(!bad.status.success());
            assert!(String::from_utf8_lossy(&bad.stderr).contains("--realtime"));
        }

        // Wrong fixes (30 %, 10-50 m off) are rejected by the alignment.
        let faulty = dir.path().join("faulty");
        let run = jointloc(&[
            "run",
            "--dataset",
            s(&data),
            "--out",
            s(&faulty),
            "--matcher",
            "orb",
            "--sequential",
            "--wrong-fixes",
            "0.3",
        ]);
        let stdout = String::from_utf8_lossy(&run.stdout).into_owned();
        assert!(run.status.success(), "{stdout}");
        let f: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(faulty.join("summary.json")).unwrap())
                .unwrap();
        assert!(f["fixes_injected_wrong"].as_u64().unwrap() >= 1, "{stdout}");
        let fixes = std::fs::read_to_string(faulty.join("fixes.txt")).unwrap();
        for line in fixes.lines().filter(|l| !l.starts_with('#')) {
            let v: Vec<&str> = line.split_whitespace().collect();
            // injected => not an inlier of the final alignment
            assert!(!(v[15] == "1" && v[14] == "1"), "{line}");
        }
        let rmse_f = f["ape_translation"]["rmse"].as_f64().unwrap();
        eprintln!(
            "seed {seed}: rmse sequential {rmse:.3}, threaded {rmse_t:.3}, wrong fixes {rmse_f:.3}"
        );
        // A short flight has few fixes, so the ones lost to injection matter; an accepted
        // wrong fix would cost metres.
        assert!(
            rmse_f < 2.0 * rmse + 0.1,
            "seed {seed}: {rmse_f} with wrong fixes vs {rmse}\n{stdout}"
        );

        // A wrong first fix (position and heading), before any alignment exists to reject
        // it: it steers the next searches and would make a two-fix alignment metres off.
        let first = dir.path().join("first-wrong");
        let cfg = dir.path().join("first-wrong.toml");
        std::fs::write(&cfg, "[faults]\nwrong_first_fixes = 1\n").unwrap();
        let run = jointloc(&[
            "run",
            "--dataset",
            s(&data),
            "--out",
            s(&first),
            "--matcher",
            "orb",
            "--sequential",
            "--config",
            s(&cfg),
        ]);
        let stdout = String::from_utf8_lossy(&run.stdout).into_owned();
        assert!(run.status.success(), "{stdout}");
        let w: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(first.join("summary.json")).unwrap())
                .unwrap();
        assert_eq!(w["fixes_injected_wrong"].as_u64(), Some(1), "{stdout}");
        let fixes = std::fs::read_to_string(first.join("fixes.txt")).unwrap();
        let first_fix: Vec<&str> = fixes
            .lines()
            .find(|l| !l.starts_with('#'))
            .unwrap()
            .split_whitespace()
            .collect();
        assert_eq!((first_fix[15], first_fix[14]), ("1", "0"), "{fixes}");
        // Geo-referenced at most two fixes (20 frames) later than without it, as accurate.
        let world_w = w["world_poses"].as_u64().unwrap();
        assert!(world_w + 20 >= world, "seed {seed}: {world_w} vs {world}");
        let rmse_w = w["ape_translation"]["rmse"].as_f64().unwrap();
        assert!(
            rmse_w < 1.5 * rmse + 0.05,
            "seed {seed}: {rmse_w} with a wrong first fix vs {rmse}\n{stdout}"
        );

        // A blinded camera (6 s of grey from 8 s): tracking is lost, and after 5 s a new map
        // starts, is geo-referenced again by the fixes, and both maps are in the outputs.
        let blind = dir.path().join("blind");
        let run = jointloc(&[
            "run",
            "--dataset",
            s(&data),
            "--out",
            s(&blind),
            "--matcher",
            "orb",
            "--sequential",
            "--blind",
            "8:6",
        ]);
        let stdout = String::from_utf8_lossy(&run.stdout).into_owned();
        assert!(run.status.success(), "{stdout}");
        let b: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(blind.join("summary.json")).unwrap())
                .unwrap();
        assert_eq!(b["new_maps"].as_u64(), Some(1), "{stdout}");
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
            assert!(!stamps.iter().any(|t| blinded.contains(t)), "{file}");
        }
        let rmse_b = b["ape_translation"]["rmse"].as_f64().unwrap();
        assert!(
            rmse_b < 1.5 * rmse + 0.05,
            "seed {seed}: {rmse_b} after a new map vs {rmse}\n{stdout}"
        );
    }
}

#[test]
fn a_bad_dataset_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let run = jointloc(&[
        "run",
        "--dataset",
        s(&dir.path().join("missing")),
        "--out",
        s(&dir.path().join("o")),
        "--matcher",
        "orb",
    ]);
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("missing"), "{err}");
    let run = jointloc(&[
        "run",
        "--dataset",
        s(dir.path()),
        "--out",
        s(&dir.path().join("o")),
        "--fusion-every",
        "0",
    ]);
    assert!(!run.status.success());
    assert!(String::from_utf8_lossy(&run.stderr).contains("fusion_every"));
    // A misspelt setting, top level or nested, is an error naming the file and the key, not
    // silently the default; so is a value out of range.
    for (text, key) in [
        ("fusion_every = 0\n", "fusion_every"),
        ("alignment_windw = 20\n", "alignment_windw"),
        (
            "[slam.local_mapping.ba]\nglobal_sigm = 0.5\n",
            "global_sigm",
        ),
    ] {
        let config = dir.path().join("settings.toml");
        std::fs::write(&config, text).unwrap();
        let run = jointloc(&[
            "run",
            "--dataset",
            s(dir.path()),
            "--out",
            s(&dir.path().join("o")),
            "--config",
            s(&config),
        ]);
        assert!(!run.status.success());
        let err = String::from_utf8_lossy(&run.stderr);
        assert!(err.contains("settings.toml") && err.contains(key), "{err}");
    }
}
