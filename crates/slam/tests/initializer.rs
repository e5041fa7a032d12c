//! Monocular initialisation on synthetic two-view data: the model choice follows the scene
//! (flat → homography, strong relief → essential), R and t are recovered, and the scale comes
//! from the altimeter.

use jointloc_geometry::{PinholeCamera, WorldToCamera};
use jointloc_slam::SlamError;
use jointloc_slam::initializer::{
    Altitudes, InitializerConfig, ScaleSource, TwoViewModel, initialize,
};
use nalgebra::{Isometry3, Point2, Point3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Terrain height above the mean plane at ground position (x, y), metres.
fn bump(relief: f64, x: f64, y: f64) -> f64 {
    0.5 * relief * ((0.21 * x).sin() + (0.17 * y + 0.5).cos())
}

struct Scene {
    x1: Vec<Point2<f64>>,
    x2: Vec<Point2<f64>>,
    pose2: WorldToCamera,
    altitude: f64,
    /// Altimeter reading at the second camera.
    altitude2: f64,
}

impl Scene {
    fn altitudes(&self) -> Altitudes {
        Altitudes {
            reference: Some(self.altitude),
            current: Some(self.altitude2),
        }
    }
}

/// A downward camera at `altitude` over terrain with `relief` metres of bumps; the second
/// camera moved `baseline` metres forward with a small rotation. World z up, camera 1 looks
/// down (its z axis is world −z).
fn scene(seed: u64, relief: f64, baseline: f64, outliers: f64) -> Scene {
    scene_at(seed, 50.0, relief, baseline, outliers)
}

/// [`scene`] at any altitude; ground points span the first camera's view.
fn scene_at(seed: u64, altitude: f64, relief: f64, baseline: f64, outliers: f64) -> Scene {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let camera = PinholeCamera::ideal(500.0, 500, 500);
    let half = 0.48 * altitude;
    // Camera 1 frame = SLAM frame: x right, y down (image), z forward (down to the ground).
    let r12 = UnitQuaternion::from_euler_angles(0.01, -0.015, 0.02);
    let c2 = Vector3::new(0.3 * baseline, -baseline, 0.05 * baseline);
    let pose2 = WorldToCamera(Isometry3::from_parts(Translation3::from(-(r12 * c2)), r12));
    let noise = Normal::new(0.0, 0.5).unwrap();
    let (mut x1, mut x2) = (Vec::new(), Vec::new());
    while x1.len() < 600 {
        // Ground point (x right, y down in the image) with relief over a horizontal mean plane.
        let gx = rng.random_range(-half..half);
        let gy = rng.random_range(-half..half);
        let p = Vector3::new(gx, gy, altitude - bump(relief, gx, gy));
        let Some(uv1) = camera.project(&Point3::from(p)) else {
            continue;
        };
        let (u, v) = (uv1.x, uv1.y);
        let q = pose2.0 * Point3::from(p);
        let Some(uv2) = camera.project(&q) else {
            continue;
        };
        if !(0.0..500.0).contains(&uv2.x) || !(0.0..500.0).contains(&uv2.y) {
            continue;
        }
        x1.push(Point2::new(
            u + noise.sample(&mut rng),
            v + noise.sample(&mut rng),
        ));
        if rng.random::<f64>() < outliers {
            x2.push(Point2::new(
                rng.random_range(0.0..500.0),
                rng.random_range(0.0..500.0),
            ));
        } else {
            x2.push(Point2::new(
                uv2.x + noise.sample(&mut rng),
                uv2.y + noise.sample(&mut rng),
            ));
        }
    }
    // The altimeter measures the height above the terrain directly below the camera.
    Scene {
        x1,
        x2,
        pose2,
        altitude: altitude - bump(relief, 0.0, 0.0),
        altitude2: altitude - bump(relief, c2.x, c2.y) - c2.z,
    }
}

/// `max_scale_error`: relative error of the metric baseline. On flat ground it is the
/// triangulation noise (0.5 px at 50 m with a 3 m baseline: ~1–2 %); strong relief adds the
/// error of interpolating the terrain height right below the camera.
fn check(s: &Scene, expected: TwoViewModel, seed: u64, max_scale_error: f64) {
    let camera = PinholeCamera::ideal(500.0, 500, 500);
    let init = initialize(
        &s.x1,
        &s.x2,
        &camera,
        s.altitudes(),
        &InitializerConfig::default(),
    )
    .unwrap_or_else(|e| panic!("seed {seed}: {e}"));
    assert_eq!(
        init.model, expected,
        "seed {seed}: R_H = {}",
        init.homography_ratio
    );
    let rot_err = init
        .pose2
        .rotation()
        .angle_to(&s.pose2.rotation())
        .to_degrees();
    let (t, t_true) = (init.pose2.translation(), s.pose2.translation());
    let dir_err = t
        .normalize()
        .dot(&t_true.normalize())
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees();
    let scale_err = (t.norm() / t_true.norm() - 1.0).abs();
    println!(
        "seed {seed} {expected:?}: R_H {:.2}, rot {rot_err:.3}°, t dir {dir_err:.2}°, scale {:.2} %, {} points",
        init.homography_ratio,
        100.0 * scale_err,
        init.points.len()
    );
    assert!(rot_err < 0.2, "seed {seed}: rotation error {rot_err}°");
    assert!(
        dir_err < 2.0,
        "seed {seed}: translation direction error {dir_err}°"
    );
    assert!(
        scale_err < max_scale_error,
        "seed {seed}: scale error {scale_err}"
    );
    assert_eq!(init.scale, ScaleSource::Altimeter(s.altitude));
    assert!(
        init.points.len() > 300,
        "seed {seed}: {} points",
        init.points.len()
    );
}

#[test]
fn flat_terrain_initialises_from_the_homography() {
    for seed in 0..5 {
        check(
            &scene(seed, 0.0, 3.0, 0.2),
            TwoViewModel::Homography,
            seed,
            0.03,
        );
    }
}

#[test]
fn strong_relief_initialises_from_the_essential_matrix() {
    for seed in 0..5 {
        check(
            &scene(100 + seed, 12.0, 3.0, 0.2),
            TwoViewModel::Essential,
            seed,
            0.08,
        );
    }
}

#[test]
fn without_altitude_the_median_depth_is_one() {
    let s = scene(7, 5.0, 3.0, 0.1);
    let camera = PinholeCamera::ideal(500.0, 500, 500);
    let init = initialize(
        &s.x1,
        &s.x2,
        &camera,
        Altitudes::default(),
        &InitializerConfig::default(),
    )
    .unwrap();
    assert_eq!(init.scale, ScaleSource::MedianDepth);
    let mut z: Vec<f64> = init.points.iter().map(|(_, p)| p.z).collect();
    z.sort_by(f64::total_cmp);
    assert!((z[z.len() / 2] - 1.0).abs() < 1e-9);
}

#[test]
fn no_baseline_or_too_few_matches_fail_cleanly() {
    let camera = PinholeCamera::ideal(500.0, 500, 500);
    let s = scene(3, 5.0, 0.0, 0.0);
    assert!(
        initialize(
            &s.x1,
            &s.x2,
            &camera,
            s.altitudes(),
            &InitializerConfig::default()
        )
        .is_err()
    );
    let s = scene(4, 5.0, 3.0, 0.0);
    let e = initialize(
        &s.x1[..20],
        &s.x2[..20],
        &camera,
        s.altitudes(),
        &InitializerConfig::default(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("20 matches"), "{e}");
    let e = initialize(
        &s.x1,
        &s.x2[..10],
        &camera,
        s.altitudes(),
        &InitializerConfig::default(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("initialisation failed"), "{e}");
}

/// An altimeter that saw a 15 % height change the pixels cannot explain vetoes the motion,
/// and the error says so.
#[test]
fn an_inconsistent_altimeter_fails_the_initialisation() {
    let camera = PinholeCamera::ideal(500.0, 500, 500);
    let s = scene_at(300, 10.0, 0.3, 1.5, 0.1);
    let altitudes = Altitudes {
        reference: Some(s.altitude),
        current: Some(0.85 * s.altitude2),
    };
    let e = initialize(
        &s.x1,
        &s.x2,
        &camera,
        altitudes,
        &InitializerConfig::default(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("height ratio"), "{e}");
}

/// High above the ground a short baseline triangulates with little parallax: the attempt
/// fails with its own error (the tracker keeps its reference and waits for more baseline),
/// and the same scene with enough baseline initialises.
#[test]
fn a_short_baseline_at_altitude_fails_for_parallax_alone() {
    let camera = PinholeCamera::ideal(500.0, 500, 500);
    let config = InitializerConfig::default();
    let s = scene_at(21, 200.0, 8.0, 5.0, 0.0);
    let e = initialize(&s.x1, &s.x2, &camera, s.altitudes(), &config).unwrap_err();
    match e {
        SlamError::ParallaxTooLow {
            median_deg,
            required_deg,
        } => {
            assert!(
                median_deg > 0.5 && median_deg < required_deg,
                "{median_deg}"
            );
        }
        other => panic!("expected ParallaxTooLow, got {other}"),
    }
    let s = scene_at(21, 200.0, 8.0, 12.0, 0.0);
    let init = initialize(&s.x1, &s.x2, &camera, s.altitudes(), &config).unwrap();
    assert!(init.median_parallax_deg >= config.min_parallax_deg);
}
