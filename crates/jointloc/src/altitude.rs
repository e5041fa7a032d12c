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
use jointloc_geometry::Sim3;
use nalgebra::Point3;

/// The recent frames' SLAM camera centres and altimeter readings.
#[derive(Debug, Clone)]
pub struct AltitudeFilter {
    window_s: f64,
    ground: Ground,
    recent: VecDeque<(f64, Point3<f64>, f64)>,
}

impl AltitudeFilter {
    /// A filter over the last `window_s` seconds (0: off) above `ground`.
    pub fn new(window_s: f64, ground: Ground) -> Self {
        Self {
            window_s,
            ground,
            recent: VecDeque::new(),
        }
    }

    /// Forgets every frame (tracking lost: the SLAM frame may change).
    pub fn clear(&mut self) {
        self.recent.clear();
    }

    /// Records a tracked frame: its time, SLAM camera centre and altimeter reading.
    pub fn push(&mut self, timestamp: f64, slam_centre: Point3<f64>, altitude: f64) {
        if self.window_s <= 0.0 || !altitude.is_finite() {
            return;
        }
        self.recent.push_back((timestamp, slam_centre, altitude));
        while self
            .recent
            .front()
            .is_some_and(|&(t, _, _)| t < timestamp - self.window_s)
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
}
