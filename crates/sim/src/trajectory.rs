//! UAV flight: a smooth, turning, compact path flown at constant ground speed, with a
//! terrain-following altitude and smooth attitude jitter.
//!
//! The plan view is a uniform cubic B-spline (C², so yaw rate is continuous) through control
//! points from a random walk with bounded turns inside a square whose side grows with
//! √length; a B-spline stays in the convex hull of its control points, so the path, and with
//! it the terrain that must be synthesised, stays compact even for 1000 m. Frames are placed at
//! equal arc length (speed / rate) by inverting a dense arc-length table.
//!
//! Attitude: the camera looks straight down (camera z = world −z) with the image "up" (camera
//! −y) along the flight direction, turned by `yaw_offset_deg`; on top of that a smooth jitter
//! rotation `exp([δx, δy, δz])` in the camera frame (δx pitch, δy roll, δz yaw), each a sum of
//! random sinusoids, so it is correlated over seconds rather than white per frame.

use jointloc_geometry::CameraToWorld;
use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::error::{Result, SimError};

/// Shape of the flight. Distances in metres, angles in degrees.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct TrajectoryConfig {
    /// Flown path length (the paper: ≈ 150 m).
    pub length_m: f64,
    /// Ground speed in m/s.
    pub speed_mps: f64,
    /// Camera frame rate in Hz.
    pub rate_hz: f64,
    /// Mean height of the camera above the (smoothed) ground below it.
    pub altitude_m: f64,
    /// Largest slow deviation from `altitude_m`.
    pub altitude_variation_m: f64,
    /// Shortest and longest wavelength of that deviation along the path.
    pub altitude_wavelength_m: [f64; 2],
    /// Along-track σ of the Gaussian that smooths the ground height the UAV follows: long
    /// enough that rocks and crater rims do not make it bob, short enough to climb a hill.
    pub ground_smoothing_m: f64,
    /// Distance between consecutive B-spline control points.
    pub waypoint_spacing_m: f64,
    /// Largest heading change at one control point (turns are drawn uniformly within it).
    pub max_turn_deg: f64,
    /// Control points stay in a square of side `max(min_region_m, region_per_sqrt_m · √length)`
    /// (a forced step at a corner may leave it by at most one spacing).
    pub region_per_sqrt_m: f64,
    /// Smallest side of that square.
    pub min_region_m: f64,
    /// σ of each attitude jitter angle (pitch, roll, yaw).
    pub attitude_jitter_deg: f64,
    /// Shortest and longest period of the jitter, seconds.
    pub jitter_period_s: [f64; 2],
    /// Angle from the flight direction to the image "up" direction, counter-clockwise seen
    /// from above (0: the image top looks ahead).
    pub yaw_offset_deg: f64,
    /// A constant tilt of the camera away from nadir, `[about image x, about image y]`
    /// degrees, under the jitter: a body-fixed camera on a UAV pitched to cruise, or mounted
    /// off nadir. A tilt about image x moves the view along the track. 0: nadir on average.
    pub camera_tilt_deg: [f64; 2],
}

impl Default for TrajectoryConfig {
    fn default() -> Self {
        Self {
            length_m: 150.0,
            speed_mps: 1.0,
            rate_hz: 5.0,
            altitude_m: 10.0,
            altitude_variation_m: 1.0,
            altitude_wavelength_m: [30.0, 90.0],
            ground_smoothing_m: 8.0,
            waypoint_spacing_m: 15.0,
            max_turn_deg: 70.0,
            region_per_sqrt_m: 3.5,
            min_region_m: 30.0,
            attitude_jitter_deg: 0.5,
            jitter_period_s: [1.5, 8.0],
            yaw_offset_deg: 0.0,
            camera_tilt_deg: [0.0, 0.0],
        }
    }
}

