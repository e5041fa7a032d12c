//! End-to-end tests of the bundle adjustment on synthetic UAV scenes.

use jointloc_geometry::{Sim3, WorldToCamera};
use nalgebra::{Point2, Point3, UnitQuaternion, Vector3};

use super::factors::camera_centre;
use super::synthetic::{SyntheticScene, SyntheticSceneConfig, synthetic_scene};
use super::*;
use crate::SlamError;

const SEEDS: [u64; 4] = [1, 2, 3, 4];

fn scene(config: SyntheticSceneConfig) -> SyntheticScene {
    synthetic_scene(&config).expect("valid scene config")
}

/// Errors of the free variables against the truth.
#[derive(Debug)]
#[allow(dead_code)] // Fields are printed.
struct Errors {
    centre_rms_m: f64,
    centre_max_m: f64,
    rotation_max_deg: f64,
    point_median_m: f64,
    /// Points more than 1 m off.
    points_off: usize,
}

fn errors(
    problem: &BaProblem,
    cams: &[WorldToCamera],
    points: &[Vector3<f64>],
    s: &SyntheticScene,
) -> Errors {
    let (mut sq, mut n, mut centre_max, mut rotation_max) = (0.0, 0, 0.0f64, 0.0f64);
    for ((c, est), truth) in problem.cameras.iter().zip(cams).zip(&s.true_cameras) {
        if !c.fixed {
            let e = (camera_centre(est) - camera_centre(truth)).norm();
            sq += e * e;
            n += 1;
            centre_max = centre_max.max(e);
            rotation_max =
                rotation_max.max(est.rotation().angle_to(&truth.rotation()).to_degrees());
        }
    }
    let mut pe: Vec<f64> = points
        .iter()
        .zip(&s.true_points)
        .map(|(a, b)| (a - b).norm())
        .collect();
    pe.sort_by(f64::total_cmp);
    Errors {
        centre_rms_m: (sq / n.max(1) as f64).sqrt(),
        centre_max_m: centre_max,
        rotation_max_deg: rotation_max,
        point_median_m: pe[pe.len() / 2],
        points_off: pe.iter().filter(|&&e| e > 1.0).count(),
    }
}

fn start_errors(s: &SyntheticScene) -> Errors {
    let cams: Vec<_> = s.problem.cameras.iter().map(|c| c.pose).collect();
    let points: Vec<_> = s.problem.points.iter().map(|p| p.position).collect();
    errors(&s.problem, &cams, &points, s)
}

/// `½ Σ χ²` of the problem's observations at the true cameras and points (no kernel).
fn truth_cost(problem: &BaProblem, s: &SyntheticScene) -> f64 {
    let (chi2, _) = super::solver::chi2_at(problem, &s.true_cameras, &s.true_points);
    0.5 * chi2.iter().sum::<f64>()
}

#[test]
fn recovers_the_exact_truth_from_noise_free_pixels() {
    // No pixel noise, no outliers: the optimum is the truth itself (two cameras fixed at their
    // true poses fix the gauge, scale included), so the solver must land on it from a start
    // 5 cm / 0.5° off on poses and 10 cm off on points.
    for seed in SEEDS {
        let s = scene(SyntheticSceneConfig {
            seed,
            pixel_noise_px: 0.0,
            outlier_fraction: 0.0,
            ..Default::default()
        });
        let config = BundleAdjustmentConfig {
            max_iterations: 50,
            ..Default::default()
        };
        let r = bundle_adjust(&s.problem, &config).unwrap();
        let e = errors(&s.problem, &r.cameras, &r.points, &s);
        let worst_point = r
            .points
            .iter()
            .zip(&s.true_points)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        eprintln!(
            "seed {seed}: noise-free {e:?}, worst point {worst_point:.2e} m, {} its",
            r.iterations
        );
        assert!(e.centre_max_m < 1e-5, "seed {seed}: {e:?}");
        assert!(e.rotation_max_deg < 1e-5, "seed {seed}: {e:?}");
        assert!(worst_point < 1e-4, "seed {seed}: {worst_point}");
        assert!(r.final_cost < 1e-8, "seed {seed}: {}", r.final_cost);
    }
}

