//! Synthetic bundle-adjustment scenes for tests and benchmarks: a UAV flying a lawnmower pattern
//! over rough terrain, looking down, with noisy starts, pixel noise and gross outliers.

use jointloc_geometry::{PinholeCamera, WorldToCamera};
use nalgebra::{Point2, Point3, UnitQuaternion, Vector3, Vector6};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use super::problem::BaProblem;
use crate::{Result, SlamError};

/// Shape and noise of a synthetic scene. World frame: x east, y north, z up; cameras look down.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SyntheticSceneConfig {
    /// Flight lines.
    pub rows: usize,
    /// Cameras per flight line.
    pub cols: usize,
    /// Distance between cameras along a line, metres.
    pub spacing_m: f64,
    /// Distance between lines, metres.
    pub row_spacing_m: f64,
    /// Flight height above the terrain's mean, metres.
    pub altitude_m: f64,
    /// Peak-to-peak height of the terrain, metres.
    pub relief_m: f64,
    /// Number of points.
    pub points: usize,
    /// Cameras that must observe a point (ORB-SLAM culls points seen by fewer than 3 keyframes;
    /// two-view points with one gross outlier cannot be recovered by any solver).
    pub min_views: usize,
    /// Probability that a point inside a camera's image is actually observed there (feature
    /// matching never finds all of them).
    pub observation_probability: f64,
    /// Focal length, pixels; the image is `image_px` square.
    pub focal_px: f64,
    /// Image width and height, pixels.
    pub image_px: u32,
    /// The first this-many cameras are fixed at their true pose (gauge).
    pub fixed_cameras: usize,
    /// Per-axis σ of the start translation error of free cameras, metres.
    pub pose_noise_m: f64,
    /// Per-axis σ of the start rotation error of free cameras, degrees.
    pub pose_noise_deg: f64,
    /// Per-axis σ of the start error of points, metres.
    pub point_noise_m: f64,
    /// Per-axis σ of the pixel noise.
    pub pixel_noise_px: f64,
    /// Fraction of observations replaced by gross outliers (20–60 px off).
    pub outlier_fraction: f64,
    /// Information given to every observation (1 = ORB-SLAM's level-0 σ of one pixel).
    pub information: f64,
    /// Seed of every random choice.
    pub seed: u64,
}

impl Default for SyntheticSceneConfig {
    fn default() -> Self {
        Self {
            rows: 2,
            cols: 5,
            spacing_m: 6.0,
            row_spacing_m: 10.0,
            altitude_m: 50.0,
            relief_m: 6.0,
            points: 1000,
            min_views: 3,
            observation_probability: 1.0,
            focal_px: 400.0,
            image_px: 500,
            fixed_cameras: 2,
            pose_noise_m: 0.05,
            pose_noise_deg: 0.5,
            point_noise_m: 0.1,
            pixel_noise_px: 0.5,
            outlier_fraction: 0.05,
            information: 1.0,
            seed: 0,
        }
    }
}

/// A scene: the noisy problem and the truth it was made from.
#[derive(Debug, Clone)]
pub struct SyntheticScene {
    /// Noisy start, fixed cameras at their truth.
    pub problem: BaProblem,
    /// True world-to-camera transforms.
    pub true_cameras: Vec<WorldToCamera>,
    /// True point positions.
    pub true_points: Vec<Vector3<f64>>,
    /// Per observation: a gross outlier was injected.
    pub gross_outliers: Vec<bool>,
}

fn terrain_height(x: f64, y: f64, relief: f64) -> f64 {
    0.25 * relief * ((x / 7.0).sin() * (y / 9.0).cos() + (0.3 * x + 0.2 * y).sin())
}

impl SyntheticSceneConfig {
    /// Every length and σ finite and ≥ 0, probabilities in `[0, 1]`, a usable camera.
    pub fn validate(&self) -> Result<()> {
        let non_negative = [
            ("spacing_m", self.spacing_m),
            ("row_spacing_m", self.row_spacing_m),
            ("relief_m", self.relief_m),
            ("pose_noise_m", self.pose_noise_m),
            ("pose_noise_deg", self.pose_noise_deg),
            ("point_noise_m", self.point_noise_m),
            ("pixel_noise_px", self.pixel_noise_px),
        ];
        for (field, value) in non_negative {
            if !(value.is_finite() && value >= 0.0) {
                return Err(invalid(field, value, "must be finite and >= 0"));
            }
        }
        let positive = [
            ("altitude_m", self.altitude_m),
            ("focal_px", self.focal_px),
            ("information", self.information),
        ];
        for (field, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(invalid(field, value, "must be finite and > 0"));
            }
        }
        for (field, value) in [
            ("observation_probability", self.observation_probability),
            ("outlier_fraction", self.outlier_fraction),
        ] {
            if !(0.0..=1.0).contains(&value) {
                return Err(invalid(field, value, "must be in [0, 1]"));
            }
        }
        if self.image_px < 16 {
            return Err(invalid("image_px", self.image_px as f64, "must be >= 16"));
        }
        Ok(())
    }
}

