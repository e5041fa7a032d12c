//! The fusion's state machine on a rendered flight, with fixes from its ground truth: not
//! geo-referenced → tied → re-fitted → (loss → new map →) end outputs. One scenario a test.

mod common;

use std::sync::{Arc, Mutex, OnceLock};

use common::{
    TruthFixes, builder, flight, found_fix, frames, ground_truth, no_match, online, pose_at, rmse,
    tilted_flight,
};
use jointloc_formats::outputs::{read_fixes, read_online_tum};
use jointloc_system::faults::BlindCamera;
use jointloc_system::{
    FixRecord, FusedFrame, JointLocBuilder, JointLocConfig, Mode, Observer, OnlineStatus, Outputs,
};

/// Runs the whole flight; the camera blinded by `config.faults`.
fn run(builder: JointLocBuilder, config: &JointLocConfig) -> (Vec<FusedFrame>, Outputs) {
    let mut system = builder.build().unwrap();
    let blind = BlindCamera::new(config.faults.clone());
    let fused = frames(flight())
        .iter()
        .map(|(image, t, alt)| system.process(&blind.frame(image, *t), *t, *alt).unwrap())
        .collect();
    (fused, system.finish().unwrap())
}

/// The plain sequential run, shared by the tests that only read it.
fn plain() -> &'static (Vec<FusedFrame>, Outputs) {
    static RUN: OnceLock<(Vec<FusedFrame>, Outputs)> = OnceLock::new();
    RUN.get_or_init(|| {
        let config = JointLocConfig::default();
        run(
            builder(flight(), config.clone(), TruthFixes::new(flight(), 0.1, 1)),
            &config,
        )
    })
}

#[test]
fn poses_are_flagged_until_three_fixes_tie_the_map_then_follow_the_truth() {
    let (fused, outputs) = plain();
    let first_world = fused.iter().position(|f| f.world_pose.is_some()).unwrap();
    let used_before = outputs
        .fixes
        .iter()
        .filter(|f| f.used && f.frame <= first_world)
        .count();
    assert!(
        used_before >= 3,
        "geo-referenced at frame {first_world} after {used_before} fixes"
    );
    for (f, o) in fused.iter().zip(&outputs.online).take(first_world) {
        let expected = match f.slam_pose {
            Some(_) => OnlineStatus::NotGeoReferenced,
            None => OnlineStatus::NotTracked,
        };
        assert_eq!(o.status, expected, "frame {}", f.index);
    }
    let world = fused[first_world..]
        .iter()
        .filter(|f| f.world_pose.is_some())
        .count();
    assert!(
        world * 10 >= 9 * (fused.len() - first_world),
        "{world} world poses after {first_world}"
    );
    let e = rmse(&ground_truth(flight()), &online(outputs));
    assert!(e < 0.3, "online rmse {e:.3} m");
    let s = &outputs.summary;
    assert_eq!(
        (s.frames, s.world_poses, s.geo_referenced_from),
        (fused.len(), outputs.online_world_poses(), Some(first_world))
    );
    // The final alignment is fitted to the fixes of its window, the newest
    // `alignment_window_s` of flight: most of those are its inliers.
    let last = outputs.fixes.iter().filter(|f| f.used).map(|f| f.timestamp);
    let last = last.fold(f64::NEG_INFINITY, f64::max);
    let window_s = JointLocConfig::default().alignment_window_s;
    let in_window = outputs
        .fixes
        .iter()
        .filter(|f| f.used && f.timestamp >= last - window_s)
        .count();
    assert!(
        in_window < s.fixes_used,
        "the window is shorter than the flight"
    );
    assert!(
        s.fixes_inliers * 10 >= 8 * in_window,
        "{in_window} in the window, {s:?}"
    );
    assert_eq!(s.mode, "sequential");
}

