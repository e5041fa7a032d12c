//! `jointloc run` end to end on a small simulated dataset with the ORB matcher (no model files
//! needed), sequential: world-frame trajectory without any alignment, fixes, final global BA;
//! a start position narrows the first search; the altimeter aid moves z only, towards the
//! truth; outputs are not replaced without `--force`; the settings a run writes repeat it; a
//! bad dataset or bad settings are a clear error. (Threaded and real-time replay:
//! `run_threaded_cli.rs`; injected faults: `run_faults_cli.rs`.)

mod common;

use common::{base, dataset, jointloc, poses, run_orb, s};

/// The base run (`--matcher orb --sequential`): its outputs, geo-referenced after a few fixes,
/// accurate in the world frame, with a final global BA, frames before the alignment flagged.
fn base_run_in_the_world_frame(seed: &str) {
    let base = base(seed);
    let (out, stdout, summary) = (&base.out, &base.stdout, &base.summary);
    for f in [
        "trajectory.tum",
        "trajectory-final.tum",
        "keyframes.tum",
        "fixes.txt",
        "timing.json",
        "summary.json",
        "config.toml",
    ] {
        assert!(out.join(f).exists(), "seed {seed}: {f}\n{stdout}");
    }
    let frames = summary["frames"].as_u64().unwrap();
    let world = summary["world_poses"].as_u64().unwrap();
    // Geo-referenced after a few fixes, then every frame.
    assert!(
        world + 40 >= frames,
        "seed {seed}: {world} of {frames}\n{stdout}"
    );
    assert!(
        summary["fixes_used"].as_u64().unwrap() >= 5,
        "seed {seed}: {stdout}"
    );
    // The map has an elevation model, so the terrain correction ran; on a 5 cm/px map in
    // the flight's light the fixes share no bias worth a decimetre.
    let terrain = &summary["terrain_correction_m"];
    assert!(
        terrain["updates"].as_u64().unwrap() > 0,
        "seed {seed}: {stdout}"
    );
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
    assert!(
        fin["count"].as_u64().unwrap() >= world,
        "seed {seed}: {stdout}"
    );
    let rmse_final = fin["rmse"].as_f64().unwrap();
    assert!(
        rmse_final < 0.3,
        "seed {seed}: final APE rmse {rmse_final}\n{stdout}"
    );
    // ... after a global BA of the whole map with the fixes.
    let ba = &summary["final_ba"];
    assert!(
        ba["keyframes"].as_u64().unwrap() >= 3,
        "seed {seed}: {stdout}"
    );
    assert!(
        ba["global_factors"].as_u64().unwrap() >= 10,
        "seed {seed}: {stdout}"
    );
    assert!(stdout.contains("final global BA"), "seed {seed}: {stdout}");
    // Frames before the alignment are flagged, not invented.
    let traj = std::fs::read_to_string(out.join("trajectory.tum")).unwrap();
    let flagged = traj
        .lines()
        .filter(|l| l.contains("not geo-referenced"))
        .count() as u64;
    assert_eq!(
        flagged + world + 1,
        frames + 1 - traj.lines().filter(|l| l.contains("not tracked")).count() as u64,
        "seed {seed}: {traj}"
    );
}

