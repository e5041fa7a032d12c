//! The true homography from a UAV frame to the map, for the matcher benchmark.
//!
//! The map is an orthographic image (map pixel `(u, v)` shows the terrain at world
//! `(u·gsd, −v·gsd)`, whatever its height); the frame is a perspective view of the same
//! terrain. Where the terrain is known ([`TerrainHeights`], e.g. the simulator's heightfield
//! regenerated from `sim.toml`), the true homography is the least-squares homography over a
//! grid of terrain points seen by the frame (exact correspondences, relief included).
//! Otherwise the ground is taken as the plane `z = camera z − altimeter reading` under the
//! camera, which errs by the altimeter noise and the relief.

use jointloc_absloc::tiles::Ground;
use jointloc_absloc::{AbslocError, Result};
use jointloc_geometry::homography::{dlt, refine_homography};
use jointloc_geometry::{CameraToWorld, PinholeCamera};
use nalgebra::{Matrix3, Point2, Point3, Vector3};

/// Terrain height at a world `(x, y)`.
pub trait TerrainHeights: Sync {
    /// Height (world z) at `(x, y)`, metres.
    fn height_at(&self, x: f64, y: f64) -> f64;
}

impl TerrainHeights for jointloc_sim::Terrain {
    fn height_at(&self, x: f64, y: f64) -> f64 {
        jointloc_sim::Terrain::height_at(self, x, y)
    }
}

impl TerrainHeights for Ground {
    fn height_at(&self, x: f64, y: f64) -> f64 {
        Ground::height_at(self, x, y)
    }
}

/// World `(x, y)` where the optical axis of `pose` meets `terrain`: what a fix measures (the
/// map point under the image centre). It differs from the camera's `(x, y)` by the height
/// times the tilt, 9 cm for 0.5° at 10 m. `None` when the axis does not point down or the
/// intersection does not settle.
pub fn optical_axis_ground_point(
    pose: &CameraToWorld,
    terrain: &dyn TerrainHeights,
) -> Option<(f64, f64)> {
    let c = pose.centre();
    let axis = pose.rotation() * Vector3::z();
    if axis.z > -1e-3 {
        return None;
    }
    // Range along the axis to the terrain: fixed point of d = (h(C + d·a) − C.z) / a.z, a
    // contraction for any slope under 1 / tan(tilt).
    let range = |d: f64| {
        let p = c + axis * d;
        (terrain.height_at(p.x, p.y) - c.z) / axis.z
    };
    let mut d = range(0.0);
    for _ in 0..50 {
        let next = range(d);
        if !next.is_finite() || next <= 0.0 {
            return None;
        }
        if (next - d).abs() < 1e-9 {
            let p = c + axis * next;
            return Some((p.x, p.y));
        }
        d = next;
    }
    None
}

/// The homography taking frame pixels to map pixels for ground plane `z = ground_z`.
pub fn plane_homography(
    pose: &CameraToWorld,
    camera: &PinholeCamera,
    gsd_m: f64,
    ground_z: f64,
) -> Option<Matrix3<f64>> {
    // Map pixel → world point on the plane: (u·g, −v·g, z0) = M (u, v, 1).
    let m = Matrix3::new(gsd_m, 0.0, 0.0, 0.0, -gsd_m, 0.0, 0.0, 0.0, ground_z);
    let w2c = pose.inverse();
    let r = w2c.rotation_matrix();
    let t = w2c.translation();
    // Camera point = R (M p) + t (p₃ = 1 for every map pixel) = (R M + t e₃ᵀ) p.
    let mut a = r * m;
    for i in 0..3 {
        a[(i, 2)] += t[i];
    }
    let h_img_from_map = camera.k() * a;
    let h = h_img_from_map.try_inverse()?;
    (h[(2, 2)].abs() > 1e-15).then(|| h / h[(2, 2)])
}