#[test]
fn the_end_outputs_cover_the_geo_referenced_frames_and_are_written_once() {
    let (_, outputs) = plain();
    let gt = ground_truth(flight());
    let end = outputs.frames.as_ref().unwrap();
    assert_eq!(end.len(), outputs.online_world_poses());
    let (e_end, e_online) = (rmse(&gt, end), rmse(&gt, &online(outputs)));
    assert!(
        e_end < 0.2 && e_end <= e_online + 0.02,
        "end {e_end:.3} m, online {e_online:.3} m"
    );
    assert!(
        outputs
            .summary
            .final_ba
            .is_some_and(|b| b.global_factors > 0)
    );
    assert!(outputs.keyframes.as_ref().is_some_and(|k| k.len() >= 5));

    let dir = tempfile::tempdir().unwrap();
    outputs.write(dir.path(), false).unwrap();
    let back = read_online_tum(&dir.path().join("trajectory.tum")).unwrap();
    assert_eq!(back.len(), outputs.online.len());
    for (b, o) in back.iter().zip(&outputs.online) {
        assert!((b.timestamp - o.timestamp).abs() < 1e-6);
        match (b.status, o.status) {
            (OnlineStatus::World(p), OnlineStatus::World(q)) => {
                assert!((p.centre() - q.centre()).norm() < 1e-5)
            }
            (x, y) => assert_eq!(x, y),
        }
    }
    let rows = read_fixes(&dir.path().join("fixes.txt")).unwrap();
    assert_eq!(rows.len(), outputs.fixes.len());
    let settings = std::fs::read_to_string(dir.path().join("config.toml")).unwrap();
    let settings: JointLocConfig = toml::from_str(&settings).unwrap();
    assert_eq!(settings, outputs.config);
    let e = outputs.write(dir.path(), false).unwrap_err().to_string();
    assert!(
        e.contains("trajectory.tum") && e.contains("already exists"),
        "{e}"
    );
    outputs.write(dir.path(), true).unwrap();
}

#[test]
fn wrong_fixes_are_flagged_and_out_voted() {
    let mut config = JointLocConfig::default();
    config.faults.wrong_fix_fraction = 0.25;
    config.faults.seed = 7;
    let source = TruthFixes::new(flight(), 0.1, 2);
    let (_, outputs) = run(builder(flight(), config.clone(), source), &config);
    let injected: Vec<&FixRecord> = outputs.fixes.iter().filter(|f| f.injected).collect();
    assert!(injected.len() >= 2, "{} wrong fixes", injected.len());
    assert!(
        injected.iter().all(|f| !f.inlier),
        "a wrong fix in the alignment"
    );
    assert_eq!(outputs.summary.fixes_injected_wrong, injected.len());
    let e = rmse(&ground_truth(flight()), &online(&outputs));
    assert!(e < 0.3, "online rmse {e:.3} m with wrong fixes");
}

/// Fixes from the truth, but the third search returns a weak fix (confidence 0.18) 30 m off,
/// and, as a local search does, every search whose prior is more than 10 m from the frame
/// finds the same wrong place again, moving with the UAV as the right one would.
#[derive(Debug)]
struct WrongPlaceNearPrior {
    truth: TruthFixes,
    gt: jointloc_geometry::trajectory::Trajectory,
    requests: usize,
}

impl jointloc_system::FixSource for WrongPlaceNearPrior {
    fn localize(
        &mut self,
        request: &jointloc_system::FixRequest<'_>,
    ) -> Result<Option<jointloc_system::Located>, jointloc_absloc::AbslocError> {
        self.requests += 1;
        let mut located = self.truth.localize(request)?;
        let i = pose_at(&self.gt, request.timestamp);
        let far_prior = match (i, request.prior.position) {
            (Some(i), Some([x, y])) => {
                let c = self.gt.poses[i].centre();
                (c.x - x).hypot(c.y - y) > 10.0
            }
            _ => false,
        };
        if let Some(fix) = found_fix(&mut located)
            && (self.requests == 3 || far_prior)
        {
            fix.position[0] += 30.0;
            fix.confidence = 0.18;
        }
        Ok(located)
    }
}

