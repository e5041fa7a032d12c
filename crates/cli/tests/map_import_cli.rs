//! `jointloc map import` on GeoTIFFs written by an independent tool (GDAL through rasterio, in
//! a venv of its own): pixels, tiles, georeference, CRS and DTM heights checked against the
//! source files (`map_import.py`); bad input gives one clear error naming the file.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

use common::{jointloc, s};

const PACKAGES: [&str; 3] = ["rasterio==1.4.3", "numpy==2.2.6", "pillow==11.3.0"];

/// A Python with rasterio, numpy and pillow; the venv is made once per target directory.
fn python() -> &'static Path {
    static PYTHON: OnceLock<PathBuf> = OnceLock::new();
    PYTHON.get_or_init(|| {
        let venv = Path::new(env!("CARGO_TARGET_TMPDIR")).join("rasterio-venv-1.4.3");
        let python = venv.join("bin").join("python");
        let marker = venv.join("jointloc-installed");
        if !marker.exists() {
            let _ = std::fs::remove_dir_all(&venv);
            let ok = Command::new("python3")
                .args(["-m", "venv"])
                .arg(&venv)
                .status()
                .expect("python3 -m venv")
                .success();
            assert!(ok, "python3 -m venv failed");
            let out = Command::new(&python)
                .args([
                    "-m",
                    "pip",
                    "install",
                    "--quiet",
                    "--disable-pip-version-check",
                ])
                .args(PACKAGES)
                .output()
                .expect("pip");
            assert!(
                out.status.success(),
                "pip install {PACKAGES:?}: {}",
                String::from_utf8_lossy(&out.stderr)
            );
            std::fs::write(&marker, PACKAGES.join("\n")).unwrap();
        }
        python
    })
}

fn script(args: &[&str]) {
    let out = Command::new(python())
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/map_import.py"))
        .args(args)
        .output()
        .expect("python");
    assert!(
        out.status.success(),
        "map_import.py {args:?}: {}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// `jointloc map import --image IMAGE [--dem DEM] --out OUT EXTRA…`.
fn import(image: &Path, dem: Option<&Path>, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["map", "import", "--image", s(image), "--out", s(out)];
    if let Some(dem) = dem {
        args.extend(["--dem", s(dem)]);
    }
    args.extend_from_slice(extra);
    jointloc(&args)
}

#[test]
fn geotiffs_written_by_gdal_import_exactly() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    script(&["write", s(d)]);
    let o = import(
        &d.join("ortho.tif"),
        Some(&d.join("dtm.tif")),
        &d.join("utm"),
        &[],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stdout).contains("EPSG:32633"));
    assert!(String::from_utf8_lossy(&o.stderr).contains("nodata posts"));
    let o = import(
        &d.join("mars16.tif"),
        None,
        &d.join("mars"),
        &["--sun", "10,-5"],
    );
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--sun 10,-5"));
    let o = import(
        &d.join("mars16.tif"),
        None,
        &d.join("mars"),
        &["--sun", "348.5,43"],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    script(&["check", s(d)]);
    let mars = jointloc_formats::MapInfo::read(&d.join("mars/map.toml")).unwrap();
    let sun = mars.sun.expect("[sun] written");
    assert_eq!((sun.azimuth_deg, sun.elevation_deg), (348.5, 43.0));

    // The map jointloc reads back.
    let map = jointloc_formats::MapInfo::read(&d.join("utm/map.toml")).unwrap();
    assert_eq!(map.tile_list().len(), 12);
    let dem =
        jointloc_formats::ElevationModel::read(map.elevation.as_ref().unwrap(), &d.join("utm"))
            .unwrap();
    // World (0, 0) is map (500000.125, 3999999.875); the DTM there: 100 + 0.05·col − 0.02·row
    // + 0.3 sin(col / 7) with (col, row) = (9.625, 9.625) posts from its first post's centre.
    let (c, r) = (9.625f64, 9.625f64);
    let want = 100.0 + 0.05 * c - 0.02 * r + 0.3 * (c / 7.0).sin();
    assert!(
        (dem.height_at(0.0, 0.0) - want).abs() < 0.02,
        "{}",
        dem.height_at(0.0, 0.0)
    );

    // Nothing is overwritten without --force; with it, the map is replaced.
    let before = std::fs::read(d.join("utm/map.toml")).unwrap();
    let o = import(&d.join("mars16.tif"), None, &d.join("utm"), &[]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--force"));
    assert_eq!(std::fs::read(d.join("utm/map.toml")).unwrap(), before);
}

#[test]
fn bad_geotiffs_are_errors_naming_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let cases: [(&str, &[u8], &str); 3] = [
        ("empty.tif", b"", "empty.tif"),
        ("text.tif", b"this is not a tiff", "not a readable TIFF"),
        // A valid little-endian TIFF header pointing past the end of the file.
        ("cut.tif", b"II*\0\xff\xff\0\0", "cut.tif"),
    ];
    for (name, bytes, needle) in cases {
        std::fs::write(d.join(name), bytes).unwrap();
        let o = import(&d.join(name), None, &d.join("o"), &[]);
        assert!(!o.status.success(), "{name} was accepted");
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(e.contains(name) && e.contains(needle), "{name}: {e}");
    }
    let o = import(&d.join("absent.tif"), None, &d.join("o"), &[]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("absent.tif"));
    assert!(!d.join("o").join("map.toml").exists());
}

/// TUM poses by timestamp string: position only.
fn positions(path: &Path) -> Vec<(String, [f64; 3])> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let v: Vec<&str> = l.split_whitespace().collect();
            let p = |i: usize| v[i].parse::<f64>().unwrap();
            (v[0].to_string(), [p(1), p(2), p(3)])
        })
        .collect()
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let p = e.unwrap().path();
        let target = to.join(p.file_name().unwrap());
        if p.is_dir() {
            copy_dir(&p, &target);
        } else {
            std::fs::copy(&p, &target).unwrap();
        }
    }
}