/// Best homography frame → map over the terrain points the frame sees: a `grid × grid` sample
/// of the plane-approximated footprint, each point lifted to the terrain, projected into the
/// frame and kept when inside it. `None` when too few points are visible.
pub fn terrain_homography(
    pose: &CameraToWorld,
    camera: &PinholeCamera,
    gsd_m: f64,
    terrain: &dyn TerrainHeights,
    grid: usize,
) -> Option<Matrix3<f64>> {
    let c = pose.centre();
    let z0 = terrain.height_at(c.x, c.y);
    let approx = plane_homography(pose, camera, gsd_m, z0)?;
    let (w, h) = (camera.width as f64, camera.height as f64);
    let w2c = pose.inverse();
    let (mut src, mut dst) = (Vec::new(), Vec::new());
    // Sample a little beyond the frame so the edges are constrained too.
    for i in 0..grid {
        for j in 0..grid {
            let fx = -0.05 * w + 1.1 * w * (i as f64 + 0.5) / grid as f64;
            let fy = -0.05 * h + 1.1 * h * (j as f64 + 0.5) / grid as f64;
            let q = approx * Point2::new(fx, fy).to_homogeneous();
            let (u, v) = (q.x / q.z, q.y / q.z);
            let (x, y) = (u * gsd_m, -v * gsd_m);
            let p = Point3::new(x, y, terrain.height_at(x, y));
            let pc = w2c.transform_point(&p);
            let Some(px) = camera.project(&pc) else {
                continue;
            };
            if px.x >= 0.0 && px.y >= 0.0 && px.x <= w - 1.0 && px.y <= h - 1.0 {
                src.push(px);
                dst.push(Point2::new(u, v));
            }
        }
    }
    if src.len() < 16 {
        return None;
    }
    let h0 = dlt(&src, &dst).ok()?;
    let idx: Vec<usize> = (0..src.len()).collect();
    let h = refine_homography(&h0, &src, &dst, &idx, 50).map_or(h0, |r| r.h);
    Some(h / h[(2, 2)])
}

/// Where the ground truth comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GroundTruthSource {
    /// The terrain heightfield.
    Terrain,
    /// A flat ground at camera z − altimeter.
    AltimeterPlane,
}

/// True homography frame → map for one frame.
pub fn true_homography(
    pose: &CameraToWorld,
    camera: &PinholeCamera,
    gsd_m: f64,
    terrain: Option<&dyn TerrainHeights>,
    altitude: Option<f64>,
) -> Result<(Matrix3<f64>, GroundTruthSource)> {
    if let Some(t) = terrain
        && let Some(h) = terrain_homography(pose, camera, gsd_m, t, 24)
    {
        return Ok((h, GroundTruthSource::Terrain));
    }
    let alt =
        altitude
            .filter(|a| a.is_finite() && *a > 0.0)
            .ok_or(AbslocError::InvalidAltitude {
                value: altitude.unwrap_or(f64::NAN),
            })?;
    let z0 = pose.centre().z - alt;
    let h =
        plane_homography(pose, camera, gsd_m, z0).ok_or_else(|| AbslocError::InvalidConfig {
            field: "ground truth",
            value: format!("{:?}", pose.centre()),
            reason: "the camera does not see the ground plane".into(),
        })?;
    Ok((h, GroundTruthSource::AltimeterPlane))
}

