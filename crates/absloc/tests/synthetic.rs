//! The search on a synthetic map: frames cut from a random texture at a known position, scale
//! and heading, matched with ORB (no model files needed). Checks positions, heading recovery
//! from the rotation sweep, the local search after the first fix, area prediction and the
//! failure semantics.

mod common;

use common::{frame_from_map, orb_localizer, texture};
use jointloc_absloc::{AbsLocConfig, AbsLocalizer, FailureReason, Outcome, Prior};

const GSD: f64 = 0.05;
const ALT: f64 = 10.0;

/// A map of `side × side` pixels (1000: 3 × 3 tiles, 2000: 7 × 7).
fn localizer(seed: u64, side: u32, config: AbsLocConfig) -> AbsLocalizer {
    orb_localizer(seed, side, GSD, config)
}

/// Frame at map pixel `(u, v)` with `heading`.
fn frame(loc: &AbsLocalizer, u: f64, v: f64, heading: f64) -> image::GrayImage {
    frame_from_map(loc.tiles().map(), (u, v), ALT / (500.0 * GSD), heading, 500)
}

#[test]
fn fixes_follow_a_turning_path_on_several_maps() {
    for seed in [1, 2, 3] {
        let mut loc = localizer(seed, 2000, AbsLocConfig::default());
        // A curved path with the heading turning along it, from an unknown start.
        let mut searched_after_first = Vec::new();
        for k in 0..6 {
            let t = k as f64;
            let (u, v) = (830.0 + 60.0 * t, 900.0 + 25.0 * t + 4.0 * t * t);
            let heading = 0.9 + 0.12 * t;
            let out = loc
                .localize(&frame(&loc, u, v, heading), ALT, &Prior::default())
                .unwrap();
            let fix = out
                .fix()
                .unwrap_or_else(|| panic!("seed {seed} frame {k}: {out:?}"));
            let (x, y) = loc.tiles().pixel_to_world(u, v);
            let err = ((fix.position[0] - x).powi(2) + (fix.position[1] - y).powi(2)).sqrt();
            assert!(err < 0.15, "seed {seed} frame {k}: error {err} m");
            assert_eq!(fix.position[2], ALT);
            let dh = (fix.heading - heading + std::f64::consts::PI)
                .rem_euclid(std::f64::consts::TAU)
                - std::f64::consts::PI;
            assert!(
                dh.abs() < 0.02,
                "seed {seed} frame {k}: heading off by {dh}"
            );
            assert!((fix.scale - 0.4).abs() < 0.01);
            assert!(fix.confidence > 0.0 && fix.confidence <= 1.0);
            assert_eq!(
                fix.next_radius,
                jointloc_absloc::search_radius(fix.confidence)
            );
            if k == 0 {
                // No prior: whole map, rotation sweep, the shortlist's pairs (and the
                // refinement's at most 3 more).
                assert!(fix.global);
                let keep = AbsLocConfig::default().shortlist.candidates;
                assert!(fix.searched_tiles <= keep + 3, "{}", fix.searched_tiles);
            } else {
                assert!(!fix.global, "seed {seed} frame {k}: local search expected");
                searched_after_first.push(fix.searched_tiles);
            }
        }
        // With the last position and heading known, later fixes match a few tiles nearest to
        // the last fix (a decisive one ends the search).
        assert!(
            searched_after_first.iter().all(|&n| n <= 4),
            "{searched_after_first:?}"
        );
    }
}

#[test]
fn without_area_prediction_every_search_is_global() {
    let mut loc = localizer(
        4,
        1000,
        AbsLocConfig {
            area_prediction: false,
            early_stop_inliers: None,
            ..Default::default()
        },
    );
    for k in 0..3 {
        let out = loc
            .localize(
                &frame(&loc, 400.0 + 50.0 * k as f64, 500.0, 0.3),
                ALT,
                &Prior::default(),
            )
            .unwrap();
        let fix = out.fix().unwrap();
        assert!(fix.global);
        if k > 0 {
            // Exhaustive: every tile, with the last heading.
            assert_eq!(fix.searched_tiles, 9);
        }
    }
}

