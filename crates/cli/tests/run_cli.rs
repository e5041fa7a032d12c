//! `jointloc run` end to end on a small simulated dataset with the ORB matcher (no model files
//! needed): world-frame trajectory without any alignment, fixes, timing; outputs are not
//! replaced without `--force`; a bad dataset is a clear error.

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
        // World frame with no alignment: the simulated map is 5 cm/px; the error is dominated
        // by the altimeter z (ground assumed at z = 0), well under a metre.
        let rmse = summary["ape_translation"]["rmse"].as_f64().unwrap();
        assert!(rmse < 0.8, "seed {seed}: APE rmse {rmse}\n{stdout}");
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
        let again = jointloc(&args);
        assert!(!again.status.success());
        assert!(String::from_utf8_lossy(&again.stderr).contains("--force"));
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
}