/// World `(x, y)` of frame pixel `(x, y)` through `h` (frame → map) at `gsd_m`.
pub fn frame_point_to_world(h: &Matrix3<f64>, gsd_m: f64, x: f64, y: f64) -> (f64, f64) {
    let q = h * Vector3::new(x, y, 1.0);
    (q.x / q.z * gsd_m, -q.y / q.z * gsd_m)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{UnitQuaternion, Vector3};

    /// Camera looking straight down (camera z = world −z), image up = world +y rotated by yaw.
    fn nadir(x: f64, y: f64, z: f64, yaw: f64) -> CameraToWorld {
        let down = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
        let turn = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw);
        CameraToWorld::from_rotation_translation(turn * down, Vector3::new(x, y, z))
    }

    struct Flat(f64);
    impl TerrainHeights for Flat {
        fn height_at(&self, _: f64, _: f64) -> f64 {
            self.0
        }
    }

    #[test]
    fn nadir_plane_homography_is_the_expected_similarity() {
        let cam = PinholeCamera::ideal(500.0, 500, 500);
        let pose = nadir(20.0, -15.0, 10.0, 0.0);
        let h = plane_homography(&pose, &cam, 0.05, 0.0).unwrap();
        // Image centre → map pixel under the camera.
        let (x, y) = frame_point_to_world(&h, 0.05, cam.cx, cam.cy);
        assert!(
            (x - 20.0).abs() < 1e-9 && (y + 15.0).abs() < 1e-9,
            "{x} {y}"
        );
        // Scale: 10 m / 500 px = 0.02 m per frame pixel = 0.4 map pixels.
        let j = jointloc_absloc::candidate::jacobian(&h, cam.cx, cam.cy).unwrap();
        assert!((j.determinant().sqrt() - 0.4).abs() < 1e-9);
        // The terrain fit on flat ground agrees.
        let t = terrain_homography(&pose, &cam, 0.05, &Flat(0.0), 16).unwrap();
        assert!(jointloc_geometry::homography::corner_error(&t, &h, 500, 500) < 1e-6);
    }

    #[test]
    fn heading_of_the_plane_homography_matches_the_pose() {
        let cam = PinholeCamera::ideal(500.0, 500, 500);
        for yaw in [0.0, 0.7, -2.0, 3.0] {
            let pose = nadir(5.0, -5.0, 12.0, yaw);
            let h = plane_homography(&pose, &cam, 0.1, 1.0).unwrap();
            let j = jointloc_absloc::candidate::jacobian(&h, cam.cx, cam.cy).unwrap();
            let got = jointloc_absloc::candidate::rotation_of(&j);
            let want =
                jointloc_absloc::heading_from_rotation(&pose.rotation().to_rotation_matrix());
            let d = (got - want + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
                - std::f64::consts::PI;
            assert!(d.abs() < 1e-9, "yaw {yaw}: {got} vs {want}");
        }
    }

    #[test]
    fn optical_axis_meets_the_terrain() {
        struct Slope;
        impl TerrainHeights for Slope {
            fn height_at(&self, x: f64, _: f64) -> f64 {
                0.3 * x
            }
        }
        // Nadir: straight below, on any terrain.
        let pose = nadir(4.0, -3.0, 10.0, 0.8);
        let (x, y) = optical_axis_ground_point(&pose, &Slope).unwrap();
        assert!((x - 4.0).abs() < 1e-9 && (y + 3.0).abs() < 1e-9, "{x} {y}");
        // Tilted 5° about the world x axis over flat ground: offset 10 m × tan 5° in y.
        let tilt = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 5f64.to_radians());
        let tilted = CameraToWorld::from_rotation_translation(
            tilt * pose.rotation(),
            Vector3::new(4.0, -3.0, 10.0),
        );
        let (x, y) = optical_axis_ground_point(&tilted, &Flat(0.0)).unwrap();
        let axis = tilted.rotation() * Vector3::z();
        let want = 10.0 * 5f64.to_radians().tan();
        assert!((x - 4.0).abs() < 1e-9, "{x}");
        assert!(((y + 3.0).abs() - want).abs() < 1e-9, "{y}");
        assert!((y + 3.0).signum() == axis.y.signum());
        // On the slope the point is on both the ray and the terrain.
        let (x, y) = optical_axis_ground_point(&tilted, &Slope).unwrap();
        let d = (0.3 * x - 10.0) / axis.z;
        assert!((4.0 + d * axis.x - x).abs() < 1e-6 && (-3.0 + d * axis.y - y).abs() < 1e-6);
        // Looking up: none.
        let up = CameraToWorld::from_rotation_translation(
            UnitQuaternion::identity(),
            Vector3::new(0.0, 0.0, 10.0),
        );
        assert_eq!(optical_axis_ground_point(&up, &Flat(0.0)), None);
    }

    #[test]
    fn altimeter_plane_and_errors() {
        let cam = PinholeCamera::ideal(500.0, 500, 500);
        let pose = nadir(0.0, 0.0, 11.0, 0.3);
        let (h, src) = true_homography(&pose, &cam, 0.05, None, Some(10.0)).unwrap();
        assert_eq!(src, GroundTruthSource::AltimeterPlane);
        let want = plane_homography(&pose, &cam, 0.05, 1.0).unwrap();
        assert!(jointloc_geometry::homography::corner_error(&h, &want, 500, 500) < 1e-9);
        assert!(true_homography(&pose, &cam, 0.05, None, None).is_err());
        assert!(true_homography(&pose, &cam, 0.05, None, Some(f64::NAN)).is_err());
        let (_, src) = true_homography(&pose, &cam, 0.05, Some(&Flat(1.0)), None).unwrap();
        assert_eq!(src, GroundTruthSource::Terrain);
    }
}
