//! Altimeter-aided height of the reported poses.
//!
//! The fixes give z only every k-th frame (DEM + altimeter at that frame, σ ≈ 0.1 m), so the
//! similarity's z translation carries the noise of the last few fixes. The altimeter, though,
//! measures every frame, and the SLAM's relative z is smooth: the reported z is shifted by
//! `ground(x, y) + altimeter − z` under the current alignment over the recent tracked frames:
//! near the reference altitude a plane through the last 15 s of them, taken at the newest
//! frame (the alignment's tilt makes the residual grow along the track), elsewhere their mean
//! over a shorter window. This uses 75 readings (15 s at 5 Hz) instead of ~3 fixes, and only
//! moves z: x, y and the attitude stay as the alignment gives them.

use std::collections::VecDeque;

use jointloc_absloc::Ground;
use jointloc_geometry::{CameraToWorld, Sim3};
use nalgebra::Point3;

/// σ of an altimeter reading the tilt prior is weighed against, metres (the simulator's and
/// a laser altimeter's at short range).
const ALTIMETER_SIGMA_M: f64 = 0.1;

/// The plane is fitted only while the window's scale is at most this (near the reference
/// altitude, over an elevation model of the reference precision). At 100 m (σ 0.5 m readings,
/// a 47 s plane) and at 10 m over a 25 cm map's 1 m DTM (σ 0.25 m, 37 s) it made z worse
/// than the mean (`docs/jointloc.md` §"z online: a plane through the altimeter's heights").
const PLANE_MAX_SCALE: f64 = 1.25;

/// The recent frames' SLAM camera centres and altimeter readings.
#[derive(Debug, Clone)]
pub struct AltitudeFilter {
    base_window_s: f64,
    /// The plane's window, seconds, and the prior σ of its slopes, radians (either 0: the
    /// plain mean, no tilt estimated).
    plane_window_s: f64,
    tilt_sigma_rad: f64,
    /// Factor on every window: longer at altitude and over a coarse elevation model.
    scale: f64,
    ground: Ground,
    recent: VecDeque<(f64, Point3<f64>, f64)>,
}

impl AltitudeFilter {
    /// A filter over the last `window_s` seconds (0: off) above `ground`.
    pub fn new(window_s: f64, ground: Ground) -> Self {
        Self {
            base_window_s: window_s,
            plane_window_s: 0.0,
            tilt_sigma_rad: 0.0,
            scale: 1.0,
            ground,
            recent: VecDeque::new(),
        }
    }

    /// Near the reference altitude, estimates over `window_s` seconds, beside the z shift,
    /// the tilt of the alignment that the heights reveal, with a prior σ of `sigma_rad`
    /// (either 0: off). See [`Self::z_offset`].
    pub fn with_plane(mut self, window_s: f64, sigma_rad: f64) -> Self {
        self.plane_window_s = window_s;
        self.tilt_sigma_rad = sigma_rad;
        self
    }

    /// Whether the plane is fitted now (see [`PLANE_MAX_SCALE`]).
    fn plane(&self) -> bool {
        self.plane_window_s > 0.0 && self.tilt_sigma_rad > 0.0 && self.scale <= PLANE_MAX_SCALE
    }

    /// The elevation model the heights are taken above.
    pub fn ground(&self) -> &Ground {
        &self.ground
    }

    /// Seconds of frames the estimate uses now, the plane's or the mean's (0: off).
    pub fn window_s(&self) -> f64 {
        if self.base_window_s <= 0.0 {
            0.0
        } else if self.plane() {
            self.scaled(self.plane_window_s)
        } else {
            self.scaled(self.base_window_s)
        }
    }

    /// Scales the window by `scale` (the readings already held are kept; the next push trims
    /// them).
    pub fn set_scale(&mut self, scale: f64) {
        self.scale = scale;
    }

    /// Another window, `base_s` seconds as given, scaled as this one is now.
    pub fn scaled(&self, base_s: f64) -> f64 {
        base_s * self.scale
    }

    /// Forgets every frame (tracking lost: the SLAM frame may change).
    pub fn clear(&mut self) {
        self.recent.clear();
    }

    /// Records a tracked frame: its time, SLAM camera centre and altimeter reading.
    pub fn push(&mut self, timestamp: f64, slam_centre: Point3<f64>, altitude: f64) {
        let window_s = self.window_s();
        if window_s <= 0.0 || !altitude.is_finite() {
            return;
        }
        self.recent.push_back((timestamp, slam_centre, altitude));
        while self
            .recent
            .front()
            .is_some_and(|&(t, _, _)| t < timestamp - window_s)
        {
            self.recent.pop_front();
        }
    }