/// Each fix in `fixes.txt` carries the frame's heading as matched: the image x axis of its
/// quaternion points where the true camera's does, to a degree (0.2° on seed 31: the ORB
/// matcher on a 5 cm map).
fn fixes_carry_the_matched_heading(seed: &str) {
    use nalgebra::{Quaternion, UnitQuaternion, Vector3};
    let base = base(seed);
    let rows = jointloc_formats::outputs::read_fixes(&base.out.join("fixes.txt")).unwrap();
    let truth: std::collections::BTreeMap<i64, UnitQuaternion<f64>> =
        std::fs::read_to_string(dataset(seed).join("uav/gt.txt"))
            .unwrap()
            .lines()
            .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
            .map(|l| {
                let v: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
                let q = Quaternion::new(v[7], v[4], v[5], v[6]);
                (
                    (v[0] * 1e6).round() as i64,
                    UnitQuaternion::from_quaternion(q),
                )
            })
            .collect();
    let azimuth = |q: &UnitQuaternion<f64>| {
        let x = q * Vector3::x();
        x.y.atan2(x.x)
    };
    let mut worst = 0f64;
    for r in &rows {
        let [qx, qy, qz, qw] = r.orientation;
        let fix = UnitQuaternion::from_quaternion(Quaternion::new(qw, qx, qy, qz));
        let t = &truth[&((r.timestamp * 1e6).round() as i64)];
        let d = (azimuth(&fix) - azimuth(t) + std::f64::consts::PI)
            .rem_euclid(std::f64::consts::TAU)
            - std::f64::consts::PI;
        worst = worst.max(d.abs().to_degrees());
        // A nadir camera: its optical axis points down.
        assert!((fix * Vector3::z()).z < -0.999, "seed {seed}: {r:?}");
    }
    assert!(rows.len() >= 5, "seed {seed}: {} fixes", rows.len());
    assert!(worst < 1.0, "seed {seed}: heading off by {worst}°");
}

#[test]
fn fixes_carry_the_matched_heading_seed_31() {
    fixes_carry_the_matched_heading("31");
}

#[test]
fn base_run_in_the_world_frame_seed_31() {
    base_run_in_the_world_frame("31");
}

#[test]
fn base_run_in_the_world_frame_seed_32() {
    base_run_in_the_world_frame("32");
}

/// The base run again into its (full) output folder, without `--force`: refused.
fn refuses_to_overwrite(seed: &str) {
    let base = base(seed);
    let again = jointloc(&base.args());
    assert!(!again.status.success(), "seed {seed}: overwrote");
    let err = String::from_utf8_lossy(&again.stderr);
    assert!(err.contains("--force"), "seed {seed}: {err}");
}

#[test]
fn refuses_to_overwrite_without_force_seed_31() {
    refuses_to_overwrite("31");
}

#[test]
fn refuses_to_overwrite_without_force_seed_32() {
    refuses_to_overwrite("32");
}