#[test]
fn recovers_poses_and_points_from_noisy_start() {
    // 0.5 px noise and 5 % gross outliers, two-stage flow. At 50 m over 6 m of relief a lateral
    // shift and a tilt are nearly indistinguishable, so even with exact points a single pose is
    // only good to a few cm (see the motion-only test): the checks are against that, plus the
    // maximum-likelihood property (final cost no higher than the truth's).
    for seed in SEEDS {
        let s = scene(SyntheticSceneConfig {
            seed,
            ..Default::default()
        });
        let start = start_errors(&s);
        let r = bundle_adjust_two_stage(&s.problem, &TwoStageConfig::default()).unwrap();
        let end = errors(&s.problem, &r.cameras, &r.points, &s);
        let inliers = BaProblem {
            observations: (s.problem.observations.iter().zip(&r.outliers))
                .filter(|(_, out)| !**out)
                .map(|(o, _)| *o)
                .collect(),
            ..s.problem.clone()
        };
        let at_truth = truth_cost(&inliers, &s);
        eprintln!(
            "seed {seed}: start {start:?}\n        end {end:?}\n        cost {:.1} -> {:.1} (truth {at_truth:.1}) in {} its ({:?})",
            r.initial_cost, r.final_cost, r.iterations, r.termination
        );
        assert!(
            r.final_cost <= at_truth,
            "seed {seed}: {} > {at_truth}",
            r.final_cost
        );
        assert!(
            end.centre_rms_m < 0.8 * start.centre_rms_m,
            "seed {seed}: {end:?}"
        );
        assert!(end.centre_rms_m < 0.07, "seed {seed}: {end:?}");
        assert!(end.rotation_max_deg < 0.15, "seed {seed}: {end:?}");
        assert!(
            end.point_median_m < start.point_median_m,
            "seed {seed}: {end:?}"
        );
        // Points whose few views include a gross outlier can end far off; ORB-SLAM culls them.
        assert!(
            end.points_off <= s.true_points.len() / 50,
            "seed {seed}: {end:?}"
        );
    }
}

#[test]
fn two_stage_flow_flags_the_gross_outliers() {
    for seed in SEEDS {
        let s = scene(SyntheticSceneConfig {
            seed: 10 + seed,
            ..Default::default()
        });
        let r = bundle_adjust_two_stage(&s.problem, &TwoStageConfig::default()).unwrap();
        let gross = s.gross_outliers.iter().filter(|&&g| g).count();
        let caught = r
            .outliers
            .iter()
            .zip(&s.gross_outliers)
            .filter(|&(&f, &g)| f && g)
            .count();
        let false_alarms = r
            .outliers
            .iter()
            .zip(&s.gross_outliers)
            .filter(|&(&f, &g)| f && !g)
            .count();
        let inliers = s.gross_outliers.len() - gross;
        eprintln!("seed {seed}: {caught}/{gross} outliers flagged, {false_alarms}/{inliers} false");
        assert!(gross > 100);
        assert!(
            caught as f64 >= 0.98 * gross as f64,
            "seed {seed}: {caught}/{gross}"
        );
        assert!(
            false_alarms as f64 <= 0.01 * inliers as f64,
            "seed {seed}: {false_alarms}"
        );
        assert_eq!(r.outliers.len(), s.problem.observations.len());
        assert_eq!(r.outlier_count(), caught + false_alarms);
    }
}

/// A drifted map: every SLAM-frame quantity is `slam_from_world` of the truth, with no camera
/// fixed; returns the problem and the true camera centres in the world.
fn drifted(s: &SyntheticScene, slam_from_world: &Sim3) -> (BaProblem, Vec<Vector3<f64>>) {
    let mut p = s.problem.clone();
    for (cam, truth) in p.cameras.iter_mut().zip(&s.true_cameras) {
        let twc = slam_from_world.transform_pose(&truth.inverse());
        cam.pose = twc.inverse();
        cam.fixed = false;
    }
    for (pt, truth) in p.points.iter_mut().zip(&s.true_points) {
        pt.position = slam_from_world
            .transform_point(&Point3::from(*truth))
            .coords;
    }
    let centres = s.true_cameras.iter().map(camera_centre).collect();
    (p, centres)
}

