//! Global bundle adjustment at the end of the flight, in the world frame, for the outputs
//! written then (`keyframes.tum`, `trajectory-final.tum`).
//!
//! Online, the local BA moves only the newest window, and the SLAM map keeps the drift
//! (scale, yaw) it had when its keyframes left the window; the end outputs then take each
//! pose to the world through an alignment fitted to the fixes nearest to it in time, one
//! rigid similarity per 40 m. Here the whole map is optimised once more with the paper's cost
//! `f(x)`: reprojection terms, every inlier fix as a global factor of its keyframe (σ_G and
//! the kernel of the local BA), and every point on the elevation model. The map starts from
//! the local alignments (each keyframe and point through the similarity at its own time), so
//! it is in metres in the world frame and `S` is the identity: the fixes can bend the map
//! where its drift needs it, weighted against the images.
//!
//! The SLAM map itself is not changed; the result is each keyframe's world pose, from which
//! every frame's pose follows through the keyframes around it in time
//! ([`RefinedKeyFrames::world_pose`]).

use std::collections::BTreeMap;

use jointloc_geometry::{CameraToWorld, Sim3};
use jointloc_slam::ba::{
    BaProblem, GlobalPositionFactor, GroundHeightFactor, Observation, TwoStageConfig,
    bundle_adjust_two_stage,
};
use jointloc_slam::frame::Undistorter;
use jointloc_slam::local_mapping::lba::ground_factor_sigma;
use jointloc_slam::local_mapping::{GroundModel, LocalBaConfig};
use jointloc_slam::map::{KeyFrameId, Map};
use nalgebra::{Isometry3, Point2, Point3, Translation3, UnitQuaternion};
use serde::{Deserialize, Serialize};

use crate::alignment::Tolerance;
use crate::error::Result;

/// Settings of the global bundle adjustment at the end (`[final_ba]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FinalBaConfig {
    /// Off: the end outputs go through the local alignments alone.
    pub enabled: bool,
    /// Levenberg–Marquardt iterations of the robust first stage.
    pub first_iterations: usize,
    /// Iterations after the observations it flags are left out.
    pub second_iterations: usize,
    /// Each keypoint's σ grows by how much the rectification stretches it
    /// ([`Undistorter::noise_stretch`]): a wide lens' peripheral keypoints, measured in the
    /// distorted image, are placed far less precisely in the tracker's pixels than the
    /// octave's σ says. No effect without a lens model; with a 133° fisheye the end output
    /// gained on four of five flights (`docs/camera.md` §"2026-12-05").
    pub lens_noise: bool,
}

impl Default for FinalBaConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            first_iterations: 10,
            second_iterations: 20,
            lens_noise: true,
        }
    }
}

/// A fix as the global BA uses it: a point of its keyframe's camera frame (SLAM units) that
/// the fix locates in the world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FinalTie {
    pub keyframe: KeyFrameId,
    pub point_in_camera: Point3<f64>,
    pub world: Point3<f64>,
    pub weight: f64,
    /// σ of this factor over `global_sigma` (the nadir factor's is smaller).
    pub sigma_scale: f64,
    /// σ of its world z over its σ ([`GlobalPositionFactor::vertical_sigma_scale`]).
    pub vertical_sigma_scale: f64,
    /// How far from the point through the local alignments the fix may be and still be
    /// used (the alignment's inlier bound for this pair).
    pub tolerance: Tolerance,
}

/// What the global BA did (a record of the run's summary, hence in `jointloc_formats`).
pub use jointloc_formats::outputs::FinalBaStats;

/// A keyframe after the global BA.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Refined {
    id: KeyFrameId,
    timestamp: f64,
    /// Camera-to-world in the SLAM frame (the map's current pose).
    slam: CameraToWorld,
    /// Camera-to-world in the world frame after the BA.
    world: CameraToWorld,
}

/// The map's keyframes in the world frame after the global BA, in time order.
#[derive(Debug, Clone, PartialEq)]
pub struct RefinedKeyFrames {
    keyframes: Vec<Refined>,
    /// Whether keyframes older than the first refined one exist (retired by the map's cap):
    /// poses before it keep their local alignment.
    older_exist: bool,
    pub stats: FinalBaStats,
}

