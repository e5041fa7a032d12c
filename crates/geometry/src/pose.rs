//! Typed rigid and similarity transforms.
//!
//! A pose is only meaningful with its direction: [`CameraToWorld`] maps points from the camera
//! frame (x right, y down, z forward) into the world frame, [`WorldToCamera`] the other way, and
//! [`Sim3`] maps points of the SLAM frame into the world frame (scale included). Keeping them as
//! distinct types makes "forgot to invert" a compile error instead of a wrong trajectory.
//!
//! Tangent vectors are ordered translation first: `[ρ; φ]` for SE(3) and `[ρ; φ; σ]` for Sim(3)
//! with scale `s = exp(σ)`, as in Sophus and Strasdat's thesis.

use nalgebra::{
    Isometry3, Matrix3, Point3, Quaternion, Rotation3, Translation3, UnitQuaternion, Vector3,
    Vector6,
};

/// Tangent vector of Sim(3): `[ρ; φ; σ]`.
pub type Vector7 = nalgebra::SVector<f64, 7>;
use serde::{Deserialize, Serialize};

/// Angles below this use Taylor expansions in exp/log.
const SMALL_ANGLE: f64 = 1e-8;

/// Skew-symmetric matrix `[v]×` such that `[v]× w = v × w`.
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// SO(3) exponential map (Rodrigues).
pub fn so3_exp(phi: &Vector3<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::from_scaled_axis(*phi)
}

/// SO(3) logarithm: the rotation vector of `q`, angle in `[0, π]`.
pub fn so3_log(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    q.scaled_axis()
}

/// Left Jacobian of SO(3), `V` in `t = V ρ` of the SE(3) exponential.
pub fn so3_left_jacobian(phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta = phi.norm();
    let k = skew(phi);
    if theta < SMALL_ANGLE {
        return Matrix3::identity() + 0.5 * k + k * k / 6.0;
    }
    let t2 = theta * theta;
    Matrix3::identity()
        + (1.0 - theta.cos()) / t2 * k
        + (theta - theta.sin()) / (t2 * theta) * k * k
}

/// Inverse of [`so3_left_jacobian`], in closed form.
pub fn so3_left_jacobian_inverse(phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta = phi.norm();
    let k = skew(phi);
    if theta < SMALL_ANGLE {
        return Matrix3::identity() - 0.5 * k + k * k / 12.0;
    }
    let half = 0.5 * theta;
    let coef = (1.0 - half * half.cos() / half.sin()) / (theta * theta);
    Matrix3::identity() - 0.5 * k + coef * k * k
}

/// SE(3) exponential of `[ρ; φ]`.
pub fn se3_exp(xi: &Vector6<f64>) -> Isometry3<f64> {
    let rho = xi.fixed_rows::<3>(0).into_owned();
    let phi = xi.fixed_rows::<3>(3).into_owned();
    let t = so3_left_jacobian(&phi) * rho;
    Isometry3::from_parts(Translation3::from(t), so3_exp(&phi))
}

/// SE(3) logarithm, inverse of [`se3_exp`].
pub fn se3_log(iso: &Isometry3<f64>) -> Vector6<f64> {
    let phi = so3_log(&iso.rotation);
    let rho = so3_left_jacobian_inverse(&phi) * iso.translation.vector;
    let mut xi = Vector6::zeros();
    xi.fixed_rows_mut::<3>(0).copy_from(&rho);
    xi.fixed_rows_mut::<3>(3).copy_from(&phi);
    xi
}

fn rigid_from_parts(translation: [f64; 3], quaternion_xyzw: [f64; 4]) -> Isometry3<f64> {
    let [qx, qy, qz, qw] = quaternion_xyzw;
    let q = UnitQuaternion::from_quaternion(Quaternion::new(qw, qx, qy, qz));
    Isometry3::from_parts(Translation3::from(Vector3::from(translation)), q)
}

fn rigid_to_parts(iso: &Isometry3<f64>) -> ([f64; 3], [f64; 4]) {
    let t = iso.translation.vector;
    let mut q = *iso.rotation.quaternion();
    // Canonical sign (qw >= 0) so written files are stable across equivalent rotations.
    if q.w < 0.0 {
        q = -q;
    }
    ([t.x, t.y, t.z], [q.i, q.j, q.k, q.w])
}