fn clean_config(seed: u64) -> SyntheticSceneConfig {
    SyntheticSceneConfig {
        seed,
        outlier_fraction: 0.0,
        ..Default::default()
    }
}

#[test]
fn global_factors_pull_a_scale_drifted_map_onto_the_fixes() {
    // Monocular scale drift: the SLAM map is the truth scaled by 0.8; the fusion's similarity
    // is still the identity, so only the global factors inside the LBA can fix the scale.
    for (seed, pixel_noise) in SEEDS.iter().flat_map(|&s| [(s, 0.0), (s, 0.5)]) {
        let s = scene(SyntheticSceneConfig {
            pixel_noise_px: pixel_noise,
            ..clean_config(20 + seed)
        });
        let shrink = Sim3::new(0.8, UnitQuaternion::identity(), Vector3::zeros());
        let (mut p, fixes) = drifted(&s, &shrink);
        for (i, fix) in fixes.iter().enumerate() {
            p.add_global_factor(GlobalPositionFactor::new(i, *fix, Sim3::identity(), 1.0));
        }
        let before: f64 = p
            .cameras
            .iter()
            .zip(&fixes)
            .map(|(c, f)| (camera_centre(&c.pose) - f).norm())
            .fold(0.0, f64::max);
        let config = BundleAdjustmentConfig {
            max_iterations: 50,
            ..Default::default()
        };
        let r = bundle_adjust(&p, &config).unwrap();
        let after: f64 = r
            .cameras
            .iter()
            .zip(&fixes)
            .map(|(c, f)| (camera_centre(c) - f).norm())
            .fold(0.0, f64::max);
        let points = errors(&p, &r.cameras, &r.points, &s);
        eprintln!(
            "seed {seed} ({pixel_noise} px): max centre-to-fix {before:.2} m -> {after:.4} m, points {points:?}, {} its ({:?})",
            r.iterations, r.termination
        );
        assert!(before > 9.0);
        // Exact pixels: the map lands on the truth. Noisy pixels: the vision-determined shape of
        // the window is a few cm off (see the motion-only test); the fixes fit it best.
        let (centre_tol, point_tol) = if pixel_noise == 0.0 {
            (1e-3, 1e-2)
        } else {
            (0.1, 0.2)
        };
        assert!(after < centre_tol, "seed {seed}: {after} m");
        assert!(points.point_median_m < point_tol, "seed {seed}: {points:?}");
        // A few points seen by three close cameras have a depth σ near 1 m at 0.5 px.
        assert!(
            points.points_off <= s.true_points.len() / 100,
            "seed {seed}: {points:?}"
        );
        assert!(r.global_chi2.iter().all(|&c| c < 0.01));
    }
}

