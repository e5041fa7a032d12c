//! `jointloc map import` on GeoTIFFs written by an independent tool (GDAL through rasterio, in
//! a venv of its own): pixels, tiles, georeference, CRS and DTM heights checked against the
//! source files (`map_import.py`); bad input gives one clear error naming the file.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
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

fn script(action: &str, dir: &Path) {
    let out = Command::new(python())
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/map_import.py"))
        .arg(action)
        .arg(dir)
        .output()
        .expect("python");
    assert!(
        out.status.success(),
        "map_import.py {action}: {}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn geotiffs_written_by_gdal_import_exactly() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    script("write", d);
    let o = jointloc(&[
        "map",
        "import",
        "--image",
        s(&d.join("ortho.tif")),
        "--dem",
        s(&d.join("dtm.tif")),
        "--out",
        s(&d.join("utm")),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stdout).contains("EPSG:32633"));
    assert!(String::from_utf8_lossy(&o.stderr).contains("nodata posts"));
    let o = jointloc(&[
        "map",
        "import",
        "--image",
        s(&d.join("mars16.tif")),
        "--out",
        s(&d.join("mars")),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    script("check", d);

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
    let o = jointloc(&[
        "map",
        "import",
        "--image",
        s(&d.join("mars16.tif")),
        "--out",
        s(&d.join("utm")),
    ]);
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
        let o = jointloc(&[
            "map",
            "import",
            "--image",
            s(&d.join(name)),
            "--out",
            s(&d.join("o")),
        ]);
        assert!(!o.status.success(), "{name} was accepted");
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(e.contains(name) && e.contains(needle), "{name}: {e}");
    }
    let o = jointloc(&[
        "map",
        "import",
        "--image",
        s(&d.join("absent.tif")),
        "--out",
        s(&d.join("o")),
    ]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("absent.tif"));
    assert!(!d.join("o").join("map.toml").exists());
}