/// Optimises `map` in the world frame. `sim_at(t)`: the SLAM→world similarity of the fixes
/// nearest to time `t` (the local alignments). Fixes whose point lies farther than
/// its tolerance from its fix through those alignments are left out (wrong fixes).
/// `None` when the map has fewer than two keyframes.
#[allow(clippy::too_many_arguments)]
pub fn refine(
    map: &Map,
    lens: &Undistorter,
    lba: &LocalBaConfig,
    config: &FinalBaConfig,
    sim_at: &mut dyn FnMut(f64) -> Sim3,
    ties: &[FinalTie],
    ground: Option<&dyn GroundModel>,
    older_exist: bool,
) -> Result<Option<RefinedKeyFrames>> {
    let started = std::time::Instant::now();
    let keyframes: Vec<_> = map.keyframes().collect();
    if keyframes.len() < 2 {
        return Ok(None);
    }
    let mut problem = BaProblem::new(lens.ideal);
    let mut index: BTreeMap<KeyFrameId, (usize, Sim3)> = BTreeMap::new();
    let mut slam_poses = Vec::with_capacity(keyframes.len());
    for kf in &keyframes {
        let s = sim_at(kf.timestamp);
        let slam = kf.pose.inverse();
        let world = s.transform_pose(&slam);
        let ci = problem.add_camera(world.inverse(), false);
        index.insert(kf.id, (ci, s));
        slam_poses.push(slam);
    }
    let mut stats = FinalBaStats {
        keyframes: keyframes.len(),
        ..FinalBaStats::default()
    };
    for tie in ties {
        let Some(&(ci, s)) = index.get(&tie.keyframe) else {
            stats.factors_left_out += 1;
            continue;
        };
        // The camera frame in metres: a similarity scales it by s.
        let point_in_camera = tie.point_in_camera.coords * s.scale;
        let world_now = problem.cameras[ci]
            .pose
            .inverse()
            .transform_point(&Point3::from(point_in_camera));
        if !tie.tolerance.contains(&(world_now - tie.world)) {
            stats.factors_left_out += 1;
            continue;
        }
        problem.add_global_factor(GlobalPositionFactor {
            sigma: lba.global_sigma * tie.sigma_scale,
            kernel: lba.global_kernel,
            point_in_camera,
            vertical_sigma_scale: tie.vertical_sigma_scale,
            ..GlobalPositionFactor::new(ci, tie.world.coords, Sim3::identity(), tie.weight)
        });
        stats.global_factors += 1;
    }
    let ground_sigma = ground.map(|g| ground_factor_sigma(lba.ground_sigma, g.sigma_m()));
    let sf = map.scale_factor();
    for p in map.points() {
        let observed: Vec<(usize, usize, KeyFrameId)> = p
            .observations()
            .iter()
            .filter_map(|(k, &i)| index.get(k).map(|&(ci, _)| (ci, i, *k)))
            .collect();
        if observed.len() < 2 {
            continue;
        }
        let reference = index
            .get(&p.reference)
            .or_else(|| index.get(&observed[0].2))
            .expect("an observing keyframe is indexed");
        let world = reference.1.transform_point(&Point3::from(p.position));
        let pi = problem.add_point(world.coords, false);
        if let (Some(g), Some(sigma)) = (ground, ground_sigma)
            && lba.ground_sigma > 0.0
            && let Some(plane) = g.plane_at(world.x, world.y)
        {
            problem.add_ground_factor(GroundHeightFactor {
                point: pi,
                slam_to_world: Sim3::identity(),
                ground: plane,
                sigma,
                kernel: lba.ground_kernel,
            });
            stats.ground_factors += 1;
        }
        for (ci, i, k) in observed {
            let kp = &map
                .keyframe(k)
                .expect("indexed keyframes exist")
                .features
                .keypoints[i];
            let mut observation =
                Observation::at_level(ci, pi, Point2::new(kp.x, kp.y), kp.octave, sf);
            if config.lens_noise {
                observation.information /= lens.noise_stretch(&observation.pixel).powi(2);
            }
            problem.observations.push(observation);
        }
    }
    stats.points = problem.points.len();
    stats.observations = problem.observations.len();
    let solver = TwoStageConfig {
        first_iterations: config.first_iterations,
        second_iterations: config.second_iterations,
        ..lba.solver
    };
    let result = bundle_adjust_two_stage(&problem, &solver)?;
    stats.iterations = result.iterations;
    stats.initial_cost = result.initial_cost;
    stats.final_cost = result.final_cost;
    let mut refined: Vec<Refined> = keyframes
        .iter()
        .zip(slam_poses)
        .map(|(kf, slam)| Refined {
            id: kf.id,
            timestamp: kf.timestamp,
            slam,
            world: result.cameras[index[&kf.id].0].inverse(),
        })
        .collect();
    refined.sort_by(|a, b| a.timestamp.total_cmp(&b.timestamp));
    stats.ms = started.elapsed().as_secs_f64() * 1e3;
    tracing::debug!(?stats, "final global BA");
    Ok(Some(RefinedKeyFrames {
        keyframes: refined,
        older_exist,
        stats,
    }))
}

