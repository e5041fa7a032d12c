//! The UAV camera: a pinhole projection with an optional lens model, either radial-tangential
//! (Brown-Conrady / OpenCV `plumb_bob`, ORB-SLAM2's `Camera.k1..p2`) or the equidistant
//! Kannala-Brandt fisheye (OpenCV `fisheye`, ORB-SLAM3's `KannalaBrandt8`).
//!
//! Camera frame: x right, y down, z forward (OpenCV). Pixel centres are at integer
//! coordinates, so the pixel `(0, 0)` covers `[-0.5, 0.5]²`.
//!
//! Both lens models map the normalised coordinates `x/z, y/z` of a point in front of the camera
//! to distorted normalised coordinates, then `u = fx·x_d + cx`. So [`PinholeCamera::project`]
//! covers the half-space `z > 0` (off-axis angles below 90°) and [`PinholeCamera::unproject`]
//! returns a point on the `z = 1` plane: a fisheye pixel at or beyond 90° off axis has no such
//! point and unprojects to `None`, never to NaN.

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

/// Equidistant Kannala-Brandt fisheye coefficients: a ray at angle `θ` off the optical axis
/// lands at normalised radius `θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)` (OpenCV
/// `cv::fisheye`, ORB-SLAM3 `KannalaBrandt8`). All zero is the pure equidistant lens.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct KannalaBrandt {
    pub k1: f64,
    pub k2: f64,
    pub k3: f64,
    pub k4: f64,
}

impl KannalaBrandt {
    /// `θ_d(θ)` and `dθ_d/dθ`.
    pub fn theta_d(&self, theta: f64) -> (f64, f64) {
        let t2 = theta * theta;
        let poly = 1.0 + t2 * (self.k1 + t2 * (self.k2 + t2 * (self.k3 + t2 * self.k4)));
        let dpoly = 1.0
            + t2 * (3.0 * self.k1
                + t2 * (5.0 * self.k2 + t2 * (7.0 * self.k3 + t2 * 9.0 * self.k4)));
        (theta * poly, dpoly)
    }

    /// Distorts normalised image coordinates `(x/z, y/z)`; also returns the 2×2 Jacobian.
    /// `None` where `θ_d` is not increasing (the polynomial folds back: no unique inverse).
    pub fn distort(&self, x: &Vector2<f64>) -> Option<(Vector2<f64>, Matrix2<f64>)> {
        let r = x.norm();
        if !r.is_finite() {
            return None;
        }
        if r < 1e-9 {
            // θ_d / r = 1 + O(r²): the identity to first order.
            return Some((*x, Matrix2::identity()));
        }
        let theta = r.atan();
        let (td, dtd) = self.theta_d(theta);
        if dtd <= 0.0 {
            return None;
        }
        let s = td / r;
        // ds/dr with dθ/dr = 1 / (1 + r²).
        let ds = (dtd / (1.0 + r * r) * r - td) / (r * r);
        let j = Matrix2::identity() * s + x * x.transpose() * (ds / r);
        Some((x * s, j))
    }

    /// Inverts `θ_d(θ)` by Newton's method on `[0, π/2)`; `None` at or beyond 90° off axis,
    /// where the polynomial is not increasing, or if it does not converge.
    pub fn undistort_angle(&self, theta_d: f64) -> Option<f64> {
        if !(theta_d.is_finite() && theta_d >= 0.0) {
            return None;
        }
        let half_pi = std::f64::consts::FRAC_PI_2;
        let mut theta = theta_d.min(half_pi);
        for _ in 0..50 {
            let (td, dtd) = self.theta_d(theta);
            if dtd <= 0.0 {
                return None;
            }
            let step = (td - theta_d) / dtd;
            theta = (theta - step).clamp(0.0, half_pi);
            if step.abs() < 1e-15 * theta.max(1.0) {
                break;
            }
        }
        let (td, dtd) = self.theta_d(theta);
        ((td - theta_d).abs() < 1e-10 && dtd > 0.0 && theta < half_pi - 1e-9).then_some(theta)
    }

