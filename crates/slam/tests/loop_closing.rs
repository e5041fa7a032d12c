//! Loop closing on a rendered flight that comes back over its own start: the loop is found
//! by position, verified, corrected, and the trajectory is more accurate than without it;
//! two runs stay identical; with the global BA on its own thread it still gains; candidates
//! by appearance (the embedded vocabulary) find it too.

use std::path::Path;

use jointloc_eval::{AlignMode, EvalConfig, evaluate};
use jointloc_features::orb::GrayImageView;
use jointloc_formats::{Sequence, read_camera_yaml};
use jointloc_geometry::trajectory::{Trajectory, TumOptions};
use jointloc_sim::TerrainKind;
use jointloc_sim::dataset::{SimConfig, generate_dataset};
use jointloc_slam::loop_closing::CandidateSource;
use jointloc_slam::system::{System, SystemConfig};
use jointloc_slam::tracking::TrackingState;

/// 100 m of gravel inside a 30 m square: the path returns over its first metres at the end.
fn loop_flight(dir: &Path) {
    let mut cfg = SimConfig {
        terrain_kind: TerrainKind::Gravel,
        seed: 35,
        ..SimConfig::default()
    };
    cfg.trajectory.length_m = 100.0;
    cfg.trajectory.region_per_sqrt_m = 0.0;
    cfg.trajectory.min_region_m = 30.0;
    generate_dataset(&cfg, dir, &mut |_, _, _| {}).expect("simulated dataset");
}

fn run(dir: &Path, loop_closing: bool) -> (System, usize) {
    run_with(dir, loop_closing, false, CandidateSource::Position)
}

/// `global_ba_thread`: the global BA after a loop on its own thread, applied when done.
fn run_with(
    dir: &Path,
    loop_closing: bool,
    global_ba_thread: bool,
    candidates: CandidateSource,
) -> (System, usize) {
    let camera = read_camera_yaml(&dir.join("camera.yaml"))
        .expect("camera")
        .camera;
    let seq = Sequence::open(dir).expect("sequence");
    let mut config = SystemConfig::default();
    config.loop_closing.enabled = loop_closing;
    config.loop_closing.global_ba_thread = global_ba_thread;
    config.loop_closing.candidates = candidates;
    let mut system = System::new(camera, config).expect("system");
    let mut lost = 0;
    for (i, f) in seq.frames.iter().enumerate() {
        let img = seq.load_image(i).expect("image");
        let r = system
            .process(GrayImageView::from(&img), f.timestamp, f.altitude)
            .expect("frame");
        lost += usize::from(r.state == TrackingState::Lost);
    }
    system.finish_background_work().expect("global BA");
    (system, lost)
}

fn sim3_ape(dir: &Path, system: &System) -> f64 {
    let gt = Trajectory::read_tum(dir.join("uav/gt.txt"), &TumOptions::default()).expect("gt");
    let est = system.trajectory().expect("trajectory");
    let config = EvalConfig {
        align: AlignMode::Sim3,
        ..EvalConfig::default()
    };
    evaluate(&gt, &est, &config)
        .expect("eval")
        .ape_translation
        .stats
        .rmse
}

#[test]
fn a_flight_over_its_own_start_closes_the_loop_and_gains_accuracy() {
    let tmp = tempfile::tempdir().expect("temp dir");
    let dir = tmp.path().join("ds");
    loop_flight(&dir);
    let (without, lost_without) = run(&dir, false);
    let (with, lost_with) = run(&dir, true);
    assert_eq!((lost_without, lost_with), (0, 0));
    assert!(without.loops_closed().is_empty());
    let loops = with.loops_closed();
    assert!(!loops.is_empty(), "no loop closed");
    for l in loops {
        // A real loop: far apart in time, a small correction (the drift), a sane scale.
        assert!(l.keyframe > l.loop_keyframe + 20, "{l:?}");
        assert!(l.correction < 0.5 && (l.scale - 1.0).abs() < 0.1, "{l:?}");
        assert!(l.matches >= 40, "{l:?}");
    }
    let (ape_without, ape_with) = (sim3_ape(&dir, &without), sim3_ape(&dir, &with));
    assert!(
        ape_with < ape_without,
        "loop closing did not help: {ape_with:.4} vs {ape_without:.4} m"
    );
    // Deterministic with loop closing on.
    let (again, _) = run(&dir, true);
    assert_eq!(with.trajectory().unwrap(), again.trajectory().unwrap());
    let key = |s: &System| -> Vec<_> {
        s.loops_closed()
            .iter()
            .map(|l| (l.keyframe, l.loop_keyframe, l.matches, l.correction))
            .collect()
    };
    assert_eq!(key(&with), key(&again));
    // The global BA on its own thread (applied whenever it lands) closes the loop too and
    // gains as much, within timing noise.
    let (threaded, lost_threaded) = run_with(&dir, true, true, CandidateSource::Position);
    assert_eq!(lost_threaded, 0);
    assert!(!threaded.loops_closed().is_empty(), "no loop closed");
    let ape_threaded = sim3_ape(&dir, &threaded);
    assert!(
        ape_threaded < ape_without,
        "threaded global BA did not help: {ape_threaded:.4} vs {ape_without:.4} m (inline {ape_with:.4})"
    );
    // Candidates by bag of words instead of position: the same place is found.
    let (by_look, lost_by_look) = run_with(&dir, true, false, CandidateSource::Appearance);
    assert_eq!(lost_by_look, 0);
    assert!(
        !by_look.loops_closed().is_empty(),
        "no loop found by appearance"
    );
    for l in by_look.loops_closed() {
        assert!(l.keyframe > l.loop_keyframe + 20, "{l:?}");
        assert!(l.correction < 0.5 && l.matches >= 40, "{l:?}");
    }
    let ape_by_look = sim3_ape(&dir, &by_look);
    assert!(
        ape_by_look < ape_without,
        "appearance loops did not help: {ape_by_look:.4} vs {ape_without:.4} m"
    );
}