impl TrajectoryConfig {
    /// Checks ranges; every error names the field.
    pub fn validate(&self) -> Result<()> {
        let positive = [
            ("trajectory.length_m", self.length_m),
            ("trajectory.speed_mps", self.speed_mps),
            ("trajectory.rate_hz", self.rate_hz),
            ("trajectory.altitude_m", self.altitude_m),
            ("trajectory.waypoint_spacing_m", self.waypoint_spacing_m),
            ("trajectory.min_region_m", self.min_region_m),
        ];
        for (field, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(invalid(field, value, "must be a positive number"));
            }
        }
        let non_negative = [
            ("trajectory.altitude_variation_m", self.altitude_variation_m),
            ("trajectory.ground_smoothing_m", self.ground_smoothing_m),
            ("trajectory.region_per_sqrt_m", self.region_per_sqrt_m),
            ("trajectory.attitude_jitter_deg", self.attitude_jitter_deg),
            ("trajectory.max_turn_deg", self.max_turn_deg),
        ];
        for (field, value) in non_negative {
            if !(value.is_finite() && value >= 0.0) {
                return Err(invalid(field, value, "must be ≥ 0"));
            }
        }
        if self.altitude_variation_m >= self.altitude_m {
            return Err(invalid(
                "trajectory.altitude_variation_m",
                self.altitude_variation_m,
                "must be below altitude_m",
            ));
        }
        if self.length_m > 100_000.0 {
            return Err(invalid(
                "trajectory.length_m",
                self.length_m,
                "at most 100 km",
            ));
        }
        for (field, [lo, hi]) in [
            (
                "trajectory.altitude_wavelength_m",
                self.altitude_wavelength_m,
            ),
            ("trajectory.jitter_period_s", self.jitter_period_s),
        ] {
            if !(lo.is_finite() && hi.is_finite() && lo > 0.0 && hi >= lo) {
                return Err(SimError::InvalidConfig {
                    field,
                    value: format!("[{lo}, {hi}]"),
                    reason: "needs 0 < min ≤ max".into(),
                });
            }
        }
        if let Some(t) = self
            .camera_tilt_deg
            .iter()
            .find(|t| !(t.is_finite() && t.abs() < 45.0))
        {
            return Err(invalid(
                "trajectory.camera_tilt_deg",
                *t,
                "each angle must be finite and within ±45°",
            ));
        }
        if !self.yaw_offset_deg.is_finite() {
            return Err(invalid(
                "trajectory.yaw_offset_deg",
                self.yaw_offset_deg,
                "must be finite",
            ));
        }
        Ok(())
    }

    /// Number of frames: one every `speed / rate` metres, both ends included.
    pub fn frame_count(&self) -> usize {
        (self.length_m / self.speed_mps * self.rate_hz + 1e-9).floor() as usize + 1
    }

    /// Side of the square the control points stay in.
    pub fn region_side_m(&self) -> f64 {
        (self.region_per_sqrt_m * self.length_m.sqrt()).max(self.min_region_m)
    }
}

fn invalid(field: &'static str, value: f64, reason: &str) -> SimError {
    SimError::InvalidConfig {
        field,
        value: value.to_string(),
        reason: reason.into(),
    }
}

/// One frame's position in the plan view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathSample {
    /// Time since the first frame, seconds.
    pub t: f64,
    /// Arc length since the start, metres.
    pub s: f64,
    /// World x (east).
    pub x: f64,
    /// World y (north).
    pub y: f64,
    /// Flight direction, radians counter-clockwise from east.
    pub heading: f64,
    /// Signed curvature of the path, 1/m (positive: turning left).
    pub curvature: f64,
}

/// The plan-view path, one sample per frame.
#[derive(Debug, Clone, PartialEq)]
pub struct PlanarPath {
    pub samples: Vec<PathSample>,
}

