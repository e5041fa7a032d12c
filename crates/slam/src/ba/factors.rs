//! Residuals and analytic Jacobians of the bundle-adjustment factors.
//!
//! Pose updates are left-multiplied: `T_cw ← exp(δ) · T_cw` with `δ = [ρ; φ]` and `exp` the
//! geometry crate's [`se3_exp`](jointloc_geometry::pose::se3_exp) (translation first), the same
//! convention as the PnP refinement. A camera-frame point `p_c = R X + t` then moves to first
//! order by `ρ + φ × p_c`, and the camera centre `C = −Rᵀt` by `−Rᵀρ` (a rotation about the
//! camera's own centre leaves the centre in place).

use jointloc_geometry::{PinholeCamera, Sim3, WorldToCamera, pose::skew};

use super::problem::GroundPlane;
use nalgebra::{Matrix2x3, Matrix3, Matrix3x6, Point2, Point3, SMatrix, Vector2, Vector3};

/// 2×6 Jacobian of a pixel residual with respect to a pose update `δ = [ρ; φ]`.
pub type Matrix2x6 = SMatrix<f64, 2, 6>;

/// Reprojection residual `e = π(R X + t) − z` with `∂e/∂δ` (2×6) and `∂e/∂X` (2×3).
/// `None` when the point is not in front of the camera.
pub fn reprojection_residual(
    intrinsics: &PinholeCamera,
    pose: &WorldToCamera,
    point: &Vector3<f64>,
    pixel: &Point2<f64>,
) -> Option<(Vector2<f64>, Matrix2x6, Matrix2x3<f64>)> {
    reprojection(
        intrinsics,
        &pose.rotation_matrix(),
        &pose.translation(),
        point,
        pixel,
    )
}

/// [`reprojection_residual`] with the rotation already as a matrix (the solver's hot path).
#[inline]
pub(crate) fn reprojection(
    intrinsics: &PinholeCamera,
    rotation: &Matrix3<f64>,
    translation: &Vector3<f64>,
    point: &Vector3<f64>,
    pixel: &Point2<f64>,
) -> Option<(Vector2<f64>, Matrix2x6, Matrix2x3<f64>)> {
    let pc = rotation * point + translation;
    let (uv, jpi) = intrinsics.project_with_jacobian(&Point3::from(pc))?;
    let residual = uv - pixel;
    // ∂p_c/∂δ = [I, −[p_c]×]  ⇒  ∂e/∂δ = [Jπ, −Jπ [p_c]×].
    let mut jac_pose = Matrix2x6::zeros();
    jac_pose.fixed_view_mut::<2, 3>(0, 0).copy_from(&jpi);
    jac_pose
        .fixed_view_mut::<2, 3>(0, 3)
        .copy_from(&(-jpi * skew(&pc)));
    Some((residual, jac_pose, jpi * rotation))
}

/// Only the residual of [`reprojection`], for cost evaluation.
#[inline]
pub(crate) fn reprojection_error(
    intrinsics: &PinholeCamera,
    rotation: &Matrix3<f64>,
    translation: &Vector3<f64>,
    point: &Vector3<f64>,
    pixel: &Point2<f64>,
) -> Option<Vector2<f64>> {
    let pc = rotation * point + translation;
    intrinsics.project(&Point3::from(pc)).map(|uv| uv - pixel)
}

/// The camera centre `C = −Rᵀt` of a world-to-camera transform.
pub fn camera_centre(pose: &WorldToCamera) -> Vector3<f64> {
    -(pose.rotation().inverse() * pose.translation())
}

/// Global-position residual `r = S · C − P_G` and `∂r/∂δ = [−s R_S Rᵀ, 0]` (3×6).
pub fn global_position_residual(
    pose: &WorldToCamera,
    slam_to_world: &Sim3,
    world_position: &Vector3<f64>,
) -> (Vector3<f64>, Matrix3x6<f64>) {
    global_point_residual(pose, slam_to_world, &Vector3::zeros(), world_position)
}

/// The residual of a fix of the point `o` of the camera frame (the optical axis' ground point,
/// or the centre for `o = 0`): `r = S · Rᵀ(o − t) − P_G`, `∂r/∂δ = s R_S [−Rᵀ, Rᵀ[o]ₓ]` (3×6).
pub fn global_point_residual(
    pose: &WorldToCamera,
    slam_to_world: &Sim3,
    point_in_camera: &Vector3<f64>,
    world_position: &Vector3<f64>,
) -> (Vector3<f64>, Matrix3x6<f64>) {
    global_position(
        &pose.rotation_matrix(),
        &pose.translation(),
        slam_to_world,
        point_in_camera,
        world_position,
    )
}