#[test]
fn a_prior_position_and_heading_select_the_candidates() {
    let mut loc = localizer(5, 2000, AbsLocConfig::default());
    assert!(
        loc.localize(&frame(&loc, 600.0, 600.0, 0.0), ALT, &Prior::default())
            .unwrap()
            .fix()
            .is_some()
    );
    // Far from the last fix (beyond its search radius): the prior moves the search there.
    let (u, v) = (1420.0, 1350.0);
    let (x, y) = loc.tiles().pixel_to_world(u, v);
    let prior = Prior {
        position: Some([x + 0.5, y - 0.3]),
        heading: Some(-1.2),
    };
    let out = loc.localize(&frame(&loc, u, v, -1.2), ALT, &prior).unwrap();
    let fix = out.fix().unwrap();
    assert!(!fix.global, "{fix:?}");
    assert!(fix.searched_tiles <= 4, "{}", fix.searched_tiles);
    assert!(((fix.position[0] - x).powi(2) + (fix.position[1] - y).powi(2)).sqrt() < 0.15);
}

#[test]
fn a_frame_from_elsewhere_fails_with_zero_confidence_and_widens_the_search() {
    let mut loc = localizer(
        6,
        1000,
        AbsLocConfig {
            global_fallback: true,
            ..Default::default()
        },
    );
    let good = loc
        .localize(&frame(&loc, 500.0, 500.0, 0.0), ALT, &Prior::default())
        .unwrap();
    assert!(good.fix().is_some());
    // A frame of another terrain: no tile may accept it, and nothing stale comes back.
    let other = frame_from_map(&texture(1000, 1000, 99), (500.0, 500.0), 0.4, 0.0, 500);
    let out = loc.localize(&other, ALT, &Prior::default()).unwrap();
    match &out {
        Outcome::Failed(f) => {
            assert!(matches!(f.reason, FailureReason::NoMatch { .. }));
            assert_eq!(f.next_radius, 10);
            assert!(
                f.global,
                "the failed local search falls back to the whole map"
            );
        }
        Outcome::Fix(f) => panic!("accepted a frame from another map: {f:?}"),
    }
    assert_eq!(out.confidence(), 0.0);
    // The next good frame is found again.
    let back = loc
        .localize(&frame(&loc, 520.0, 480.0, 0.1), ALT, &Prior::default())
        .unwrap();
    assert!(back.fix().is_some());
}

#[test]
fn a_wrong_altitude_is_caught_by_the_scale_check() {
    let mut loc = localizer(7, 1000, AbsLocConfig::default());
    // The frame is rendered at 10 m; an altimeter saying 20 m doubles the expected scale.
    let out = loc
        .localize(
            &frame(&loc, 500.0, 500.0, 0.0),
            2.0 * ALT,
            &Prior::default(),
        )
        .unwrap();
    assert!(out.fix().is_none(), "{out:?}");
    assert_eq!(out.confidence(), 0.0);
}

#[test]
fn inner_tiles_first_gives_the_exhaustive_fix_from_fewer_tiles() {
    // Early stop off, so "off" matches every tile of the radius as the paper does; the tiles
    // containing the predicted position hold the best match, so "on" ends with the same fix.
    for seed in [11, 12, 13] {
        let mut results = Vec::new();
        for inner_tiles_first in [false, true] {
            let mut loc = localizer(
                seed,
                2000,
                AbsLocConfig {
                    early_stop_inliers: None,
                    inner_tiles_first,
                    // The tiles alone (the predicted window is the next test's).
                    predicted_window_margin_m: 0.0,
                    ..Default::default()
                },
            );
            let (u, v) = (1010.0 + 37.0 * seed as f64, 980.0);
            let (x, y) = loc.tiles().pixel_to_world(u, v);
            let prior = Prior {
                position: Some([x - 0.4, y + 0.6]),
                heading: Some(0.7),
            };
            let out = loc.localize(&frame(&loc, u, v, 0.7), ALT, &prior).unwrap();
            let fix = out
                .fix()
                .unwrap_or_else(|| panic!("seed {seed}: {out:?}"))
                .clone();
            assert!(((fix.position[0] - x).powi(2) + (fix.position[1] - y).powi(2)).sqrt() < 0.15);
            results.push(fix);
        }
        let (all, inner) = (&results[0], &results[1]);
        assert_eq!(inner.tile, all.tile, "seed {seed}");
        assert_eq!(inner.position, all.position, "seed {seed}");
        assert!(
            inner.searched_tiles <= 4,
            "seed {seed}: {}",
            inner.searched_tiles
        );
        assert!(
            all.searched_tiles > 2 * inner.searched_tiles,
            "seed {seed}: {} vs {}",
            all.searched_tiles,
            inner.searched_tiles
        );
    }
}

