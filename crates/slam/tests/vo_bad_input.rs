//! Bad input gives clear errors, never a panic: missing or corrupt images, malformed or
//! non-finite altimeter readings, frames of the wrong size, timestamps out of order.

use std::path::Path;

use jointloc_features::orb::GrayImageView;
use jointloc_formats::{FormatError, Sequence};
use jointloc_geometry::PinholeCamera;
use jointloc_slam::SlamError;
use jointloc_slam::system::{System, SystemConfig};

/// A dataset folder with `n` small valid PNG frames and the given altimeter text.
fn write_dataset(dir: &Path, n: usize, altimeter: Option<&str>) {
    let uav = dir.join("uav");
    std::fs::create_dir_all(uav.join("images")).unwrap();
    let mut list = String::from("# timestamp filename\n");
    for i in 0..n {
        let name = format!("images/{i:06}.png");
        image::GrayImage::from_fn(64, 48, |x, y| {
            image::Luma([((x * 7 + y * 3 + i as u32) % 256) as u8])
        })
        .save(uav.join(&name))
        .unwrap();
        list += &format!("{:.6} {name}\n", i as f64 * 0.2);
    }
    std::fs::write(uav.join("images.txt"), list).unwrap();
    if let Some(a) = altimeter {
        std::fs::write(uav.join("altimeter.txt"), a).unwrap();
    }
}

#[test]
fn a_valid_sequence_reads_with_altitudes() {
    let tmp = tempfile::tempdir().unwrap();
    write_dataset(
        tmp.path(),
        3,
        Some("# t alt\n0.000000 10.5\n0.200000 10.25\n"),
    );
    let seq = Sequence::open(tmp.path()).unwrap();
    assert_eq!(seq.len(), 3);
    assert_eq!(seq.frames[0].altitude, Some(10.5));
    assert_eq!(seq.frames[1].altitude, Some(10.25));
    assert_eq!(seq.frames[2].altitude, None);
    assert_eq!(seq.load_image(2).unwrap().dimensions(), (64, 48));
}

#[test]
fn missing_files_are_named() {
    let tmp = tempfile::tempdir().unwrap();
    let err = Sequence::open(tmp.path()).unwrap_err();
    assert!(matches!(err, FormatError::Io { .. }), "{err}");
    assert!(err.to_string().contains("images.txt"), "{err}");
    write_dataset(tmp.path(), 3, None);
    std::fs::remove_file(tmp.path().join("uav/images/000001.png")).unwrap();
    let err = Sequence::open(tmp.path()).unwrap_err().to_string();
    assert!(
        err.contains("000001.png") && err.contains("does not exist") && err.contains(":3:"),
        "{err}"
    );
}

#[test]
fn a_corrupt_png_is_a_decode_error() {
    let tmp = tempfile::tempdir().unwrap();
    write_dataset(tmp.path(), 2, None);
    std::fs::write(
        tmp.path().join("uav/images/000001.png"),
        b"\x89PNG\r\n\x1a\nnot really",
    )
    .unwrap();
    let seq = Sequence::open(tmp.path()).unwrap();
    assert!(seq.load_image(0).is_ok());
    let err = seq.load_image(1).unwrap_err();
    assert!(matches!(err, FormatError::Invalid { .. }), "{err}");
    assert!(err.to_string().contains("000001.png"), "{err}");
}

#[test]
fn non_finite_or_malformed_altitudes_are_parse_errors_with_the_line() {
    for (text, needle) in [
        ("0.0 10\n0.2 NaN\n", ":2:"),
        ("0.0 inf\n", ":1:"),
        ("0.0 10\n\n0.4 abc\n", ":3:"),
        ("0.0 -3\n", "not positive"),
        ("0.0\n", "expected"),
    ] {
        let tmp = tempfile::tempdir().unwrap();
        write_dataset(tmp.path(), 2, Some(text));
        let err = Sequence::open(tmp.path()).unwrap_err();
        assert!(matches!(err, FormatError::Parse { .. }), "{text:?}: {err}");
        let msg = err.to_string();
        assert!(
            msg.contains("altimeter.txt") && msg.contains(needle),
            "{text:?}: {msg}"
        );
    }
}

#[test]
fn timestamps_must_increase_in_the_image_list() {
    let tmp = tempfile::tempdir().unwrap();
    write_dataset(tmp.path(), 2, None);
    std::fs::write(
        tmp.path().join("uav/images.txt"),
        "0.2 images/000000.png\n0.2 images/000001.png\n",
    )
    .unwrap();
    let err = Sequence::open(tmp.path()).unwrap_err().to_string();
    assert!(err.contains("not after"), "{err}");
}

#[test]
fn the_system_rejects_bad_frames() {
    let camera = PinholeCamera::ideal(64.0, 64, 48);
    let mut system = System::new(camera, SystemConfig::default()).unwrap();
    let img = vec![128u8; 64 * 48];
    let small = vec![128u8; 32 * 24];
    let view = GrayImageView::new(64, 48, &img).unwrap();
    let wrong = GrayImageView::new(32, 24, &small).unwrap();
    let invalid = |r: Result<_, SlamError>| matches!(r, Err(SlamError::InvalidFrame { .. }));
    assert!(invalid(system.process(wrong, 0.0, None)));
    assert!(invalid(system.process(view, f64::NAN, None)));
    assert!(invalid(system.process(view, 0.0, Some(f64::NAN))));
    assert!(invalid(system.process(view, 0.0, Some(-1.0))));
    // A flat frame is processed (nothing to track) and time must then move forward.
    assert!(system.process(view, 0.0, Some(10.0)).is_ok());
    assert!(invalid(system.process(view, 0.0, Some(10.0))));
    assert!(system.process(view, 0.2, None).is_ok());
}