/// [`global_point_residual`] with the rotation as a matrix.
pub(crate) fn global_position(
    rotation: &Matrix3<f64>,
    translation: &Vector3<f64>,
    slam_to_world: &Sim3,
    point_in_camera: &Vector3<f64>,
    world_position: &Vector3<f64>,
) -> (Vector3<f64>, Matrix3x6<f64>) {
    let rt = rotation.transpose();
    let point = rt * (point_in_camera - translation);
    let residual = slam_to_world.transform_point(&Point3::from(point)).coords - world_position;
    let sr = slam_to_world.scale * slam_to_world.rotation_matrix();
    let mut jac = Matrix3x6::zeros();
    jac.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-sr * rt));
    jac.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&(sr * rt * skew(point_in_camera)));
    (residual, jac)
}

/// Residual of a map point against the terrain, linearised at `anchor` (world x, y): `r =
/// z − (h + ∇h · (x − anchor))` of `(x, y, z) = S · X`, with `∂r/∂X = (e_z − [∇h, 0])ᵀ s R_S`.
pub fn ground_height_residual(
    point: &Vector3<f64>,
    slam_to_world: &Sim3,
    ground: &GroundPlane,
) -> (f64, nalgebra::RowVector3<f64>) {
    let w = slam_to_world.transform_point(&Point3::from(*point));
    let [gx, gy] = ground.slope;
    let expected = ground.height + gx * (w.x - ground.anchor[0]) + gy * (w.y - ground.anchor[1]);
    let sr = slam_to_world.scale * slam_to_world.rotation_matrix();
    let normal = nalgebra::RowVector3::new(-gx, -gy, 1.0);
    (w.z - expected, normal * sr)
}

