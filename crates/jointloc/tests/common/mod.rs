//! Test material for the fusion: a small rendered flight (generated once per test binary) and
//! a fix source that measures from its ground truth, so the fusion's state machine is tested
//! without the networks (their own tests are in `jointloc-features` and `jointloc-absloc`).

#![allow(dead_code)]

use std::path::Path;
use std::sync::OnceLock;

use jointloc_absloc::{AbslocError, Failure, FailureReason, Fix, Ground, MapTiles, Outcome};
use jointloc_geometry::trajectory::{Trajectory, TumOptions};
use jointloc_system::{
    FixRequest, FixSource, JointLoc, JointLocBuilder, JointLocConfig, Located, Outputs,
};
use nalgebra::{Matrix3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// A crater flight of `length_m` at 5 Hz (500 × 500 frames at 10 m), the camera tilted
/// `camera_tilt_deg` off nadir, rendered into a fresh folder of this process's.
fn render(
    seed: u64,
    length_m: f64,
    camera_tilt_deg: [f64; 2],
) -> jointloc_sim::scratch::ProcessScratch {
    let dir =
        jointloc_sim::scratch::ProcessScratch::new(env!("CARGO_TARGET_TMPDIR"), "fusion-flight")
            .unwrap();
    let mut cfg = jointloc_sim::SimConfig {
        seed,
        ..Default::default()
    };
    cfg.trajectory.length_m = length_m;
    cfg.trajectory.camera_tilt_deg = camera_tilt_deg;
    jointloc_sim::generate_dataset(&cfg, dir.path(), &mut |_, _, _| {}).unwrap();
    dir
}

/// A 40 m crater flight at 5 Hz (201 frames of 500 × 500 at 10 m), rendered once.
pub fn flight() -> &'static Path {
    static DIR: OnceLock<jointloc_sim::scratch::ProcessScratch> = OnceLock::new();
    DIR.get_or_init(|| render(20261203, 40.0, [0.0, 0.0]))
        .path()
}

/// The same kind of flight with the camera tilted 3° off nadir along the track (a UAV
/// pitched to cruise), 60 m, rendered once.
pub fn tilted_flight() -> &'static Path {
    static DIR: OnceLock<jointloc_sim::scratch::ProcessScratch> = OnceLock::new();
    DIR.get_or_init(|| render(20261206, 60.0, [3.0, 0.0]))
        .path()
}

pub fn ground_truth(dir: &Path) -> Trajectory {
    Trajectory::read_tum(dir.join("uav/gt.txt"), &TumOptions::default()).unwrap()
}

/// The index of the ground-truth pose at `timestamp` (to 1 ms).
pub fn pose_at(gt: &Trajectory, timestamp: f64) -> Option<usize> {
    gt.timestamps
        .iter()
        .position(|&t| (t - timestamp).abs() < 1e-3)
}

/// A search that found no tile.
pub fn no_match() -> Outcome {
    Outcome::Failed(Failure {
        reason: FailureReason::NoMatch { best: None },
        searched_tiles: 1,
        global: false,
        next_radius: 1,
        ms: 0.0,
    })
}

/// Fixes measured from the ground truth: the map point under the image centre, with
/// Gaussian noise of `sigma_m` on x and y (seeded), the true heading and confidence 0.5;
/// a frame without ground truth fails.
#[derive(Debug)]
pub struct TruthFixes {
    gt: Trajectory,
    ground: Ground,
    noise: Normal<f64>,
    rng: ChaCha8Rng,
}

impl TruthFixes {
    pub fn new(dir: &Path, sigma_m: f64, seed: u64) -> Self {
        Self {
            gt: ground_truth(dir),
            ground: MapTiles::open(dir).unwrap().ground(),
            noise: Normal::new(0.0, sigma_m).unwrap(),
            rng: ChaCha8Rng::seed_from_u64(seed),
        }
    }
}

impl FixSource for TruthFixes {
    fn localize(&mut self, request: &FixRequest<'_>) -> Result<Option<Located>, AbslocError> {
        let Some(i) = pose_at(&self.gt, request.timestamp) else {
            return Ok(Some(Located {
                outcome: no_match(),
                injected: false,
            }));
        };
        let pose = &self.gt.poses[i];
        let centre = pose.centre();
        let axis = pose.rotation() * Vector3::z();
        // The optical axis meets the terrain: a few fixed-point steps on its height.
        let mut ground = centre.coords + axis * (request.altitude / axis.z.abs());
        for _ in 0..4 {
            let h = self.ground.height_at(ground.x, ground.y);
            ground = centre.coords + axis * ((h - centre.z) / axis.z);
        }
        let (dx, dy) = (
            self.noise.sample(&mut self.rng),
            self.noise.sample(&mut self.rng),
        );
        let (x, y) = (ground.x + dx, ground.y + dy);
        let heading = jointloc_absloc::heading_from_rotation(&pose.rotation().to_rotation_matrix());
        let fix = Fix {
            position: [x, y, self.ground.height_at(x, y) + request.altitude],
            confidence: 0.5,
            ssim: 0.7,
            match_score: 0.7,
            tile: 0,
            inliers: 100,
            searched_tiles: 1,
            global: false,
            homography: Matrix3::identity(),
            heading,
            scale: 1.0,
            next_radius: 1,
            ms: 0.0,
        };
        Ok(Some(Located {
            outcome: Outcome::Fix(fix),
            injected: false,
        }))
    }
}

/// The fix of a search that found one, to edit in a scripted source.
pub fn found_fix(located: &mut Option<Located>) -> Option<&mut Fix> {
    match located.as_mut()?.outcome {
        Outcome::Fix(ref mut fix) => Some(fix),
        _ => None,
    }
}

/// The builder for the test flight with fixes from its ground truth.
pub fn builder(
    dir: &Path,
    config: JointLocConfig,
    source: impl FixSource + 'static,
) -> JointLocBuilder {
    let camera = jointloc_formats::camera_yaml::read_camera_yaml(&dir.join("camera.yaml"))
        .unwrap()
        .camera;
    JointLoc::builder(camera, MapTiles::open(dir).unwrap(), config).fix_source(Box::new(source))
}

/// The flight's frames: (image, timestamp, altitude).
pub fn frames(dir: &Path) -> Vec<(image::GrayImage, f64, Option<f64>)> {
    let sequence = jointloc_formats::sequence::Sequence::open(dir).unwrap();
    (0..sequence.len())
        .map(|i| {
            let f = &sequence.frames[i];
            (sequence.load_image(i).unwrap(), f.timestamp, f.altitude)
        })
        .collect()
}

/// Translation rmse of `est` against the ground truth at the same timestamps.
pub fn rmse(gt: &Trajectory, est: &Trajectory) -> f64 {
    let mut sum = 0.0;
    for (t, p) in est.timestamps.iter().zip(&est.poses) {
        let i = gt
            .timestamps
            .iter()
            .position(|g| (g - t).abs() < 1e-3)
            .unwrap();
        sum += (gt.poses[i].centre() - p.centre()).norm_squared();
    }
    (sum / est.len() as f64).sqrt()
}

/// The online world poses as a trajectory.
pub fn online(outputs: &Outputs) -> Trajectory {
    let (stamps, poses) = outputs
        .online
        .iter()
        .filter_map(|f| Some((f.timestamp, f.world_pose()?)))
        .unzip();
    Trajectory::new(stamps, poses).unwrap()
}