/// Before the alignment exists, a weak fix far from where the strong ones put the frame does
/// not become the search prior: the searches after it still look at the right place, and the
/// alignment out-votes it. (Had it moved the prior, every later search would have found the
/// wrong place again and the first alignment would have been 30 m off.)
#[test]
fn a_weak_far_fix_before_the_alignment_does_not_steer_the_searches() {
    let config = JointLocConfig::default();
    let source = WrongPlaceNearPrior {
        truth: TruthFixes::new(flight(), 0.1, 5),
        gt: ground_truth(flight()),
        requests: 0,
    };
    let (_, outputs) = run(builder(flight(), config.clone(), source), &config);
    let wrong: Vec<&FixRecord> = outputs
        .fixes
        .iter()
        .filter(|f| f.confidence < 0.2)
        .collect();
    assert_eq!(wrong.len(), 1, "{:?}", outputs.fixes);
    assert!(!wrong[0].inlier, "the wrong fix is in the alignment");
    let e = rmse(&ground_truth(flight()), &online(&outputs));
    assert!(e < 0.3, "online rmse {e:.3} m");
}

/// Fixes from the truth, but the first `turned` searches return the flight turned half a
/// turn about a point 10 m from the first fix, headings turned with it, all weak
/// (confidence 0.15): what a virtual frame's correlation found under a sun reversed from
/// the map's. The chain agrees with itself and with the SLAM's path.
#[derive(Debug)]
struct TurnedChain {
    truth: TruthFixes,
    requests: usize,
    turned: usize,
    pivot: Option<[f64; 2]>,
}

impl jointloc_system::FixSource for TurnedChain {
    fn localize(
        &mut self,
        request: &jointloc_system::FixRequest<'_>,
    ) -> Result<Option<jointloc_system::Located>, jointloc_absloc::AbslocError> {
        self.requests += 1;
        let mut located = self.truth.localize(request)?;
        if let Some(fix) = found_fix(&mut located)
            && self.requests <= self.turned
        {
            let [x, y, _] = fix.position;
            let first = *self.pivot.get_or_insert([x, y]);
            let pivot = [first[0] + 6.0, first[1] + 8.0];
            fix.position[0] = pivot[0] - (x - first[0]);
            fix.position[1] = pivot[1] - (y - first[1]);
            fix.heading += std::f64::consts::PI;
            fix.confidence = 0.15;
        }
        Ok(located)
    }
}

/// With the take-off position given, a chain of turned fixes does not make the first
/// alignment: it would put the take-off 10–20 m from where the user said the flight began.
/// The right fixes after it do. Without the check the chain geo-references the flight
/// metres off.
#[test]
fn the_take_off_keeps_a_turned_chain_of_fixes_from_the_alignment() {
    let gt = ground_truth(flight());
    let start = gt.poses[0].centre();
    let run_with = |radius_m: f64| {
        let config = JointLocConfig {
            start_position: Some([start.x, start.y]),
            start_radius_m: radius_m,
            ..JointLocConfig::default()
        };
        let source = TurnedChain {
            truth: TruthFixes::new(flight(), 0.1, 12),
            requests: 0,
            turned: 12,
            pivot: None,
        };
        run(builder(flight(), config.clone(), source), &config).1
    };
    let checked = run_with(JointLocConfig::default().start_radius_m);
    let turned: Vec<&FixRecord> = checked
        .fixes
        .iter()
        .filter(|f| f.confidence < 0.2)
        .collect();
    assert!(turned.len() >= 10, "{:?}", checked.fixes);
    assert!(
        turned.iter().all(|f| !f.inlier),
        "a turned fix is an inlier"
    );
    let e = rmse(&gt, &online(&checked));
    assert!(e < 0.3, "online rmse {e:.3} m with the take-off check");
    let unchecked = run_with(0.0);
    let e = rmse(&gt, &online(&unchecked));
    assert!(e > 3.0, "online rmse {e:.3} m without the take-off check");
}

/// Each search's time and prior heading, as a source saw them.
type PriorLog = Arc<Mutex<Vec<(f64, Option<f64>)>>>;

/// Fixes from the ground truth, one of them (the `flip_at`-th request) with its heading
/// turned by 167° (its position right), as seen at 100 m over gravel; records each request's
/// time and prior heading.
#[derive(Debug)]
struct HeadingFlip {
    truth: TruthFixes,
    requests: usize,
    flip_at: usize,
    priors: PriorLog,
}

