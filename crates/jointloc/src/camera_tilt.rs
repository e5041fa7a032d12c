//! The camera's mean tilt off nadir, in its own frame: a body-fixed camera on a UAV pitched
//! to cruise, or mounted a few degrees off nadir.
//!
//! The nadir pairs of the fusion (the camera above the fix, [`crate::JointLocConfig`]'s
//! `nadir_weight` and `nadir_sigma_scale`) assume that the camera looks straight down on
//! average: the jitter of its attitude averages out, a constant tilt does not. With a
//! constant 3° tilt at 10 m every nadir pair is 0.52 m off, and they pulled the outputs 0.16 m
//! off (`docs/jointloc.md` §"A camera that does not look straight down"). The fused
//! attitudes know better: the ground points and the SLAM's own geometry put the mean tilt of
//! the online attitudes at 2.6° on that flight. So the mean tilt of the fused attitudes, in
//! the camera frame (it turns with the heading, unlike an error of the alignment's tilt), is
//! taken at each refit, and each nadir pair puts the camera where it looks from at that tilt
//! ([`shrunk`] first: tilts within the attitude's own wander are taken as none). Refit after
//! refit, the estimate moves to the tilt that the pairs and the rest agree on.

use nalgebra::{Point3, UnitQuaternion, Vector3};

/// The level camera at the heading of `x_axis` (the image x axis in the world): x along it,
/// z straight down, y = z × x. `None` for an image x axis pointing (almost) vertically.
fn level_frame(x_axis: &Vector3<f64>) -> Option<[Vector3<f64>; 3]> {
    let flat = Vector3::new(x_axis.x, x_axis.y, 0.0);
    let n = flat.norm();
    if n.is_nan() || n <= 1e-6 {
        return None;
    }
    let x = flat / n;
    let z = Vector3::new(0.0, 0.0, -1.0);
    Some([x, z.cross(&x), z])
}

/// The tilt `[about image x, about image y]`, radians, of a camera whose image x axis and
/// optical axis are `x_axis` and `optical_axis` (world): the rotation from the level camera
/// at its heading to it, without the turn about the optical axis.
pub(crate) fn tilt_of(x_axis: &Vector3<f64>, optical_axis: &Vector3<f64>) -> Option<[f64; 2]> {
    let [x, y, z] = level_frame(x_axis)?;
    let n = optical_axis.norm();
    if !(n > 0.0 && n.is_finite()) {
        return None;
    }
    let a = optical_axis / n;
    let (ax, ay, az) = (a.dot(&x), a.dot(&y), a.dot(&z));
    if az <= 0.0 {
        return None;
    }
    // exp([bx, by, 0]) turns the level axis (0, 0, 1) to ≈ (by, −bx, 1).
    Some([(-ay).atan2(az), ax.atan2(az)])
}

/// Where a camera is that looks at `ground` from `range` metres along its optical axis, with
/// its image x axis along `x_axis` and tilted by `tilt` (as [`tilt_of`] gives it). With no
/// tilt: `range` straight above. `None` as [`level_frame`].
pub(crate) fn camera_looking_at(
    ground: &Point3<f64>,
    range: f64,
    x_axis: &Vector3<f64>,
    tilt: [f64; 2],
) -> Option<Point3<f64>> {
    let [x, y, z] = level_frame(x_axis)?;
    let local =
        UnitQuaternion::from_scaled_axis(Vector3::new(tilt[0], tilt[1], 0.0)) * Vector3::z();
    let axis = x * local.x + y * local.y + z * local.z;
    Some(ground - range * axis)
}

/// The tilt to use from an estimate `tilt`: shrunk towards none by `min` radians
/// (`tilt · max(0, 1 − min²/|tilt|²)`, a non-negative garrote). The estimate wanders by
/// 0.1–0.2° on a camera that looks straight down (the fused attitudes' own slow tilt error),
/// and following it cost 10 % of the online accuracy on the development flights; a
/// constant tilt of degrees is used almost whole.
pub(crate) fn shrunk(tilt: [f64; 2], min: f64) -> [f64; 2] {
    let m2 = tilt[0] * tilt[0] + tilt[1] * tilt[1];
    if m2.is_nan() || m2 <= 0.0 {
        return [0.0, 0.0];
    }
    let k = (1.0 - min * min / m2).max(0.0);
    [tilt[0] * k, tilt[1] * k]
}