#[test]
fn ground_point_fixes_pull_the_map_onto_the_points_they_fix() {
    // A map fix locates the point on the optical axis at the altimeter range, not the camera:
    // the factor of that camera-frame point must move the pose so that the point lands on the
    // fix. From the 0.8-scaled map, exact pixels must give back the true poses.
    for (seed, pixel_noise) in SEEDS.iter().flat_map(|&s| [(s, 0.0), (s, 0.5)]) {
        let config = SyntheticSceneConfig {
            pixel_noise_px: pixel_noise,
            ..clean_config(60 + seed)
        };
        let s = scene(config);
        let shrink = Sim3::new(0.8, UnitQuaternion::identity(), Vector3::zeros());
        let (mut p, _) = drifted(&s, &shrink);
        let o = Vector3::new(0.0, 0.0, config.altitude_m);
        let fixes: Vec<Vector3<f64>> = s
            .true_cameras
            .iter()
            .map(|t| t.inverse().transform_point(&Point3::from(o)).coords)
            .collect();
        for (i, fix) in fixes.iter().enumerate() {
            p.add_global_factor(GlobalPositionFactor {
                point_in_camera: o,
                ..GlobalPositionFactor::new(i, *fix, Sim3::identity(), 1.0)
            });
        }
        let ground_error = |cams: &[WorldToCamera]| {
            cams.iter()
                .zip(&fixes)
                .map(|(c, f)| (c.inverse().transform_point(&Point3::from(o)).coords - f).norm())
                .fold(0.0, f64::max)
        };
        let start: Vec<WorldToCamera> = p.cameras.iter().map(|c| c.pose).collect();
        let before = ground_error(&start);
        let config = BundleAdjustmentConfig {
            max_iterations: 50,
            ..Default::default()
        };
        let r = bundle_adjust(&p, &config).unwrap();
        let after = ground_error(&r.cameras);
        let e = errors(&p, &r.cameras, &r.points, &s);
        eprintln!(
            "seed {seed} ({pixel_noise} px): max ground point to fix {before:.2} m -> {after:.4} m, {e:?}"
        );
        assert!(before > 5.0, "seed {seed}: {before}");
        let tol = if pixel_noise == 0.0 { 1e-3 } else { 0.1 };
        assert!(after < tol, "seed {seed}: {after} m");
        if pixel_noise == 0.0 {
            assert!(e.centre_max_m < 1e-3, "seed {seed}: {e:?}");
            assert!(e.rotation_max_deg < 1e-2, "seed {seed}: {e:?}");
        }
    }
}

#[test]
fn loose_heights_of_ground_point_fixes_do_not_roll_the_map() {
    // At altitude a fix's x, y come from the map and its z from the altimeter, whose noise
    // grows with the range. Heights 3 cm off per metre across the track, under fixes of the
    // camera centres (right, but 4× looser): isotropic ground-point fixes roll the map to
    // fit the wrong heights; with their z σ ten times their x, y σ the cameras stay where
    // the camera-centre fixes and the images put them.
    let mut isotropic = Vec::new();
    let mut loose = Vec::new();
    for seed in SEEDS {
        let config = clean_config(80 + seed);
        let s = scene(config);
        let (mut p, centres) = drifted(&s, &Sim3::identity());
        let cy = centres.iter().map(|c| c.y).sum::<f64>() / centres.len() as f64;
        let o = Vector3::new(0.0, 0.0, config.altitude_m);
        for (i, t) in s.true_cameras.iter().enumerate() {
            let mut ground = t.inverse().transform_point(&Point3::from(o)).coords;
            ground.z += 0.03 * (ground.y - cy);
            p.add_global_factor(GlobalPositionFactor {
                sigma: 0.15,
                point_in_camera: o,
                ..GlobalPositionFactor::new(i, ground, Sim3::identity(), 1.0)
            });
            p.add_global_factor(GlobalPositionFactor {
                sigma: 0.6,
                ..GlobalPositionFactor::new(i, centres[i], Sim3::identity(), 1.0)
            });
        }
        let n = p.global_factors.len();
        let config = BundleAdjustmentConfig {
            max_iterations: 50,
            ..Default::default()
        };
        for (scale, out) in [(1.0, &mut isotropic), (10.0, &mut loose)] {
            for g in p.global_factors.iter_mut().step_by(2) {
                g.vertical_sigma_scale = scale;
            }
            assert_eq!(p.global_factors.len(), n);
            let r = bundle_adjust(&p, &config).unwrap();
            let e = errors(&p, &r.cameras, &r.points, &s);
            eprintln!("seed {seed}, z σ × {scale}: {e:?}");
            out.push(e.rotation_max_deg);
        }
    }
    for (i, l) in isotropic.iter().zip(&loose) {
        assert!(*i > 0.2, "the wrong heights roll the isotropic map: {i}°");
        assert!(*l < i / 3.0, "loose heights {l}° vs isotropic {i}°");
    }
}