impl PlanarPath {
    /// Axis-aligned bounding box `([min_x, min_y], [max_x, max_y])` of the frame positions.
    pub fn bbox(&self) -> ([f64; 2], [f64; 2]) {
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for s in &self.samples {
            lo = [lo[0].min(s.x), lo[1].min(s.y)];
            hi = [hi[0].max(s.x), hi[1].max(s.y)];
        }
        (lo, hi)
    }

    /// Shifts the whole path by `(dx, dy)`.
    pub fn translate(&mut self, dx: f64, dy: f64) {
        for s in &mut self.samples {
            s.x += dx;
            s.y += dy;
        }
    }
}

/// Draws the plan-view path: control points by a bounded-turn random walk, a cubic B-spline
/// through them, frames at equal arc length. The path starts near the origin of a local frame;
/// callers translate it into the map.
pub fn plan_path(cfg: &TrajectoryConfig, seed: u64) -> Result<PlanarPath> {
    cfg.validate()?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let half = cfg.region_side_m() / 2.0;
    let spacing = cfg.waypoint_spacing_m.min(half);
    let start = Vector2::new(
        rng.random_range(-half / 2.0..=half / 2.0),
        rng.random_range(-half / 2.0..=half / 2.0),
    );
    let mut heading: f64 = rng.random_range(0.0..std::f64::consts::TAU);
    let mut points = vec![start];
    let max_turn = cfg.max_turn_deg.to_radians();
    let inside = |p: Vector2<f64>| p.x.abs() <= half && p.y.abs() <= half;
    let mut target = cfg.length_m + 2.0 * spacing;
    loop {
        // Extend the control polygon to the target length (corner cutting makes the spline
        // shorter than its polygon, so the spline itself is checked below).
        while polygon_length(&points) < target {
            let last = *points.last().expect("non-empty");
            let step = |h: f64| spacing * Vector2::new(h.cos(), h.sin());
            let candidates: Vec<f64> = (0..16)
                .map(|_| {
                    heading
                        + if max_turn > 0.0 {
                            rng.random_range(-max_turn..=max_turn)
                        } else {
                            0.0
                        }
                })
                .collect();
            // Prefer turns that leave room for one more straight step, so the walk starts
            // turning before it meets the region's edge; else any turn that stays inside;
            // else the allowed turn that points most towards the centre.
            let h = candidates
                .iter()
                .copied()
                .find(|&h| inside(last + step(h)) && inside(last + 2.0 * step(h)))
                .or_else(|| candidates.iter().copied().find(|&h| inside(last + step(h))))
                .unwrap_or_else(|| {
                    let to_centre = (-last.y).atan2(-last.x);
                    let off = wrap_angle(to_centre - heading).clamp(-max_turn, max_turn);
                    heading + off
                });
            points.push(last + step(h));
            heading = h;
        }
        let spline = BSpline::new(&points);
        let length = spline.length();
        if length >= cfg.length_m {
            return Ok(sample_path(&spline, cfg));
        }
        target += 1.2 * (cfg.length_m - length) + spacing;
    }
}

/// Angle wrapped to (−π, π].
pub fn wrap_angle(a: f64) -> f64 {
    let w = a.rem_euclid(std::f64::consts::TAU);
    if w > std::f64::consts::PI {
        w - std::f64::consts::TAU
    } else {
        w
    }
}

fn polygon_length(points: &[Vector2<f64>]) -> f64 {
    points.windows(2).map(|w| (w[1] - w[0]).norm()).sum()
}

fn sample_path(spline: &BSpline, cfg: &TrajectoryConfig) -> PlanarPath {
    let n = cfg.frame_count();
    let step = cfg.speed_mps / cfg.rate_hz;
    let samples = (0..n)
        .map(|i| {
            let s = i as f64 * step;
            let u = spline.param_at_length(s);
            let p = spline.point(u);
            let d1 = spline.derivative(u);
            let d2 = spline.second_derivative(u);
            let speed = d1.norm();
            let curvature = (d1.x * d2.y - d1.y * d2.x) / (speed * speed * speed).max(1e-12);
            PathSample {
                t: i as f64 / cfg.rate_hz,
                s,
                x: p.x,
                y: p.y,
                heading: d1.y.atan2(d1.x),
                curvature,
            }
        })
        .collect();
    PlanarPath { samples }
}