#[test]
fn the_predicted_window_fixes_the_frame_from_one_matcher_call() {
    for seed in [31, 32, 33] {
        let config = |margin: f64, tiles_after_window: bool| AbsLocConfig {
            predicted_window_margin_m: margin,
            tiles_after_window,
            ..Default::default()
        };
        let k = (seed - 30) as f64;
        let (u, v) = (880.0 + 130.0 * k, 1240.0 - 90.0 * k);
        let heading = 2.1 - 0.8 * k;
        let mut fixes = Vec::new();
        for margin in [0.0, 1.5] {
            let mut loc = localizer(seed, 2000, config(margin, false));
            let (x, y) = loc.tiles().pixel_to_world(u, v);
            let prior = Prior {
                position: Some([x + 0.3, y - 0.4]),
                heading: Some(heading),
            };
            let out = loc
                .localize(&frame(&loc, u, v, heading), ALT, &prior)
                .unwrap();
            let fix = out
                .fix()
                .unwrap_or_else(|| panic!("seed {seed}, margin {margin}: {out:?}"))
                .clone();
            let err = ((fix.position[0] - x).powi(2) + (fix.position[1] - y).powi(2)).sqrt();
            assert!(err < 0.15, "seed {seed}, margin {margin}: {err} m");
            fixes.push(fix);
        }
        let (tiles, window) = (&fixes[0], &fixes[1]);
        assert_eq!(window.searched_tiles, 1, "seed {seed}");
        assert!(!window.global);
        assert!(tiles.searched_tiles >= 1);
        // The same place, from keypoints of several tiles instead of one.
        let d = ((window.position[0] - tiles.position[0]).powi(2)
            + (window.position[1] - tiles.position[1]).powi(2))
        .sqrt();
        assert!(d < 0.05, "seed {seed}: {d} m apart");
        assert_eq!(window.tile, tiles.tile, "seed {seed}");

        // A prediction 4 m off (beyond the margin): the window may still match part of the
        // footprint, but its fix is beyond the margin, and the tiles decide.
        let mut loc = localizer(seed, 2000, config(1.5, false));
        let (x, y) = loc.tiles().pixel_to_world(u, v);
        let prior = Prior {
            position: Some([x + 4.0, y]),
            heading: Some(heading),
        };
        let out = loc
            .localize(&frame(&loc, u, v, heading), ALT, &prior)
            .unwrap();
        let fix = out.fix().unwrap_or_else(|| panic!("seed {seed}: {out:?}"));
        let err = ((fix.position[0] - x).powi(2) + (fix.position[1] - y).powi(2)).sqrt();
        assert!(err < 0.15, "seed {seed}, prior 4 m off: {err} m");
        assert!(
            fix.searched_tiles > 1,
            "seed {seed}: {}",
            fix.searched_tiles
        );

        // A frame from elsewhere where the prior says: one matcher call and no fix, unless the
        // tiles are asked for after the window.
        for tiles_after_window in [false, true] {
            let mut loc = localizer(seed, 2000, config(1.5, tiles_after_window));
            let (x, y) = loc.tiles().pixel_to_world(u, v);
            let prior = Prior {
                position: Some([x, y]),
                heading: Some(heading),
            };
            let elsewhere = frame(&loc, u + 700.0, v - 600.0, heading);
            let out = loc.localize(&elsewhere, ALT, &prior).unwrap();
            match (&out, tiles_after_window) {
                (Outcome::Failed(f), false) => {
                    assert_eq!(f.searched_tiles, 1, "seed {seed}");
                    assert!(!f.global);
                }
                (Outcome::Fix(f), true) => {
                    // The whole map, as before the window: the frame's true place.
                    let (tx, ty) = loc.tiles().pixel_to_world(u + 700.0, v - 600.0);
                    let err = ((f.position[0] - tx).powi(2) + (f.position[1] - ty).powi(2)).sqrt();
                    assert!(err < 0.15, "seed {seed}: {err} m");
                    assert!(f.searched_tiles > 1);
                }
                (Outcome::Failed(f), true) => assert!(f.searched_tiles > 1, "seed {seed}"),
                _ => panic!("seed {seed}, tiles_after_window {tiles_after_window}: {out:?}"),
            }
        }
    }
}

