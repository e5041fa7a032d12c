//! `jointloc bench` end to end on one tiny dataset (ORB everywhere: no model files needed):
//! the report, its JSON and figures are written; an existing report is not replaced without
//! `--force`; bad options are clear errors.

use std::process::{Command, Output};

fn jointloc(args: &[&str]) -> Output {
    // Outside any checkout: the report's commit must come from the build.
    Command::new(env!("CARGO_BIN_EXE_jointloc"))
        .args(args)
        .current_dir(std::env::temp_dir())
        .output()
        .expect("running jointloc")
}

#[test]
fn writes_the_report_and_refuses_to_replace_it() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bench");
    let out_s = out.to_str().unwrap();
    // Peers: our own VO file under another name (its row must equal VO's), and a missing one.
    let peer_vo = format!("again={out_s}/runs/{{dataset}}-vo.tum");
    let peer_absent = format!("absent={out_s}/nowhere/{{dataset}}.tum");
    let args = [
        "bench",
        "--out",
        out_s,
        "--quick",
        "--terrains",
        "crater",
        "--length-m",
        "20",
        "--matchers",
        "orb",
        "--matcher",
        "orb",
        "--pairs",
        "2",
        "--replay-speed",
        "4",
        "--tables",
        "matching,localisation",
        "--peer",
        &peer_vo,
        "--peer",
        &peer_absent,
    ];
    let run = jointloc(&args);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    for needle in [
        "## 1. Matching (paper Table V)",
        "| crater | easy | orb |",
        "## 2. Visual localisation (paper Table VI)",
        "| crater | easy | JointLoc (orb) |",
        "| crater | easy | JointLoc, as known at the end (orb) | 1 |",
        "| crater | easy | JointLoc real time (orb, 4× camera rate) | 1 |",
        "| crater | easy | VO only (Sim(3)-aligned) | 1 |",
        "| crater | easy | VO only, no loop closing (Sim(3)-aligned) | 1 |",
        "--no-loop-closing",
        "| crater | easy | Absolute only (orb, every 10, 2-D) | 1 |",
        "jointloc vo --dataset",
        "2 cores",
    ] {
        assert!(md.contains(needle), "missing {needle:?} in\n{md}");
    }
    // The commit is the one the binary was built from (it runs in the temporary folder).
    let built = env!("JOINTLOC_BUILD_COMMIT");
    if !built.is_empty() {
        assert!(md.contains(&format!("commit `{built}`")), "{md}");
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let vo = json["localisation"]
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["method"].as_str().unwrap().starts_with("VO"))
        .unwrap();
    let rmse = vo["stats"]["rmse"].as_f64().unwrap();
    assert!(rmse > 0.0 && rmse < 1.0, "VO rmse {rmse}");
    let rows = json["localisation"].as_array().unwrap();
    let method = |m: &str| rows.iter().find(|r| r["method"] == m).unwrap();
    let again = method("again (peer, Sim(3)-aligned)");
    assert_eq!(again["stats"], vo["stats"]);
    let absent = method("absent (peer, Sim(3)-aligned)");
    assert!(
        absent["failed"].as_str().unwrap().contains("no file"),
        "{absent}"
    );
    for f in [
        "crater-easy-s201-trajectories.svg",
        "crater-easy-s201-trajectories.map.png",
        "crater-easy-s201-error.svg",
    ] {
        assert!(out.join("figures").join(f).exists(), "{f}");
    }
    assert!(std::fs::read_dir(out.join("logs")).unwrap().count() >= 4);

    // The report exists: not replaced without --force.
    let again = jointloc(&args);
    assert!(!again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("--force"));

    // --resume: every run finished before with this executable is reused, not repeated, and
    // the rows come out the same.
    let mut resume_args = args.to_vec();
    resume_args.push("--resume");
    let resumed = jointloc(&resume_args);
    assert!(
        resumed.status.success(),
        "{}",
        String::from_utf8_lossy(&resumed.stderr)
    );
    let json2: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    // The dataset exists, so its `jointloc sim` is not even looked up.
    let runs = std::fs::read_to_string(out.join("runs/journal.jsonl"))
        .unwrap()
        .lines()
        .filter(|l| !l.contains("\"jointloc sim "))
        .count();
    assert!(runs >= 4, "{runs} journal entries");
    assert_eq!(json2["reused_runs"].as_u64(), Some(runs as u64));
    assert_eq!(json2["localisation"], json["localisation"]);
    assert!(
        std::fs::read_to_string(out.join("report.md"))
            .unwrap()
            .contains("reused with `--resume`")
    );

    // A corrupt journal is a clear error naming the file.
    std::fs::write(out.join("runs/journal.jsonl"), "not json\n").unwrap();
    let corrupt = jointloc(&resume_args);
    assert!(!corrupt.status.success());
    let err = String::from_utf8_lossy(&corrupt.stderr);
    assert!(
        err.contains("journal.jsonl") && err.contains("line 1"),
        "{err}"
    );
}