impl jointloc_system::FixSource for HeadingFlip {
    fn localize(
        &mut self,
        request: &jointloc_system::FixRequest<'_>,
    ) -> Result<Option<jointloc_system::Located>, jointloc_absloc::AbslocError> {
        self.requests += 1;
        self.priors
            .lock()
            .unwrap()
            .push((request.timestamp, request.prior.heading));
        let mut located = self.truth.localize(request)?;
        if let Some(fix) = found_fix(&mut located)
            && self.requests == self.flip_at
        {
            fix.heading += 167f64.to_radians();
        }
        Ok(located)
    }
}

/// Before the alignment, a fix whose heading disagrees with the provisional similarity's by
/// far does not hand its heading to the next search (which sweeps the headings instead);
/// with consistent fixes every search before it had the true heading.
#[test]
fn a_fix_that_turns_the_heading_leaves_the_next_search_without_one() {
    let truth_heading = |t: f64| {
        let gt = ground_truth(flight());
        let i = pose_at(&gt, t).unwrap();
        jointloc_absloc::heading_from_rotation(&gt.poses[i].rotation().to_rotation_matrix())
    };
    let off_deg = |a: f64, b: f64| {
        let d = (a - b).rem_euclid(std::f64::consts::TAU);
        d.min(std::f64::consts::TAU - d).to_degrees()
    };
    let run_with = |turn_deg: f64| {
        let config = JointLocConfig {
            provisional_turn_deg: turn_deg,
            ..JointLocConfig::default()
        };
        let priors = Arc::new(Mutex::new(Vec::new()));
        let source = HeadingFlip {
            truth: TruthFixes::new(flight(), 0.02, 6),
            requests: 0,
            flip_at: 3,
            priors: priors.clone(),
        };
        let (_, outputs) = run(builder(flight(), config.clone(), source), &config);
        let priors = priors.lock().unwrap().clone();
        (priors, outputs)
    };
    let (priors, outputs) = run_with(JointLocConfig::default().provisional_turn_deg);
    // The second request's prior comes from the first tied fix: the true heading.
    let (t, h) = priors[2];
    assert!(
        off_deg(h.expect("a heading"), truth_heading(t)) < 5.0,
        "{priors:?}"
    );
    // The fourth comes after the turned fix: no heading.
    assert_eq!(priors[3].1, None, "{priors:?}");
    let e = rmse(&ground_truth(flight()), &online(&outputs));
    assert!(e < 0.3, "online rmse {e:.3} m");
    // Without the rule the fourth search would look 167° off.
    let (priors, _) = run_with(0.0);
    let (t, h) = priors[3];
    assert!(
        off_deg(h.expect("a heading"), truth_heading(t)) > 150.0,
        "{priors:?}"
    );
}

/// Fixes from the ground truth moved by `offset_m` in x, with `confidence`, for the first
/// `found` searches; every later search fails (a place the matcher no longer finds).
#[derive(Debug)]
struct FewFixes {
    truth: TruthFixes,
    requests: usize,
    found: usize,
    offset_m: f64,
    confidence: f64,
}

impl jointloc_system::FixSource for FewFixes {
    fn localize(
        &mut self,
        request: &jointloc_system::FixRequest<'_>,
    ) -> Result<Option<jointloc_system::Located>, jointloc_absloc::AbslocError> {
        self.requests += 1;
        let mut located = self.truth.localize(request)?;
        if let Some(jointloc_system::Located { outcome, .. }) = located.as_mut() {
            if self.requests > self.found {
                *outcome = no_match();
            } else if let jointloc_absloc::Outcome::Fix(fix) = outcome {
                fix.position[0] += self.offset_m;
                fix.confidence = self.confidence;
            }
        }
        Ok(located)
    }
}

