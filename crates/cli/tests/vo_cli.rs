//! `jointloc vo`: a short simulated flight gives a trajectory, keyframes, map points and a timing
//! summary; a bad dataset gives one clear error line.

use std::path::Path;
use std::process::{Command, Output};

fn jointloc(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_jointloc"))
        .args(args)
        .output()
        .expect("run jointloc")
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

fn tum_lines(path: &Path) -> usize {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .count()
}

#[test]
fn a_short_flight_writes_trajectory_keyframes_points_and_timing() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = tmp.path().join("ds");
    let sim = jointloc(&[
        "sim",
        "--length-m",
        "12",
        "--seed",
        "31",
        "--terrain",
        "gravel",
        "--out",
        ds.to_str().unwrap(),
    ]);
    assert!(sim.status.success(), "{}", text(&sim.stderr));
    let out = tmp.path().join("traj.tum");
    let kf = tmp.path().join("kf.tum");
    let ply = tmp.path().join("points.ply");
    let vo = jointloc(&[
        "vo",
        "--dataset",
        ds.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--sequential",
        "--keyframes",
        kf.to_str().unwrap(),
        "--map-points",
        ply.to_str().unwrap(),
    ]);
    let stdout = text(&vo.stdout);
    assert!(vo.status.success(), "{}\n{stdout}", text(&vo.stderr));
    for needle in [
        "0 lost",
        "median ms: ORB extraction",
        "local BA",
        "throughput",
        " Hz",
    ] {
        assert!(
            stdout.contains(needle),
            "summary lacks `{needle}`:\n{stdout}"
        );
    }
    let frames = tum_lines(&ds.join("uav/gt.txt"));
    let tracked = tum_lines(&out);
    assert!(
        tracked + 10 >= frames && tracked <= frames,
        "{tracked} of {frames} frames written"
    );
    assert!(tum_lines(&kf) >= 2);
    let ply = std::fs::read_to_string(&ply).unwrap();
    let n: usize = ply
        .lines()
        .find_map(|l| l.strip_prefix("element vertex "))
        .unwrap()
        .parse()
        .unwrap();
    assert!(n > 100);
    assert_eq!(
        ply.lines().skip_while(|l| *l != "end_header").count() - 1,
        n
    );
}

#[test]
fn a_missing_dataset_is_one_clear_error() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("t.tum");
    let o = jointloc(&[
        "vo",
        "--dataset",
        tmp.path().join("nope").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let e = text(&o.stderr);
    assert!(e.starts_with("error:") && e.contains("camera.yaml"), "{e}");
    assert!(!out.exists());
}

#[test]
fn existing_outputs_are_refused_without_force() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = tmp.path().join("ds");
    let sim = jointloc(&[
        "sim",
        "--length-m",
        "6",
        "--seed",
        "32",
        "--terrain",
        "gravel",
        "--out",
        ds.to_str().unwrap(),
    ]);
    assert!(sim.status.success(), "{}", text(&sim.stderr));
    let out = tmp.path().join("traj.tum");
    let kf = tmp.path().join("kf.tum");
    let vo = |extra: &[&str]| {
        let mut a = vec![
            "vo",
            "--dataset",
            ds.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--keyframes",
            kf.to_str().unwrap(),
        ];
        a.extend_from_slice(extra);
        jointloc(&a)
    };
    // Each output on its own is guarded.
    for existing in [&out, &kf] {
        std::fs::write(existing, "keep me").unwrap();
        let o = vo(&[]);
        assert!(!o.status.success());
        let e = text(&o.stderr);
        assert!(e.contains("--force") && e.contains("already exists"), "{e}");
        assert_eq!(std::fs::read_to_string(existing).unwrap(), "keep me");
        std::fs::remove_file(existing).unwrap();
    }
    // A value out of range in the settings file is an error naming the file and the field.
    let config = tmp.path().join("vo-settings.toml");
    std::fs::write(&config, "[orb]\nn_features = 0\n").unwrap();
    let o = vo(&["--config", config.to_str().unwrap()]);
    assert!(!o.status.success());
    let e = text(&o.stderr);
    assert!(
        e.contains("vo-settings.toml") && e.contains("n_features"),
        "{e}"
    );
    assert!(!out.exists());
    std::fs::write(&out, "keep me").unwrap();
    let o = vo(&["--force"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(tum_lines(&out) > 10);
    assert!(tum_lines(&kf) >= 2);
}

/// Sim(3)-aligned APE rmse of `est` against the dataset's ground truth, by `jointloc eval`.
fn sim3_ape(ds: &Path, est: &Path) -> f64 {
    let e = jointloc(&[
        "eval",
        "--gt",
        ds.join("uav/gt.txt").to_str().unwrap(),
        "--est",
        est.to_str().unwrap(),
        "--align",
        "sim3",
    ]);
    assert!(e.status.success(), "{}", text(&e.stderr));
    let out = text(&e.stdout);
    out.lines()
        .find_map(|l| l.strip_prefix("APE trans [m]"))
        .and_then(|l| l.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no APE in\n{out}"))
}

#[test]
fn a_fisheye_flight_tracks_as_well_as_the_pinhole_one() {
    // The same ground and path seen through a 133° Kannala-Brandt lens and through the
    // default pinhole: the fisheye is rendered, written as ORB-SLAM3's KannalaBrandt8, read
    // back, and tracked from its undistorted keypoints.
    let tmp = tempfile::tempdir().unwrap();
    let mut ape = Vec::new();
    for lens in [&["--camera", "fisheye", "--fov-deg", "133"][..], &[]] {
        let ds = tmp.path().join(format!("ds{}", ape.len()));
        let mut a = vec![
            "sim",
            "--length-m",
            "12",
            "--seed",
            "33",
            "--terrain",
            "crater",
            "--out",
            ds.to_str().unwrap(),
        ];
        a.extend_from_slice(lens);
        let sim = jointloc(&a);
        assert!(sim.status.success(), "{}", text(&sim.stderr));
        let yaml = std::fs::read_to_string(ds.join("camera.yaml")).unwrap();
        assert_eq!(yaml.contains("KannalaBrandt8"), !lens.is_empty(), "{yaml}");
        let out = tmp.path().join(format!("vo{}.tum", ape.len()));
        let vo = jointloc(&[
            "vo",
            "--dataset",
            ds.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--sequential",
        ]);
        assert!(vo.status.success(), "{}", text(&vo.stderr));
        let frames = tum_lines(&ds.join("uav/gt.txt"));
        let tracked = tum_lines(&out);
        assert!(
            tracked + 10 >= frames,
            "{tracked} of {frames} frames tracked"
        );
        ape.push(sim3_ape(&ds, &out));
    }
    let (fisheye, pinhole) = (ape[0], ape[1]);
    assert!(fisheye < 0.05, "fisheye APE {fisheye} m");
    assert!(
        fisheye <= 1.5 * pinhole,
        "fisheye {fisheye} m against pinhole {pinhole} m"
    );
}
