//! The take-off position as a check on the geo-reference of the flight's first map.
//!
//! With `--start` the user says where the flight began. Every alignment of the first map,
//! and a one-fix similarity that steers the searches before the first one, must put the
//! SLAM's take-off near that place. Under a sun reversed from the map's the correlation of a
//! virtual frame finds weak placements with the view turned about half a turn (a crater lit
//! from the east, turned, looks like one lit from the west); searched around each other,
//! such fixes agree among themselves and with the SLAM's path, and only an outside reference
//! shows them wrong (`docs/jointloc.md` §"The take-off checks the first alignment").
//!
//! The SLAM's first tracked frame comes a moment after the flight's first frame (seconds at
//! altitude, where the SLAM needs parallax to start), so the take-off is that frame carried
//! back along the SLAM's velocity over its first second.

use jointloc_geometry::Sim3;
use jointloc_slam::map::{KeyFrameId, Map};
use nalgebra::{Isometry3, Point3};

/// Seconds of tracking after the first tracked frame over which the velocity that carries it
/// back to the take-off is measured.
pub(crate) const VELOCITY_SPAN_S: f64 = 1.0;

/// Allowance for the alignment's tilt, as a fraction of the range at the first tracked frame:
/// the take-off is a camera position, the fixes measure ground points, and an alignment
/// tilted by δ moves a camera h above the ground by h·δ. At 200 m a first alignment's 2°
/// (7 m) was seen on right fixes; 0.05 allows 3°.
pub(crate) const TILT_ALLOWANCE: f64 = 0.05;

/// A tracked frame's SLAM centre, tied to the keyframe current then so that it follows the
/// keyframe when the BA moves it.
#[derive(Debug, Clone)]
struct Anchor {
    keyframe: KeyFrameId,
    centre_in_kf: Point3<f64>,
    /// Last known SLAM position (kept when the keyframe is culled).
    slam: Point3<f64>,
    timestamp: f64,
}

impl Anchor {
    /// A frame's SLAM centre `centre` at `timestamp`, tied to `keyframe` (world-to-camera
    /// pose `t_cw`).
    fn new(
        timestamp: f64,
        keyframe: KeyFrameId,
        t_cw: &Isometry3<f64>,
        centre: Point3<f64>,
    ) -> Self {
        Self {
            keyframe,
            centre_in_kf: t_cw.transform_point(&centre),
            slam: centre,
            timestamp,
        }
    }

    fn refresh(&mut self, map: &Map) {
        if map.keyframe(self.keyframe).is_none()
            && let Some(kf) = map
                .keyframes()
                .min_by(|a, b| a.timestamp.total_cmp(&b.timestamp))
        {
            self.keyframe = kf.id;
            self.centre_in_kf = kf.pose.0.transform_point(&self.slam);
        }
        if let Some(kf) = map.keyframe(self.keyframe) {
            self.slam = kf.pose.0.inverse_transform_point(&self.centre_in_kf);
        }
    }
}

/// Where the flight took off, in the SLAM frame of its first map.
#[derive(Debug, Clone)]
pub(crate) struct TakeOff {
    /// Time of the flight's first frame.
    first_frame_s: f64,
    /// The altimeter's range at the first tracked frame, metres (0 without a reading).
    range_m: f64,
    /// The first tracked frame.
    first: Anchor,
    /// A frame at least [`VELOCITY_SPAN_S`] after it.
    later: Option<Anchor>,
}

impl TakeOff {
    /// The first tracked frame (SLAM centre `centre` at `timestamp`, `range_m` above the
    /// ground, with `keyframe` and its world-to-camera pose `t_cw` current) of a flight whose
    /// first frame came at `first_frame_s`.
    pub(crate) fn new(
        first_frame_s: f64,
        timestamp: f64,
        range_m: f64,
        keyframe: KeyFrameId,
        t_cw: &Isometry3<f64>,
        centre: Point3<f64>,
    ) -> Self {
        Self {
            first_frame_s,
            range_m,
            first: Anchor::new(timestamp, keyframe, t_cw, centre),
            later: None,
        }
    }

    /// A later tracked frame: kept as the velocity's second point once it is
    /// [`VELOCITY_SPAN_S`] after the first.
    pub(crate) fn observe(
        &mut self,
        timestamp: f64,
        keyframe: KeyFrameId,
        t_cw: &Isometry3<f64>,
        centre: Point3<f64>,
    ) {
        if self.later.is_none() && timestamp - self.first.timestamp >= VELOCITY_SPAN_S {
            self.later = Some(Anchor::new(timestamp, keyframe, t_cw, centre));
        }
    }

