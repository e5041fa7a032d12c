//! Virtual frames (`AbsLocalizer::localize_view` with a zoom): a strip of a synthetic map,
//! seen as the orthographic virtual frame of a UAV at 10 m with zoom 5, is registered by
//! correlation around a prior a few metres off and with the heading 1.5° off: the fix is
//! the map point under the principal point, the heading is refined; too far a prior gives a
//! failure, never a wrong fix. With no prior the whole map is searched, coarse to fine, over
//! all headings: the strip is found, a view of another map is not placed with confidence.

mod common;

use common::{frame_from_map, orb_localizer};
use jointloc_absloc::correlate::NoPeak;
use jointloc_absloc::{AbsLocConfig, AbsLocalizer, FailureReason, FrameView, Outcome, Prior};

const GSD: f64 = 0.25;
const ALT: f64 = 10.0;
const ZOOM: f64 = 5.0;

fn localizer(seed: u64) -> AbsLocalizer {
    orb_localizer(seed, 1000, GSD, AbsLocConfig::default())
}

/// A diagonal strip 140 pixels wide through the centre: the track of the last frames.
fn strip() -> Vec<bool> {
    (0..500 * 500)
        .map(|i| {
            let (x, y) = ((i % 500) as f64, (i / 500) as f64);
            (x - y).abs() < 100.0 && x > 100.0
        })
        .collect()
}

/// The map around pixel `centre` as the virtual frame of a UAV at 10 m with zoom 5 sees it,
/// its x axis at `heading`.
fn seen_from_10_m(map: &image::GrayImage, centre: (f64, f64), heading: f64) -> image::GrayImage {
    frame_from_map(map, centre, ALT * ZOOM / (500.0 * GSD), heading, 500)
}

/// `image` as a virtual frame from 10 m with zoom 5, valid where `valid`.
fn virtual_view<'a>(image: &'a image::GrayImage, valid: &'a [bool]) -> FrameView<'a> {
    FrameView {
        image,
        altitude: ALT,
        zoom: ZOOM,
        valid: Some(valid),
    }
}

#[test]
fn a_strip_seen_from_10_m_is_placed_to_a_tenth_of_a_map_pixel() {
    for (seed, (u, v), heading) in [(1u64, (480.0, 530.0), 0.6), (2, (610.0, 420.0), 2.4)] {
        let mut loc = localizer(seed);
        let image = seen_from_10_m(loc.tiles().map(), (u, v), heading);
        let valid = strip();
        let view = virtual_view(&image, &valid);
        let (x, y) = loc.tiles().pixel_to_world(u, v);
        let prior = Prior {
            position: Some([x + 4.0, y - 3.0]),
            heading: Some(heading + 1.5f64.to_radians()),
        };
        let out = loc.localize_view(&view, &prior).unwrap();
        let fix = out.fix().unwrap_or_else(|| panic!("seed {seed}: {out:?}"));
        let err = (fix.position[0] - x).hypot(fix.position[1] - y);
        eprintln!(
            "seed {seed}: {err:.4} m, heading error {:.3} deg",
            (fix.heading - heading).to_degrees()
        );
        assert!(err < 0.1 * GSD, "seed {seed}: {err} m");
        assert!(
            (fix.heading - heading).abs() < 0.6f64.to_radians(),
            "seed {seed}: heading {} vs {heading}",
            fix.heading
        );
        assert!(
            (fix.position[2] - ALT).abs() < 1e-9,
            "z = ground 0 + altitude"
        );
        assert!(fix.confidence > 0.0 && fix.confidence <= 1.0);

        // 60 m off: the true place is outside the search; no fix rather than a wrong one.
        let far = Prior {
            position: Some([x + 60.0, y]),
            heading: Some(heading),
        };
        match loc.localize_view(&view, &far).unwrap() {
            Outcome::Failed(f) => assert!(matches!(f.reason, FailureReason::NoPeak(_))),
            Outcome::Fix(f) => {
                let e = (f.position[0] - x).hypot(f.position[1] - y);
                panic!("seed {seed}: a fix {e} m off from a prior 60 m off")
            }
        }
    }
}

#[test]
fn with_no_prior_the_whole_map_is_searched_and_too_little_ground_is_refused() {
    let mut loc = localizer(3);
    for (seed, (u, v), heading) in [(3u64, (500.0, 500.0), 0.0), (4, (300.0, 710.0), 2.2)] {
        let mut loc = localizer(seed);
        let image = seen_from_10_m(loc.tiles().map(), (u, v), heading);
        let valid = strip();
        let view = virtual_view(&image, &valid);
        let out = loc.localize_view(&view, &Prior::default()).unwrap();
        let fix = out.fix().unwrap_or_else(|| panic!("seed {seed}: {out:?}"));
        let (x, y) = loc.tiles().pixel_to_world(u, v);
        let err = (fix.position[0] - x).hypot(fix.position[1] - y);
        assert!(err < 0.1 * GSD, "seed {seed}: {err} m");
        assert!(fix.global, "a whole-map search is flagged global");
        let turn = (fix.heading - heading + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
            - std::f64::consts::PI;
        assert!(turn.abs() < 0.6f64.to_radians(), "seed {seed}: {turn} rad");

        assert!(fix.confidence >= 0.15, "seed {seed}: w {}", fix.confidence);
        // Registered by correlation: the tile features were never needed, nor extracted.
        assert!(loc.tile_store().is_none() && loc.cache_status().is_none());

        // The same view against another map: nothing there to find, so no fix, or a weak one
        // (below the 0.25 at which JointLoc aligns on whole-map fixes of any span).
        let mut other = localizer(seed + 100);
        match other.localize_view(&view, &Prior::default()).unwrap() {
            Outcome::Failed(f) => assert!(f.global, "{f:?}"),
            Outcome::Fix(f) => assert!(
                f.global && f.confidence < 0.25,
                "seed {seed}: a strong fix on another map: {f:?}"
            ),
        }
    }
    // The whole-map search turned off: no prior, no fix.
    let mut config = AbsLocConfig::default();
    config.correlation.whole_map.candidates = 0;
    let mut off = orb_localizer(3, 1000, GSD, config);
    let image = seen_from_10_m(off.tiles().map(), (500.0, 500.0), 0.0);
    let valid = strip();
    let view = virtual_view(&image, &valid);
    let out = off.localize_view(&view, &Prior::default()).unwrap();
    assert!(
        matches!(&out, Outcome::Failed(f) if f.reason == FailureReason::NoPrior),
        "{out:?}"
    );
    // A sliver of 40 × 20 pixels: too small to correlate.
    let sliver: Vec<bool> = (0..500 * 500)
        .map(|i| (230..270).contains(&(i % 500)) && (240..260).contains(&(i / 500)))
        .collect();
    let view = FrameView {
        valid: Some(&sliver),
        ..view
    };
    let (x, y) = loc.tiles().pixel_to_world(500.0, 500.0);
    let prior = Prior {
        position: Some([x, y]),
        heading: Some(0.0),
    };
    let out = loc.localize_view(&view, &prior).unwrap();
    assert!(
        matches!(&out, Outcome::Failed(f) if matches!(f.reason, FailureReason::NoPeak(NoPeak::TooSmall { .. }))),
        "{out:?}"
    );
    // A mask of the wrong length is an error.
    let short = vec![true; 10];
    let bad = FrameView {
        valid: Some(&short),
        ..view
    };
    assert!(loc.localize_view(&bad, &prior).is_err());
}