#[test]
fn envelope_table_flies_the_hirise_class_preset() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bench");
    let run = jointloc(&[
        "bench",
        "--out",
        out.to_str().unwrap(),
        "--quick",
        "--terrains",
        "crater",
        "--length-m",
        "20",
        "--matcher",
        "orb",
        "--tables",
        "envelope",
        "--envelope-altitudes",
        "30",
        "--envelope-sun-changes",
        "0",
        "--envelope-map-size-m",
        "100",
    ]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("## 8. The Mars envelope"), "{md}");
    assert!(md.contains("| 30 | 0 | crater | 1 |"), "{md}");
    assert!(md.contains("--difficulty mars --altitude 30"), "{md}");
    // The other tables were not asked for: no dataset of theirs was made.
    assert!(md.contains("## 2. Visual localisation (paper Table VI)\n\nNot run."));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let row = &json["envelope"][0];
    assert!(row["failed"].is_null(), "{row}");
    assert_eq!(row["map_size_m"].as_f64(), Some(100.0));
    assert!(row["frames"].as_u64().unwrap() > 10, "{row}");
    let geo = row["geo_referenced"].as_f64().unwrap();
    assert!(geo > 0.3 && geo <= 1.0, "{row}");
    assert!(row["fixes_found"].as_u64().unwrap() > 0, "{row}");
    let right = row["fixes_right"].as_f64().unwrap();
    assert!((0.0..=1.0).contains(&right), "{row}");
    // A 25 cm/px map: the online error is within a few map pixels, world frame, no alignment.
    let online = row["online"]["rmse"].as_f64().unwrap();
    assert!(online > 0.0 && online < 1.0, "{row}");
    assert!(
        row["commands"][1].as_str().unwrap().contains("--start"),
        "{row}"
    );
    // At 30 m a frame spans 120 map pixels: single frames, so the search with no prior is
    // timed too.
    assert!(
        row["commands"][2]
            .as_str()
            .unwrap()
            .contains("--no-area-prediction"),
        "{row}"
    );
    assert!(row["whole_map_s"].as_f64().unwrap() > 0.0, "{row}");
    let whole_right = row["whole_map_right"].as_f64().unwrap();
    assert!((0.0..=1.0).contains(&whole_right), "{row}");
}

#[test]
fn bad_options_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().to_str().unwrap();
    for (args, needle) in [
        (vec!["--terrains", "moon"], "unknown terrain"),
        (vec!["--tables", "everything"], "unknown table"),
        (vec!["--seeds", "0"], "--seeds"),
        (vec!["--abs-every", "0"], "--abs-every"),
        (vec!["--length-m", "5"], "--length-m"),
        (vec!["--replay-speed", "0"], "--replay-speed"),
        (vec!["--pairs", "0"], "--pairs"),
        (vec!["--peer", "orbslam"], "NAME=PATTERN"),
        (vec!["--peer", "orbslam=fixed.tum"], "{dataset}"),
        (
            vec!["--envelope-sun-changes", "200"],
            "--envelope-sun-changes",
        ),
        (vec!["--envelope-altitudes", "0"], "--envelope-altitudes"),
        (vec!["--envelope-map-size-m", "0"], "--envelope-map-size-m"),
    ] {
        let mut a = vec!["bench", "--out", out];
        a.extend(args);
        let run = jointloc(&a);
        assert!(!run.status.success());
        let err = String::from_utf8_lossy(&run.stderr);
        assert!(err.contains(needle), "{needle}: {err}");
    }
}