/// Without a start position the first search sweeps the whole map (tens of tile and rotation
/// evaluations); with the take-off position (here the first ground-truth x, y, 1 m off) it
/// starts from the nearest tile and stops there. A start that is no position is an error.
fn start_position_narrows_the_first_search(seed: &str) {
    let base = base(seed);
    let data = dataset(seed);
    let dir = tempfile::tempdir().unwrap();
    let gt = poses(&data.join("uav/gt.txt"));
    let first = gt.values().next().unwrap();
    let start = format!("{},{}", first[0] + 0.7, first[1] - 0.7);
    let started = dir.path().join("started");
    let (_, st) = run_orb(seed, &started, &["--sequential", "--start", &start]);
    let (with_start, without) = (
        st["first_fix_searched_tiles"].as_u64().unwrap(),
        base.summary["first_fix_searched_tiles"].as_u64().unwrap(),
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
    assert!(!bad.status.success(), "seed {seed}: --start north accepted");
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(
        err.contains("--start north: expected X,Y"),
        "seed {seed}: {err}"
    );
}

#[test]
fn start_position_narrows_the_first_search_seed_31() {
    start_position_narrows_the_first_search("31");
}

#[test]
fn start_position_narrows_the_first_search_seed_32() {
    start_position_narrows_the_first_search("32");
}

/// A run's `config.toml` repeats it: the base run again with `--config <its config.toml>` and
/// `--sequential` alone (the matcher comes from the file) writes the same trajectories, byte
/// for byte.
#[test]
fn the_settings_a_run_writes_repeat_it() {
    let base = base("31");
    let written = base.out.join("config.toml");
    let text = std::fs::read_to_string(&written).unwrap();
    assert!(text.contains("matcher = \"orb\""), "{text}");
    let dir = tempfile::tempdir().unwrap();
    let again = dir.path().join("again");
    let run = jointloc(&[
        "run",
        "--dataset",
        s(&dataset("31")),
        "--out",
        s(&again),
        "--sequential",
        "--config",
        s(&written),
    ]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    for f in ["trajectory.tum", "trajectory-final.tum", "config.toml"] {
        let (a, b) = (base.out.join(f), again.join(f));
        assert!(
            std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap(),
            "{f} differs"
        );
    }
}

/// `--print-config` prints the merged settings as TOML and runs nothing (no dataset needed);
/// a flag shows in it, and bad settings are refused as in a run.
#[test]
fn print_config_shows_the_merged_settings() {
    let out = jointloc(&["run", "--print-config", "--fusion-every", "7"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    let value: toml::Table = toml::from_str(&text).unwrap();
    assert_eq!(value["fusion_every"].as_integer(), Some(7), "{text}");
    assert!(
        value["slam"]["orb"]["n_features"].as_integer().is_some(),
        "{text}"
    );
    let bad = jointloc(&["run", "--print-config", "--fusion-every", "0"]);
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("fusion_every"));
    let none = jointloc(&["run", "--matcher", "orb"]);
    assert!(!none.status.success());
    assert!(String::from_utf8_lossy(&none.stderr).contains("--dataset"));
}

/// The altimeter aid moves z only, and towards the truth: the same run without it
/// (`altitude_window_s = 0.0`) has identical x, y and a larger z error online. At the end
/// (`final_altitude_window_s = 0.0`) it moves z only; whether towards the truth is measured
/// on 150 m flights (`docs/jointloc.md` §"z at the end"): on this 30 m one its 30 s window
/// spans the whole flight.
fn altimeter_aid_moves_z_towards_the_truth(seed: &str) {
    let base = base(seed);
    let data = dataset(seed);
    let dir = tempfile::tempdir().unwrap();
    let no_aid = dir.path().join("no-aid");
    let cfg = dir.path().join("no-aid.toml");
    std::fs::write(
        &cfg,
        "altitude_window_s = 0.0\nfinal_altitude_window_s = 0.0\n",
    )
    .unwrap();
    run_orb(seed, &no_aid, &["--sequential", "--config", s(&cfg)]);
    let gt = poses(&data.join("uav/gt.txt"));
    for file in ["trajectory.tum", "trajectory-final.tum"] {
        let (with, without) = (poses(&base.out.join(file)), poses(&no_aid.join(file)));
        assert_eq!(with.len(), without.len(), "seed {seed}, {file}");
        let mut z2 = [0.0, 0.0];
        for (t, p) in &with {
            let q = &without[t];
            assert!(
                (p[0] - q[0]).abs() < 1e-9 && (p[1] - q[1]).abs() < 1e-9,
                "seed {seed}, {file}: x, y moved at {t}"
            );
            z2[0] += (p[2] - gt[t][2]).powi(2);
            z2[1] += (q[2] - gt[t][2]).powi(2);
        }
        let rms = |sum: f64| (sum / with.len() as f64).sqrt();
        if file == "trajectory.tum" {
            assert!(
                z2[0] < z2[1],
                "seed {seed}: z error with the altimeter aid {} >= without {}",
                rms(z2[0]),
                rms(z2[1])
            );
        } else {
            assert!(
                (rms(z2[0]) - rms(z2[1])).abs() > 1e-4,
                "seed {seed}, {file}: z unmoved by the aid ({})",
                rms(z2[0])
            );
        }
    }
}

#[test]
fn altimeter_aid_moves_z_towards_the_truth_seed_31() {
    altimeter_aid_moves_z_towards_the_truth("31");
}

#[test]
fn altimeter_aid_moves_z_towards_the_truth_seed_32() {
    altimeter_aid_moves_z_towards_the_truth("32");
}

#[test]
fn a_missing_dataset_is_a_clear_error() {
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
}

#[test]
fn bad_settings_are_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
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
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("fusion_every"), "{err}");
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
        assert!(!run.status.success(), "{text}");
        let err = String::from_utf8_lossy(&run.stderr);
        assert!(err.contains("settings.toml") && err.contains(key), "{err}");
    }
}