impl RefinedKeyFrames {
    /// The world pose of a SLAM pose at time `t`, given the local alignment `s` at `t`, and
    /// the keyframe the SLAM expresses it through (`reference`, as ORB-SLAM2 saves frames):
    /// its pose relative to that keyframe, in metres through `s`, on the refined keyframe,
    /// when that keyframe is one of the two refined ones around `t`. Otherwise relative to the refined keyframes around `t`,
    /// interpolated between the two (translation linearly, rotation along the geodesic);
    /// before the first refined keyframe, when older ones were retired, the local alignment
    /// alone (the BA did not see them).
    pub fn world_pose(
        &self,
        t: f64,
        s: &Sim3,
        slam: &CameraToWorld,
        reference: Option<KeyFrameId>,
    ) -> CameraToWorld {
        let local = s.transform_pose(slam);
        let correction =
            |k: &Refined| -> Isometry3<f64> { k.world.0 * s.transform_pose(&k.slam).0.inverse() };
        let after = self.keyframes.partition_point(|k| k.timestamp <= t);
        // The reference keyframe only when it is one of the two refined keyframes around `t`:
        // a frame whose own keyframe was culled is expressed through the end of the culling
        // chain, which at altitude (few keyframes, many culled) can be 40 m away, and the
        // refined keyframe's attitude error times that lever arm then lands on the frame.
        let around = |i: usize| i + 1 == after || i == after;
        if let Some((_, k)) = reference.and_then(|id| {
            self.keyframes
                .iter()
                .enumerate()
                .find(|(i, k)| k.id == id && around(*i))
        }) {
            return CameraToWorld(correction(k) * local.0);
        }
        let c = if after == 0 {
            if self.older_exist {
                return local;
            }
            correction(&self.keyframes[0])
        } else if after == self.keyframes.len() {
            correction(&self.keyframes[after - 1])
        } else {
            let (k0, k1) = (&self.keyframes[after - 1], &self.keyframes[after]);
            let span = k1.timestamp - k0.timestamp;
            let alpha = if span > 0.0 {
                (t - k0.timestamp) / span
            } else {
                0.0
            };
            interpolate(&correction(k0), &correction(k1), alpha)
        };
        CameraToWorld(c * local.0)
    }
}

/// `a` to `b` by `alpha` ∈ [0, 1]: translation linear, rotation along the geodesic.
fn interpolate(a: &Isometry3<f64>, b: &Isometry3<f64>, alpha: f64) -> Isometry3<f64> {
    let t = a.translation.vector.lerp(&b.translation.vector, alpha);
    let r: UnitQuaternion<f64> = a
        .rotation
        .try_slerp(&b.rotation, alpha, 1e-12)
        .unwrap_or(a.rotation);
    Isometry3::from_parts(Translation3::from(t), r)
}

#[cfg(test)]
mod tests {
    use super::*;
    use jointloc_features::orb::matcher::FeatureGrid;
    use jointloc_features::orb::{KeyPoint, OrbFeatures};
    use jointloc_geometry::PinholeCamera;
    use jointloc_slam::map::KeyFrame;
    use nalgebra::Vector3;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    const SPACING_M: f64 = 2.0;
    const KEYFRAMES: usize = 30;
    const ALTITUDE_M: f64 = 10.0;

    /// The SLAM's drift at time `t` (1 m/s along x): SLAM→world with a scale and yaw that
    /// drift by 0.4 % and 0.2° a second.
    fn drift(t: f64) -> Sim3 {
        Sim3::new(
            1.0 + 0.004 * t,
            UnitQuaternion::from_euler_angles(0.0, 0.0, (0.2 * t).to_radians()),
            Vector3::new(0.02 * t, -0.01 * t, 0.0),
        )
    }

    /// The local alignments as the end outputs have them: each fitted over a 10 s window,
    /// so each is the drift at its window's centre (worst at the window's ends).
    fn windowed(t: f64) -> Sim3 {
        drift(10.0 * (t / 10.0).floor() + 5.0)
    }