/// An alignment of weak fixes only that no later fix confirms stops giving world poses after
/// `unconfirmed_weak_alignment_s`; one with strong fixes is kept through the same gap.
#[test]
fn an_unconfirmed_alignment_of_weak_fixes_is_dropped() {
    let run_with = |limit: f64, confidence: f64| {
        let config = JointLocConfig {
            unconfirmed_weak_alignment_s: limit,
            ..JointLocConfig::default()
        };
        let source = FewFixes {
            truth: TruthFixes::new(flight(), 0.05, 9),
            requests: 0,
            found: 6,
            offset_m: 30.0,
            confidence,
        };
        run(builder(flight(), config.clone(), source), &config).1
    };
    let world = |outputs: &Outputs| -> Vec<f64> {
        outputs
            .online
            .iter()
            .filter(|f| f.world_pose().is_some())
            .map(|f| f.timestamp)
            .collect()
    };
    // Six searches: fixes up to 10 s; the last world pose 10 s after the newest inlier.
    let outputs = run_with(10.0, 0.1);
    let dropped = world(&outputs);
    assert!(!dropped.is_empty());
    let last = dropped.last().copied().unwrap();
    assert!((15.0..=21.0).contains(&last), "last world pose at {last} s");
    assert_eq!(
        outputs.summary.fixes_inliers, 0,
        "the dropped fixes are no inliers"
    );
    // The same weak fixes without the rule, and strong ones with it: world poses to the end.
    for (limit, confidence) in [(0.0, 0.1), (10.0, 0.5)] {
        let kept = world(&run_with(limit, confidence));
        let last = kept.last().copied().unwrap_or(0.0);
        assert!(
            last > 39.0,
            "limit {limit}, w {confidence}: last world pose at {last} s"
        );
    }
}

#[test]
fn an_outage_is_counted_and_the_slam_carries_the_poses_through_it() {
    let mut config = JointLocConfig::default();
    config.faults.outage_start_s = Some(18.0);
    config.faults.outage_duration_s = 10.0;
    let source = TruthFixes::new(flight(), 0.1, 3);
    let (fused, outputs) = run(builder(flight(), config.clone(), source), &config);
    // Every `fusion_every`-th frame at 5 Hz (5: one attempt a second): 10 s of outage.
    let expected = 50 / config.fusion_every;
    assert_eq!(
        outputs.summary.skipped_outage, expected,
        "{:?}",
        outputs.summary
    );
    let during = fused
        .iter()
        .filter(|f| (18.0..28.0).contains(&f.timestamp))
        .filter(|f| f.world_pose.is_some())
        .count();
    assert!(during >= 45, "{during} world poses during the outage");
    assert!(
        outputs
            .fixes
            .iter()
            .all(|f| !(18.0..28.0).contains(&f.timestamp))
    );
}

#[test]
fn a_long_loss_starts_a_new_map_which_the_fixes_geo_reference_again() {
    let mut config = JointLocConfig::default();
    config.faults.blind_start_s = Some(15.0);
    config.faults.blind_duration_s = 7.0;
    let source = TruthFixes::new(flight(), 0.1, 4);
    let (fused, outputs) = run(builder(flight(), config.clone(), source), &config);
    assert!(outputs.summary.new_maps >= 1, "{:?}", outputs.summary);
    assert!(outputs.summary.lost > 0);
    let again = fused
        .iter()
        .find(|f| f.timestamp > 22.0 && f.world_pose.is_some())
        .map(|f| f.timestamp);
    assert!(
        again.is_some_and(|t| t < 32.0),
        "world poses again at {again:?}"
    );
    let end = outputs.frames.as_ref().unwrap();
    assert!(end.timestamps.first().is_some_and(|&t| t < 15.0));
    assert!(end.timestamps.last().is_some_and(|&t| t > 35.0));
    let e = rmse(&ground_truth(flight()), end);
    assert!(e < 0.3, "end rmse {e:.3} m over both maps");
    // Both maps were geo-referenced: the end outputs come from one merged map, without the
    // blinded frames or the new map's frames before its first world pose.
    let s = &outputs.summary;
    assert_eq!((s.maps_merged, s.maps_at_end), (s.new_maps, 1), "{s:?}");
    let first_again = again.unwrap();
    assert!(
        !end.timestamps
            .iter()
            .any(|&t| (15.0..first_again).contains(&t)),
        "end outputs inside the loss"
    );
}