#[test]
fn a_flight_over_a_map_that_went_through_geotiff_flies_the_same_and_speaks_map_coordinates() {
    let base = common::base("31");
    let data = common::dataset("31");
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    // The same flight with its map written as GeoTIFF by GDAL, then imported.
    let imported = d.join("imported");
    std::fs::create_dir_all(&imported).unwrap();
    copy_dir(&data.join("uav"), &imported.join("uav"));
    std::fs::copy(data.join("camera.yaml"), imported.join("camera.yaml")).unwrap();
    let (e0, n0) = (4_590_960.0, 1_093_031.0); // Jezero crater in Mars equirectangular metres
    let (e0_s, n0_s) = (e0.to_string(), n0.to_string());
    script(&["togeotiff", s(&data), s(d), &e0_s, &n0_s]);
    // The simulated map's suns, which a user gives as the map's `--sun` at import and the
    // flight's `--flight-sun` in runs: the map is relit the same either way.
    let scene = jointloc_formats::MapInfo::read(&data.join("map.toml"))
        .unwrap()
        .scene
        .expect("a simulated map records its suns");
    let sun =
        |s: jointloc_formats::map_toml::SunInfo| format!("{},{}", s.azimuth_deg, s.elevation_deg);
    let (map_sun, flight_sun) = (sun(scene.satellite_sun), sun(scene.uav_sun));
    let o = import(
        &d.join("satellite.tif"),
        Some(&d.join("elevation.tif")),
        &imported,
        &["--dem-sigma-m", "0.05", "--sun", &map_sun],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    // Same run, local frame: the same trajectory to 1 mm.
    let run = |out: &Path, extra: &[&str]| {
        let args: Vec<&str> = base
            .args()
            .iter()
            .map(|a| {
                if *a == s(&data) {
                    s(&imported)
                } else if *a == s(&base.out) {
                    s(out)
                } else {
                    a
                }
            })
            .chain(["--flight-sun", flight_sun.as_str()])
            .chain(extra.iter().copied())
            .collect();
        let o = jointloc(&args);
        assert!(
            o.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    };
    let local = d.join("local");
    run(&local, &[]);
    for file in ["trajectory.tum", "trajectory-final.tum"] {
        let (a, b) = (
            positions(&base.out.join(file)),
            positions(&local.join(file)),
        );
        assert_eq!(a.len(), b.len(), "{file}");
        assert!(a.len() > 100, "{file}: {} poses", a.len());
        for ((ta, pa), (tb, pb)) in a.iter().zip(&b) {
            assert_eq!(ta, tb);
            let err = (0..3).map(|k| (pa[k] - pb[k]).powi(2)).sum::<f64>().sqrt();
            assert!(err < 1e-3, "{file} {ta}: {pa:?} vs {pb:?}");
        }
    }

    // In the map's coordinates: the local trajectory shifted to (e0, n0), and the same APE
    // against the ground truth (shifted the same way).
    let mapped = d.join("map");
    run(&mapped, &["--out-crs", "map"]);
    let (a, b) = (
        positions(&local.join("trajectory.tum")),
        positions(&mapped.join("trajectory.tum")),
    );
    assert_eq!(a.len(), b.len());
    for ((_, pa), (_, pb)) in a.iter().zip(&b) {
        assert!((pb[0] - pa[0] - e0).abs() < 1e-3 && (pb[1] - pa[1] - n0).abs() < 1e-3);
        assert!((pb[2] - pa[2]).abs() < 1e-6);
    }
    let (sl, sm) = (common::summary(&local), common::summary(&mapped));
    assert_eq!(sm["output_crs"]["easting_m"], e0);
    let ape = |v: &serde_json::Value| v["ape_translation"]["rmse"].as_f64().unwrap();
    assert!(
        (ape(&sl) - ape(&sm)).abs() < 1e-6,
        "{} vs {}",
        ape(&sl),
        ape(&sm)
    );
    // A map without a CRS cannot give map coordinates.
    let nocrs = d.join("nocrs");
    let args: Vec<&str> = base
        .args()
        .iter()
        .map(|a| if *a == s(&base.out) { s(&nocrs) } else { a })
        .chain(["--out-crs", "map"])
        .collect();
    let o = jointloc(&args);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("[crs]"));
}

#[test]
fn the_simulator_writes_geotiffs_that_gdal_places_on_mars_and_import_restores() {
    let tmp = tempfile::tempdir().unwrap();
    let (d, back) = (tmp.path().join("sim"), tmp.path().join("back"));
    let o = jointloc(&[
        "sim",
        "--out",
        s(&d),
        "--length-m",
        "2",
        "--width",
        "96",
        "--height",
        "80",
        "--fx",
        "96",
        "--geotiff",
        "--quiet",
        "--seed",
        "4",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    script(&["checkmars", s(&d)]);
    let o = import(
        &d.join("satellite.tif"),
        Some(&d.join("elevation.tif")),
        &back,
        &[
            "--tile-width",
            "96",
            "--tile-height",
            "80",
            "--dem-sigma-m",
            "0.05",
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (a, b) = (
        jointloc_formats::MapInfo::read(&d.join("map.toml")).unwrap(),
        jointloc_formats::MapInfo::read(&back.join("map.toml")).unwrap(),
    );
    assert_eq!(
        (a.width_px, a.height_px, a.gsd_m),
        (b.width_px, b.height_px, b.gsd_m)
    );
    assert_eq!(a.tiles, b.tiles);
    for tile in a.tile_list() {
        let f = |dir: &Path| std::fs::read(dir.join("satellite").join(tile.file_name())).unwrap();
        assert!(f(&d) == f(&back), "tile {} differs", tile.file_name());
    }
    let crs = b.crs.as_ref().unwrap();
    assert_eq!((crs.easting_m, crs.northing_m), (4_590_960.0, 1_093_031.0));
    let (ea, eb) = (a.elevation.as_ref().unwrap(), b.elevation.as_ref().unwrap());
    assert!((ea.origin_x_m - eb.origin_x_m).abs() < 1e-6 && ea.gsd_m == eb.gsd_m);
    let (ma, mb) = (
        jointloc_formats::ElevationModel::read(ea, &d).unwrap(),
        jointloc_formats::ElevationModel::read(eb, &back).unwrap(),
    );
    for (x, y) in [(1.0, -1.0), (3.3, -2.7), (0.2, -4.1)] {
        assert!((ma.height_at(x, y) - mb.height_at(x, y)).abs() < 1e-3);
    }
}
