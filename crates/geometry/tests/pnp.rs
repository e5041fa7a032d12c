//! Acceptance tests of PnP RANSAC + refinement on synthetic scenes resembling a UAV frame:
//! 500 correspondences at 8–12 m depth spread over a 500×500 image (f = 500 px), σ = 0.5 px
//! pixel noise and 30 % gross outliers.

use jointloc_geometry::pnp::{PnpConfig, PnpResult, projection_pose_jacobian, solve_pnp_ransac};
use jointloc_geometry::{
    GeometryError, KannalaBrandt, PinholeCamera, RadTan, RansacConfig, WorldToCamera,
};
use nalgebra::{Matrix6, Point2, Point3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

struct Scene {
    truth: WorldToCamera,
    world: Vec<Point3<f64>>,
    pixels: Vec<Point2<f64>>,
    is_outlier: Vec<bool>,
}

fn scene(seed: u64, camera: &PinholeCamera, n: usize, outlier_ratio: f64, sigma: f64) -> Scene {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let axis = Vector3::new(
        rng.random_range(-1.0..1.0),
        rng.random_range(-1.0..1.0),
        rng.random_range(-1.0..1.0),
    );
    let truth = WorldToCamera::from_rotation_translation(
        UnitQuaternion::from_scaled_axis(axis.normalize() * rng.random_range(0.0..3.0)),
        Vector3::new(
            rng.random_range(-50.0..50.0),
            rng.random_range(-50.0..50.0),
            rng.random_range(-50.0..50.0),
        ),
    );
    let to_world = truth.inverse();
    let noise = Normal::new(0.0, sigma).unwrap();
    let (w, h) = (camera.width as f64, camera.height as f64);
    let mut scene = Scene {
        truth,
        world: Vec::with_capacity(n),
        pixels: Vec::with_capacity(n),
        is_outlier: Vec::with_capacity(n),
    };
    for _ in 0..n {
        let uv = Point2::new(
            rng.random_range(-0.5..w - 0.5),
            rng.random_range(-0.5..h - 0.5),
        );
        let ray = camera.unproject(&uv).unwrap();
        let depth = rng.random_range(8.0..12.0);
        scene
            .world
            .push(to_world.transform_point(&Point3::from(ray * depth)));
        let outlier = rng.random_bool(outlier_ratio);
        let observed = if outlier {
            Point2::new(
                rng.random_range(-0.5..w - 0.5),
                rng.random_range(-0.5..h - 0.5),
            )
        } else {
            Point2::new(uv.x + noise.sample(&mut rng), uv.y + noise.sample(&mut rng))
        };
        scene.pixels.push(observed);
        scene.is_outlier.push(outlier);
    }
    scene
}

/// Camera-centre error in metres and rotation error in degrees.
fn errors(estimate: &WorldToCamera, truth: &WorldToCamera) -> (f64, f64) {
    let centre = |p: &WorldToCamera| p.inverse().0.translation.vector;
    let dc = (centre(estimate) - centre(truth)).norm();
    let dr = (estimate.rotation() * truth.rotation().inverse())
        .angle()
        .to_degrees();
    (dc, dr)
}

fn config(seed: u64) -> PnpConfig {
    PnpConfig {
        ransac: RansacConfig {
            seed,
            ..PnpConfig::default().ransac
        },
        ..PnpConfig::default()
    }
}

/// Cramér-Rao bound on the camera-centre error (root of the covariance trace) for the true
/// inliers of `s` with isotropic pixel noise `sigma`: what no estimator can beat on average.
fn centre_crlb(s: &Scene, camera: &PinholeCamera, sigma: f64) -> f64 {
    let mut info = Matrix6::zeros();
    for (p, _) in s.world.iter().zip(&s.is_outlier).filter(|(_, o)| !**o) {
        let (_, j) = projection_pose_jacobian(camera, &s.truth, p).unwrap();
        info += j.transpose() * j / (sigma * sigma);
    }
    let cov = info.try_inverse().unwrap();
    // Left perturbation exp(δ)·T moves the centre C = −Rᵀt by −Rᵀρ to first order.
    let rt = s.truth.rotation_matrix().transpose();
    (rt * cov.fixed_view::<3, 3>(0, 0) * rt.transpose())
        .trace()
        .sqrt()
}

fn check_accuracy(camera: &PinholeCamera, label: &str) {
    let seeds = 0..8u64;
    let (mut sum_sq, mut sum_sq_crlb) = (0.0, 0.0);
    let (mut worst_centre, mut worst_rot): (f64, f64) = (0.0, 0.0);
    for seed in seeds.clone() {
        let s = scene(seed, camera, 500, 0.3, 0.5);
        let r = solve_pnp_ransac(&s.world, &s.pixels, camera, &config(seed)).unwrap();
        let (dc, dr) = errors(&r.pose, &s.truth);
        let crlb = centre_crlb(&s, camera, 0.5);
        let true_inliers = s.is_outlier.iter().filter(|o| !**o).count();
        let recovered = r.inliers.iter().filter(|&&i| !s.is_outlier[i]).count();
        eprintln!(
            "{label} seed {seed}: centre error {:.2} mm (CRLB {:.2} mm), rotation error \
             {:.4} deg, {} inliers ({recovered}/{true_inliers} true), {} iterations, rms {:.3} px",
            dc * 1e3,
            crlb * 1e3,
            dr,
            r.inliers.len(),
            r.iterations,
            r.rms_reprojection_px
        );
        // Per scene, a bound that noise alone cannot break (the error is ~CRLB-distributed).
        assert!(
            dc < 0.02 && dc < 5.0 * crlb,
            "seed {seed}: centre error {dc} m"
        );
        assert!(dr < 0.1, "seed {seed}: rotation error {dr} deg");
        assert!(r.inliers.windows(2).all(|w| w[0] < w[1]), "inliers sorted");
        // Almost every true inlier is kept (σ = 0.5 px vs a 2.5 px threshold) ...
        assert!(recovered as f64 >= 0.98 * true_inliers as f64);
        // ... and only outliers that happen to land near the right pixel slip in.
        assert!(r.inliers.len() - recovered <= 5);
        // E‖e‖² = 2σ² for 2-D pixel noise, so the RMS is about 0.71 px.
        assert!(r.rms_reprojection_px > 0.55 && r.rms_reprojection_px < 0.85);
        sum_sq += dc * dc;
        sum_sq_crlb += crlb * crlb;
        worst_centre = worst_centre.max(dc);
        worst_rot = worst_rot.max(dr);
    }
    let n = seeds.count() as f64;
    let (rms, rms_crlb) = ((sum_sq / n).sqrt(), (sum_sq_crlb / n).sqrt());
    eprintln!(
        "{label}: centre error RMS {:.2} mm (CRLB {:.2} mm), worst {:.2} mm, worst rotation \
         {:.4} deg",
        rms * 1e3,
        rms_crlb * 1e3,
        worst_centre * 1e3,
        worst_rot
    );
    assert!(rms < 0.01, "centre RMS {rms} m");
    // Statistically efficient: close to the bound (the refinement is a robust ML estimate).
    assert!(rms < 1.5 * rms_crlb, "RMS {rms} vs CRLB {rms_crlb}");
}

#[test]
fn accurate_pose_with_noise_and_outliers() {
    check_accuracy(&PinholeCamera::ideal(500.0, 500, 500), "pinhole");
}

#[test]
fn accurate_pose_with_radial_tangential_distortion() {
    let camera = PinholeCamera {
        distortion: Some(
            RadTan {
                k1: -0.28,
                k2: 0.07,
                p1: 2e-4,
                p2: -1.5e-4,
                k3: 0.01,
            }
            .into(),
        ),
        ..PinholeCamera::ideal(500.0, 500, 500)
    };
    check_accuracy(&camera, "radtan");
}

#[test]
fn accurate_pose_with_a_kannala_brandt_fisheye() {
    // 133° × 100° on 640 × 480 (Ingenuity's navigation camera), TUM-VI's cam0 coefficients
    // (ORB-SLAM3's TUM-VI.yaml); the corners are 83° off axis.
    let lens = KannalaBrandt {
        k1: 0.0034823894022493434,
        k2: 0.0007150348452162257,
        k3: -0.0020532361418706202,
        k4: 0.00020293673591811182,
    };
    let camera = PinholeCamera::fisheye(133.0, 640, 480, lens).unwrap();
    check_accuracy(&camera, "fisheye");
}

#[test]
fn refinement_improves_on_ransac_pose() {
    let camera = PinholeCamera::ideal(500.0, 500, 500);
    let mut raw_sum = 0.0;
    let mut refined_sum = 0.0;
    for seed in 10..15u64 {
        let s = scene(seed, &camera, 500, 0.3, 0.5);
        let raw_cfg = PnpConfig {
            refine: false,
            ..config(seed)
        };
        let raw = solve_pnp_ransac(&s.world, &s.pixels, &camera, &raw_cfg).unwrap();
        let refined = solve_pnp_ransac(&s.world, &s.pixels, &camera, &config(seed)).unwrap();
        assert_eq!(raw.iterations, refined.iterations);
        assert!(refined.rms_reprojection_px <= raw.rms_reprojection_px + 1e-9);
        raw_sum += errors(&raw.pose, &s.truth).0;
        refined_sum += errors(&refined.pose, &s.truth).0;
    }
    assert!(
        refined_sum < 0.5 * raw_sum,
        "refined {refined_sum} vs raw {raw_sum}"
    );
}

#[test]
fn same_seed_same_result() {
    let camera = PinholeCamera::ideal(500.0, 500, 500);
    let s = scene(3, &camera, 500, 0.3, 0.5);
    let run = |seed| -> PnpResult {
        solve_pnp_ransac(&s.world, &s.pixels, &camera, &config(seed)).unwrap()
    };
    let (a, b) = (run(7), run(7));
    assert_eq!(a, b);
    // A different sampler seed still finds the same consensus.
    let c = run(8);
    let (dc, _) = errors(&a.pose, &c.pose);
    assert!(dc < 1e-3);
}

#[test]
fn bad_input_is_an_error_not_a_panic() {
    let camera = PinholeCamera::ideal(500.0, 500, 500);
    let s = scene(1, &camera, 20, 0.0, 0.5);
    let cfg = PnpConfig::default();
    assert!(matches!(
        solve_pnp_ransac(&s.world[..2], &s.pixels[..2], &camera, &cfg),
        Err(GeometryError::TooFewPoints {
            required: 3,
            found: 2
        })
    ));
    assert!(matches!(
        solve_pnp_ransac(&s.world, &s.pixels[..19], &camera, &cfg),
        Err(GeometryError::LengthMismatch { .. })
    ));
    let mut world = s.world.clone();
    world[4].y = f64::NAN;
    assert!(matches!(
        solve_pnp_ransac(&world, &s.pixels, &camera, &cfg),
        Err(GeometryError::NonFinite(_))
    ));
    let mut pixels = s.pixels.clone();
    pixels[7].x = f64::INFINITY;
    assert!(matches!(
        solve_pnp_ransac(&s.world, &pixels, &camera, &cfg),
        Err(GeometryError::NonFinite(_))
    ));
    let bad_cfg = PnpConfig {
        ransac: RansacConfig {
            threshold: -1.0,
            ..cfg.ransac
        },
        ..cfg
    };
    assert!(matches!(
        solve_pnp_ransac(&s.world, &s.pixels, &camera, &bad_cfg),
        Err(GeometryError::InvalidConfig { .. })
    ));
    // Pure noise: no pose explains enough points.
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let junk: Vec<Point2<f64>> = (0..20)
        .map(|_| Point2::new(rng.random_range(0.0..500.0), rng.random_range(0.0..500.0)))
        .collect();
    let strict = PnpConfig {
        ransac: RansacConfig {
            min_inliers: 15,
            ..cfg.ransac
        },
        ..cfg
    };
    assert!(matches!(
        solve_pnp_ransac(&s.world, &junk, &camera, &strict),
        Err(GeometryError::NoConsensus { .. })
    ));
}

#[test]
fn points_behind_the_camera_are_outliers() {
    let camera = PinholeCamera::ideal(500.0, 500, 500);
    let s = scene(2, &camera, 100, 0.0, 0.0);
    // Mirror some points through the camera centre: same pixel, but behind the camera.
    let centre = s.truth.inverse().0.translation.vector;
    let mut world = s.world.clone();
    for p in world.iter_mut().take(20) {
        *p = Point3::from(2.0 * centre - p.coords);
    }
    let r = solve_pnp_ransac(&world, &s.pixels, &camera, &config(0)).unwrap();
    assert!(r.inliers.iter().all(|&i| i >= 20));
    assert_eq!(r.inliers.len(), 80);
    assert!(errors(&r.pose, &s.truth).0 < 1e-6);
}