fn invalid(field: &'static str, value: f64, reason: &'static str) -> SlamError {
    SlamError::InvalidConfig {
        field,
        value: value.to_string(),
        reason,
    }
}

fn normal(sigma: f64) -> Result<Normal<f64>> {
    Normal::new(0.0, sigma).map_err(|_| invalid("noise sigma", sigma, "must be finite and >= 0"))
}

/// Builds a scene; deterministic for a given config.
pub fn synthetic_scene(config: &SyntheticSceneConfig) -> Result<SyntheticScene> {
    config.validate()?;
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    let intrinsics = PinholeCamera::ideal(config.focal_px, config.image_px, config.image_px);
    let down = UnitQuaternion::from_euler_angles(std::f64::consts::PI, 0.0, 0.0);
    let mut true_cameras = Vec::new();
    let mut centres = Vec::new();
    for r in 0..config.rows {
        for c in 0..config.cols {
            let centre = Vector3::new(
                c as f64 * config.spacing_m + rng.random_range(-0.5..0.5),
                r as f64 * config.row_spacing_m + rng.random_range(-0.5..0.5),
                config.altitude_m + rng.random_range(-1.0..1.0),
            );
            let tilt = UnitQuaternion::from_euler_angles(
                rng.random_range(-0.05..0.05),
                rng.random_range(-0.05..0.05),
                rng.random_range(-0.1..0.1),
            );
            let r_cw = (down * tilt).inverse();
            true_cameras.push(WorldToCamera::from_rotation_translation(
                r_cw,
                -(r_cw * centre),
            ));
            centres.push(centre);
        }
    }
    // Points on the terrain inside the union of the footprints, seen by `min_views` cameras.
    let half = 0.5 * config.image_px as f64 / config.focal_px * config.altitude_m;
    let (min_x, max_x) = (
        -half,
        (config.cols.max(1) - 1) as f64 * config.spacing_m + half,
    );
    let (min_y, max_y) = (
        -half,
        (config.rows.max(1) - 1) as f64 * config.row_spacing_m + half,
    );
    let mut true_points = Vec::new();
    let mut seen_by = Vec::new();
    let mut attempts = 0;
    while true_points.len() < config.points && attempts < 100 * config.points.max(1) {
        attempts += 1;
        let x = rng.random_range(min_x..max_x);
        let y = rng.random_range(min_y..max_y);
        let p = Vector3::new(x, y, terrain_height(x, y, config.relief_m));
        let cams: Vec<(usize, Point2<f64>)> = true_cameras
            .iter()
            .enumerate()
            .filter_map(|(i, t)| {
                let uv = intrinsics.project(&t.transform_point(&Point3::from(p)))?;
                intrinsics.contains(&uv, 2.0).then_some((i, uv))
            })
            .filter(|_| rng.random_bool(config.observation_probability))
            .collect();
        if cams.len() >= config.min_views.max(2) {
            true_points.push(p);
            seen_by.push(cams);
        }
    }
    let pixel = normal(config.pixel_noise_px)?;
    let trans = normal(config.pose_noise_m)?;
    let rot = normal(config.pose_noise_deg.to_radians())?;
    let point = normal(config.point_noise_m)?;
    let mut problem = BaProblem::new(intrinsics);
    for (i, t) in true_cameras.iter().enumerate() {
        let fixed = i < config.fixed_cameras;
        let pose = if fixed {
            *t
        } else {
            let d = Vector6::new(
                trans.sample(&mut rng),
                trans.sample(&mut rng),
                trans.sample(&mut rng),
                rot.sample(&mut rng),
                rot.sample(&mut rng),
                rot.sample(&mut rng),
            );
            WorldToCamera(WorldToCamera::exp(&d).0 * t.0)
        };
        problem.add_camera(pose, fixed);
    }
    let mut gross_outliers = Vec::new();
    for (j, (p, cams)) in true_points.iter().zip(&seen_by).enumerate() {
        let noisy = p + Vector3::from_fn(|_, _| point.sample(&mut rng));
        problem.add_point(noisy, false);
        for &(i, uv) in cams {
            let outlier = rng.random_bool(config.outlier_fraction);
            let offset = if outlier {
                let angle = rng.random_range(0.0..std::f64::consts::TAU);
                rng.random_range(20.0..60.0) * nalgebra::Vector2::new(angle.cos(), angle.sin())
            } else {
                nalgebra::Vector2::new(pixel.sample(&mut rng), pixel.sample(&mut rng))
            };
            problem.add_observation(i, j, uv + offset, config.information);
            gross_outliers.push(outlier);
        }
    }
    Ok(SyntheticScene {
        problem,
        true_cameras,
        true_points,
        gross_outliers,
    })
}