/// Uniform cubic B-spline; parameter `u ∈ [0, segments]`. A phantom control point mirrored
/// at each end makes the curve start at the first and end at the last control point.
struct BSpline {
    ctrl: Vec<Vector2<f64>>,
    /// Dense arc-length table: `(u, s)` pairs, s increasing.
    table: Vec<(f64, f64)>,
}

/// Samples per segment of the arc-length table (segments are ≈ 15 m, so ≈ 6 cm apart).
const TABLE_SAMPLES: usize = 256;

impl BSpline {
    fn new(points: &[Vector2<f64>]) -> Self {
        let n = points.len();
        let mut ctrl = Vec::with_capacity(n + 2);
        ctrl.push(2.0 * points[0] - points[1]);
        ctrl.extend_from_slice(points);
        ctrl.push(2.0 * points[n - 1] - points[n - 2]);
        let mut spline = Self {
            ctrl,
            table: Vec::new(),
        };
        let segments = spline.segments();
        let mut table = Vec::with_capacity(segments * TABLE_SAMPLES + 1);
        let mut s = 0.0;
        let mut prev = spline.point(0.0);
        table.push((0.0, 0.0));
        for k in 1..=segments * TABLE_SAMPLES {
            let u = k as f64 / TABLE_SAMPLES as f64;
            let p = spline.point(u);
            s += (p - prev).norm();
            prev = p;
            table.push((u, s));
        }
        spline.table = table;
        spline
    }

    fn segments(&self) -> usize {
        self.ctrl.len() - 3
    }

    fn length(&self) -> f64 {
        self.table.last().map_or(0.0, |&(_, s)| s)
    }

    /// Segment index and local parameter in [0, 1].
    fn locate(&self, u: f64) -> (usize, f64) {
        let segs = self.segments();
        let u = u.clamp(0.0, segs as f64);
        let i = (u.floor() as usize).min(segs - 1);
        (i, u - i as f64)
    }