#[test]
fn a_non_positive_vertical_sigma_scale_is_an_error() {
    let s = scene(clean_config(90));
    let mut p = s.problem.clone();
    for v in [0.0, -1.0, f64::NAN] {
        p.global_factors = vec![GlobalPositionFactor {
            vertical_sigma_scale: v,
            ..GlobalPositionFactor::new(1, Vector3::zeros(), Sim3::identity(), 1.0)
        }];
        assert!(p.validate().is_err(), "{v}");
    }
}

#[test]
fn global_factors_use_the_slam_to_world_similarity() {
    // SLAM frame = a rotated, shifted, 0.4-scaled copy of the world, plus a 10 % scale drift
    // the similarity does not know about.
    for seed in SEEDS {
        let s = scene(clean_config(30 + seed));
        let world_to_slam = Sim3::new(
            0.4,
            UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1),
            Vector3::new(5.0, -3.0, 2.0),
        );
        let drift = Sim3::new(1.1, UnitQuaternion::identity(), Vector3::zeros());
        let (mut p, fixes) = drifted(&s, &drift.compose(&world_to_slam));
        let slam_to_world = world_to_slam.inverse();
        for (i, fix) in fixes.iter().enumerate() {
            let mut f = GlobalPositionFactor::new(i, *fix, slam_to_world, 0.8);
            f.kernel = jointloc_geometry::RobustKernel::Cauchy { c: 2.0 };
            p.add_global_factor(f);
        }
        let config = BundleAdjustmentConfig {
            max_iterations: 50,
            ..Default::default()
        };
        let r = bundle_adjust(&p, &config).unwrap();
        let after: f64 = r
            .cameras
            .iter()
            .zip(&fixes)
            .map(|(c, f)| {
                let w = slam_to_world.transform_point(&Point3::from(camera_centre(c)));
                (w.coords - f).norm()
            })
            .fold(0.0, f64::max);
        eprintln!(
            "seed {seed}: max world centre error {after:.4} m ({} its)",
            r.iterations
        );
        assert!(after < 0.1, "seed {seed}: {after} m");
    }
}

#[test]
fn zero_weight_global_factors_change_nothing() {
    for seed in SEEDS {
        let s = scene(SyntheticSceneConfig {
            seed: 40 + seed,
            points: 300,
            ..Default::default()
        });
        let config = BundleAdjustmentConfig::default();
        let plain = bundle_adjust(&s.problem, &config).unwrap();
        let mut p = s.problem.clone();
        for i in 0..p.cameras.len() {
            // Fixes far from the cameras: any leak would show.
            let fix = Vector3::new(100.0 * i as f64, -500.0, 3.0);
            p.add_global_factor(GlobalPositionFactor::new(i, fix, Sim3::identity(), 0.0));
        }
        let weighted = bundle_adjust(&p, &config).unwrap();
        assert_eq!(plain.cameras, weighted.cameras);
        assert_eq!(plain.points, weighted.points);
        assert_eq!(plain.final_cost, weighted.final_cost);
        assert_eq!(plain.iterations, weighted.iterations);
        // With weight, the same fixes do move the map.
        for f in &mut p.global_factors {
            f.weight = 1.0;
        }
        let pulled = bundle_adjust(&p, &config).unwrap();
        assert_ne!(plain.cameras, pulled.cameras);
    }
}

