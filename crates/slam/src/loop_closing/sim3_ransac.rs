//! The similarity between two keyframes' cameras from matched map points (ORB-SLAM2's
//! `Sim3Solver`): RANSAC over minimal sets of three 3D–3D pairs (Horn/Umeyama), where a pair
//! is an inlier when each point, moved by the similarity, reprojects onto the other camera's
//! keypoint (χ² 9.21 at the keypoint's pyramid level, both ways). The winner is refitted to
//! all its inliers.
//!
//! Monocular maps drift in scale, so the loop's correction is a similarity: its scale is the
//! ratio of the two maps' scales at the loop.

use jointloc_geometry::{PinholeCamera, Sim3, umeyama};
use nalgebra::{Point2, Point3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// One matched pair: the same physical point seen by camera 1 and camera 2.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sim3Pair {
    /// The map point in camera 1's frame, and the keypoint that observes it there.
    pub in_camera1: Point3<f64>,
    pub pixel1: Point2<f64>,
    /// σ² of that keypoint (its pyramid level's scale squared).
    pub sigma2_1: f64,
    /// The same for camera 2.
    pub in_camera2: Point3<f64>,
    pub pixel2: Point2<f64>,
    pub sigma2_2: f64,
}

/// The fitted similarity `S_12` (camera 2's frame → camera 1's) and which pairs support it.
#[derive(Debug, Clone, PartialEq)]
pub struct Sim3Fit {
    pub s12: Sim3,
    pub inliers: Vec<bool>,
    pub n_inliers: usize,
}

/// χ² (2 DoF, 99 %) of a reprojection inlier, in units of the keypoint's σ².
const INLIER_CHI2: f64 = 9.21;

/// Whether `pair` supports `s12`: both reprojections within the χ² gate.
pub fn is_inlier(pair: &Sim3Pair, s12: &Sim3, s21: &Sim3, camera: &PinholeCamera) -> bool {
    let close = |p: Point3<f64>, pixel: &Point2<f64>, sigma2: f64| {
        camera
            .project(&p)
            .is_some_and(|uv| (uv - pixel).norm_squared() < INLIER_CHI2 * sigma2)
    };
    close(
        s12.transform_point(&pair.in_camera2),
        &pair.pixel1,
        pair.sigma2_1,
    ) && close(
        s21.transform_point(&pair.in_camera1),
        &pair.pixel2,
        pair.sigma2_2,
    )
}

fn inliers_of(pairs: &[Sim3Pair], s12: &Sim3, camera: &PinholeCamera) -> Vec<bool> {
    let s21 = s12.inverse();
    pairs
        .iter()
        .map(|p| is_inlier(p, s12, &s21, camera))
        .collect()
}

fn fit(pairs: &[Sim3Pair], chosen: impl Iterator<Item = usize>) -> Option<Sim3> {
    let (src, dst): (Vec<Point3<f64>>, Vec<Point3<f64>>) = chosen
        .map(|i| (pairs[i].in_camera2, pairs[i].in_camera1))
        .unzip();
    let s = umeyama::align(&src, &dst, None, true).ok()?.sim3;
    (s.scale.is_finite() && s.scale > 0.0).then_some(s)
}