    fn height(x: f64, y: f64) -> f64 {
        0.6 * (0.3 * x).sin() * (0.2 * y).cos() + 0.2 * (0.9 * y + 0.5 * x).sin()
    }

    struct Scene {
        map: Map,
        camera: PinholeCamera,
        truth: Vec<CameraToWorld>,
        ties: Vec<FinalTie>,
    }

    /// A straight 58 m flight at 10 m over relief. The SLAM map is the truth seen through
    /// the drift at each keyframe's time; observations are the true projections with 0.5 px
    /// noise; every keyframe has a fix of its ground point with σ 0.1 m in x, y, and one fix
    /// is 30 m off.
    fn scene(seed: u64) -> Scene {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let camera = PinholeCamera::ideal(500.0, 500, 500);
        let down = UnitQuaternion::from_euler_angles(std::f64::consts::PI, 0.0, 0.0);
        let truth: Vec<CameraToWorld> = (0..KEYFRAMES)
            .map(|k| {
                let c = Vector3::new(k as f64 * SPACING_M, 0.3 * (0.2 * k as f64).sin(), 0.0);
                let tilt = UnitQuaternion::from_euler_angles(
                    rng.random_range(-0.01..0.01),
                    rng.random_range(-0.01..0.01),
                    0.0,
                );
                CameraToWorld::from_rotation_translation(
                    down * tilt,
                    c + Vector3::z() * (height(c.x, c.y) + ALTITUDE_M),
                )
            })
            .collect();
        let points: Vec<Vector3<f64>> = (0..6000)
            .map(|_| {
                let x = rng.random_range(-6.0..(KEYFRAMES as f64 * SPACING_M + 4.0));
                let y = rng.random_range(-6.0..6.0);
                Vector3::new(x, y, height(x, y))
            })
            .collect();
        let pixel = Normal::new(0.0, 0.5).unwrap();
        let mut seen: Vec<Vec<(usize, usize)>> = vec![Vec::new(); points.len()];
        let mut keypoints: Vec<Vec<KeyPoint>> = vec![Vec::new(); KEYFRAMES];
        for (k, pose) in truth.iter().enumerate() {
            let t_cw = pose.inverse();
            for (j, p) in points.iter().enumerate() {
                let Some(uv) = camera.project(&t_cw.transform_point(&Point3::from(*p))) else {
                    continue;
                };
                if !camera.contains(&uv, 2.0) {
                    continue;
                }
                let uv =
                    uv + nalgebra::Vector2::new(pixel.sample(&mut rng), pixel.sample(&mut rng));
                seen[j].push((k, keypoints[k].len()));
                keypoints[k].push(KeyPoint {
                    x: uv.x,
                    y: uv.y,
                    octave: 0,
                    angle: 0.0,
                    response: 1.0,
                    size: 31.0,
                });
            }
        }
        let mut map = Map::new(1.2, 8);
        let mut ids = Vec::new();
        for (k, kps) in keypoints.iter().enumerate() {
            let t = k as f64 * SPACING_M;
            let slam = drift(t).inverse().transform_pose(&truth[k]);
            let features = OrbFeatures {
                descriptors: vec![[0; 32]; kps.len()],
                keypoints: kps.clone(),
                level_scales: vec![1.0],
            };
            let grid = FeatureGrid::new(&features.keypoints, 500, 500, 10.0);
            ids.push(map.insert_keyframe(KeyFrame::new(k, t, slam.inverse(), features, grid)));
        }
        for (p, obs) in points.iter().zip(&seen) {
            if obs.len() < 2 {
                continue;
            }
            let (k0, i0) = obs[0];
            let slam = drift(k0 as f64 * SPACING_M)
                .inverse()
                .transform_point(&Point3::from(*p));
            let id = map.insert_point(slam.coords, ids[k0], i0).unwrap();
            for &(k, i) in &obs[1..] {
                assert!(map.add_observation(id, ids[k], i));
            }
        }
        let fix = Normal::new(0.0, 0.1).unwrap();
        // Each fix as JointLoc ties it: its ground point on the optical axis, and the camera
        // above it at the altimeter's height (a nadir view, σ × 0.25).
        let mut ties = Vec::new();
        for (k, pose) in truth.iter().enumerate() {
            let c = pose.centre();
            let range = c.z - height(c.x, c.y);
            let s = drift(k as f64 * SPACING_M).scale;
            let mut ground = pose.0.transform_point(&Point3::new(0.0, 0.0, range));
            ground.x += fix.sample(&mut rng);
            ground.y += fix.sample(&mut rng);
            if k == 17 {
                ground.x += 30.0;
            }
            let above = Point3::new(ground.x, ground.y, c.z + fix.sample(&mut rng));
            for (point_in_camera, world, sigma_scale) in [
                (Point3::new(0.0, 0.0, range / s), ground, 1.0),
                (Point3::origin(), above, 0.25),
            ] {
                ties.push(FinalTie {
                    keyframe: ids[k],
                    point_in_camera,
                    world,
                    weight: 1.0,
                    sigma_scale,
                    vertical_sigma_scale: 1.0,
                    tolerance: Tolerance::sphere(2.0),
                });
            }
        }
        Scene {
            map,
            camera,
            truth,
            ties,
        }
    }

