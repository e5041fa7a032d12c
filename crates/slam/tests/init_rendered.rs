//! The altimeter's check of the initial motion on rendered nadir views of mountain terrain
//! (the terrain where the planar twin motion fooled the initialisation of a real flight):
//! every motion it lets through is the true sideways one, it never vetoes a motion the
//! plain initialisation got right, and it settles pairs the homography vote leaves ambiguous.

#[path = "../../features/tests/common/sim_frames.rs"]
mod sim_frames;

use jointloc_features::orb::{OrbConfig, OrbExtractor};
use jointloc_geometry::PinholeCamera;
use jointloc_sim::TerrainKind;
use jointloc_slam::frame::Frame;
use jointloc_slam::initializer::{Altitudes, Initialization, InitializerConfig, initialize};
use jointloc_slam::tracking::initialization::match_for_initialization;
use nalgebra::Point2;
use sim_frames::{View, render_views};

/// The views move along world y, which is the camera's x axis; the twin dives along z.
fn is_true_motion(init: &Initialization) -> bool {
    let t = init.pose2.translation();
    init.pose2.rotation().angle().to_degrees() < 2.0 && t.x.abs() > 0.8 * t.norm()
}

#[test]
fn the_height_check_passes_only_true_motions_and_settles_ambiguous_pairs() {
    let camera = PinholeCamera::ideal(500.0, 500, 500);
    let extractor = OrbExtractor::new(OrbConfig::default()).expect("ORB");
    let checked = InitializerConfig::default();
    let unchecked = InitializerConfig {
        max_height_ratio_error: 0.0,
        ..checked.clone()
    };
    // The renderer keeps each view 10 m above the terrain below it.
    let altitudes = Altitudes {
        reference: Some(10.0),
        current: Some(10.0),
    };
    let (mut with_check, mut without_check) = (0, 0);
    for seed in 2100..2108 {
        let views: Vec<View> = [0.0, 1.0, 1.4, 2.0]
            .iter()
            .map(|&dy| View {
                dx: 0.0,
                dy,
                yaw: 0.0,
            })
            .collect();
        let frames: Vec<Frame> = render_views(TerrainKind::Mountain, seed, 500, &views)
            .iter()
            .enumerate()
            .map(|(i, img)| {
                let features = extractor.extract(img).expect("features");
                Frame::new(i, i as f64, features, &camera, Some(10.0), 0.0)
            })
            .collect();
        for (k, current) in frames.iter().enumerate().skip(1) {
            let m = match_for_initialization(&frames[0], current, 100.0);
            let x1: Vec<Point2<f64>> = m.iter().map(|m| frames[0].pixel(m.query)).collect();
            let x2: Vec<Point2<f64>> = m.iter().map(|m| current.pixel(m.train)).collect();
            let a = initialize(&x1, &x2, &camera, altitudes, &checked);
            let b = initialize(&x1, &x2, &camera, altitudes, &unchecked);
            println!(
                "seed {seed} view {k}: checked {:?}, unchecked {:?}",
                a.as_ref().map(is_true_motion).map_err(ToString::to_string),
                b.as_ref().map(is_true_motion).map_err(ToString::to_string)
            );
            if let Ok(init) = &a {
                assert!(
                    is_true_motion(init),
                    "seed {seed} view {k}: {:?}",
                    init.pose2
                );
                with_check += 1;
            }
            if let Ok(init) = &b
                && is_true_motion(init)
            {
                assert!(a.is_ok(), "seed {seed} view {k}: vetoed a true motion");
                without_check += 1;
            }
        }
    }
    println!("true initialisations: {with_check} checked, {without_check} unchecked");
    assert!(with_check > without_check);
}
