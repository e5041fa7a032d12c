//! Bad input never panics: a missing or unreadable map, tiles of another size than the frame,
//! a missing GSD, blank frames, a missing or NaN altimeter give a clear error or a failed fix
//! with confidence 0.

mod common;

use std::path::Path;

use common::{frame_from_map, texture};
use jointloc_absloc::registry::{RegistryOptions, resolve};
use jointloc_absloc::{
    AbsLocConfig, AbsLocalizer, AbslocError, FailureReason, MapTiles, Outcome, Prior,
};
use jointloc_formats::MapInfo;
use jointloc_geometry::PinholeCamera;

fn orb() -> jointloc_absloc::FeaturePipeline {
    resolve("orb", &RegistryOptions::default()).unwrap()
}

fn map() -> MapTiles {
    MapTiles::from_image(
        texture(1000, 1000, 11),
        0.05,
        (500, 500),
        0.5,
        Path::new("."),
    )
    .unwrap()
}

fn no_cache() -> AbsLocConfig {
    AbsLocConfig {
        cache: false,
        ..Default::default()
    }
}

/// A dataset-like folder with map.toml and satellite.png.
fn map_folder(dir: &Path) {
    let info = MapInfo::new(0.05, 1000, 1000, 500, 500, 0.5).unwrap();
    info.write(&dir.join("map.toml")).unwrap();
    texture(1000, 1000, 3)
        .save(dir.join("satellite.png"))
        .unwrap();
}

#[test]
fn missing_and_unreadable_maps_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let e = MapTiles::open(&d.join("absent")).unwrap_err();
    assert!(matches!(e, AbslocError::MapMissing { .. }), "{e}");
    let e = MapTiles::open(d).unwrap_err();
    assert!(e.to_string().contains("map.toml"), "{e}");
    map_folder(d);
    assert!(MapTiles::open(d).is_ok());
    // An unreadable image.
    std::fs::write(d.join("satellite.png"), b"\x89PNG but not really").unwrap();
    let e = MapTiles::open(d).unwrap_err();
    assert!(matches!(e, AbslocError::Image { .. }), "{e}");
    assert!(e.to_string().contains("satellite.png"), "{e}");
    // No image and no tiles.
    std::fs::remove_file(d.join("satellite.png")).unwrap();
    let e = MapTiles::open(d).unwrap_err();
    assert!(matches!(e, AbslocError::MapMissing { .. }), "{e}");
    // An image of the wrong size.
    texture(600, 600, 3).save(d.join("satellite.png")).unwrap();
    let e = MapTiles::open(d).unwrap_err();
    assert!(e.to_string().contains("600x600"), "{e}");
    // A broken map.toml.
    std::fs::write(d.join("map.toml"), "format_version = 1\ngsd_m = \"fine\"\n").unwrap();
    assert!(MapTiles::open(d).is_err());
}

#[test]
fn a_broken_elevation_model_is_an_error_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    map_folder(d);
    let mut info = MapInfo::read(&d.join("map.toml")).unwrap();
    info.elevation = Some(jointloc_formats::ElevationInfo {
        image: "elevation.png".into(),
        gsd_m: 0.2,
        width_px: 250,
        height_px: 250,
        origin_x_m: 0.075,
        origin_y_m: -0.075,
        offset_m: -5.0,
        scale_m: 0.001,
        sigma_m: 0.05,
    });
    info.write(&d.join("map.toml")).unwrap();
    let e = MapTiles::open(d).unwrap_err();
    assert!(e.to_string().contains("elevation.png"), "{e}");
    std::fs::write(d.join("elevation.png"), b"not a png").unwrap();
    let e = MapTiles::open(d).unwrap_err();
    assert!(e.to_string().contains("elevation.png"), "{e}");
    // The right size at 16 bits: heights come out as offset + value · scale.
    image::ImageBuffer::<image::Luma<u16>, _>::from_pixel(250, 250, image::Luma([7000u16]))
        .save(d.join("elevation.png"))
        .unwrap();
    let tiles = MapTiles::open(d).unwrap();
    assert!((tiles.ground_height(20.0, -20.0) - 2.0).abs() < 1e-4);
    // Its stated precision reaches the ground factors (never held tighter than it).
    assert_eq!(tiles.ground().stated_sigma_m(), Some(0.05));
    // A wrong size.
    image::ImageBuffer::<image::Luma<u16>, _>::from_pixel(25, 250, image::Luma([7000u16]))
        .save(d.join("elevation.png"))
        .unwrap();
    let e = MapTiles::open(d).unwrap_err();
    assert!(e.to_string().contains("25x250"), "{e}");
}