    /// Inverts [`KannalaBrandt::distort`]; `None` at or beyond 90° off axis.
    pub fn undistort(&self, xd: &Vector2<f64>) -> Option<Vector2<f64>> {
        let td = xd.norm();
        if td < 1e-12 {
            return xd.iter().all(|c| c.is_finite()).then_some(*xd);
        }
        let theta = self.undistort_angle(td)?;
        Some(xd * (theta.tan() / td))
    }
}

/// The lens model of a [`PinholeCamera`]. Serialised with a `model` key (`rad_tan` or
/// `kannala_brandt`); a table without one is read as radial-tangential, the only model of
/// files written before the fisheye existed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "snake_case")]
#[serde(try_from = "DistortionFile")]
pub enum Distortion {
    /// Radial-tangential (OpenCV `plumb_bob`).
    RadTan(RadTan),
    /// Equidistant Kannala-Brandt fisheye.
    KannalaBrandt(KannalaBrandt),
}

/// What a `[distortion]` table may hold: a tagged model, or the untagged radial-tangential
/// coefficients of older files (unknown keys refused, so a misspelt `model` is an error, not
/// a silent zero distortion).
#[derive(Deserialize)]
#[serde(untagged)]
enum DistortionFile {
    Tagged(TaggedDistortion),
    Legacy(LegacyRadTan),
}

#[derive(Deserialize)]
#[serde(tag = "model", rename_all = "snake_case")]
enum TaggedDistortion {
    RadTan(RadTan),
    KannalaBrandt(KannalaBrandt),
}

#[derive(Deserialize)]
#[serde(default, deny_unknown_fields)]
#[derive(Default)]
struct LegacyRadTan {
    k1: f64,
    k2: f64,
    p1: f64,
    p2: f64,
    k3: f64,
}

impl TryFrom<DistortionFile> for Distortion {
    type Error = String;

    fn try_from(d: DistortionFile) -> Result<Self, Self::Error> {
        Ok(match d {
            DistortionFile::Tagged(TaggedDistortion::RadTan(r)) => Self::RadTan(r),
            DistortionFile::Tagged(TaggedDistortion::KannalaBrandt(k)) => Self::KannalaBrandt(k),
            DistortionFile::Legacy(LegacyRadTan { k1, k2, p1, p2, k3 }) => {
                Self::RadTan(RadTan { k1, k2, p1, p2, k3 })
            }
        })
    }
}

impl From<RadTan> for Distortion {
    fn from(d: RadTan) -> Self {
        Self::RadTan(d)
    }
}

impl From<KannalaBrandt> for Distortion {
    fn from(d: KannalaBrandt) -> Self {
        Self::KannalaBrandt(d)
    }
}

impl Distortion {
    /// True when the model is the identity (a radial-tangential model with zero
    /// coefficients). A Kannala-Brandt lens is never the identity: with zero coefficients it
    /// is the equidistant fisheye.
    pub fn is_identity(&self) -> bool {
        match self {
            Self::RadTan(d) => d.is_zero(),
            Self::KannalaBrandt(_) => false,
        }
    }

    /// The coefficients, in the model's order (`k1, k2, p1, p2, k3` or `k1..k4`).
    pub fn coefficients(&self) -> Vec<f64> {
        match self {
            Self::RadTan(d) => vec![d.k1, d.k2, d.p1, d.p2, d.k3],
            Self::KannalaBrandt(d) => vec![d.k1, d.k2, d.k3, d.k4],
        }
    }

    /// Distorts normalised coordinates, with the Jacobian; `None` where the model is invalid.
    pub fn distort(&self, x: &Vector2<f64>) -> Option<(Vector2<f64>, Matrix2<f64>)> {
        match self {
            Self::RadTan(d) => Some(d.distort(x)),
            Self::KannalaBrandt(d) => d.distort(x),
        }
    }

    /// Inverts [`Distortion::distort`]; `None` where it cannot be inverted.
    pub fn undistort(&self, xd: &Vector2<f64>) -> Option<Vector2<f64>> {
        match self {
            Self::RadTan(d) => d.undistort(xd),
            Self::KannalaBrandt(d) => d.undistort(xd),
        }
    }
}