#[test]
fn after_the_coarse_places_fail_the_shortlist_matches_its_own_count() {
    // A frame of another map: the coarse places are matched and fail, then the shortlist
    // matches `after_coarse_places` pairs (none at 0), never `candidates`.
    for seed in [31, 32] {
        let elsewhere = localizer(seed + 100, 2000, AbsLocConfig::default());
        let stranger = frame(&elsewhere, 1000.0, 1000.0, 0.7);
        let mut searched = Vec::new();
        for after in [48, 16, 0] {
            let mut config = AbsLocConfig::default();
            config.shortlist.after_coarse_places = after;
            let mut loc = localizer(seed, 2000, config);
            let out = loc.localize(&stranger, ALT, &Prior::default()).unwrap();
            let Outcome::Failed(failure) = out else {
                panic!("seed {seed}, after {after}: a fix on another map: {out:?}");
            };
            searched.push(failure.searched_tiles);
        }
        let places = AbsLocConfig::default().correlation.whole_map.candidates;
        assert!(searched[2] <= places, "seed {seed}: {searched:?}");
        assert!(searched[2] > 0, "seed {seed}: {searched:?}");
        assert_eq!(searched[1] - searched[2], 16, "seed {seed}: {searched:?}");
        assert_eq!(searched[0] - searched[2], 48, "seed {seed}: {searched:?}");
    }
}

#[test]
fn a_shortlisted_whole_map_search_finds_the_exhaustive_fix_from_fewer_pairs() {
    // 7 × 7 tiles × 8 rotations = 392 pairs; no prior, so both search the whole map.
    for seed in [21, 22, 23] {
        let mut fixes = Vec::new();
        // Every pair; the VLAD shortlist alone; the coarse places first (the default).
        for (candidates, coarse) in [(0, false), (48, false), (48, true)] {
            let mut config = AbsLocConfig::default();
            config.shortlist.candidates = candidates;
            config.coarse_places_first = coarse;
            let mut loc = localizer(seed, 2000, config);
            let k = (seed - 20) as f64;
            let (u, v) = (1150.0 + 160.0 * k, 1250.0 + 95.0 * k);
            let heading = -2.0 + 0.9 * k;
            let (x, y) = loc.tiles().pixel_to_world(u, v);
            let out = loc
                .localize(&frame(&loc, u, v, heading), ALT, &Prior::default())
                .unwrap();
            let fix = out
                .fix()
                .unwrap_or_else(|| panic!("seed {seed}, {candidates}: {out:?}"))
                .clone();
            let err = ((fix.position[0] - x).powi(2) + (fix.position[1] - y).powi(2)).sqrt();
            assert!(err < 0.15, "seed {seed}, {candidates}: {err} m");
            assert!(fix.global);
            fixes.push(fix);
        }
        let (all, short, coarse) = (&fixes[0], &fixes[1], &fixes[2]);
        assert!(short.searched_tiles <= 48 + 3, "{}", short.searched_tiles);
        // The tiles under the best coarse place hold the frame: a few pairs, not 48.
        assert!(
            coarse.searched_tiles <= 4,
            "seed {seed}: {}",
            coarse.searched_tiles
        );
        // The same search with the tile features streamed from the cache file, 1 MB of them
        // (one ORB tile) in memory: the same fix, every tile read, the budget kept.
        let dir = tempfile::tempdir().unwrap();
        let config = AbsLocConfig {
            tile_memory_mb: 1,
            coarse_places_first: false,
            ..Default::default()
        };
        let mut streamed = common::orb_localizer_cached(seed, 2000, GSD, config, dir.path());
        let k = (seed - 20) as f64;
        let (u, v) = (1150.0 + 160.0 * k, 1250.0 + 95.0 * k);
        let out = streamed
            .localize(
                &frame(&streamed, u, v, -2.0 + 0.9 * k),
                ALT,
                &Prior::default(),
            )
            .unwrap();
        let fix = out
            .fix()
            .unwrap_or_else(|| panic!("seed {seed}, streamed: {out:?}"));
        assert_eq!(fix.position, short.position, "seed {seed}");
        assert_eq!(fix.searched_tiles, short.searched_tiles, "seed {seed}");
        let store = streamed.tile_store().expect("opened by the search");
        assert_eq!(
            streamed.cache_status(),
            Some(jointloc_absloc::CacheStatus::Built)
        );
        assert!(
            store.reads() >= store.len(),
            "{} of {}",
            store.reads(),
            store.len()
        );
        // At most the budget, or the one tile just read where a tile is larger (ORB: 256
        // binary values per keypoint, held as floats).
        let largest = (0..store.len())
            .map(|t| store.keypoints(t) * (8 + 4 + 4 * 256))
            .max()
            .unwrap_or(0);
        let resident = store.resident_bytes();
        assert!(resident <= largest.max(1 << 20), "{resident} of {largest}");
        assert!(
            all.searched_tiles > 2 * short.searched_tiles,
            "seed {seed}: exhaustive {} vs shortlist {}",
            all.searched_tiles,
            short.searched_tiles
        );
    }
}

