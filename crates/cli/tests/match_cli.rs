//! `jointloc match` end to end: the table on simulated pairs and on a pairs file, JSON keys,
//! clear errors for unknown matchers and malformed pairs files.

use std::path::Path;
use std::process::{Command, Output};
use std::sync::OnceLock;

fn jointloc(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_jointloc"))
        .args(args)
        .output()
        .expect("running jointloc")
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A 3 m gravel flight at 2 Hz, made once for this test binary.
fn dataset() -> &'static Path {
    static DIR: OnceLock<jointloc_sim::scratch::ProcessScratch> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir =
            jointloc_sim::scratch::ProcessScratch::new(env!("CARGO_TARGET_TMPDIR"), "cli-match")
                .unwrap();
        let out = jointloc(&[
            "sim",
            "--out",
            s(dir.path()),
            "--terrain",
            "gravel",
            "--length-m",
            "3",
            "--rate",
            "2",
            "--seed",
            "5",
        ]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        dir
    })
    .path()
}

fn failure(out: &Output) -> String {
    assert!(
        !out.status.success(),
        "expected failure: {}",
        String::from_utf8_lossy(&out.stdout)
    );
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(!err.contains("panicked"), "{err}");
    err
}

#[test]
fn simulated_pairs_give_the_table_and_json() {
    let tmp = tempfile::tempdir().unwrap();
    let json = tmp.path().join("m.json");
    let out = jointloc(&[
        "match",
        "--dataset",
        s(dataset()),
        "--matcher",
        "orb",
        "--pairs",
        "5",
        "--seed",
        "3",
        "--json",
        s(&json),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(
        table.contains("| matcher | fit | pairs | @1px | @5px | @10px | @50px | @100px |"),
        "{table}"
    );
    assert!(table.contains("terrain heightfield"), "{table}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let m = &v["matchers"][0];
    assert_eq!(m["matcher"], "orb");
    assert_eq!(m["pairs"], 5);
    // Easy simulated pairs: ORB finds every homography within 10 px.
    assert_eq!(m["accuracy"]["@10px"], 1.0, "{m}");
    assert!(m["accuracy"]["@1px"].as_f64().unwrap() <= m["accuracy"]["@5px"].as_f64().unwrap());
    assert_eq!(m["results"].as_array().unwrap().len(), 5);
    // A simulated pair's ground truth is the whole footprint's homography: by default it is
    // scored on the biweight refit.
    assert_eq!(m["fit"], "biweight");
    assert_eq!(v["fits"], serde_json::json!(["biweight"]));
    // Several fits score the same pairs from the same matches, one report each, in the order
    // asked (a repeated name once).
    let again = jointloc(&[
        "match",
        "--dataset",
        s(dataset()),
        "--matcher",
        "orb",
        "--pairs",
        "5",
        "--seed",
        "3",
        "--json",
        s(&json),
        "--force",
        "--fit",
        "tight,footprint,tight",
    ]);
    assert!(again.status.success());
    let stdout = String::from_utf8_lossy(&again.stdout);
    assert!(stdout.contains("homography scored: tight"), "{stdout}");
    assert!(stdout.contains("homography scored: footprint"), "{stdout}");
    assert!(stdout.contains("| orb | footprint | 5 |"), "{stdout}");
    let both: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(both["fits"], serde_json::json!(["tight", "footprint"]));
    assert_eq!(both["footprint_threshold_px"], 20.0);
    assert_eq!(both["matchers"].as_array().unwrap().len(), 2);
    assert_eq!(both["matchers"][1]["fit"], "footprint");
    let column = |v: &serde_json::Value, report: usize, key: &str| -> Vec<serde_json::Value> {
        v["matchers"][report]["results"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| r[key].clone())
            .collect()
    };
    // The same seed draws the same pairs.
    assert_eq!(column(&v, 0, "label"), column(&both, 0, "label"));
    assert_eq!(column(&both, 0, "label"), column(&both, 1, "label"));
    assert_eq!(column(&both, 0, "matches"), column(&both, 1, "matches"));
    assert_eq!(column(&v, 0, "matches"), column(&both, 0, "matches"));
    // Both refits keep the tight inliers (within 3 px) and add matches within 20 px.
    for refit in [column(&v, 0, "inliers"), column(&both, 1, "inliers")] {
        for (tight, wide) in column(&both, 0, "inliers").iter().zip(refit) {
            let (tight, wide) = (tight.as_u64().unwrap(), wide.as_u64().unwrap());
            assert!(wide >= tight, "refit {wide} < tight {tight} inliers");
        }
    }
    for report in [
        &v["matchers"][0],
        &both["matchers"][0],
        &both["matchers"][1],
    ] {
        assert_eq!(report["accuracy"]["@10px"], 1.0, "{report}");
    }
    for (extra, expected) in [
        (&["--fit", "wide"][..], "tight, footprint or biweight"),
        (&["--pairs", "2", "--json", s(&json)][..], "already exists"),
    ] {
        let mut args = vec!["match", "--dataset", s(dataset()), "--matcher", "orb"];
        args.extend_from_slice(extra);
        let err = failure(&jointloc(&args));
        assert!(err.contains(expected), "{err}");
    }
}

#[test]
fn pairs_files_work_and_fail_clearly() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    // Reference: a tile; query: a 400x400 crop of it shifted by (37, 21): H = translation.
    let tile = image::open(dataset().join("satellite/0_0_0.png"))
        .unwrap()
        .into_luma8();
    image::imageops::crop_imm(&tile, 37, 21, 400, 400)
        .to_image()
        .save(d.join("q.png"))
        .unwrap();
    tile.save(d.join("r.png")).unwrap();
    std::fs::write(
        d.join("pairs.txt"),
        "# query reference H\nq.png r.png 1 0 37 0 1 21 0 0 1\n",
    )
    .unwrap();
    let out = jointloc(&[
        "match",
        "--pairs-file",
        s(&d.join("pairs.txt")),
        "--matcher",
        "orb",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let table = String::from_utf8_lossy(&out.stdout);
    let row = table.lines().find(|l| l.starts_with("| orb |")).unwrap();
    // A pairs file's homography is exact for every pixel: scored on the tight fit.
    assert!(
        row.starts_with("| orb | tight | 1 | 1.00 | 1.00 |"),
        "{row}"
    );
    // Malformed lines name the file and line.
    std::fs::write(d.join("bad.txt"), "q.png r.png 1 0 37 0 1 21 0 0\n").unwrap();
    let err = failure(&jointloc(&[
        "match",
        "--pairs-file",
        s(&d.join("bad.txt")),
        "--matcher",
        "orb",
    ]));
    assert!(err.contains("bad.txt:1"), "{err}");
    // Unknown matcher, listed ones shown.
    let err = failure(&jointloc(&[
        "match",
        "--pairs-file",
        s(&d.join("pairs.txt")),
        "--matcher",
        "orb,loftr",
    ]));
    assert!(
        err.contains("loftr") && err.contains("aliked-lightglue"),
        "{err}"
    );
    let list = jointloc(&["match", "--list"]);
    assert!(String::from_utf8_lossy(&list.stdout).contains("disk-lightglue"));
}