/// Counts what it is shown.
#[derive(Default)]
struct Counter {
    frames: usize,
    fixes: usize,
}

struct Counting(Arc<Mutex<Counter>>);

impl Observer for Counting {
    fn frame(&mut self, _: &FusedFrame) {
        self.0.lock().unwrap().frames += 1;
    }
    fn fix(&mut self, _: &FixRecord) {
        self.0.lock().unwrap().fixes += 1;
    }
}

#[test]
fn threaded_mode_applies_every_search_by_the_finish_and_observers_see_all() {
    let config = JointLocConfig::default();
    let counter = Arc::new(Mutex::new(Counter::default()));
    let b = builder(flight(), config.clone(), TruthFixes::new(flight(), 0.1, 5))
        .mode(Mode::Threaded)
        .observer(Box::new(Counting(counter.clone())));
    let (fused, outputs) = run(b, &config);
    let s = &outputs.summary;
    assert_eq!(s.mode, "threaded");
    assert_eq!(s.absolute_attempts, s.fixes_found, "{s:?}");
    assert!(s.world_poses * 10 >= 7 * fused.len(), "{s:?}");
    let c = counter.lock().unwrap();
    assert_eq!((c.frames, c.fixes), (fused.len(), outputs.fixes.len()));
    let e = rmse(&ground_truth(flight()), &online(&outputs));
    assert!(e < 0.3, "threaded online rmse {e:.3} m");
}

/// A fix source as slow as a search from high above (hundreds of ms): the keyframe current at
/// the searched frame may be culled before the fix comes back.
#[derive(Debug)]
struct Slow(TruthFixes, std::time::Duration);

impl jointloc_system::FixSource for Slow {
    fn localize(
        &mut self,
        request: &jointloc_system::FixRequest<'_>,
    ) -> Result<Option<jointloc_system::Located>, jointloc_absloc::AbslocError> {
        std::thread::sleep(self.1);
        self.0.localize(request)
    }
}

/// Frames no faster than one per `.0` (as a camera would give them): the number of searches a
/// slow source completes does not then depend on how fast this machine tracks.
struct Paced(std::time::Duration);

impl Observer for Paced {
    fn frame(&mut self, _: &FusedFrame) {
        std::thread::sleep(self.0);
    }
}

/// On its own thread a fix comes back after its keyframe may have been culled; it is then
/// tied to the keyframe nearest in time instead of being dropped (at 200 m that dropped the
/// first fixes and held off the world frame by 22 s).
#[test]
fn threaded_fixes_whose_keyframe_was_culled_meanwhile_are_still_used() {
    let config = JointLocConfig::default();
    let slow = Slow(
        TruthFixes::new(flight(), 0.1, 7),
        std::time::Duration::from_millis(600),
    );
    // 201 frames at most 40 Hz: at least 5 s, 8 searches of 600 ms or more.
    let b = builder(flight(), config.clone(), slow)
        .mode(Mode::Threaded)
        .observer(Box::new(Paced(std::time::Duration::from_millis(25))));
    let (_, outputs) = run(b, &config);
    let s = &outputs.summary;
    assert!(s.fixes_found >= 5, "{s:?}");
    assert_eq!(s.fixes_used, s.fixes_found, "{s:?}");
}

