//! `jointloc sim`: bad arguments give one clear error line; an existing dataset is never
//! overwritten without `--force`.

use std::path::Path;
use std::process::{Command, Output};

fn sim(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_jointloc"))
        .arg("sim")
        .args(args)
        .output()
        .expect("run jointloc")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn fails_with(o: &Output, needles: &[&str]) {
    assert!(
        !o.status.success(),
        "expected failure, got success: {}",
        stderr(o)
    );
    let e = stderr(o);
    for n in needles {
        assert!(e.contains(n), "stderr lacks `{n}`:\n{e}");
    }
}

/// A tiny, fast flight.
const TINY: &[&str] = &[
    "--length-m",
    "1",
    "--width",
    "64",
    "--height",
    "48",
    "--fx",
    "64",
    "--quiet",
];

#[test]
fn unknown_terrain_is_rejected() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("ds");
    let o = sim(&["--terrain", "moon", "--out", out.to_str().unwrap()]);
    fails_with(&o, &["moon", "crater", "gravel", "mountain"]);
    assert!(!out.exists());
}

#[test]
fn zero_or_negative_length_is_rejected() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("ds");
    for bad in ["--length-m=0", "--length-m=-5", "--length-m=abc"] {
        let o = sim(&[bad, "--out", out.to_str().unwrap()]);
        fails_with(&o, &["--length-m"]);
    }
    assert!(!out.exists());
}

#[test]
fn unwritable_output_is_a_clear_error() {
    let tmp = tempfile::tempdir().unwrap();
    let file = tmp.path().join("a-file");
    std::fs::write(&file, b"x").unwrap();
    // A folder below a regular file can never be created (even by root).
    let out = file.join("ds");
    let o = sim(&["--out", out.to_str().unwrap(), "--quiet"]);
    fails_with(&o, &["output directory", "a-file"]);
    assert_eq!(stderr(&o).trim().lines().count(), 1, "{}", stderr(&o));
    let o = sim(&["--out", file.to_str().unwrap(), "--quiet"]);
    fails_with(&o, &["not a directory"]);
}

fn tree_bytes(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push((p.display().to_string(), std::fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

#[test]
fn existing_dataset_needs_force() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("ds");
    let outs = out.to_str().unwrap();

    // A non-empty folder that is not a dataset.
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("notes.txt"), b"keep me").unwrap();
    let o = sim(&[&["--out", outs], TINY].concat());
    fails_with(&o, &["not empty", "--force"]);
    assert_eq!(tree_bytes(&out).len(), 1);

    // --force writes the dataset and keeps unrelated files.
    let o = sim(&[&["--out", outs, "--seed", "3", "--force"], TINY].concat());
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(String::from_utf8_lossy(&o.stdout).contains("wrote 6 frames"));
    for f in [
        "uav/images/000005.png",
        "uav/gt.txt",
        "camera.yaml",
        "map.toml",
        "satellite.png",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    assert_eq!(std::fs::read(out.join("notes.txt")).unwrap(), b"keep me");

    // Without --force the dataset stays untouched.
    let before = tree_bytes(&out);
    let o = sim(&[&["--out", outs, "--seed", "4"], TINY].concat());
    fails_with(&o, &["not empty", "--force"]);
    assert_eq!(tree_bytes(&out), before);

    // With --force a new dataset replaces the old one entirely (no stale frames).
    let o = sim(&[
        &["--out", outs, "--seed", "4", "--force", "--length-m", "0.4"],
        &TINY[2..],
    ]
    .concat());
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(out.join("uav/images/000002.png").is_file());
    assert!(!out.join("uav/images/000003.png").exists());
    assert_eq!(std::fs::read(out.join("notes.txt")).unwrap(), b"keep me");
}

#[test]
fn envelope_options_out_of_range_name_the_option() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("ds");
    let outs = out.to_str().unwrap();
    for (args, needles) in [
        (
            &["--sun-azimuth-change-deg", "200"][..],
            &["sun_azimuth_change_deg", "[0, 180]"][..],
        ),
        (
            &["--sun-elevation-deg", "0"],
            &["sun_elevation_deg", "(0, 90]"],
        ),
        (
            &["--flight-sun-elevation-deg", "91"],
            &["flight_sun_elevation_deg"],
        ),
        (&["--map-size-m=-3"], &["--map-size-m"]),
        (
            &["--map-size-m", "20"],
            &["map_size_m", "smaller than the flight"],
        ),
        (&["--altitude", "900"], &["altitude_m", "500"]),
    ] {
        let o = sim(&[&["--out", outs], args, TINY].concat());
        fails_with(&o, needles);
        assert!(!out.join("map.toml").exists());
    }
}

#[test]
fn a_map_larger_than_the_flight_at_high_altitude_under_another_sun() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("ds");
    let o = sim(&[
        &[][..],
        &[
            "--out",
            out.to_str().unwrap(),
            "--seed",
            "2",
            "--difficulty",
            "mars",
        ],
        &[
            "--map-size-m",
            "300",
            "--altitude",
            "120",
            "--sun-azimuth-change-deg",
            "180",
        ],
        &["--flight-sun-elevation-deg", "15"],
        TINY,
    ]
    .concat());
    assert!(o.status.success(), "{}", stderr(&o));
    let map = std::fs::read_to_string(out.join("map.toml")).unwrap();
    // 300 m at 25 cm/px (tiles of 64 × 48, stride 32 × 24), a 1 m DEM, the detailed region.
    for needle in [
        "gsd_m = 0.25",
        "width_px = 1216",
        "gsd_m = 1.0",
        "detailed_region_px",
        "difficulty = \"mars\"",
    ] {
        assert!(map.contains(needle), "map.toml lacks {needle}:\n{map}");
    }
    let sim_toml = std::fs::read_to_string(out.join("sim.toml")).unwrap();
    assert!(
        sim_toml.contains("sun_azimuth_change_deg = 180.0"),
        "{sim_toml}"
    );
}