/// Camera-centre prior residual `r = C − C_prior` with `∂r/∂δ = [−Rᵀ, 0]`.
pub(crate) fn position_prior(
    rotation: &Matrix3<f64>,
    translation: &Vector3<f64>,
    prior: &Vector3<f64>,
) -> (Vector3<f64>, Matrix3x6<f64>) {
    let rt = rotation.transpose();
    let mut jac = Matrix3x6::zeros();
    jac.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-rt));
    (-(rt * translation) - prior, jac)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{DMatrix, DVector, UnitQuaternion, Vector6};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    const H: f64 = 1e-6;

    fn perturbed(pose: &WorldToCamera, d: &Vector6<f64>) -> WorldToCamera {
        WorldToCamera(WorldToCamera::exp(d).0 * pose.0)
    }

    /// Central differences of `f` over the 6 left increments of `pose`.
    fn numeric_pose_jacobian(
        pose: &WorldToCamera,
        f: impl Fn(&WorldToCamera) -> DVector<f64>,
    ) -> DMatrix<f64> {
        let columns: Vec<DVector<f64>> = (0..6)
            .map(|k| {
                let mut d = Vector6::zeros();
                d[k] = H;
                (f(&perturbed(pose, &d)) - f(&perturbed(pose, &-d))) / (2.0 * H)
            })
            .collect();
        DMatrix::from_columns(&columns)
    }

    /// Central differences of `f` over the 3 coordinates of `x`.
    fn numeric_point_jacobian(
        x: &Vector3<f64>,
        f: impl Fn(&Vector3<f64>) -> DVector<f64>,
    ) -> DMatrix<f64> {
        let columns: Vec<DVector<f64>> = (0..3)
            .map(|k| {
                let mut d = Vector3::zeros();
                d[k] = H;
                (f(&(x + d)) - f(&(x - d))) / (2.0 * H)
            })
            .collect();
        DMatrix::from_columns(&columns)
    }

    /// ‖A − B‖_F / max(‖B‖_F, 1).
    fn rel_err(a: &DMatrix<f64>, b: &DMatrix<f64>) -> f64 {
        (a - b).norm() / b.norm().max(1.0)
    }

    fn random_pose(rng: &mut ChaCha8Rng) -> WorldToCamera {
        // A camera ~50 m above the origin, looking down, with a random tilt of up to ~10°.
        let down = UnitQuaternion::from_euler_angles(std::f64::consts::PI, 0.0, 0.0);
        let tilt = UnitQuaternion::from_euler_angles(
            rng.random_range(-0.2..0.2),
            rng.random_range(-0.2..0.2),
            rng.random_range(-3.0..3.0),
        );
        let c = Vector3::new(
            rng.random_range(-20.0..20.0),
            rng.random_range(-20.0..20.0),
            rng.random_range(40.0..60.0),
        );
        let r_cw = (down * tilt).inverse();
        WorldToCamera::from_rotation_translation(r_cw, -(r_cw * c))
    }

    #[test]
    fn reprojection_jacobians_match_central_differences() {
        let cam = PinholeCamera::ideal(400.0, 500, 500);
        for seed in 0..5 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            for _ in 0..20 {
                let pose = random_pose(&mut rng);
                // A point on the ground inside the view.
                let c = camera_centre(&pose);
                let ray = pose.rotation().inverse()
                    * Vector3::new(
                        rng.random_range(-0.5..0.5),
                        rng.random_range(-0.5..0.5),
                        1.0,
                    );
                let x = c + ray * (rng.random_range(30.0..70.0) / ray.norm());
                let z = Point2::new(rng.random_range(0.0..500.0), rng.random_range(0.0..500.0));
                let (e, jp, jx) = reprojection_residual(&cam, &pose, &x, &z).unwrap();
                let e_of = |p: &WorldToCamera, x: &Vector3<f64>| {
                    DVector::from_column_slice(
                        reprojection_residual(&cam, p, x, &z).unwrap().0.as_slice(),
                    )
                };
                let num_p = numeric_pose_jacobian(&pose, |p| e_of(p, &x));
                let num_x = numeric_point_jacobian(&x, |x| e_of(&pose, x));
                let ana_p = DMatrix::from_column_slice(2, 6, jp.as_slice());
                let ana_x = DMatrix::from_column_slice(2, 3, jx.as_slice());
                assert!(rel_err(&num_p, &ana_p) < 1e-6, "{num_p} vs {ana_p}");
                assert!(rel_err(&num_x, &ana_x) < 1e-6, "{num_x} vs {ana_x}");
                assert!(e.iter().all(|v| v.is_finite()));
            }
        }
    }

    /// A SLAM→world similarity of any scale, attitude and offset.
    fn random_sim3(rng: &mut ChaCha8Rng) -> Sim3 {
        Sim3::new(
            rng.random_range(0.3..3.0),
            UnitQuaternion::from_euler_angles(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-3.0..3.0),
            ),
            Vector3::new(
                rng.random_range(-100.0..100.0),
                rng.random_range(-100.0..100.0),
                rng.random_range(-10.0..10.0),
            ),
        )
    }

    #[test]
    fn global_position_jacobian_matches_central_differences() {
        for seed in 0..5 {
            let mut rng = ChaCha8Rng::seed_from_u64(100 + seed);
            for _ in 0..20 {
                let pose = random_pose(&mut rng);
                let s = random_sim3(&mut rng);
                let pg = Vector3::new(rng.random_range(-50.0..50.0), 3.0, 60.0);
                let (r, j) = global_position_residual(&pose, &s, &pg);
                let expected = s
                    .transform_point(&Point3::from(camera_centre(&pose)))
                    .coords
                    - pg;
                assert!((r - expected).norm() < 1e-9);
                let num = numeric_pose_jacobian(&pose, |p| {
                    DVector::from_column_slice(global_position_residual(p, &s, &pg).0.as_slice())
                });
                let ana = DMatrix::from_column_slice(3, 6, j.as_slice());
                assert!(rel_err(&num, &ana) < 1e-6, "{num} vs {ana}");
                // A fix of a point of the camera frame (the optical axis' ground point).
                let o = Vector3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(5.0..15.0),
                );
                let (r, j) = global_point_residual(&pose, &s, &o, &pg);
                let point = pose.inverse().transform_point(&Point3::from(o));
                assert!((r - (s.transform_point(&point).coords - pg)).norm() < 1e-9);
                let num = numeric_pose_jacobian(&pose, |p| {
                    DVector::from_column_slice(global_point_residual(p, &s, &o, &pg).0.as_slice())
                });
                let ana = DMatrix::from_column_slice(3, 6, j.as_slice());
                assert!(rel_err(&num, &ana) < 1e-6, "{num} vs {ana}");
                // The position prior is the same factor with the identity similarity.
                let (rp, jp) = position_prior(&pose.rotation_matrix(), &pose.translation(), &pg);
                let (rg, jg) = global_position_residual(&pose, &Sim3::identity(), &pg);
                assert!((rp - rg).norm() < 1e-9 && (jp - jg).norm() < 1e-12);
            }
        }
    }

    #[test]
    fn ground_height_jacobian_matches_central_differences() {
        for seed in 0..5 {
            let mut rng = ChaCha8Rng::seed_from_u64(200 + seed);
            for _ in 0..20 {
                let s = random_sim3(&mut rng);
                let x = Vector3::new(
                    rng.random_range(-20.0..20.0),
                    rng.random_range(-20.0..20.0),
                    rng.random_range(-5.0..5.0),
                );
                let ground = GroundPlane {
                    anchor: [rng.random_range(-50.0..50.0), rng.random_range(-50.0..50.0)],
                    height: rng.random_range(-3.0..3.0),
                    slope: [rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5)],
                };
                let (r, j) = ground_height_residual(&x, &s, &ground);
                let w = s.transform_point(&Point3::from(x));
                let plane = ground.height
                    + ground.slope[0] * (w.x - ground.anchor[0])
                    + ground.slope[1] * (w.y - ground.anchor[1]);
                assert!((r - (w.z - plane)).abs() < 1e-9);
                let num = numeric_point_jacobian(&x, |x| {
                    DVector::from_element(1, ground_height_residual(x, &s, &ground).0)
                });
                let ana = DMatrix::from_column_slice(1, 3, j.as_slice());
                assert!(rel_err(&num, &ana) < 1e-6, "{num} vs {ana}");
            }
        }
    }
}
