//! Pinhole camera with optional radial-tangential (Brown-Conrady / OpenCV `plumb_bob`)
//! distortion, as written in ORB-SLAM style `camera.yaml` files.
//!
//! Camera frame: x right, y down, z forward (OpenCV). Pixel centres are at integer
//! coordinates, so the pixel `(0, 0)` covers `[-0.5, 0.5]²`.

use nalgebra::{Matrix2, Matrix2x3, Matrix3, Point2, Point3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

/// Radial-tangential distortion coefficients `k1, k2, p1, p2, k3` (OpenCV order).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct RadTan {
    pub k1: f64,
    pub k2: f64,
    pub p1: f64,
    pub p2: f64,
    pub k3: f64,
}

impl RadTan {
    /// True when every coefficient is zero.
    pub fn is_zero(&self) -> bool {
        [self.k1, self.k2, self.p1, self.p2, self.k3]
            .iter()
            .all(|&c| c == 0.0)
    }

    /// Distorts normalised image coordinates; also returns the 2×2 Jacobian.
    pub fn distort(&self, x: &Vector2<f64>) -> (Vector2<f64>, Matrix2<f64>) {
        let (u, v) = (x.x, x.y);
        let r2 = u * u + v * v;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let d_radial_d_r2 = self.k1 + r2 * (2.0 * self.k2 + 3.0 * r2 * self.k3);
        let du = u * radial + 2.0 * self.p1 * u * v + self.p2 * (r2 + 2.0 * u * u);
        let dv = v * radial + self.p1 * (r2 + 2.0 * v * v) + 2.0 * self.p2 * u * v;
        let j = Matrix2::new(
            radial + 2.0 * u * u * d_radial_d_r2 + 2.0 * self.p1 * v + 6.0 * self.p2 * u,
            2.0 * u * v * d_radial_d_r2 + 2.0 * self.p1 * u + 2.0 * self.p2 * v,
            2.0 * u * v * d_radial_d_r2 + 2.0 * self.p1 * u + 2.0 * self.p2 * v,
            radial + 2.0 * v * v * d_radial_d_r2 + 6.0 * self.p1 * v + 2.0 * self.p2 * u,
        );
        (Vector2::new(du, dv), j)
    }

    /// Inverts [`RadTan::distort`] by Gauss-Newton; `None` if it does not converge.
    pub fn undistort(&self, xd: &Vector2<f64>) -> Option<Vector2<f64>> {
        let mut x = *xd;
        for _ in 0..30 {
            let (d, j) = self.distort(&x);
            let r = d - xd;
            if r.norm() < 1e-13 {
                return Some(x);
            }
            x -= j.try_inverse()? * r;
        }
        (self.distort(&x).0 - xd).norm().lt(&1e-9).then_some(x)
    }
}

/// A pinhole camera with image size and optional distortion.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PinholeCamera {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Lens distortion; `None` for an ideal pinhole.
    pub distortion: Option<RadTan>,
}

impl PinholeCamera {
    /// An ideal pinhole with the principal point at the image centre.
    pub fn ideal(f: f64, width: u32, height: u32) -> Self {
        Self {
            fx: f,
            fy: f,
            cx: (width as f64 - 1.0) / 2.0,
            cy: (height as f64 - 1.0) / 2.0,
            width,
            height,
            distortion: None,
        }
    }

    /// The intrinsic matrix `K`.
    pub fn k(&self) -> Matrix3<f64> {
        Matrix3::new(self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)
    }

    /// Projects a point in the camera frame; `None` behind or on the image plane.
    pub fn project(&self, p: &Point3<f64>) -> Option<Point2<f64>> {
        self.project_with_jacobian(p).map(|(uv, _)| uv)
    }

    /// Projects a camera-frame point and returns `∂(u, v)/∂(x, y, z)`.
    pub fn project_with_jacobian(&self, p: &Point3<f64>) -> Option<(Point2<f64>, Matrix2x3<f64>)> {
        if p.z <= f64::EPSILON || !p.coords.iter().all(|c| c.is_finite()) {
            return None;
        }
        let iz = 1.0 / p.z;
        let xn = Vector2::new(p.x * iz, p.y * iz);
        // ∂xn/∂p
        let dn = Matrix2x3::new(iz, 0.0, -p.x * iz * iz, 0.0, iz, -p.y * iz * iz);
        let (xd, dd) = match &self.distortion {
            Some(d) if !d.is_zero() => d.distort(&xn),
            _ => (xn, Matrix2::identity()),
        };
        let f = Matrix2::new(self.fx, 0.0, 0.0, self.fy);
        let uv = Point2::new(self.fx * xd.x + self.cx, self.fy * xd.y + self.cy);
        Some((uv, f * dd * dn))
    }

    /// Back-projects a pixel to the point on the `z = 1` plane of the camera frame.
    /// `None` when the distortion cannot be inverted there.
    pub fn unproject(&self, uv: &Point2<f64>) -> Option<Vector3<f64>> {
        let xd = Vector2::new((uv.x - self.cx) / self.fx, (uv.y - self.cy) / self.fy);
        let xn = match &self.distortion {
            Some(d) if !d.is_zero() => d.undistort(&xd)?,
            _ => xd,
        };
        Some(Vector3::new(xn.x, xn.y, 1.0))
    }

    /// True when the pixel lies inside the image (with a margin in pixels).
    pub fn contains(&self, uv: &Point2<f64>, margin: f64) -> bool {
        uv.x >= -0.5 + margin
            && uv.y >= -0.5 + margin
            && uv.x <= self.width as f64 - 0.5 - margin
            && uv.y <= self.height as f64 - 0.5 - margin
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn distorted() -> PinholeCamera {
        PinholeCamera {
            distortion: Some(RadTan {
                k1: -0.28,
                k2: 0.07,
                p1: 2e-4,
                p2: -1.5e-4,
                k3: 0.01,
            }),
            ..PinholeCamera::ideal(500.0, 500, 500)
        }
    }

    #[test]
    fn projection_jacobian_matches_central_differences() {
        for cam in [PinholeCamera::ideal(500.0, 500, 500), distorted()] {
            for p in [
                Point3::new(0.3, -0.2, 2.0),
                Point3::new(-1.1, 0.9, 3.5),
                Point3::new(0.0, 0.0, 1.0),
            ] {
                let (_, j) = cam.project_with_jacobian(&p).unwrap();
                for k in 0..3 {
                    let h = 1e-6;
                    let (mut pp, mut pm) = (p, p);
                    pp[k] += h;
                    pm[k] -= h;
                    let num = (cam.project(&pp).unwrap() - cam.project(&pm).unwrap()) / (2.0 * h);
                    let ana = j.column(k);
                    let rel = (num - ana).norm() / ana.norm().max(1.0);
                    assert!(rel < 1e-6, "column {k}: {num} vs {ana}");
                }
            }
        }
    }

    #[test]
    fn unproject_inverts_project() {
        let cam = distorted();
        for p in [Point3::new(0.3, -0.2, 2.0), Point3::new(-0.4, 0.35, 1.0)] {
            let uv = cam.project(&p).unwrap();
            let ray = cam.unproject(&uv).unwrap();
            assert!((ray - p.coords / p.z).norm() < 1e-10);
        }
    }

    #[test]
    fn behind_camera_is_not_projected() {
        let cam = PinholeCamera::ideal(500.0, 500, 500);
        assert!(cam.project(&Point3::new(0.0, 0.0, -1.0)).is_none());
        assert!(cam.project(&Point3::new(f64::NAN, 0.0, 1.0)).is_none());
    }
}