    /// The z shift of the world poses under `slam_to_world`: mean of
    /// `ground(x, y) + altitude − z` over the recorded frames; `None` with none recorded.
    ///
    /// With a plane ([`Self::with_plane`]) near the reference altitude the shift is the
    /// intercept, at the newest frame's x, y, of a plane fitted to those residuals over the
    /// frames' x, y (a ridge regression: the slopes' prior σ against the altimeter's 0.1 m).
    /// A tilt of the alignment makes the residual grow along the track, and a trailing mean
    /// then lags by the tilt × half the window's length; the plane follows it, so the window
    /// can be longer and average more readings. Across a straight track the slope is
    /// unobserved and the prior keeps it level.
    pub fn z_offset(&self, slam_to_world: &Sim3) -> Option<f64> {
        let (_, newest, _) = self.recent.back()?;
        let newest = slam_to_world.transform_point(newest);
        // Normal equations of r = c + gx·dx + gy·dy, summed in one pass: their first row
        // also gives the mean (Σr / n).
        let mut a = nalgebra::Matrix3::<f64>::zeros();
        let mut b = nalgebra::Vector3::<f64>::zeros();
        for (_, c, altitude) in &self.recent {
            let p = slam_to_world.transform_point(c);
            let r = self.ground.height_at(p.x, p.y) + altitude - p.z;
            let v = nalgebra::Vector3::new(1.0, p.x - newest.x, p.y - newest.y);
            a += v * v.transpose();
            b += v * r;
        }
        let mean = b[0] / a[(0, 0)];
        if !self.plane() {
            return Some(mean);
        }
        // Ridge λ on (gx, gy).
        let ridge = (ALTIMETER_SIGMA_M / self.tilt_sigma_rad).powi(2);
        a[(1, 1)] += ridge;
        a[(2, 2)] += ridge;
        let Some(x) = a.cholesky().map(|c| c.solve(&b)) else {
            return Some(mean);
        };
        Some(x[0])
    }
}