#[test]
fn a_heading_sweep_around_a_position_matches_the_tiles_that_contain_it() {
    // A 3 × 3-tile map: the search radius around any position holds every tile, so the sweep
    // with the outer tiles is every tile at every heading.
    for seed in [41, 42] {
        let (u, v, heading) = (700.0 + 20.0 * (seed - 40) as f64, 720.0, 0.7);
        let run = |sweep_outer_tiles: bool, at: (f64, f64)| {
            let mut loc = localizer(
                seed,
                1000,
                AbsLocConfig {
                    sweep_outer_tiles,
                    ..Default::default()
                },
            );
            let (x, y) = loc.tiles().pixel_to_world(u, v);
            let (px, py) = loc.tiles().pixel_to_world(at.0, at.1);
            let prior = Prior {
                position: Some([px, py]),
                heading: None,
            };
            let out = loc.localize(&frame(&loc, u, v, heading), ALT, &prior);
            let fix = out
                .unwrap()
                .fix()
                .unwrap_or_else(|| panic!("seed {seed}, outer {sweep_outer_tiles}, at {at:?}"))
                .clone();
            let err = ((fix.position[0] - x).powi(2) + (fix.position[1] - y).powi(2)).sqrt();
            assert!(
                err < 0.15,
                "seed {seed}, outer {sweep_outer_tiles}: {err} m"
            );
            fix
        };
        let sweep = AbsLocConfig::default().rotation_hypotheses;
        // The position is right: the tiles that contain it hold the frame, with or without
        // the outer tiles.
        let (near, near_outer) = (
            run(false, (u + 8.0, v - 5.0)),
            run(true, (u + 8.0, v - 5.0)),
        );
        assert_eq!(near.position, near_outer.position, "seed {seed}");
        assert!(
            near.searched_tiles <= 4 * sweep,
            "seed {seed}: {}",
            near.searched_tiles
        );
        // The position is 25 m off: after its own tiles, the whole-map search (coarse places
        // first) instead of every other tile at every heading.
        let far_at = (150.0, 130.0);
        let (far, far_outer) = (run(false, far_at), run(true, far_at));
        let places = AbsLocConfig::default().correlation.whole_map.candidates;
        assert!(
            far.searched_tiles <= 4 * sweep + places + 3,
            "seed {seed}: {}",
            far.searched_tiles
        );
        assert!(
            far.searched_tiles < far_outer.searched_tiles,
            "seed {seed}: {} vs {}",
            far.searched_tiles,
            far_outer.searched_tiles
        );
    }
}