#[test]
fn non_finite_or_malformed_input_is_an_error() {
    let s = scene(SyntheticSceneConfig {
        points: 50,
        ..Default::default()
    });
    let config = BundleAdjustmentConfig::default();
    type Corruption = Box<dyn Fn(&mut BaProblem)>;
    let cases: Vec<(&str, Corruption)> = vec![
        ("point", Box::new(|p| p.points[3].position.x = f64::NAN)),
        (
            "pose",
            Box::new(|p| p.cameras[4].pose.0.translation.vector.y = f64::NAN),
        ),
        (
            "pixel",
            Box::new(|p| p.observations[7].pixel = Point2::new(f64::INFINITY, 1.0)),
        ),
        (
            "information",
            Box::new(|p| p.observations[0].information = f64::NAN),
        ),
        ("intrinsics", Box::new(|p| p.intrinsics.fx = f64::NAN)),
        (
            "fix",
            Box::new(|p| {
                p.add_global_factor(GlobalPositionFactor::new(
                    2,
                    Vector3::new(f64::NAN, 0.0, 0.0),
                    Sim3::identity(),
                    1.0,
                ))
            }),
        ),
        (
            "weight",
            Box::new(|p| {
                p.add_global_factor(GlobalPositionFactor::new(
                    2,
                    Vector3::zeros(),
                    Sim3::identity(),
                    f64::NAN,
                ))
            }),
        ),
        (
            "similarity",
            Box::new(|p| {
                let mut sim = Sim3::identity();
                sim.scale = f64::NAN;
                p.add_global_factor(GlobalPositionFactor::new(2, Vector3::zeros(), sim, 1.0))
            }),
        ),
        (
            "prior",
            Box::new(|p| {
                p.add_position_prior(PositionPrior {
                    camera: 1,
                    position: Vector3::new(0.0, f64::NAN, 0.0),
                    sigma: 1.0,
                })
            }),
        ),
    ];
    for (name, corrupt) in &cases {
        let mut p = s.problem.clone();
        corrupt(&mut p);
        let err = bundle_adjust(&p, &config).expect_err(name);
        assert!(matches!(err, SlamError::NonFinite(_)), "{name}: {err}");
        let two = bundle_adjust_two_stage(&p, &TwoStageConfig::default());
        assert!(two.is_err(), "{name}");
    }
    let mut p = s.problem.clone();
    p.observations[0].point = p.points.len();
    assert!(matches!(
        bundle_adjust(&p, &config),
        Err(SlamError::InvalidProblem(_))
    ));
    let mut p = s.problem.clone();
    p.add_global_factor(GlobalPositionFactor::new(
        0,
        Vector3::zeros(),
        Sim3::identity(),
        -1.0,
    ));
    assert!(matches!(
        bundle_adjust(&p, &config),
        Err(SlamError::InvalidProblem(_))
    ));
    let bad = BundleAdjustmentConfig {
        initial_damping: f64::NAN,
        ..config
    };
    assert!(matches!(
        bundle_adjust(&s.problem, &bad),
        Err(SlamError::InvalidConfig { .. })
    ));
}

#[test]
fn all_fixed_problem_returns_its_input() {
    let s = scene(SyntheticSceneConfig {
        points: 50,
        ..Default::default()
    });
    let mut p = s.problem.clone();
    p.cameras.iter_mut().for_each(|c| c.fixed = true);
    p.points.iter_mut().for_each(|x| x.fixed = true);
    let r = bundle_adjust(&p, &BundleAdjustmentConfig::default()).unwrap();
    assert_eq!(r.termination, Termination::NothingToDo);
    assert_eq!(r.iterations, 0);
    assert_eq!(r.initial_cost, r.final_cost);
    assert!(r.cameras.iter().zip(&p.cameras).all(|(a, b)| *a == b.pose));
}

#[test]
fn fixed_points_and_position_priors_are_respected() {
    // Motion-only BA (all points fixed at the truth) with a prior that agrees with the truth.
    for seed in SEEDS {
        let s = scene(SyntheticSceneConfig {
            seed: 50 + seed,
            points: 300,
            ..Default::default()
        });
        let mut p = s.problem.clone();
        for (pt, truth) in p.points.iter_mut().zip(&s.true_points) {
            *pt = BaPoint {
                position: *truth,
                fixed: true,
            };
        }
        p.add_position_prior(PositionPrior {
            camera: 5,
            position: camera_centre(&s.true_cameras[5]),
            sigma: 0.01,
        });
        let r = bundle_adjust(&p, &BundleAdjustmentConfig::default()).unwrap();
        assert_eq!(
            r.points,
            p.points.iter().map(|x| x.position).collect::<Vec<_>>()
        );
        let e = errors(&p, &r.cameras, &r.points, &s);
        let prior_error = (camera_centre(&r.cameras[5]) - camera_centre(&s.true_cameras[5])).norm();
        eprintln!(
            "seed {seed}: motion-only {e:?}, prior camera {prior_error:.4} m ({:?})",
            r.termination
        );
        let mut at_truth = p.clone();
        for (c, t) in at_truth.cameras.iter_mut().zip(&s.true_cameras) {
            c.pose = *t;
            c.fixed = true;
        }
        let truth = bundle_adjust(&at_truth, &BundleAdjustmentConfig::default()).unwrap();
        assert!(
            r.final_cost <= truth.initial_cost,
            "seed {seed}: {} > {}",
            r.final_cost,
            truth.initial_cost
        );
        assert!(
            e.centre_max_m < 0.15 && e.rotation_max_deg < 0.15,
            "seed {seed}: {e:?}"
        );
        // The 1 cm prior holds its camera where the images alone leave it several cm off.
        assert!(prior_error < 0.01, "seed {seed}: {prior_error}");
    }
}

