//! `jointloc absloc` end to end on a small simulated dataset (ORB: no model files needed):
//! fixes file and summary; clear errors for bad input, never a panic.

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

/// A 4 m crater flight at 2 Hz (9 frames), made once for this test binary.
fn dataset() -> &'static Path {
    static DIR: OnceLock<jointloc_sim::scratch::ProcessScratch> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir =
            jointloc_sim::scratch::ProcessScratch::new(env!("CARGO_TARGET_TMPDIR"), "cli-absloc")
                .unwrap();
        let out = jointloc(&[
            "sim",
            "--out",
            s(dir.path()),
            "--length-m",
            "4",
            "--rate",
            "2",
            "--seed",
            "77",
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

/// A copy of the dataset to damage.
fn copy_dataset(to: &Path) {
    fn copy(from: &Path, to: &Path) {
        std::fs::create_dir_all(to).unwrap();
        for e in std::fs::read_dir(from).unwrap() {
            let p = e.unwrap().path();
            let t = to.join(p.file_name().unwrap());
            if p.is_dir() {
                copy(&p, &t);
            } else {
                std::fs::copy(&p, &t).unwrap();
            }
        }
    }
    copy(dataset(), to);
}

fn stderr_line(out: &Output) -> String {
    assert!(
        !out.status.success(),
        "expected failure, got: {}",
        String::from_utf8_lossy(&out.stdout)
    );
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(!err.contains("panicked"), "{err}");
    err
}

#[test]
fn writes_fixes_and_a_summary() {
    let tmp = tempfile::tempdir().unwrap();
    let fixes = tmp.path().join("fixes.txt");
    let json = tmp.path().join("summary.json");
    let args = [
        "absloc",
        "--dataset",
        s(dataset()),
        "--matcher",
        "orb",
        "--every",
        "2",
        "--out",
        s(&fixes),
        "--json",
        s(&json),
    ];
    let out = jointloc(&args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("2-D error (m): rmse") && stdout.contains("ms per fix"),
        "{stdout}"
    );
    let text = std::fs::read_to_string(&fixes).unwrap();
    let rows: Vec<Vec<f64>> = text
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.split_whitespace().map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), 5, "{text}");
    for r in &rows {
        assert_eq!(r.len(), 13);
        let q = (r[4] * r[4] + r[5] * r[5] + r[6] * r[6] + r[7] * r[7]).sqrt();
        assert!((q - 1.0).abs() < 1e-6);
        assert!((0.0..=1.0).contains(&r[8]));
    }
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(summary["frames"], 5);
    assert_eq!(summary["success_rate_1m"], 1.0, "{summary}");
    let camera = summary["error_2d_m"]["rmse"].as_f64().unwrap();
    assert!(camera < 0.3, "{summary}");
    // What a fix measures, the ground point under the optical axis, it measures better than
    // the camera's x, y, which the attitude jitter moves by centimetres.
    let ground = summary["error_ground_point_2d_m"]["rmse"].as_f64().unwrap();
    assert!(ground < camera, "{summary}");
    // The tile feature cache sits next to the map; the second run reads it.
    assert!(dataset().join("jointloc-cache/orb.tiles").is_file());
    // No overwrite without --force; with it, fine; without area prediction too.
    let again = jointloc(&args);
    assert!(stderr_line(&again).contains("already exists"));
    let mut forced = args.to_vec();
    forced.extend(["--force", "--no-area-prediction", "--exhaustive"]);
    let out = jointloc(&forced);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn bad_input_is_a_clear_error() {
    let tmp = tempfile::tempdir().unwrap();
    let out_file = tmp.path().join("f.txt");
    let run = |dir: &Path, matcher: &str| {
        jointloc(&[
            "absloc",
            "--dataset",
            s(dir),
            "--matcher",
            matcher,
            "--out",
            s(&out_file),
            "--force",
        ])
    };
    // Unknown matcher: the known ones are listed.
    let err = stderr_line(&run(dataset(), "sift"));
    assert!(
        err.contains("unknown matcher") && err.contains("xfeat-lighterglue"),
        "{err}"
    );
    // Missing dataset.
    let err = stderr_line(&run(&tmp.path().join("nope"), "orb"));
    assert!(err.contains("nope"), "{err}");
    // Missing altimeter.
    let d = tmp.path().join("no-alt");
    copy_dataset(&d);
    std::fs::remove_file(d.join("uav/altimeter.txt")).unwrap();
    let err = stderr_line(&run(&d, "orb"));
    assert!(err.contains("altimeter.txt"), "{err}");
    // Missing map.
    let d = tmp.path().join("no-map");
    copy_dataset(&d);
    std::fs::remove_file(d.join("map.toml")).unwrap();
    let err = stderr_line(&run(&d, "orb"));
    assert!(err.contains("map.toml"), "{err}");
    // Frames of another size than the tiles.
    let d = tmp.path().join("small-frames");
    copy_dataset(&d);
    let yaml = std::fs::read_to_string(d.join("camera.yaml")).unwrap();
    std::fs::write(
        d.join("camera.yaml"),
        yaml.replace("Camera.width: 500", "Camera.width: 400"),
    )
    .unwrap();
    let err = stderr_line(&run(&d, "orb"));
    assert!(err.contains("500x500") && err.contains("400x500"), "{err}");
}

#[test]
fn missing_altitudes_and_blank_frames_fail_alone() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path().join("ds");
    copy_dataset(&d);
    let fixes = tmp.path().join("fixes.txt");
    let absloc = |d: &Path| {
        jointloc(&[
            "absloc",
            "--dataset",
            s(d),
            "--matcher",
            "orb",
            "--out",
            s(&fixes),
            "--no-cache",
            "--force",
        ])
    };
    // A NaN reading is a malformed dataset: refused before any work, naming the file and line.
    let alt = std::fs::read_to_string(d.join("uav/altimeter.txt")).unwrap();
    let mut lines: Vec<String> = alt.lines().map(String::from).collect();
    let k = lines.iter().position(|l| !l.starts_with('#')).unwrap() + 1;
    let stamp = lines[k].split_whitespace().next().unwrap().to_string();
    lines[k] = format!("{stamp} nan");
    std::fs::write(d.join("uav/altimeter.txt"), lines.join("\n") + "\n").unwrap();
    let err = stderr_line(&absloc(&d));
    assert!(
        err.contains(&format!("altimeter.txt:{}:", k + 1)) && err.contains("not finite"),
        "{err}"
    );
    // Frame 1 has no altimeter reading, frame 2 is black.
    lines.remove(k);
    std::fs::write(d.join("uav/altimeter.txt"), lines.join("\n") + "\n").unwrap();
    image::GrayImage::new(500, 500)
        .save(d.join("uav/images/000002.png"))
        .unwrap();
    let out = absloc(&d);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(&fixes).unwrap();
    let failed: Vec<&str> = text.lines().filter(|l| l.contains("failed")).collect();
    assert_eq!(failed.len(), 2, "{text}");
    assert!(
        failed[0].contains("altimeter") && failed[1].contains("Textureless"),
        "{failed:?}"
    );
    assert_eq!(text.lines().filter(|l| !l.starts_with('#')).count(), 7);
    assert!(
        !d.join("jointloc-cache").exists(),
        "--no-cache wrote a cache"
    );
}