/// A pinhole camera with image size and optional lens distortion.
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
    pub distortion: Option<Distortion>,
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

    /// A Kannala-Brandt fisheye whose horizontal field of view is `fov_deg` across the image
    /// width (edge to edge: `θ_d(fov/2) · f = width / 2`), square pixels, principal point at
    /// the image centre. `None` unless `0 < fov_deg < 180` and `θ_d` increases up to fov/2.
    pub fn fisheye(fov_deg: f64, width: u32, height: u32, lens: KannalaBrandt) -> Option<Self> {
        if !(fov_deg > 0.0 && fov_deg < 180.0) || width == 0 {
            return None;
        }
        let half = (fov_deg / 2.0).to_radians();
        let (td, dtd) = lens.theta_d(half);
        if !(td > 0.0 && dtd > 0.0) {
            return None;
        }
        let f = width as f64 / 2.0 / td;
        Some(Self {
            distortion: Some(Distortion::KannalaBrandt(lens)),
            ..Self::ideal(f, width, height)
        })
    }

    /// Horizontal field of view in degrees, edge to edge through the principal point's row;
    /// `None` where an edge pixel's ray is at or beyond 90° from the axis.
    pub fn horizontal_fov_deg(&self) -> Option<f64> {
        let left = self.off_axis_angle(&Point2::new(-0.5, self.cy))?;
        let right = self.off_axis_angle(&Point2::new(self.width as f64 - 0.5, self.cy))?;
        Some((left + right).to_degrees())
    }

    /// True when the camera has a lens model other than the identity.
    pub fn has_distortion(&self) -> bool {
        self.distortion.is_some_and(|d| !d.is_identity())
    }

    /// The same intrinsics without distortion (the camera of undistorted pixels).
    pub fn without_distortion(&self) -> Self {
        Self {
            distortion: None,
            ..*self
        }
    }

    /// The intrinsic matrix `K`.
    pub fn k(&self) -> Matrix3<f64> {
        Matrix3::new(self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)
    }

    /// Projects a point in the camera frame; `None` behind or on the image plane (a fisheye
    /// included: its projection covers off-axis angles below 90°).
    pub fn project(&self, p: &Point3<f64>) -> Option<Point2<f64>> {
        self.project_with_jacobian(p).map(|(uv, _)| uv)
    }

    /// Distorts normalised coordinates `(x/z, y/z)` into pixels; `None` where the lens model
    /// is invalid (a Kannala-Brandt polynomial folding back).
    pub fn distort_to_pixel(&self, xn: &Vector2<f64>) -> Option<Point2<f64>> {
        let xd = match &self.distortion {
            Some(d) if !d.is_identity() => d.distort(xn)?.0,
            _ => *xn,
        };
        Some(Point2::new(
            self.fx * xd.x + self.cx,
            self.fy * xd.y + self.cy,
        ))
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
            Some(d) if !d.is_identity() => d.distort(&xn)?,
            _ => (xn, Matrix2::identity()),
        };
        let f = Matrix2::new(self.fx, 0.0, 0.0, self.fy);
        let uv = Point2::new(self.fx * xd.x + self.cx, self.fy * xd.y + self.cy);
        Some((uv, f * dd * dn))
    }

    /// Back-projects a pixel to the point on the `z = 1` plane of the camera frame.
    /// `None` when the distortion cannot be inverted there (for a fisheye: at or beyond 90°
    /// off axis).
    pub fn unproject(&self, uv: &Point2<f64>) -> Option<Vector3<f64>> {
        let xd = Vector2::new((uv.x - self.cx) / self.fx, (uv.y - self.cy) / self.fy);
        if !xd.iter().all(|c| c.is_finite()) {
            return None;
        }
        let xn = match &self.distortion {
            Some(d) if !d.is_identity() => d.undistort(&xd)?,
            _ => xd,
        };
        Some(Vector3::new(xn.x, xn.y, 1.0))
    }

    /// Angle between the optical axis and the ray through a pixel, radians; `None` where the
    /// pixel does not unproject.
    pub fn off_axis_angle(&self, uv: &Point2<f64>) -> Option<f64> {
        self.unproject(uv).map(|r| r.xy().norm().atan())
    }

    /// Bounds `[min_u, min_v, max_u, max_v]` of the image's pixels once undistorted (in the
    /// pixels of [`Self::without_distortion`]), rays further than `max_off_axis` radians from the
    /// axis being pulled in to that angle: ORB-SLAM2's `mnMinX..mnMaxY`, made finite for a
    /// fisheye whose border reaches 90° and beyond. The border is sampled at every pixel.
    pub fn undistorted_bounds(&self, max_off_axis: f64) -> [f64; 4] {
        let max_tan = max_off_axis.clamp(0.0, 89f64.to_radians()).tan();
        let (w, h) = (self.width as f64, self.height as f64);
        let mut b = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        let border = (0..=self.width)
            .flat_map(|u| [(u as f64 - 0.5, -0.5), (u as f64 - 0.5, h - 0.5)])
            .chain(
                (0..=self.height).flat_map(|v| [(-0.5, v as f64 - 0.5), (w - 0.5, v as f64 - 0.5)]),
            );
        for (u, v) in border {
            let uv = Point2::new(u, v);
            let xd = Vector2::new((u - self.cx) / self.fx, (v - self.cy) / self.fy);
            let xn = match self.unproject(&uv) {
                Some(r) if r.xy().norm() <= max_tan => r.xy(),
                _ if xd.norm() > 0.0 => xd.normalize() * max_tan,
                _ => continue,
            };
            let (pu, pv) = (self.fx * xn.x + self.cx, self.fy * xn.y + self.cy);
            b = [b[0].min(pu), b[1].min(pv), b[2].max(pu), b[3].max(pv)];
        }
        b
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

    #[test]
    fn distortion_tables_with_and_without_a_model_key() {
        let read = |t: &str| toml::from_str::<Distortion>(t);
        assert_eq!(
            read("k1 = -0.2\np2 = 0.001").unwrap(),
            Distortion::RadTan(RadTan {
                k1: -0.2,
                p2: 0.001,
                ..RadTan::default()
            })
        );
        assert!(matches!(
            read("model = \"kannala_brandt\"\nk1 = 0.01").unwrap(),
            Distortion::KannalaBrandt(k) if k.k1 == 0.01
        ));
        assert!(read("model = \"rad_tan\"\nk1 = 0.1").is_ok());
        assert!(read("model = \"fisheye\"\nk1 = 0.1").is_err());
        assert!(read("k9 = 0.1").is_err());
        let kb = Distortion::KannalaBrandt(KannalaBrandt::default());
        assert_eq!(read(&toml::to_string(&kb).unwrap()).unwrap(), kb);
    }

    fn distorted() -> PinholeCamera {
        PinholeCamera {
            distortion: Some(
                RadTan {
                    k1: -0.28,
                    k2: 0.07,
                    p1: 2e-4,
                    p2: -1.5e-4,
                    k3: 0.01,
                }
                .into(),
            ),
            ..PinholeCamera::ideal(500.0, 500, 500)
        }
    }

    /// TUM-VI's cam0 Kannala-Brandt coefficients (as in ORB-SLAM3's `TUM-VI.yaml`).
    fn tum_vi() -> KannalaBrandt {
        KannalaBrandt {
            k1: 0.0034823894022493434,
            k2: 0.0007150348452162257,
            k3: -0.0020532361418706202,
            k4: 0.00020293673591811182,
        }
    }

    fn fisheyes() -> Vec<PinholeCamera> {
        vec![
            PinholeCamera::fisheye(133.0, 500, 500, KannalaBrandt::default()).unwrap(),
            PinholeCamera::fisheye(133.0, 640, 480, tum_vi()).unwrap(),
            PinholeCamera {
                fy: 230.0,
                cx: 240.2,
                ..PinholeCamera::fisheye(170.0, 500, 400, tum_vi()).unwrap()
            },
        ]
    }

    #[test]
    fn projection_jacobian_matches_central_differences() {
        let mut cams = vec![PinholeCamera::ideal(500.0, 500, 500), distorted()];
        cams.extend(fisheyes());
        for cam in cams {
            for p in [
                Point3::new(0.3, -0.2, 2.0),
                Point3::new(-1.1, 0.9, 3.5),
                Point3::new(0.0, 0.0, 1.0),
                Point3::new(1e-12, -2e-12, 1.0),
                Point3::new(4.0, -3.0, 1.0),
                Point3::new(-20.0, 5.0, 1.0),
            ] {
                let Some((_, j)) = cam.project_with_jacobian(&p) else {
                    // Only the radial-tangential model folds over far off axis.
                    assert!(matches!(cam.distortion, Some(Distortion::RadTan(_))), "{p}");
                    continue;
                };
                for k in 0..3 {
                    let h = 1e-6 * p.coords.norm();
                    let (mut pp, mut pm) = (p, p);
                    pp[k] += h;
                    pm[k] -= h;
                    let num = (cam.project(&pp).unwrap() - cam.project(&pm).unwrap()) / (2.0 * h);
                    let ana = j.column(k);
                    let rel = (num - ana).norm() / ana.norm().max(1.0);
                    assert!(rel < 1e-6, "{cam:?} {p} column {k}: {num} vs {ana}");
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
    fn fisheye_round_trips_up_to_the_edge_of_its_field_of_view() {
        for cam in fisheyes() {
            // Every pixel of the image that lies within 89.9° of the axis.
            let mut n = 0;
            for v in (0..cam.height).step_by(7).chain([cam.height - 1]) {
                for u in (0..cam.width).step_by(7).chain([cam.width - 1]) {
                    let uv = Point2::new(u as f64, v as f64);
                    let Some(ray) = cam.unproject(&uv) else {
                        let xd = Vector2::new((uv.x - cam.cx) / cam.fx, (uv.y - cam.cy) / cam.fy);
                        let Some(Distortion::KannalaBrandt(kb)) = cam.distortion else {
                            unreachable!()
                        };
                        assert!(kb.theta_d(std::f64::consts::FRAC_PI_2).0 <= xd.norm() + 1e-9);
                        continue;
                    };
                    assert!(ray.iter().all(|c| c.is_finite()));
                    let back = cam.project(&Point3::from(ray)).unwrap();
                    assert!((back - uv).norm() < 1e-6, "{uv} -> {ray} -> {back}");
                    n += 1;
                }
            }
            assert!(n > 1000);
            // Angles up to the edge of the field of view and just short of 90°.
            for deg in [0.0, 1e-6, 10.0, 45.0, 66.5, 80.0, 89.0, 89.99] {
                let t = f64::to_radians(deg);
                for phi in [0.0, 0.7, 2.0, 4.0] {
                    let p = Point3::new(t.sin() * f64::cos(phi), t.sin() * f64::sin(phi), t.cos());
                    let uv = cam.project(&p).unwrap();
                    let ray = cam.unproject(&uv).unwrap();
                    let angle = ray.cross(&p.coords).norm().atan2(ray.dot(&p.coords));
                    assert!(angle < 1e-9, "{deg}° {phi}: {angle}");
                    let off = cam.off_axis_angle(&uv).unwrap();
                    assert!((off - t).abs() < 1e-9, "{deg}°: {off}");
                }
            }
        }
    }

    #[test]
    fn horizontal_field_of_view_of_a_pinhole_and_a_fisheye() {
        let pinhole = PinholeCamera::ideal(500.0, 500, 400);
        let expected = 2.0 * (250.0f64 / 500.0).atan().to_degrees();
        assert!((pinhole.horizontal_fov_deg().unwrap() - expected).abs() < 1e-9);
        for fov in [90.0, 133.0, 170.0] {
            let fisheye = PinholeCamera::fisheye(fov, 640, 480, KannalaBrandt::default()).unwrap();
            let got = fisheye.horizontal_fov_deg().unwrap();
            assert!((got - fov).abs() < 1e-6, "{fov}: {got}");
        }
    }

    #[test]
    fn fisheye_field_of_view_and_the_edge_at_90_degrees() {
        let cam = PinholeCamera::fisheye(133.0, 500, 500, KannalaBrandt::default()).unwrap();
        // Equidistant: f = (W / 2) / θ_max.
        assert!((cam.fx - 250.0 / 66.5f64.to_radians()).abs() < 1e-9);
        let edge = cam
            .project(&Point3::new(66.5f64.to_radians().tan(), 0.0, 1.0))
            .unwrap();
        assert!((edge.x - (cam.cx + 250.0)).abs() < 1e-9, "{edge}");
        // At and beyond 90°: None, not NaN, both ways.
        for p in [
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(1.0, 1.0, -0.1),
            Point3::new(1.0, 0.0, 1e-300),
        ] {
            assert!(cam.project(&p).is_none(), "{p}");
            assert!(cam.project_with_jacobian(&p).is_none(), "{p}");
        }
        let r90 = cam.fx * std::f64::consts::FRAC_PI_2;
        for r in [r90, r90 + 1e-7, r90 + 5.0, 1e9] {
            assert!(
                cam.unproject(&Point2::new(cam.cx + r, cam.cy)).is_none(),
                "{r}"
            );
        }
        assert!(cam.unproject(&Point2::new(f64::NAN, 3.0)).is_none());
        let near = cam
            .unproject(&Point2::new(cam.cx + r90 - 1e-3, cam.cy))
            .unwrap();
        assert!(near.x.is_finite() && near.x > 1e4, "{near}");
        // A polynomial that folds back before 90° stops there.
        let folding = KannalaBrandt {
            k1: -0.3,
            ..Default::default()
        };
        // dθ_d/dθ = 1 − 0.9 θ² vanishes at θ ≈ 60.4°.
        assert!(folding.distort(&Vector2::new(1.0, 0.0)).is_some());
        assert!(folding.distort(&Vector2::new(2.0, 0.0)).is_none());
        // θ_d peaks at 0.703 (θ = 1.054): beyond it nothing inverts.
        assert!(folding.undistort_angle(0.75).is_none());
        let t = folding.undistort_angle(folding.theta_d(0.9).0).unwrap();
        assert!((t - 0.9).abs() < 1e-12, "{t}");
        assert!(PinholeCamera::fisheye(180.0, 500, 500, KannalaBrandt::default()).is_none());
        assert!(PinholeCamera::fisheye(133.0, 500, 500, folding).is_none());
    }

    #[test]
    fn undistorted_bounds() {
        let pin = PinholeCamera::ideal(500.0, 500, 500);
        assert_eq!(pin.undistorted_bounds(1.5), [-0.5, -0.5, 499.5, 499.5]);
        let cam = PinholeCamera::fisheye(133.0, 500, 500, KannalaBrandt::default()).unwrap();
        let b = cam.undistorted_bounds(70f64.to_radians());
        // The corners are beyond 90°: pulled in to 70° along the diagonal; the middle of the
        // sides is at 66.5°.
        // The widest point is the border pixel at 70° (radius f·70° on the side x = W/2, polar
        // angle φ = acos(W/2 ÷ f·70°)): undistorted, it lies at f·tan 70° · cos φ.
        let r70 = cam.fx * 70f64.to_radians().tan();
        let phi = (250.0 / (cam.fx * 70f64.to_radians())).acos();
        let want = r70 * phi.cos();
        assert!((b[2] - cam.cx - want).abs() < 1.0, "{b:?} {want}");
        assert!((cam.cx - b[0] - want).abs() < 1.0, "{b:?}");
        assert!((b[3] - cam.cy - want).abs() < 1.0, "{b:?}");
    }

    #[test]
    fn behind_camera_is_not_projected() {
        let cam = PinholeCamera::ideal(500.0, 500, 500);
        assert!(cam.project(&Point3::new(0.0, 0.0, -1.0)).is_none());
        assert!(cam.project(&Point3::new(f64::NAN, 0.0, 1.0)).is_none());
    }
}