macro_rules! rigid_pose {
    ($name:ident, $inverse:ident, $doc:literal) => {
        #[doc = $doc]
        #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
        pub struct $name(pub Isometry3<f64>);

        impl $name {
            /// The identity transform.
            pub fn identity() -> Self {
                Self(Isometry3::identity())
            }

            /// From a rotation and a translation.
            pub fn from_rotation_translation(r: UnitQuaternion<f64>, t: Vector3<f64>) -> Self {
                Self(Isometry3::from_parts(Translation3::from(t), r))
            }

            /// From a translation and a Hamilton quaternion given as `[qx, qy, qz, qw]` (the TUM
            /// order). The quaternion is normalised.
            pub fn from_translation_quaternion(t: [f64; 3], q_xyzw: [f64; 4]) -> Self {
                Self(rigid_from_parts(t, q_xyzw))
            }

            /// Translation and `[qx, qy, qz, qw]` with `qw >= 0`.
            pub fn to_translation_quaternion(&self) -> ([f64; 3], [f64; 4]) {
                rigid_to_parts(&self.0)
            }

            /// SE(3) exponential of `[ρ; φ]`.
            pub fn exp(xi: &Vector6<f64>) -> Self {
                Self(se3_exp(xi))
            }

            /// SE(3) logarithm `[ρ; φ]`.
            pub fn log(&self) -> Vector6<f64> {
                se3_log(&self.0)
            }

            /// The rotation part.
            pub fn rotation(&self) -> UnitQuaternion<f64> {
                self.0.rotation
            }

            /// The rotation part as a 3×3 matrix.
            pub fn rotation_matrix(&self) -> Matrix3<f64> {
                self.0.rotation.to_rotation_matrix().into_inner()
            }

            /// The translation part.
            pub fn translation(&self) -> Vector3<f64> {
                self.0.translation.vector
            }

            /// The same transform followed by a shift of `t` (its rotation unchanged).
            pub fn translated(&self, t: Vector3<f64>) -> Self {
                Self::from_rotation_translation(self.rotation(), self.translation() + t)
            }

            /// Applies the transform to a point.
            pub fn transform_point(&self, p: &Point3<f64>) -> Point3<f64> {
                self.0.transform_point(p)
            }

            /// The inverse transform, which maps in the other direction.
            pub fn inverse(&self) -> $inverse {
                $inverse(self.0.inverse())
            }

            /// True when every entry is finite.
            pub fn is_finite(&self) -> bool {
                self.0.translation.vector.iter().all(|v| v.is_finite())
                    && self.0.rotation.coords.iter().all(|v| v.is_finite())
            }
        }
    };
}

rigid_pose!(
    CameraToWorld,
    WorldToCamera,
    "Pose of a camera: maps camera-frame points into the world frame (`T_wc`). Its translation \
     is the camera centre in world coordinates; this is what TUM trajectories store."
);
rigid_pose!(
    WorldToCamera,
    CameraToWorld,
    "Extrinsics of a camera: maps world points into the camera frame (`T_cw`), the form used \
     for projection and bundle adjustment."
);

impl CameraToWorld {
    /// The camera centre in world coordinates.
    pub fn centre(&self) -> Point3<f64> {
        Point3::from(self.0.translation.vector)
    }

    /// Relative motion `T_a⁻¹ T_b`: pose of `other` expressed in the frame of `self`.
    pub fn relative_to(&self, other: &CameraToWorld) -> Isometry3<f64> {
        self.0.inverse() * other.0
    }
}

/// A similarity transform `x ↦ s R x + t` mapping SLAM-frame points into the world frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Sim3 {
    /// Scale factor `s > 0`.
    pub scale: f64,
    /// Rotation `R`.
    pub rotation: UnitQuaternion<f64>,
    /// Translation `t`.
    pub translation: Vector3<f64>,
}

impl Default for Sim3 {
    fn default() -> Self {
        Self::identity()
    }
}

impl Sim3 {
    /// The identity.
    pub fn identity() -> Self {
        Self {
            scale: 1.0,
            rotation: UnitQuaternion::identity(),
            translation: Vector3::zeros(),
        }
    }

    /// From scale, rotation and translation.
    pub fn new(scale: f64, rotation: UnitQuaternion<f64>, translation: Vector3<f64>) -> Self {
        Self {
            scale,
            rotation,
            translation,
        }
    }

    /// Applies the transform to a point.
    pub fn transform_point(&self, p: &Point3<f64>) -> Point3<f64> {
        Point3::from(self.scale * (self.rotation * p.coords) + self.translation)
    }

