//! Altimeter-aided height of the reported poses.
//!
//! The fixes give z only every k-th frame (DEM + altimeter at that frame, σ ≈ 0.1 m), so the
//! similarity's z translation carries the noise of the last few fixes. The altimeter, though,
//! measures every frame, and the SLAM's relative z is smooth: the reported z is shifted by the
//! mean, over the last `window_s` seconds of tracked frames, of `ground(x, y) + altimeter − z`
//! under the current alignment. This averages the altimeter over ~25 frames instead of ~2
//! fixes, and only moves z: x, y and the attitude stay as the alignment gives them.

use std::collections::VecDeque;

use jointloc_absloc::Ground;
use jointloc_geometry::{CameraToWorld, Sim3};
use nalgebra::Point3;

/// The recent frames' SLAM camera centres and altimeter readings.
#[derive(Debug, Clone)]
pub struct AltitudeFilter {
    base_window_s: f64,
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
            scale: 1.0,
            ground,
            recent: VecDeque::new(),
        }
    }

    /// The elevation model the heights are taken above.
    pub fn ground(&self) -> &Ground {
        &self.ground
    }

    /// Seconds of frames the estimate averages over (0: off).
    pub fn window_s(&self) -> f64 {
        self.scaled(self.base_window_s)
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
    pub fn z_offset(&self, slam_to_world: &Sim3) -> Option<f64> {
        if self.recent.is_empty() {
            return None;
        }
        let sum: f64 = self
            .recent
            .iter()
            .map(|(_, c, altitude)| {
                let p = slam_to_world.transform_point(c);
                self.ground.height_at(p.x, p.y) + altitude - p.z
            })
            .sum();
        Some(sum / self.recent.len() as f64)
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