/// RANSAC for `S_12` over `pairs` with `iterations` minimal samples drawn by an RNG seeded
/// with `seed`; `None` when fewer than `min_inliers` pairs support the best hypothesis.
pub fn estimate_sim3(
    pairs: &[Sim3Pair],
    camera: &PinholeCamera,
    iterations: usize,
    min_inliers: usize,
    seed: u64,
) -> Option<Sim3Fit> {
    let n = pairs.len();
    if n < 3 || n < min_inliers {
        return None;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut best: Option<(usize, Sim3)> = None;
    for _ in 0..iterations {
        let a = rng.random_range(0..n);
        let mut b = rng.random_range(0..n - 1);
        if b >= a {
            b += 1;
        }
        let mut c = rng.random_range(0..n - 2);
        for taken in [a.min(b), a.max(b)] {
            if c >= taken {
                c += 1;
            }
        }
        let Some(s) = fit(pairs, [a, b, c].into_iter()) else {
            continue;
        };
        let count = inliers_of(pairs, &s, camera).iter().filter(|&&i| i).count();
        if best.as_ref().is_none_or(|(c0, _)| count > *c0) {
            best = Some((count, s));
        }
    }
    let (count, s) = best?;
    if count < min_inliers.max(3) {
        return None;
    }
    // Refit to the consensus, keep it only if it does not lose support.
    let inliers = inliers_of(pairs, &s, camera);
    let refit = fit(pairs, (0..n).filter(|&i| inliers[i]))
        .map(|r| (inliers_of(pairs, &r, camera), r))
        .filter(|(i, _)| i.iter().filter(|&&x| x).count() >= count);
    let (inliers, s12) = refit.unwrap_or((inliers, s));
    let n_inliers = inliers.iter().filter(|&&i| i).count();
    Some(Sim3Fit {
        s12,
        inliers,
        n_inliers,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{UnitQuaternion, Vector3};
    use rand_distr::{Distribution, Normal};

    fn camera() -> PinholeCamera {
        PinholeCamera::ideal(500.0, 500, 500)
    }

    /// Ground points seen by two downward cameras 3 m apart at 10 m; camera 2's map has a
    /// different scale (drift), pixels get 0.5 px noise and `outliers` pairs are wrong.
    fn scene(seed: u64, outliers: usize) -> (Vec<Sim3Pair>, Sim3) {
        let cam = camera();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let noise = Normal::new(0.0, 0.5).expect("valid σ");
        // S_12: camera 2 (scale 1.3 map units per camera-1 unit) → camera 1.
        let truth = Sim3::new(
            1.0 / 1.3,
            UnitQuaternion::from_euler_angles(0.02, -0.03, 0.4),
            Vector3::new(3.0, -1.0, 0.2),
        );
        let s21 = truth.inverse();
        let mut pairs = Vec::new();
        while pairs.len() < 120 {
            let p1 = Point3::new(
                rng.random_range(-4.0..4.0),
                rng.random_range(-4.0..4.0),
                10.0 + rng.random_range(-0.5..0.5),
            );
            let p2 = s21.transform_point(&p1);
            let (Some(u1), Some(u2)) = (cam.project(&p1), cam.project(&p2)) else {
                continue;
            };
            if !cam.contains(&u1, 0.0) || !cam.contains(&u2, 0.0) {
                continue;
            }
            let jitter = |u: Point2<f64>, rng: &mut ChaCha8Rng| {
                Point2::new(u.x + noise.sample(rng), u.y + noise.sample(rng))
            };
            pairs.push(Sim3Pair {
                in_camera1: p1,
                pixel1: jitter(u1, &mut rng),
                sigma2_1: 1.0,
                in_camera2: p2,
                pixel2: jitter(u2, &mut rng),
                sigma2_2: 1.0,
            });
        }
        for i in 0..outliers {
            let j = (i * 7 + 3) % pairs.len();
            let k = (i * 13 + 5) % pairs.len();
            pairs[j].in_camera2 = pairs[k].in_camera2 + Vector3::new(0.7, -0.4, 0.1);
        }
        (pairs, truth)
    }

    #[test]
    fn recovers_the_similarity_with_outliers() {
        for seed in [1, 2, 3] {
            let (pairs, truth) = scene(seed, 40);
            let fit = estimate_sim3(&pairs, &camera(), 300, 20, seed).expect("a loop");
            assert!(fit.n_inliers >= 75, "inliers {}", fit.n_inliers);
            assert!((fit.s12.scale / truth.scale - 1.0).abs() < 0.01);
            assert!((fit.s12.translation - truth.translation).norm() < 0.05);
            assert!(fit.s12.rotation.angle_to(&truth.rotation) < 0.005);
        }
    }

    #[test]
    fn random_pairs_give_no_loop() {
        let (mut pairs, _) = scene(4, 0);
        let n = pairs.len();
        let shuffled: Vec<Point3<f64>> = (0..n)
            .map(|i| pairs[(i * 37 + 11) % n].in_camera2)
            .collect();
        for (p, q) in pairs.iter_mut().zip(shuffled) {
            p.in_camera2 = q;
        }
        assert!(estimate_sim3(&pairs, &camera(), 300, 20, 4).is_none());
    }

    #[test]
    fn deterministic_and_safe_on_tiny_input() {
        let (pairs, _) = scene(5, 30);
        let a = estimate_sim3(&pairs, &camera(), 200, 20, 9);
        let b = estimate_sim3(&pairs, &camera(), 200, 20, 9);
        assert_eq!(a, b);
        assert!(estimate_sim3(&pairs[..2], &camera(), 200, 2, 9).is_none());
        assert!(estimate_sim3(&[], &camera(), 200, 0, 9).is_none());
    }
}