#[test]
fn a_missing_gsd_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let tiles = dir.path().join("satellite");
    std::fs::create_dir(&tiles).unwrap();
    let m = map();
    for (i, t) in m.tiles().iter().enumerate() {
        m.tile_image(i)
            .save(tiles.join(format!("{}_{}_{}.png", t.index, t.x, t.y)))
            .unwrap();
    }
    let e = MapTiles::from_tile_folder(&tiles, None).unwrap_err();
    assert!(matches!(e, AbslocError::GsdMissing { .. }));
    assert!(e.to_string().contains("ground sampling distance"), "{e}");
    // A map.toml without gsd_m fails to parse, naming the key.
    let info = MapInfo::new(0.05, 1000, 1000, 500, 500, 0.5).unwrap();
    let text: String = info
        .to_toml_string()
        .lines()
        .filter(|l| !l.starts_with("gsd_m"))
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(dir.path().join("map.toml"), text).unwrap();
    let e = MapTiles::open(dir.path()).unwrap_err();
    assert!(e.to_string().contains("gsd_m"), "{e}");
}

#[test]
fn tiles_must_have_the_frame_size() {
    let cam = PinholeCamera::ideal(400.0, 640, 480);
    let e = AbsLocalizer::new(map(), cam, orb(), no_cache()).unwrap_err();
    assert!(matches!(e, AbslocError::TileSizeMismatch { .. }), "{e}");
    assert!(
        e.to_string().contains("500x500") && e.to_string().contains("640x480"),
        "{e}"
    );
    let mut loc = AbsLocalizer::new(
        map(),
        PinholeCamera::ideal(500.0, 500, 500),
        orb(),
        no_cache(),
    )
    .unwrap();
    let e = loc
        .localize(&image::GrayImage::new(640, 480), 10.0, &Prior::default())
        .unwrap_err();
    assert!(matches!(e, AbslocError::TileSizeMismatch { .. }), "{e}");
}

#[test]
fn blank_frames_fail_with_zero_confidence() {
    let mut loc = AbsLocalizer::new(
        map(),
        PinholeCamera::ideal(500.0, 500, 500),
        orb(),
        no_cache(),
    )
    .unwrap();
    for level in [0u8, 255, 128] {
        let img = image::GrayImage::from_pixel(500, 500, image::Luma([level]));
        let out = loc.localize(&img, 10.0, &Prior::default()).unwrap();
        assert_eq!(out.confidence(), 0.0);
        assert!(
            matches!(out, Outcome::Failed(ref f) if matches!(f.reason, FailureReason::Textureless { .. })),
            "{out:?}"
        );
    }
    // Nearly blank (noise of one grey level) also fails, without panicking.
    let img = image::GrayImage::from_fn(500, 500, |x, y| {
        image::Luma([100 + ((x * 7 + y * 3) % 3) as u8])
    });
    let out = loc.localize(&img, 10.0, &Prior::default()).unwrap();
    assert_eq!(out.confidence(), 0.0);
}

#[test]
fn unusable_altitudes_are_errors_and_change_nothing() {
    let mut loc = AbsLocalizer::new(
        map(),
        PinholeCamera::ideal(500.0, 500, 500),
        orb(),
        no_cache(),
    )
    .unwrap();
    let img = frame_from_map(loc.tiles().map(), (500.0, 500.0), 0.4, 0.0, 500);
    for alt in [f64::NAN, f64::INFINITY, 0.0, -3.0] {
        let e = loc.localize(&img, alt, &Prior::default()).unwrap_err();
        assert!(matches!(e, AbslocError::InvalidAltitude { .. }), "{e}");
    }
    assert!(
        loc.localize(&img, 10.0, &Prior::default())
            .unwrap()
            .fix()
            .is_some()
    );
}

#[test]
fn invalid_configurations_are_errors() {
    let bad = AbsLocConfig {
        rotation_hypotheses: 0,
        ..no_cache()
    };
    let e =
        AbsLocalizer::new(map(), PinholeCamera::ideal(500.0, 500, 500), orb(), bad).unwrap_err();
    assert!(matches!(e, AbslocError::InvalidConfig { .. }), "{e}");
    let mut cam = PinholeCamera::ideal(500.0, 500, 500);
    cam.fx = f64::NAN;
    assert!(AbsLocalizer::new(map(), cam, orb(), no_cache()).is_err());
    // The configuration reads from TOML with defaults for missing keys.
    let cfg: AbsLocConfig =
        toml::from_str("confidence = \"fixed:0.4\"\narea_prediction = false\n").unwrap();
    assert_eq!(cfg.confidence, jointloc_absloc::ConfidenceMode::Fixed(0.4));
    assert!(!cfg.area_prediction && cfg.global_fallback);
}