/// The mean of `tilts`; `None` for none.
pub(crate) fn mean_tilt(tilts: &[[f64; 2]]) -> Option<[f64; 2]> {
    if tilts.is_empty() {
        return None;
    }
    let n = tilts.len() as f64;
    let sum = tilts
        .iter()
        .fold([0.0, 0.0], |s, t| [s[0] + t[0], s[1] + t[1]]);
    Some([sum[0] / n, sum[1] / n])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A camera at heading `h` (its image x axis turned `h` from world x), tilted by `b`:
    /// (image x axis, optical axis) in the world.
    fn camera(h: f64, b: [f64; 2]) -> (Vector3<f64>, Vector3<f64>) {
        let x = Vector3::new(h.cos(), h.sin(), 0.0);
        let z = Vector3::new(0.0, 0.0, -1.0);
        let y = z.cross(&x);
        let r = nalgebra::Matrix3::from_columns(&[x, y, z]);
        let q =
            UnitQuaternion::from_rotation_matrix(&nalgebra::Rotation3::from_matrix_unchecked(r))
                * UnitQuaternion::from_scaled_axis(Vector3::new(b[0], b[1], 0.0));
        (q * Vector3::x(), q * Vector3::z())
    }

    #[test]
    fn the_tilt_of_a_tilted_camera_is_its_tilt_at_every_heading() {
        for b in [[0.0, 0.0], [0.05, 0.0], [0.0, -0.03], [0.02, 0.04]] {
            for k in 0..24 {
                let h = k as f64 * std::f64::consts::TAU / 24.0 - 3.0;
                let (x, axis) = camera(h, b);
                let t = tilt_of(&x, &axis).unwrap();
                assert!(
                    (t[0] - b[0]).abs() < 2e-3 && (t[1] - b[1]).abs() < 2e-3,
                    "{b:?} at {h}: {t:?}"
                );
                // The camera placed from the ground point it looks at is where it is (to
                // second order in the tilt: the heading is read off the tilted x axis).
                let centre = Point3::new(3.0, -2.0, 10.0);
                let range = 10.0;
                let ground = centre + range * axis;
                let placed = camera_looking_at(&ground, range, &x, b).unwrap();
                assert!((placed - centre).norm() < 1e-3, "{b:?} at {h}: {placed}");
            }
        }
    }

    #[test]
    fn no_tilt_puts_the_camera_straight_above() {
        let ground = Point3::new(1.0, 2.0, -0.5);
        let x = Vector3::new(0.3, -0.9, 0.1);
        let c = camera_looking_at(&ground, 10.0, &x, [0.0, 0.0]).unwrap();
        assert!((c - Point3::new(1.0, 2.0, 9.5)).norm() < 1e-12);
        assert!(camera_looking_at(&ground, 10.0, &Vector3::z(), [0.0, 0.0]).is_none());
        assert!(
            tilt_of(&Vector3::x(), &Vector3::z()).is_none(),
            "looking up"
        );
        assert_eq!(mean_tilt(&[[0.1, -0.2], [0.3, 0.0]]), Some([0.2, -0.1]));
        assert_eq!(mean_tilt(&[]), None);
    }

    #[test]
    fn small_tilts_are_shrunk_to_none_and_large_ones_kept() {
        let min = 0.5f64.to_radians();
        assert_eq!(
            shrunk([0.3f64.to_radians(), 0.3f64.to_radians()], min),
            [0.0, 0.0]
        );
        assert_eq!(shrunk([0.0, 0.0], min), [0.0, 0.0]);
        let big = [3f64.to_radians(), -1f64.to_radians()];
        let s = shrunk(big, min);
        let ratio = s[0] / big[0];
        assert!((0.97..1.0).contains(&ratio), "{ratio}");
        assert!(
            (s[1] / big[1] - ratio).abs() < 1e-12,
            "the direction is kept"
        );
        assert_eq!(shrunk(big, 0.0), big);
    }
}