#[test]
fn gauge_free_problem_is_damped_not_singular() {
    // No fixed camera and no global factor: the 7-DoF gauge makes the Gauss–Newton system
    // singular; the Marquardt damping must keep it solvable and the cost must still drop.
    for seed in SEEDS {
        let s = scene(SyntheticSceneConfig {
            seed: 60 + seed,
            points: 200,
            fixed_cameras: 0,
            outlier_fraction: 0.0,
            ..Default::default()
        });
        let config = BundleAdjustmentConfig {
            max_iterations: 30,
            ..Default::default()
        };
        let r = bundle_adjust(&s.problem, &config).unwrap();
        assert!(r.iterations > 0, "seed {seed}: {:?}", r.termination);
        assert!(
            r.final_cost < 0.05 * r.initial_cost,
            "seed {seed}: {} -> {}",
            r.initial_cost,
            r.final_cost
        );
        assert!(r.cameras.iter().all(|c| c.is_finite()));
        assert_eq!(r.outlier_count(), 0, "seed {seed}");
    }
}

#[test]
fn ground_factors_take_the_tilt_out_of_the_map() {
    // The map is tilted by 1° about the line through the first two cameras, whose fixes then
    // still hold: positions alone leave that tilt free. The points' heights on the terrain
    // must take it out.
    for seed in SEEDS {
        let s = scene(SyntheticSceneConfig {
            pixel_noise_px: 0.0,
            ..clean_config(80 + seed)
        });
        let c0 = camera_centre(&s.true_cameras[0]);
        let c1 = camera_centre(&s.true_cameras[1]);
        let r = UnitQuaternion::from_axis_angle(
            &nalgebra::Unit::new_normalize(c1 - c0),
            1f64.to_radians(),
        );
        let tilt = Sim3::new(1.0, r, c0 - r * c0);
        let (mut p, fixes) = drifted(&s, &tilt);
        for (i, fix) in fixes.iter().enumerate().take(2) {
            p.add_global_factor(GlobalPositionFactor::new(i, *fix, Sim3::identity(), 1.0));
        }
        let config = BundleAdjustmentConfig {
            max_iterations: 50,
            ..Default::default()
        };
        let solve = |p: &BaProblem| {
            let r = bundle_adjust(p, &config).unwrap();
            errors(p, &r.cameras, &r.points, &s)
        };
        let without = solve(&p);
        for (j, x) in s.true_points.iter().enumerate() {
            p.add_ground_factor(GroundHeightFactor {
                point: j,
                slam_to_world: Sim3::identity(),
                ground: GroundPlane {
                    anchor: [x.x, x.y],
                    height: x.z,
                    slope: [0.0, 0.0],
                },
                sigma: 0.1,
                kernel: jointloc_geometry::RobustKernel::Huber { delta: 1.0 },
            });
        }
        let with = solve(&p);
        eprintln!("seed {seed}: without {without:?}, with {with:?}");
        assert!(without.rotation_max_deg > 0.9, "seed {seed}: {without:?}");
        assert!(with.rotation_max_deg < 0.01, "seed {seed}: {with:?}");
        assert!(with.centre_max_m < 1e-3, "seed {seed}: {with:?}");
        assert!(with.point_median_m < 1e-3, "seed {seed}: {with:?}");
    }
}