    /// Applies the rotation and scale to a vector (no translation).
    pub fn transform_vector(&self, v: &Vector3<f64>) -> Vector3<f64> {
        self.scale * (self.rotation * v)
    }

    /// The inverse similarity.
    pub fn inverse(&self) -> Sim3 {
        let r_inv = self.rotation.inverse();
        let s_inv = 1.0 / self.scale;
        Sim3 {
            scale: s_inv,
            rotation: r_inv,
            translation: -(s_inv * (r_inv * self.translation)),
        }
    }

    /// Composition `self ∘ other` (apply `other` first).
    pub fn compose(&self, other: &Sim3) -> Sim3 {
        Sim3 {
            scale: self.scale * other.scale,
            rotation: self.rotation * other.rotation,
            translation: self.scale * (self.rotation * other.translation) + self.translation,
        }
    }

    /// Maps a camera pose of the SLAM frame into the world frame. The camera centre is
    /// transformed as a point; the orientation is rotated; the scale only affects positions.
    pub fn transform_pose(&self, pose: &CameraToWorld) -> CameraToWorld {
        CameraToWorld::from_rotation_translation(
            self.rotation * pose.rotation(),
            self.transform_point(&pose.centre()).coords,
        )
    }

    /// The 4×4 homogeneous matrix `[sR t; 0 1]`.
    pub fn to_homogeneous(&self) -> nalgebra::Matrix4<f64> {
        let mut m = nalgebra::Matrix4::identity();
        let sr = self.scale * self.rotation.to_rotation_matrix().into_inner();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&sr);
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.translation);
        m
    }

    /// Sim(3) exponential of `[ρ; φ; σ]`, scale `exp(σ)`.
    pub fn exp(xi: &Vector7) -> Sim3 {
        let rho = xi.fixed_rows::<3>(0).into_owned();
        let phi = xi.fixed_rows::<3>(3).into_owned();
        let sigma = xi[6];
        let w = sim3_w(&phi, sigma);
        Sim3 {
            scale: sigma.exp(),
            rotation: so3_exp(&phi),
            translation: w * rho,
        }
    }

    /// Sim(3) logarithm, inverse of [`Sim3::exp`].
    pub fn log(&self) -> Vector7 {
        let phi = so3_log(&self.rotation);
        let sigma = self.scale.ln();
        let w = sim3_w(&phi, sigma);
        // W is invertible for every finite (φ, σ); fall back to identity only on NaN input.
        let rho = w.try_inverse().unwrap_or_else(Matrix3::identity) * self.translation;
        let mut xi = Vector7::zeros();
        xi.fixed_rows_mut::<3>(0).copy_from(&rho);
        xi.fixed_rows_mut::<3>(3).copy_from(&phi);
        xi[6] = sigma;
        xi
    }

    /// The rotation as a matrix.
    pub fn rotation_matrix(&self) -> Matrix3<f64> {
        Rotation3::from(self.rotation).into_inner()
    }
}

/// The matrix `W(φ, σ)` with `t = W ρ` in the Sim(3) exponential.
fn sim3_w(phi: &Vector3<f64>, sigma: f64) -> Matrix3<f64> {
    let theta = phi.norm();
    let k = skew(phi);
    let s = sigma.exp();
    let (a, b, c);
    if sigma.abs() < SMALL_ANGLE {
        c = 1.0;
        if theta < SMALL_ANGLE {
            a = 0.5;
            b = 1.0 / 6.0;
        } else {
            let t2 = theta * theta;
            a = (1.0 - theta.cos()) / t2;
            b = (theta - theta.sin()) / (t2 * theta);
        }
    } else {
        c = (s - 1.0) / sigma;
        if theta < SMALL_ANGLE {
            let s2 = sigma * sigma;
            a = ((sigma - 1.0) * s + 1.0) / s2;
            b = (s * (0.5 * s2 - sigma + 1.0) - 1.0) / (s2 * sigma);
        } else {
            let sa = s * theta.sin();
            let sb = s * theta.cos();
            let denom = theta * theta + sigma * sigma;
            a = (sa * sigma + (1.0 - sb) * theta) / (theta * denom);
            b = (c - ((sb - 1.0) * sigma + sa * theta) / denom) / (theta * theta);
        }
    }
    a * k + b * k * k + c * Matrix3::identity()
}

impl std::ops::Mul<CameraToWorld> for Sim3 {
    type Output = CameraToWorld;
    fn mul(self, rhs: CameraToWorld) -> CameraToWorld {
        self.transform_pose(&rhs)
    }
}