/// The same aid for a trajectory known as a whole (the final frame trajectory): the z shift
/// at each time of `at`, the mean of `ground(x, y) + altitude − z` over the poses within
/// `window_s / 2` of it (centred rather than trailing); `None` where no reading is in reach,
/// or with the aid off (`window_s` 0).
pub fn z_shifts(
    timestamps: &[f64],
    poses: &[CameraToWorld],
    altitudes: &[Option<f64>],
    ground: &Ground,
    window_s: f64,
    at: &[f64],
) -> Vec<Option<f64>> {
    if window_s <= 0.0 {
        return vec![None; at.len()];
    }
    let offsets: Vec<Option<f64>> = poses
        .iter()
        .zip(altitudes)
        .map(|(p, a)| {
            let c = p.centre();
            a.filter(|a| a.is_finite())
                .map(|a| ground.height_at(c.x, c.y) + a - c.z)
        })
        .collect();
    let half = 0.5 * window_s;
    at.iter()
        .map(|&t| {
            // Timestamps are increasing: the window is a contiguous range.
            let lo = timestamps.partition_point(|&x| x < t - half);
            let hi = timestamps.partition_point(|&x| x <= t + half);
            let near: Vec<f64> = offsets[lo..hi].iter().filter_map(|o| *o).collect();
            (!near.is_empty()).then(|| near.iter().sum::<f64>() / near.len() as f64)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{UnitQuaternion, Vector3};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// A level flight 10 m above flat ground, seen through an alignment whose z is 0.3 m off:
    /// the offset recovers the 0.3 m from noisy altimeter readings, and only the recent frames
    /// count.
    #[test]
    fn recovers_a_z_bias_from_noisy_altimeter_readings() {
        let s = Sim3::new(
            2.0,
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.7),
            Vector3::new(5.0, -3.0, 0.3),
        );
        let noise = Normal::new(0.0, 0.1).unwrap();
        for seed in 0..5 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let mut f = AltitudeFilter::new(5.0, Ground::default());
            // Old frames from another SLAM map, outside the window.
            for i in 0..50 {
                f.push(i as f64 * 0.2, Point3::new(0.0, 0.0, 100.0), 10.0);
            }
            for i in 50..200 {
                let t = i as f64 * 0.2;
                // World camera at z = 10 maps back to SLAM z = (10 − 0.3) / 2.
                let world = Point3::new(t, 0.5 * t, 10.0 - 0.3);
                let slam = s.inverse().transform_point(&world);
                f.push(t, slam, 10.0 + noise.sample(&mut rng));
            }
            let dz = f.z_offset(&s).unwrap();
            assert!((dz - 0.3).abs() < 0.06, "seed {seed}: offset {dz}");
        }
        let mut off = AltitudeFilter::new(0.0, Ground::default());
        off.push(0.0, Point3::origin(), 10.0);
        assert!(off.z_offset(&Sim3::identity()).is_none());
    }

    /// Through an alignment tilted by 3 mrad along a straight track at 1 m/s, the height
    /// residual grows along the track: over a 30 s window the plain mean lags the newest
    /// frame's shift by the tilt × 15 m (4.5 cm); the plane follows it, and its prior keeps
    /// the unobserved cross-track slope level (mean absolute errors over 20 seeds: 0.038
    /// and 0.007 m).
    #[test]
    fn the_plane_follows_a_tilted_alignment_where_the_mean_lags() {
        let noise = Normal::new(0.0, 0.1).unwrap();
        let tilt = 0.003;
        let (mut err_mean, mut err_plane) = (0f64, 0f64);
        for seed in 0..20 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let mut mean = AltitudeFilter::new(30.0, Ground::default());
            let mut plane =
                AltitudeFilter::new(30.0, Ground::default()).with_plane(30.0, 0.2f64.to_radians());
            let mut truth = 0.0;
            for i in 0..400 {
                let t = i as f64 * 0.2;
                // Heading 30° off the x axis; the world z through the alignment sinks with x.
                let (x, y) = (t * 0.866, t * 0.5);
                let z = 10.0 - 0.3 - tilt * x;
                let reading = 10.0 + noise.sample(&mut rng);
                for f in [&mut mean, &mut plane] {
                    f.push(t, Point3::new(x, y, z), reading);
                }
                truth = 0.3 + tilt * x;
            }
            let s = Sim3::identity();
            err_mean += (mean.z_offset(&s).unwrap() - truth).abs() / 20.0;
            err_plane += (plane.z_offset(&s).unwrap() - truth).abs() / 20.0;
        }
        assert!(err_mean > 0.035, "mean {err_mean}");
        assert!(
            err_plane < 0.4 * err_mean,
            "plane {err_plane}, mean {err_mean}"
        );
    }

    /// Up high (the window scaled by more than 1.25) the plane gives way to the mean, over
    /// the mean's own window.
    #[test]
    fn up_high_the_mean_replaces_the_plane() {
        let mut mean = AltitudeFilter::new(5.0, Ground::default());
        let mut plane = AltitudeFilter::new(5.0, Ground::default()).with_plane(15.0, 0.0035);
        for f in [&mut mean, &mut plane] {
            f.set_scale(2.0);
        }
        assert_eq!(plane.window_s(), 10.0);
        for i in 0..200 {
            let t = i as f64 * 0.2;
            for f in [&mut mean, &mut plane] {
                f.push(
                    t,
                    Point3::new(t, 0.0, 100.0 - 0.01 * t),
                    100.0 + (i % 7) as f64 * 0.1,
                );
            }
        }
        let s = Sim3::identity();
        assert_eq!(plane.z_offset(&s), mean.z_offset(&s));
        plane.set_scale(1.0);
        assert_eq!(plane.window_s(), 15.0);
        mean.set_scale(1.0);
        assert_eq!(mean.window_s(), 5.0);
    }

    /// A climbing flight whose z is 0.3 m low: the centred mean over the frames removes the
    /// bias from noisy readings at the sampled times, follows the climb (no lag), a time
    /// without a reading takes its neighbours' shift, and with the aid off nothing is shifted.
    #[test]
    fn z_shifts_of_a_whole_trajectory_are_centred() {
        let noise = Normal::new(0.0, 0.1).unwrap();
        for seed in 0..5 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let ts: Vec<f64> = (0..750).map(|i| i as f64 * 0.2).collect();
            let true_z = |t: f64| 10.0 + 0.02 * t;
            let poses: Vec<CameraToWorld> = ts
                .iter()
                .map(|&t| {
                    CameraToWorld(nalgebra::Isometry3::from_parts(
                        Vector3::new(t, -0.5 * t, true_z(t) - 0.3).into(),
                        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 3.1),
                    ))
                })
                .collect();
            let mut readings: Vec<Option<f64>> = ts
                .iter()
                .map(|&t| Some(true_z(t) + noise.sample(&mut rng)))
                .collect();
            readings[300] = None;
            // Sampled every 2 s, as keyframes are, and at the frame without a reading.
            let at: Vec<f64> = (0..75).map(|k| k as f64 * 2.0).chain([60.0]).collect();
            let shifts = z_shifts(&ts, &poses, &readings, &Ground::default(), 5.0, &at);
            for (&t, dz) in at.iter().zip(&shifts) {
                let dz = dz.expect("readings in reach");
                // 13–26 readings of σ 0.1 m per mean: within 4 σ / √13.
                assert!((dz - 0.3).abs() < 0.12, "seed {seed}, t {t}: shift {dz}");
            }
        }
        let ts = [0.0, 1.0];
        let poses = vec![CameraToWorld::identity(); 2];
        let r = [Some(5.0), Some(5.0)];
        assert_eq!(
            z_shifts(&ts, &poses, &r, &Ground::default(), 0.0, &ts),
            vec![None, None]
        );
        assert_eq!(
            z_shifts(&ts, &poses, &[None, None], &Ground::default(), 5.0, &ts),
            vec![None, None]
        );
    }
}