    /// Basis weights (value, first and second derivative) at local parameter `t`.
    fn basis(t: f64) -> [[f64; 4]; 3] {
        let (t2, t3) = (t * t, t * t * t);
        [
            [
                (1.0 - t).powi(3) / 6.0,
                (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0,
                (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0,
                t3 / 6.0,
            ],
            [
                -(1.0 - t).powi(2) / 2.0,
                (3.0 * t2 - 4.0 * t) / 2.0,
                (-3.0 * t2 + 2.0 * t + 1.0) / 2.0,
                t2 / 2.0,
            ],
            [1.0 - t, 3.0 * t - 2.0, -3.0 * t + 1.0, t],
        ]
    }

    fn eval(&self, u: f64, order: usize) -> Vector2<f64> {
        let (i, t) = self.locate(u);
        let w = Self::basis(t)[order];
        (0..4).map(|k| w[k] * self.ctrl[i + k]).sum()
    }

    fn point(&self, u: f64) -> Vector2<f64> {
        self.eval(u, 0)
    }

    fn derivative(&self, u: f64) -> Vector2<f64> {
        self.eval(u, 1)
    }

    fn second_derivative(&self, u: f64) -> Vector2<f64> {
        self.eval(u, 2)
    }

    /// Parameter at arc length `s` (linear between table entries, ≈ 0.1 mm error).
    fn param_at_length(&self, s: f64) -> f64 {
        let k = self.table.partition_point(|&(_, ts)| ts < s);
        if k == 0 {
            return 0.0;
        }
        if k >= self.table.len() {
            return self.table.last().expect("non-empty").0;
        }
        let (u0, s0) = self.table[k - 1];
        let (u1, s1) = self.table[k];
        if s1 > s0 {
            u0 + (u1 - u0) * (s - s0) / (s1 - s0)
        } else {
            u0
        }
    }
}

/// A smooth random function: a sum of sinusoids with random (log-uniform) periods and phases.
#[derive(Debug, Clone)]
pub struct SmoothNoise {
    components: Vec<(f64, f64, f64)>,
}

impl SmoothNoise {
    /// `count` sinusoids with periods in `[period_min, period_max]`, scaled so the standard
    /// deviation over a long run is `sigma`.
    pub fn with_sigma(rng: &mut impl Rng, count: usize, period: [f64; 2], sigma: f64) -> Self {
        let amp = sigma * (2.0 / count.max(1) as f64).sqrt();
        Self::draw(rng, count, period, |_| amp)
    }

    /// Sinusoids whose amplitudes sum to `max_abs`, so `|f| ≤ max_abs` everywhere.
    pub fn with_max(rng: &mut impl Rng, count: usize, period: [f64; 2], max_abs: f64) -> Self {
        let amp = max_abs / count.max(1) as f64;
        Self::draw(rng, count, period, |_| amp)
    }

    fn draw(
        rng: &mut impl Rng,
        count: usize,
        period: [f64; 2],
        amp: impl Fn(usize) -> f64,
    ) -> Self {
        let (lo, hi) = (period[0].ln(), period[1].ln());
        let components = (0..count)
            .map(|k| {
                let p = if hi > lo {
                    rng.random_range(lo..=hi)
                } else {
                    lo
                }
                .exp();
                let phase = rng.random_range(0.0..std::f64::consts::TAU);
                (amp(k), std::f64::consts::TAU / p, phase)
            })
            .collect();
        Self { components }
    }

    /// Value at `x`.
    pub fn eval(&self, x: f64) -> f64 {
        self.components
            .iter()
            .map(|&(a, w, p)| a * (w * x + p).sin())
            .sum()
    }
}

/// Rotation camera-to-world of a nadir camera whose image "up" points along `up_angle`
/// (radians counter-clockwise from east).
pub fn nadir_rotation(up_angle: f64) -> Rotation3<f64> {
    let (s, c) = up_angle.sin_cos();
    // Columns: camera x (image right), y (image down), z (optical axis) in world coordinates.
    let m = Matrix3::new(s, -c, 0.0, -c, -s, 0.0, 0.0, 0.0, -1.0);
    Rotation3::from_matrix_unchecked(m)
}

/// Camera-to-world poses along `path`: the camera holds `altitude_m` (plus a slow variation)
/// above the ground height under it, smoothed along the track; attitude as in the module doc.
/// `ground(x, y)` is the terrain height.
pub fn fly(
    path: &PlanarPath,
    ground: &(dyn Fn(f64, f64) -> f64 + Sync),
    cfg: &TrajectoryConfig,
    seed: u64,
) -> Vec<CameraToWorld> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let altitude = SmoothNoise::with_max(
        &mut rng,
        3,
        cfg.altitude_wavelength_m,
        cfg.altitude_variation_m,
    );
    let sigma = cfg.attitude_jitter_deg.to_radians();
    let jitter: Vec<SmoothNoise> = (0..3)
        .map(|_| SmoothNoise::with_sigma(&mut rng, 4, cfg.jitter_period_s, sigma))
        .collect();
    let ground_level = smoothed_ground(path, ground, cfg);
    let [tx, ty] = cfg.camera_tilt_deg.map(f64::to_radians);
    let tilt = UnitQuaternion::from_scaled_axis(Vector3::new(tx, ty, 0.0));
    path.samples
        .iter()
        .zip(ground_level)
        .map(|(p, g)| {
            let z = g + cfg.altitude_m + altitude.eval(p.s);
            let nominal = nadir_rotation(p.heading + cfg.yaw_offset_deg.to_radians());
            let delta = Vector3::new(
                jitter[0].eval(p.t),
                jitter[1].eval(p.t),
                jitter[2].eval(p.t),
            );
            let r = UnitQuaternion::from_rotation_matrix(&nominal)
                * tilt
                * UnitQuaternion::from_scaled_axis(delta);
            CameraToWorld::from_rotation_translation(r, Vector3::new(p.x, p.y, z))
        })
        .collect()
}

/// Mean ground height over the camera footprint at each sample, then a Gaussian along track.
fn smoothed_ground(
    path: &PlanarPath,
    ground: &(dyn Fn(f64, f64) -> f64 + Sync),
    cfg: &TrajectoryConfig,
) -> Vec<f64> {
    use rayon::prelude::*;
    // Footprint of a 90° camera at the flight altitude, sampled on a 5 × 5 grid.
    let half = 0.4 * cfg.altitude_m;
    let local: Vec<f64> = path
        .samples
        .par_iter()
        .map(|p| {
            let mut sum = 0.0;
            for i in 0..5 {
                for j in 0..5 {
                    let dx = (i as f64 - 2.0) / 2.0 * half;
                    let dy = (j as f64 - 2.0) / 2.0 * half;
                    sum += ground(p.x + dx, p.y + dy);
                }
            }
            sum / 25.0
        })
        .collect();
    let step = cfg.speed_mps / cfg.rate_hz;
    let sigma = cfg.ground_smoothing_m / step;
    if sigma < 0.5 {
        return local;
    }
    let radius = (3.0 * sigma).ceil() as isize;
    let weights: Vec<f64> = (-radius..=radius)
        .map(|k| (-0.5 * (k as f64 / sigma).powi(2)).exp())
        .collect();
    let n = local.len() as isize;
    (0..n)
        .map(|i| {
            let (mut sum, mut wsum) = (0.0, 0.0);
            for (k, w) in (-radius..=radius).zip(&weights) {
                let j = i + k;
                if (0..n).contains(&j) {
                    sum += w * local[j as usize];
                    wsum += w;
                }
            }
            sum / wsum
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_are_equally_spaced_and_the_path_turns() {
        for seed in 0..6 {
            let cfg = TrajectoryConfig::default();
            let path = plan_path(&cfg, seed).unwrap();
            assert_eq!(path.samples.len(), 751);
            for w in path.samples.windows(2) {
                let d = ((w[1].x - w[0].x).powi(2) + (w[1].y - w[0].y).powi(2)).sqrt();
                assert!((d - 0.2).abs() < 1e-3, "seed {seed}: step {d}");
            }
            let turn: f64 = path
                .samples
                .windows(2)
                .map(|w| {
                    let d = w[1].heading - w[0].heading;
                    (d + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
                        - std::f64::consts::PI
                })
                .map(f64::abs)
                .sum();
            assert!(
                turn.to_degrees() > 60.0,
                "seed {seed}: only {turn} rad of turning"
            );
            let max_k = path
                .samples
                .iter()
                .map(|s| s.curvature.abs())
                .fold(0.0, f64::max);
            assert!(
                max_k < 1.0 / 3.0,
                "seed {seed}: turn radius {}",
                1.0 / max_k
            );
            let (lo, hi) = path.bbox();
            let side = cfg.region_side_m() + 2.0 * cfg.waypoint_spacing_m;
            assert!(hi[0] - lo[0] <= side && hi[1] - lo[1] <= side);
        }
    }

    #[test]
    fn long_flight_stays_compact() {
        let cfg = TrajectoryConfig {
            length_m: 1000.0,
            ..Default::default()
        };
        for seed in 0..3 {
            let path = plan_path(&cfg, seed).unwrap();
            let (lo, hi) = path.bbox();
            // Control points stay in the square but for rare forced steps (≤ one spacing out).
            let side = cfg.region_side_m() + 2.0 * cfg.waypoint_spacing_m;
            assert!(hi[0] - lo[0] <= side, "{lo:?} {hi:?}");
            assert!(hi[1] - lo[1] <= side, "{lo:?} {hi:?}");
        }
    }

    #[test]
    fn nadir_camera_looks_down_with_image_up_ahead() {
        for angle in [0.0, 0.7, 2.0, -2.5] {
            let r = nadir_rotation(angle);
            assert!((r.matrix().determinant() - 1.0).abs() < 1e-12);
            let ahead = Vector3::new(f64::cos(angle), f64::sin(angle), 0.0);
            // Optical axis down, image up (−y) ahead.
            assert!((r * Vector3::z() - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-12);
            assert!((r * -Vector3::y() - ahead).norm() < 1e-12);
        }
    }

    #[test]
    fn altitude_follows_ground_and_jitter_is_small_and_smooth() {
        let cfg = TrajectoryConfig::default();
        let path = plan_path(&cfg, 3).unwrap();
        let ground = |x: f64, y: f64| 3.0 * (x / 17.0).sin() + 2.0 * (y / 23.0).cos();
        let poses = fly(&path, &ground, &cfg, 3);
        let mut prev: Option<UnitQuaternion<f64>> = None;
        let mut tilts = Vec::new();
        for (pose, s) in poses.iter().zip(&path.samples) {
            let above = pose.translation().z - ground(s.x, s.y);
            assert!((6.0..14.0).contains(&above), "height above ground {above}");
            let axis = pose.rotation() * Vector3::z();
            tilts.push(
                axis.dot(&-Vector3::z())
                    .clamp(-1.0, 1.0)
                    .acos()
                    .to_degrees(),
            );
            if let Some(q) = prev {
                let step = q.angle_to(&pose.rotation()).to_degrees();
                assert!(step < 3.0, "attitude step {step}°");
            }
            prev = Some(pose.rotation());
        }
        let rms = (tilts.iter().map(|t| t * t).sum::<f64>() / tilts.len() as f64).sqrt();
        assert!(rms > 0.2 && rms < 1.5, "tilt rms {rms}°");
    }

    #[test]
    fn a_camera_tilt_moves_the_mean_optical_axis_off_nadir() {
        let cfg = TrajectoryConfig {
            attitude_jitter_deg: 0.0,
            camera_tilt_deg: [3.0, 0.0],
            ..Default::default()
        };
        cfg.validate().unwrap();
        let path = plan_path(&cfg, 5).unwrap();
        let poses = fly(&path, &|_, _| 0.0, &cfg, 5);
        for (pose, s) in poses.iter().zip(&path.samples) {
            let axis = pose.rotation() * Vector3::z();
            let tilt = axis
                .dot(&-Vector3::z())
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees();
            assert!((tilt - 3.0).abs() < 1e-9, "tilt {tilt}°");
            // About image x: the axis leans along the track, not across it.
            let ahead = Vector3::new(s.heading.cos(), s.heading.sin(), 0.0);
            let across = Vector3::new(-s.heading.sin(), s.heading.cos(), 0.0);
            assert!(axis.dot(&ahead).abs() > 0.05, "{axis:?}");
            assert!(axis.dot(&across).abs() < 1e-9, "{axis:?}");
        }
        let bad = TrajectoryConfig {
            camera_tilt_deg: [0.0, f64::NAN],
            ..Default::default()
        };
        assert!(bad.validate().is_err());
    }

    #[test]
    fn bad_config_is_rejected() {
        for cfg in [
            TrajectoryConfig {
                length_m: 0.0,
                ..Default::default()
            },
            TrajectoryConfig {
                speed_mps: -1.0,
                ..Default::default()
            },
            TrajectoryConfig {
                rate_hz: f64::NAN,
                ..Default::default()
            },
        ] {
            assert!(plan_path(&cfg, 0).is_err());
        }
    }
}