    /// The altimeter's range at the first tracked frame, metres.
    pub(crate) fn range_m(&self) -> f64 {
        self.range_m
    }

    /// Whether the velocity's second point is still to come.
    pub(crate) fn needs_later(&self) -> bool {
        self.later.is_none()
    }

    /// The anchors from their keyframes' current poses. When a keyframe was culled, its anchor
    /// moves to the map's oldest keyframe, its last known position kept.
    pub(crate) fn refresh(&mut self, map: &Map) {
        self.first.refresh(map);
        if let Some(l) = &mut self.later {
            l.refresh(map);
        }
    }

    /// The take-off in the SLAM frame and how far it was carried back from the first tracked
    /// frame (SLAM units); `None` until the velocity is known, when the first tracked frame
    /// came after the first frame.
    pub(crate) fn slam(&self) -> Option<(Point3<f64>, f64)> {
        let lead = self.first.timestamp - self.first_frame_s;
        if lead <= 0.0 {
            return Some((self.first.slam, 0.0));
        }
        let later = self.later.as_ref()?;
        let dt = later.timestamp - self.first.timestamp;
        let back = (later.slam - self.first.slam) * (lead / dt);
        Some((self.first.slam - back, back.norm()))
    }
}

/// How far (horizontally, metres) `s` puts the take-off's SLAM position `slam` from the
/// take-off position `start`.
pub(crate) fn miss_m(s: &Sim3, slam: &Point3<f64>, start: [f64; 2]) -> f64 {
    let p = s.transform_point(slam);
    (p.x - start[0]).hypot(p.y - start[1])
}

/// The largest miss accepted, metres: the take-off's own uncertainty `radius_m`, a fifth of
/// the `carried_m` it was carried back along the first second's velocity (the UAV may have
/// sped up or turned meanwhile), [`TILT_ALLOWANCE`] of the `range_m`, and the SLAM's drift
/// (`drift`, a fraction) over the `distance_m` from the take-off to the fixes.
pub(crate) fn tolerance_m(
    radius_m: f64,
    carried_m: f64,
    range_m: f64,
    drift: f64,
    distance_m: f64,
) -> f64 {
    radius_m + 0.2 * carried_m + TILT_ALLOWANCE * range_m + drift * distance_m
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{UnitQuaternion, Vector3};

    #[test]
    fn the_take_off_is_the_first_tracked_frame_carried_back_along_the_velocity() {
        let t_cw = Isometry3::identity();
        // Tracked from 4 s at 3 m/s along x; the flight began at 0 s.
        let mut t = TakeOff::new(
            0.0,
            4.0,
            10.0,
            KeyFrameId(1),
            &t_cw,
            Point3::new(12.0, 0.0, 0.0),
        );
        assert!(t.slam().is_none(), "no velocity yet");
        t.observe(4.5, KeyFrameId(1), &t_cw, Point3::new(13.5, 0.0, 0.0));
        assert!(t.needs_later());
        t.observe(5.0, KeyFrameId(1), &t_cw, Point3::new(15.0, 0.0, 0.0));
        let (p, carried) = t.slam().unwrap();
        assert!((p - Point3::origin()).norm() < 1e-9, "{p}");
        assert!((carried - 12.0).abs() < 1e-9);
        // Tracked from the first frame: no carrying back.
        let t = TakeOff::new(
            2.0,
            2.0,
            10.0,
            KeyFrameId(1),
            &t_cw,
            Point3::new(1.0, 2.0, 3.0),
        );
        assert_eq!(t.slam(), Some((Point3::new(1.0, 2.0, 3.0), 0.0)));
    }

    #[test]
    fn the_miss_is_horizontal_and_the_tolerance_grows_with_distance() {
        let s = Sim3 {
            scale: 2.0,
            rotation: UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2),
            translation: Vector3::new(10.0, 0.0, 50.0),
        };
        // (1, 0, 0) → (10, 2, 50): 2 m from (10, 0) whatever the height.
        let m = miss_m(&s, &Point3::new(1.0, 0.0, 0.0), [10.0, 0.0]);
        assert!((m - 2.0).abs() < 1e-9, "{m}");
        assert_eq!(tolerance_m(5.0, 0.0, 0.0, 0.05, 0.0), 5.0);
        assert!((tolerance_m(5.0, 10.0, 200.0, 0.05, 200.0) - 27.0).abs() < 1e-9);
    }
}