/// A camera tilted 3° off nadir (a UAV pitched to cruise): assuming a nadir view the
/// camera pairs are 0.52 m off at 10 m and pull the outputs off; with the tilt estimated
/// from the fused attitudes they place the camera where it looks from.
#[test]
fn a_camera_tilted_off_nadir_is_placed_where_it_looks_from() {
    let dir = tilted_flight();
    let gt = ground_truth(dir);
    let images = frames(dir);
    let errors: Vec<(f64, f64)> = [false, true]
        .into_iter()
        .map(|estimate| {
            let config = JointLocConfig {
                estimate_camera_tilt: estimate,
                ..Default::default()
            };
            let mut system = builder(dir, config, TruthFixes::new(dir, 0.02, 11))
                .build()
                .unwrap();
            for (image, t, alt) in &images {
                system.process(image, *t, *alt).unwrap();
            }
            let outputs = system.finish().unwrap();
            let tilt = outputs.summary.camera_tilt;
            if estimate {
                // Reported as estimated: the flight's 3° about the image x axis.
                let t = tilt.expect("the estimated tilt in the summary");
                let off = (t.estimated_deg[0] - 3.0).hypot(t.estimated_deg[1]);
                assert!(off < 0.5, "estimated {:?}°, flown [3, 0]°", t.estimated_deg);
                assert!(t.used_deg[0] < t.estimated_deg[0] && t.used_deg[0] > 2.5);
            } else {
                assert_eq!(tilt, None, "not estimated, not reported");
            }
            let end = outputs.frames.as_ref().unwrap();
            (rmse(&gt, &online(&outputs)), rmse(&gt, end))
        })
        .collect();
    let [(nadir_online, nadir_end), (tilt_online, tilt_end)] = errors[..] else {
        unreachable!()
    };
    assert!(
        tilt_end < 0.6 * nadir_end && tilt_end < 0.1,
        "at the end: {tilt_end:.3} m with the tilt, {nadir_end:.3} m assuming nadir"
    );
    assert!(
        tilt_online < 0.8 * nadir_online,
        "online: {tilt_online:.3} m with the tilt, {nadir_online:.3} m assuming nadir"
    );
}

/// Fails every search until `until_s` of flight, then gives fixes from the truth; records
/// the frame times it was asked at.
#[derive(Debug)]
struct FailsUntil {
    truth: TruthFixes,
    until_s: f64,
    asked: Arc<Mutex<Vec<f64>>>,
}

impl jointloc_system::FixSource for FailsUntil {
    fn localize(
        &mut self,
        request: &jointloc_system::FixRequest<'_>,
    ) -> Result<Option<jointloc_system::Located>, jointloc_absloc::AbslocError> {
        self.asked.lock().unwrap().push(request.timestamp);
        if request.timestamp < self.until_s {
            return Ok(Some(jointloc_system::Located {
                outcome: no_match(),
                injected: false,
            }));
        }
        self.truth.localize(request)
    }
}

/// Before the first fix a sequential run backs off after failed searches (each would search
/// the whole map): searches 1, 2, 4, 8 s apart (the cap 8 s here), then one a second again.
#[test]
fn searches_before_the_first_fix_back_off_after_failures() {
    let run_with = |max_s: f64| {
        let config = JointLocConfig {
            blind_retry_max_s: max_s,
            ..JointLocConfig::default()
        };
        let asked = Arc::new(Mutex::new(Vec::new()));
        let source = FailsUntil {
            truth: TruthFixes::new(flight(), 0.1, 11),
            until_s: 12.0,
            asked: asked.clone(),
        };
        let (_, outputs) = run(builder(flight(), config.clone(), source), &config);
        let asked = asked.lock().unwrap().clone();
        (asked, outputs)
    };
    let second = |t: &f64| t.round() as i64;
    let (asked, outputs) = run_with(8.0);
    let before: Vec<i64> = asked.iter().filter(|&&t| t < 16.0).map(second).collect();
    assert_eq!(before, [0, 1, 3, 7, 15], "searches before the first fix");
    let s = &outputs.summary;
    // 16 due searches in 0–15 s, 5 made; then one every second again.
    assert_eq!(s.skipped_backoff, 11, "{s:?}");
    assert_eq!(s.absolute_attempts + s.skipped_backoff, 41, "{s:?}");
    assert_eq!(
        outputs.fixes.first().map(|f| second(&f.timestamp)),
        Some(15)
    );
    let e = rmse(&ground_truth(flight()), &online(&outputs));
    assert!(e < 0.3, "online rmse {e:.3} m");

    let (asked, outputs) = run_with(0.0);
    assert_eq!(asked.len(), 41, "0: a search at every due frame");
    assert_eq!(outputs.summary.skipped_backoff, 0);
    assert_eq!(
        outputs.fixes.first().map(|f| second(&f.timestamp)),
        Some(12)
    );
}