    fn rmse(a: &[CameraToWorld], b: &[CameraToWorld]) -> f64 {
        let sum: f64 = a
            .iter()
            .zip(b)
            .map(|(x, y)| (x.centre() - y.centre()).norm_squared())
            .sum();
        (sum / a.len() as f64).sqrt()
    }

    /// The refined keyframes are closer to the truth than the windowed alignments gave
    /// them, and the wrong fix is left out.
    #[test]
    fn the_global_ba_undoes_the_drift_the_local_alignments_leave() {
        for seed in 0..3 {
            let sc = scene(seed);
            let refined = refine(
                &sc.map,
                &Undistorter::new(&sc.camera, 70.0),
                &LocalBaConfig::default(),
                &FinalBaConfig::default(),
                &mut windowed,
                &sc.ties,
                None,
                false,
            )
            .unwrap()
            .unwrap();
            eprintln!("seed {seed}: {:?}", refined.stats);
            assert_eq!(refined.stats.factors_left_out, 2, "seed {seed}");
            assert_eq!(
                refined.stats.global_factors,
                2 * KEYFRAMES - 2,
                "seed {seed}"
            );
            let kfs: Vec<_> = sc.map.keyframes().collect();
            let before: Vec<CameraToWorld> = kfs
                .iter()
                .map(|k| windowed(k.timestamp).transform_pose(&k.pose.inverse()))
                .collect();
            let after: Vec<CameraToWorld> = kfs
                .iter()
                .map(|k| {
                    refined.world_pose(k.timestamp, &windowed(k.timestamp), &k.pose.inverse(), None)
                })
                .collect();
            let (e0, e1) = (rmse(&before, &sc.truth), rmse(&after, &sc.truth));
            assert!(e0 > 0.1, "seed {seed}: the windows leave {e0} m");
            eprintln!("seed {seed}: {e0:.3} -> {e1:.3} m");
            assert!(e1 < 0.08 && e1 < 0.2 * e0, "seed {seed}: {e0} -> {e1} m");
            // A frame between two keyframes lands between their refined poses.
            let (k0, k1) = (kfs[10], kfs[11]);
            let t = 0.5 * (k0.timestamp + k1.timestamp);
            let mid_slam = CameraToWorld(k0.pose.inverse().0.lerp_slerp(&k1.pose.inverse().0, 0.5));
            let mid = refined
                .world_pose(t, &windowed(t), &mid_slam, None)
                .centre();
            let expected = nalgebra::center(&after[10].centre(), &after[11].centre());
            assert!(
                (mid - expected).norm() < 0.02,
                "seed {seed}: {}",
                (mid - expected).norm()
            );
        }
    }

    #[test]
    fn interpolation_ends_at_both_transforms() {
        let a = Isometry3::new(Vector3::new(1.0, 2.0, 3.0), Vector3::new(0.1, 0.0, 0.0));
        let b = Isometry3::new(Vector3::new(3.0, 2.0, 1.0), Vector3::new(0.0, 0.2, 0.0));
        assert!((interpolate(&a, &b, 0.0).to_homogeneous() - a.to_homogeneous()).norm() < 1e-12);
        assert!((interpolate(&a, &b, 1.0).to_homogeneous() - b.to_homogeneous()).norm() < 1e-12);
        let mid = interpolate(&a, &b, 0.5);
        assert!((mid.translation.vector - Vector3::new(2.0, 2.0, 2.0)).norm() < 1e-12);
    }
}