impl std::ops::Mul for Sim3 {
    type Output = Sim3;
    fn mul(self, rhs: Sim3) -> Sim3 {
        self.compose(&rhs)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_vec<const N: usize>(rng: &mut ChaCha8Rng, scale: f64) -> nalgebra::SVector<f64, N> {
        nalgebra::SVector::<f64, N>::from_fn(|_, _| rng.random_range(-scale..scale))
    }

    #[test]
    fn se3_exp_log_roundtrip() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for _ in 0..200 {
            let xi = random_vec::<6>(&mut rng, 1.5);
            let back = se3_log(&se3_exp(&xi));
            assert!((back - xi).norm() < 1e-10, "{xi} vs {back}");
        }
        let tiny = Vector6::new(1e-3, 2e-3, 0.5, 1e-12, -1e-12, 0.0);
        assert!((se3_log(&se3_exp(&tiny)) - tiny).norm() < 1e-12);
    }

    #[test]
    fn sim3_exp_log_roundtrip_and_group_laws() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        for _ in 0..200 {
            let xi = random_vec::<7>(&mut rng, 1.2);
            let s = Sim3::exp(&xi);
            assert!((s.log() - xi).norm() < 1e-9, "{xi} vs {}", s.log());
            let p = Point3::from(random_vec::<3>(&mut rng, 10.0));
            let back = s.inverse().transform_point(&s.transform_point(&p));
            assert!((back - p).norm() < 1e-10);
            let t = Sim3::exp(&random_vec::<7>(&mut rng, 1.0));
            let lhs = (s * t).transform_point(&p);
            let rhs = s.transform_point(&t.transform_point(&p));
            assert!((lhs - rhs).norm() < 1e-9);
        }
        // Degenerate branches: no rotation, no scale, both.
        for xi in [
            Vector7::from_column_slice(&[1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 0.3]),
            Vector7::from_column_slice(&[1.0, 2.0, 3.0, 0.2, -0.1, 0.4, 0.0]),
            Vector7::from_column_slice(&[1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 0.0]),
        ] {
            assert!((Sim3::exp(&xi).log() - xi).norm() < 1e-9);
        }
    }

    #[test]
    fn sim3_exp_matches_its_definition_as_matrix_exponential() {
        // exp of the 4×4 generator, by a long Taylor series, must equal the closed form.
        let xi = Vector7::from_column_slice(&[0.3, -0.7, 1.1, 0.4, -0.2, 0.9, 0.35]);
        let mut gen4 = nalgebra::Matrix4::zeros();
        let phi = Vector3::new(xi[3], xi[4], xi[5]);
        gen4.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(skew(&phi) + xi[6] * Matrix3::identity()));
        gen4.fixed_view_mut::<3, 1>(0, 3)
            .copy_from(&Vector3::new(xi[0], xi[1], xi[2]));
        let mut term = nalgebra::Matrix4::identity();
        let mut sum = term;
        for k in 1..60 {
            term = term * gen4 / k as f64;
            sum += term;
        }
        assert!((Sim3::exp(&xi).to_homogeneous() - sum).norm() < 1e-12);
    }

    #[test]
    fn pose_inverse_and_quaternion_roundtrip() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for _ in 0..50 {
            let twc = CameraToWorld::exp(&random_vec::<6>(&mut rng, 2.0));
            let p = Point3::from(random_vec::<3>(&mut rng, 5.0));
            let pc = twc.inverse().transform_point(&twc.transform_point(&p));
            assert!((pc - p).norm() < 1e-12);
            let (t, q) = twc.to_translation_quaternion();
            assert!(q[3] >= 0.0);
            let back = CameraToWorld::from_translation_quaternion(t, q);
            assert!((back.log() - twc.log()).norm() < 1e-12);
        }
    }

    #[test]
    fn sim3_maps_camera_centres_and_orientations() {
        let s = Sim3::new(
            2.0,
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.5),
            Vector3::new(1.0, 2.0, 3.0),
        );
        let pose = CameraToWorld::from_rotation_translation(
            UnitQuaternion::from_euler_angles(0.1, 0.0, 0.0),
            Vector3::new(1.0, 0.0, 0.0),
        );
        let w = s * pose;
        assert!((w.centre() - s.transform_point(&pose.centre())).norm() < 1e-12);
        assert!(w.rotation().angle_to(&(s.rotation * pose.rotation())) < 1e-12);
    }
}
