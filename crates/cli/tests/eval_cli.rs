//! `jointloc eval` end to end: a good run prints the table and writes JSON/plots; malformed
//! input fails with a non-zero exit and one stderr line naming the file (and line), no panic.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn jointloc(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_jointloc"))
        .args(args)
        .output()
        .expect("running jointloc")
}

/// A smooth 10 Hz trajectory of `n` poses as TUM text; `scale` and `shift` distort positions.
fn tum(n: usize, t0: f64, scale: f64, shift: f64) -> String {
    (0..n)
        .map(|i| {
            let a = i as f64 * 0.1;
            let wobble = 0.01 * (7.0 * a).sin();
            format!(
                "{} {} {} {} 0 0 {} {}\n",
                t0 + a,
                scale * (10.0 * a.cos() + wobble) + shift,
                scale * 10.0 * a.sin(),
                scale * 0.5 * a,
                (0.5 * a).sin(),
                (0.5 * a).cos()
            )
        })
        .collect()
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// Runs `eval` expecting failure; returns the single stderr line.
fn expect_failure(gt: &Path, est: &Path, extra: &[&str]) -> String {
    let mut args = vec![
        "eval",
        "--gt",
        gt.to_str().unwrap(),
        "--est",
        est.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let out = jointloc(&args);
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!out.status.success(), "expected failure, stderr: {stderr}");
    assert_ne!(out.status.code(), Some(101), "panicked: {stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_eq!(
        stderr.trim_end().lines().count(),
        1,
        "not one line: {stderr}"
    );
    stderr
}

#[test]
fn good_run_prints_table_and_writes_outputs() {
    let dir = tempfile::tempdir().unwrap();
    let gt = write(dir.path(), "gt.txt", &tum(100, 5.0, 1.0, 0.0));
    let est = write(dir.path(), "est.txt", &tum(100, 5.0, 0.5, 3.0));
    let json = dir.path().join("out.json");
    let svg = dir.path().join("out.svg");
    let args = [
        "eval",
        "--gt",
        gt.to_str().unwrap(),
        "--est",
        est.to_str().unwrap(),
        "--align",
        "sim3",
        "--rpe-delta",
        "2",
        "--rpe-unit",
        "m",
        "--json",
        json.to_str().unwrap(),
        "--plot",
        svg.to_str().unwrap(),
    ];
    let out = jointloc(&args);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("100 pose pairs"), "{stdout}");
    assert!(stdout.contains("scale 2.000000"), "{stdout}");
    assert!(
        stdout.contains("APE trans [m]") && stdout.contains("RPE rot [deg]"),
        "{stdout}"
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert!(report["ape_translation"]["stats"]["rmse"].as_f64().unwrap() < 1e-6);
    assert_eq!(report["associated_poses"], 100);
    assert!(std::fs::read_to_string(&svg).unwrap().contains("<svg"));

    // Existing outputs are not overwritten without --force.
    let again = jointloc(&args);
    assert!(!again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("--force"));
    let mut forced = args.to_vec();
    forced.push("--force");
    assert!(jointloc(&forced).status.success());
}

#[test]
fn qw_first_estimate_is_read_with_the_flag() {
    let dir = tempfile::tempdir().unwrap();
    let gt = write(dir.path(), "gt.txt", &tum(50, 0.0, 1.0, 0.0));
    // Same poses with the quaternion written qw first.
    let swapped: String = tum(50, 0.0, 1.0, 0.0)
        .lines()
        .map(|l| {
            let f: Vec<&str> = l.split(' ').collect();
            format!(
                "{} {} {} {} {} {} {} {}\n",
                f[0], f[1], f[2], f[3], f[7], f[4], f[5], f[6]
            )
        })
        .collect();
    let est = write(dir.path(), "est.txt", &swapped);
    let json = dir.path().join("r.json");
    let out = jointloc(&[
        "eval",
        "--gt",
        gt.to_str().unwrap(),
        "--est",
        est.to_str().unwrap(),
        "--est-qw-first",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert!(report["ape_rotation"]["stats"]["max"].as_f64().unwrap() < 1e-6);
}

#[test]
fn malformed_inputs_fail_with_one_line_naming_file_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let good = write(dir.path(), "good.txt", &tum(30, 0.0, 1.0, 0.0));

    let missing = dir.path().join("missing.txt");
    let msg = expect_failure(&good, &missing, &[]);
    assert!(msg.contains("missing.txt"), "{msg}");

    let mut nan = tum(30, 0.0, 1.0, 0.0);
    nan = nan.replacen("\n", "\n0.15 NaN 0 0 0 0 0 1\n", 1);
    let nan = write(dir.path(), "nan.txt", &nan);
    let msg = expect_failure(&good, &nan, &[]);
    assert!(msg.contains("nan.txt:2:"), "{msg}");

    let short = write(dir.path(), "short.txt", "# comment\n0.0 1 2 3 0 0 1\n");
    let msg = expect_failure(&short, &good, &[]);
    assert!(
        msg.contains("short.txt:2:") && msg.contains("columns"),
        "{msg}"
    );

    let unordered = write(
        dir.path(),
        "unordered.txt",
        "0.0 0 0 0 0 0 0 1\n0.2 0 0 0 0 0 0 1\n0.1 0 0 0 0 0 0 1\n",
    );
    let msg = expect_failure(&good, &unordered, &[]);
    assert!(msg.contains("unordered.txt:3:"), "{msg}");

    let later = write(dir.path(), "later.txt", &tum(30, 1000.0, 1.0, 0.0));
    let msg = expect_failure(&good, &later, &[]);
    assert!(msg.contains("no matching timestamps"), "{msg}");
    assert!(
        msg.contains("later.txt") && msg.contains("good.txt"),
        "{msg}"
    );

    let euroc = write(dir.path(), "gt.csv", "#timestamp,x\n1000,1,2\n");
    let msg = expect_failure(&euroc, &good, &["--gt-format", "euroc"]);
    assert!(msg.contains("gt.csv:2:"), "{msg}");
}
