//! Minimal absolute pose from three points: Lambda Twist P3P (Persson & Nordberg, ECCV 2018).
//!
//! The unknown depths `Λ = (λ₁, λ₂, λ₃)` along the unit bearings `yᵢ` satisfy the three
//! distance constraints `Λᵀ Mᵢⱼ Λ = aᵢⱼ = ‖xᵢ − xⱼ‖²`. Eliminating the right-hand sides gives
//! two homogeneous conics `D₁, D₂`; a root `γ` of the cubic `det(D₁ + γ D₂) = 0` makes
//! `D₀ = D₁ + γ D₂` a degenerate conic, i.e. a pair of planes through the origin of Λ-space.
//! Intersecting each plane with one conic is a quadratic, so the whole solver needs one cubic
//! and two quadratics instead of the quartic of Grunert/Kneip. The depths are polished by a
//! few Gauss-Newton steps on the distance equations and the pose follows from two triads.
//!
//! Deviation from the paper (same algebra, different bookkeeping): instead of the explicit
//! eigen-decomposition of `D₀` we factor its quadratic form on the plane orthogonal to its null
//! vector, and we parametrise each plane by an orthogonal basis rather than by `λ₁ = w₀λ₂ + w₁λ₃`,
//! which avoids dividing by a coefficient that can vanish. Among real roots of the cubic we take
//! the one with the steepest slope first, as the paper recommends.

use nalgebra::{Matrix3, Point3, Rotation3, UnitQuaternion, Vector3};

use crate::pose::WorldToCamera;

/// At most this many poses come out of one P3P problem.
pub const MAX_P3P_SOLUTIONS: usize = 4;

/// Gauss-Newton steps used to polish the depths.
const DEPTH_REFINE_STEPS: usize = 5;

/// Camera poses consistent with three bearings and three world points.
///
/// `bearings[i]` is the direction of world point `world[i]` in the camera frame (any non-zero
/// length; e.g. [`crate::PinholeCamera::unproject`]); points must lie in front of the camera.
/// Returns zero to four poses; degenerate input (collinear points, parallel bearings,
/// non-finite values) gives an empty vector rather than an error, as RANSAC expects.
pub fn p3p(bearings: &[Vector3<f64>; 3], world: &[Point3<f64>; 3]) -> Vec<WorldToCamera> {
    let Some(y) = unit_bearings(bearings) else {
        return Vec::new();
    };
    let d12 = world[0] - world[1];
    let d13 = world[0] - world[2];
    let d23 = world[1] - world[2];
    let a = [d12.norm_squared(), d13.norm_squared(), d23.norm_squared()];
    let scale = a[0].max(a[1]).max(a[2]);
    if !(scale.is_finite() && scale > 0.0)
        || d12.cross(&d13).norm_squared() <= 1e-20 * scale * scale
    {
        return Vec::new();
    }
    let b = [
        -2.0 * y[0].dot(&y[1]),
        -2.0 * y[0].dot(&y[2]),
        -2.0 * y[1].dot(&y[2]),
    ];
    let m12 = Matrix3::new(1.0, b[0] / 2.0, 0.0, b[0] / 2.0, 1.0, 0.0, 0.0, 0.0, 0.0);
    let m13 = Matrix3::new(1.0, 0.0, b[1] / 2.0, 0.0, 0.0, 0.0, b[1] / 2.0, 0.0, 1.0);
    let m23 = Matrix3::new(0.0, 0.0, 0.0, 0.0, 1.0, b[2] / 2.0, 0.0, b[2] / 2.0, 1.0);
    // Both vanish on every solution: a₂₃·(Λᵀ M₁₂ Λ) − a₁₂·(Λᵀ M₂₃ Λ) = 0, likewise for 13.
    let d1 = m12 * a[2] - m23 * a[0];
    let d2 = m13 * a[2] - m23 * a[1];

    let mut depths: Vec<Vector3<f64>> = Vec::with_capacity(MAX_P3P_SOLUTIONS);
    for d0 in degenerate_pencil_members(&d1, &d2) {
        let Some(planes) = factor_degenerate_conic(&d0) else {
            continue;
        };
        for (e, dir) in planes {
            intersect_plane(&e, &dir, &d1, &d2, &[m12, m13, m23], &a, &mut depths);
        }
        break;
    }

    let mut poses = Vec::with_capacity(depths.len());
    let mut kept: Vec<Vector3<f64>> = Vec::with_capacity(depths.len());
    for mut lambda in depths {
        refine_depths(&mut lambda, &a, &b);
        if lambda.iter().any(|&l| !(l.is_finite() && l > 0.0)) {
            continue;
        }
        // The two planes meet on the null line of D₀, so a solution there appears twice.
        if kept
            .iter()
            .any(|k| (k - lambda).norm() <= 1e-9 * lambda.norm())
        {
            continue;
        }
        if let Some(pose) = pose_from_depths(&y, world, &lambda) {
            kept.push(lambda);
            poses.push(pose);
        }
    }
    poses
}

fn unit_bearings(bearings: &[Vector3<f64>; 3]) -> Option<[Vector3<f64>; 3]> {
    let mut y = [Vector3::zeros(); 3];
    for (out, b) in y.iter_mut().zip(bearings) {
        let n = b.norm();
        if !(n.is_finite() && n > 0.0) {
            return None;
        }
        *out = b / n;
    }
    Some(y)
}

/// `D₁ + γ D₂` (or `D₂ + μ D₁` when `D₂` is the nearly singular one) for every real root of the
/// determinant cubic, steepest root first.
fn degenerate_pencil_members(d1: &Matrix3<f64>, d2: &Matrix3<f64>) -> Vec<Matrix3<f64>> {
    // det(A + γB) = det A + γ tr(adj(A) B) + γ² tr(adj(B) A) + γ³ det B.
    let c0 = d1.determinant();
    let c3 = d2.determinant();
    let (a, b, lead, tail) = if c3.abs() >= c0.abs() {
        (d1, d2, c3, c0)
    } else {
        (d2, d1, c0, c3)
    };
    if lead == 0.0 || !lead.is_finite() {
        // Both are singular: A itself is degenerate.
        return vec![*a];
    }
    let adj_a = adjugate(a);
    let adj_b = adjugate(b);
    let c1 = (adj_a * b).trace();
    let c2 = (adj_b * a).trace();
    let (p2, p1, p0) = (c2 / lead, c1 / lead, tail / lead);
    let mut roots = real_cubic_roots(p2, p1, p0);
    let slope = |g: f64| (3.0 * g * g + 2.0 * p2 * g + p1).abs();
    roots.sort_by(|x, y| slope(*y).total_cmp(&slope(*x)));
    roots.into_iter().map(|g| a + b * g).collect()
}

fn adjugate(m: &Matrix3<f64>) -> Matrix3<f64> {
    let c0 = m.column(0).into_owned();
    let c1 = m.column(1).into_owned();
    let c2 = m.column(2).into_owned();
    // Rows of the adjugate are cross products of the columns.
    Matrix3::from_rows(&[
        c1.cross(&c2).transpose(),
        c2.cross(&c0).transpose(),
        c0.cross(&c1).transpose(),
    ])
}

/// Real roots of the monic cubic `x³ + p2 x² + p1 x + p0`, each polished by Newton.
fn real_cubic_roots(p2: f64, p1: f64, p0: f64) -> Vec<f64> {
    let shift = p2 / 3.0;
    let p = p1 - p2 * shift;
    let q = 2.0 * shift * shift * shift - p1 * shift + p0;
    let disc = 0.25 * q * q + p * p * p / 27.0;
    let mut roots = if disc > 0.0 {
        let u = (-0.5 * q - 0.5 * q.signum() * (4.0 * disc).sqrt()).cbrt();
        let t = if u == 0.0 { 0.0 } else { u - p / (3.0 * u) };
        vec![t - shift]
    } else if p == 0.0 {
        vec![-shift]
    } else {
        let r = (-p / 3.0).sqrt();
        let cos_arg = (-0.5 * q / (r * r * r)).clamp(-1.0, 1.0);
        let theta = cos_arg.acos() / 3.0;
        (0..3)
            .map(|k| 2.0 * r * (theta - 2.0 * std::f64::consts::PI * k as f64 / 3.0).cos() - shift)
            .collect()
    };
    for x in &mut roots {
        for _ in 0..2 {
            let f = ((*x + p2) * *x + p1) * *x + p0;
            let df = (3.0 * *x + 2.0 * p2) * *x + p1;
            if df != 0.0 {
                let step = f / df;
                if step.is_finite() {
                    *x -= step;
                }
            }
        }
    }
    roots.retain(|x| x.is_finite());
    roots
}

/// Splits the rank-2 quadratic form `ΛᵀD₀Λ` into two planes through the origin, each returned as
/// `(e, d)`: the common null direction `e` of `D₀` and a second orthogonal spanning direction.
/// `None` when `D₀` is not a real pair of planes.
fn factor_degenerate_conic(d0: &Matrix3<f64>) -> Option<[(Vector3<f64>, Vector3<f64>); 2]> {
    let rows = [
        d0.row(0).transpose(),
        d0.row(1).transpose(),
        d0.row(2).transpose(),
    ];
    let candidates = [
        rows[0].cross(&rows[1]),
        rows[0].cross(&rows[2]),
        rows[1].cross(&rows[2]),
    ];
    let e = candidates
        .iter()
        .max_by(|x, y| x.norm_squared().total_cmp(&y.norm_squared()))?;
    let scale = d0.norm_squared();
    // Also rejects NaN: the comparison is false then.
    if e.norm_squared().partial_cmp(&(1e-24 * scale * scale)) != Some(std::cmp::Ordering::Greater) {
        return None;
    }
    let e = e.normalize();
    // Orthonormal basis (u, v) of e⊥.
    let helper = if e.x.abs() < 0.6 {
        Vector3::x()
    } else if e.y.abs() < 0.6 {
        Vector3::y()
    } else {
        Vector3::z()
    };
    let u = e.cross(&helper).normalize();
    let v = e.cross(&u);
    // Λ = c e + s u + t v gives ΛᵀD₀Λ = A₁₁ s² + 2 A₁₂ s t + A₂₂ t².
    let du = d0 * u;
    let dv = d0 * v;
    let (a11, a12, a22) = (u.dot(&du), u.dot(&dv), v.dot(&dv));
    let disc = a12 * a12 - a11 * a22;
    let tol = 1e-12 * (a11 * a11 + 2.0 * a12 * a12 + a22 * a22);
    if disc < -tol {
        return None;
    }
    let root = disc.max(0.0).sqrt();
    let [d_first, d_second] = quadratic_directions(a11, a12, a22, root, &u, &v)?;
    Some([(e, d_first), (e, d_second)])
}

/// The two null directions of `A₁₁ s² + 2 A₁₂ s t + A₂₂ t²` in the basis `(u, v)`, with
/// `root = √(A₁₂² − A₁₁A₂₂)`, solved for the better-conditioned ratio.
fn quadratic_directions(
    a11: f64,
    a12: f64,
    a22: f64,
    root: f64,
    u: &Vector3<f64>,
    v: &Vector3<f64>,
) -> Option<[Vector3<f64>; 2]> {
    let big = -(a12 + a12.signum() * root);
    if a11.abs() >= a22.abs() {
        if a11 == 0.0 {
            return None;
        }
        // s/t roots: (−A₁₂ ± root)/A₁₁; the second via the product of roots A₂₂/A₁₁.
        let r1 = big / a11;
        let r2 = if big != 0.0 { a22 / big } else { 0.0 };
        Some([(u * r1 + v).normalize(), (u * r2 + v).normalize()])
    } else {
        let r1 = big / a22;
        let r2 = if big != 0.0 { a11 / big } else { 0.0 };
        Some([(u + v * r1).normalize(), (u + v * r2).normalize()])
    }
}

/// Intersects the plane `Λ = α e + β d` with the solution set and pushes positive depths.
fn intersect_plane(
    e: &Vector3<f64>,
    dir: &Vector3<f64>,
    d1: &Matrix3<f64>,
    d2: &Matrix3<f64>,
    m: &[Matrix3<f64>; 3],
    a: &[f64; 3],
    out: &mut Vec<Vector3<f64>>,
) {
    // D₁ and D₂ agree up to a factor on the plane; use the one that is larger there.
    let restrict = |d: &Matrix3<f64>| {
        let de = d * e;
        let dd = d * dir;
        (e.dot(&de), e.dot(&dd), dir.dot(&dd))
    };
    let q1 = restrict(d1);
    let q2 = restrict(d2);
    let norm = |q: &(f64, f64, f64)| q.0 * q.0 + 2.0 * q.1 * q.1 + q.2 * q.2;
    let (q11, q12, q22) = if norm(&q1) >= norm(&q2) { q1 } else { q2 };
    let disc = q12 * q12 - q11 * q22;
    if disc < -1e-12 * (q11 * q11 + 2.0 * q12 * q12 + q22 * q22) {
        return;
    }
    let Some(candidates) = quadratic_directions(q11, q12, q22, disc.max(0.0).sqrt(), e, dir) else {
        return;
    };
    for mut l in candidates {
        if l.iter().any(|x| !x.is_finite()) {
            continue;
        }
        if l.sum() < 0.0 {
            l = -l;
        }
        if l.iter().any(|&x| x <= 0.0) {
            continue;
        }
        // Fix the scale with the best-conditioned distance constraint.
        let (k2, best) = m
            .iter()
            .zip(a)
            .map(|(mij, aij)| (aij, l.dot(&(mij * l))))
            .max_by(|x, y| x.1.total_cmp(&y.1))
            .map(|(aij, q)| (aij / q, q))
            .unwrap_or((0.0, 0.0));
        if best > 0.0 && k2.is_finite() && k2 > 0.0 {
            out.push(l * k2.sqrt());
        }
    }
}

/// A few verified Gauss-Newton steps on `λᵢ² + λⱼ² + bᵢⱼ λᵢ λⱼ = aᵢⱼ`.
fn refine_depths(lambda: &mut Vector3<f64>, a: &[f64; 3], b: &[f64; 3]) {
    let residual = |l: &Vector3<f64>| {
        Vector3::new(
            l[0] * l[0] + l[1] * l[1] + b[0] * l[0] * l[1] - a[0],
            l[0] * l[0] + l[2] * l[2] + b[1] * l[0] * l[2] - a[1],
            l[1] * l[1] + l[2] * l[2] + b[2] * l[1] * l[2] - a[2],
        )
    };
    let mut r = residual(lambda);
    for _ in 0..DEPTH_REFINE_STEPS {
        let l = *lambda;
        let j = Matrix3::new(
            2.0 * l[0] + b[0] * l[1],
            2.0 * l[1] + b[0] * l[0],
            0.0,
            2.0 * l[0] + b[1] * l[2],
            0.0,
            2.0 * l[2] + b[1] * l[0],
            0.0,
            2.0 * l[1] + b[2] * l[2],
            2.0 * l[2] + b[2] * l[1],
        );
        let Some(inv) = j.try_inverse() else {
            return;
        };
        let candidate = l - inv * r;
        let rc = residual(&candidate);
        if rc.norm_squared().partial_cmp(&r.norm_squared()) != Some(std::cmp::Ordering::Less) {
            return;
        }
        *lambda = candidate;
        r = rc;
    }
}

/// Rigid transform mapping the world triangle onto the camera-frame points `λᵢ yᵢ`.
fn pose_from_depths(
    y: &[Vector3<f64>; 3],
    world: &[Point3<f64>; 3],
    lambda: &Vector3<f64>,
) -> Option<WorldToCamera> {
    let cam = [y[0] * lambda[0], y[1] * lambda[1], y[2] * lambda[2]];
    let fc = triad(&(cam[1] - cam[0]), &(cam[2] - cam[0]))?;
    let fw = triad(&(world[1] - world[0]), &(world[2] - world[0]))?;
    let r = fc * fw.transpose();
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let centroid_w = (world[0].coords + world[1].coords + world[2].coords) / 3.0;
    let centroid_c = (cam[0] + cam[1] + cam[2]) / 3.0;
    let t = centroid_c - rotation * centroid_w;
    let pose = WorldToCamera::from_rotation_translation(rotation, t);
    pose.is_finite().then_some(pose)
}

/// Orthonormal frame with first axis along `p` and third along `p × q`.
fn triad(p: &Vector3<f64>, q: &Vector3<f64>) -> Option<Matrix3<f64>> {
    let e1 = p.try_normalize(0.0)?;
    let e3 = p.cross(q).try_normalize(0.0)?;
    let e2 = e3.cross(&e1);
    Some(Matrix3::from_columns(&[e1, e2, e3]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_pose(rng: &mut ChaCha8Rng) -> WorldToCamera {
        let axis = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        let angle = rng.random_range(0.0..std::f64::consts::PI);
        let r = UnitQuaternion::from_scaled_axis(axis.normalize() * angle);
        let t = Vector3::new(
            rng.random_range(-20.0..20.0),
            rng.random_range(-20.0..20.0),
            rng.random_range(-20.0..20.0),
        );
        WorldToCamera::from_rotation_translation(r, t)
    }

    /// Three camera-frame points in a 60° cone at depths 1–30, their bearings and world points.
    fn random_problem(
        rng: &mut ChaCha8Rng,
        pose: &WorldToCamera,
    ) -> ([Vector3<f64>; 3], [Point3<f64>; 3]) {
        let cam_to_world = pose.inverse();
        let mut bearings = [Vector3::zeros(); 3];
        let mut world = [Point3::origin(); 3];
        for k in 0..3 {
            let ray = Vector3::new(
                rng.random_range(-0.6..0.6),
                rng.random_range(-0.6..0.6),
                1.0,
            );
            let depth = rng.random_range(1.0..30.0);
            bearings[k] = ray;
            world[k] = cam_to_world.transform_point(&Point3::from(ray * depth));
        }
        (bearings, world)
    }

    fn pose_error(a: &WorldToCamera, b: &WorldToCamera) -> f64 {
        let dr = (a.rotation_matrix() - b.rotation_matrix()).norm();
        let dt = (a.translation() - b.translation()).norm() / (1.0 + b.translation().norm());
        dr.max(dt)
    }

    #[test]
    fn recovers_true_pose_on_random_noise_free_problems() {
        let mut worst: f64 = 0.0;
        let trials = 2000;
        for seed in 0..4u64 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            for _ in 0..trials / 4 {
                let truth = random_pose(&mut rng);
                let (bearings, world) = random_problem(&mut rng, &truth);
                let poses = p3p(&bearings, &world);
                assert!(!poses.is_empty() && poses.len() <= MAX_P3P_SOLUTIONS);
                let best = poses
                    .iter()
                    .map(|p| pose_error(p, &truth))
                    .fold(f64::INFINITY, f64::min);
                worst = worst.max(best);
                assert!(best < 1e-8, "seed {seed}: best error {best:e}");
            }
        }
        eprintln!("p3p worst best-solution error over {trials} problems: {worst:e}");
    }

    #[test]
    fn every_solution_reprojects_the_three_points() {
        let mut rng = ChaCha8Rng::seed_from_u64(99);
        for _ in 0..200 {
            let truth = random_pose(&mut rng);
            let (bearings, world) = random_problem(&mut rng, &truth);
            for pose in p3p(&bearings, &world) {
                for k in 0..3 {
                    let pc = pose.transform_point(&world[k]);
                    assert!(pc.z > 0.0);
                    let angle = pc.coords.normalize().dot(&bearings[k].normalize());
                    assert!(angle > 1.0 - 1e-12, "bearing mismatch {angle}");
                }
            }
        }
    }

    #[test]
    fn degenerate_input_gives_no_solution() {
        let b = [
            Vector3::new(0.0, 0.0, 1.0),
            Vector3::new(0.1, 0.0, 1.0),
            Vector3::new(0.0, 0.1, 1.0),
        ];
        let collinear = [
            Point3::new(0.0, 0.0, 5.0),
            Point3::new(1.0, 0.0, 5.0),
            Point3::new(2.0, 0.0, 5.0),
        ];
        assert!(p3p(&b, &collinear).is_empty());
        let mut nan = b;
        nan[1].x = f64::NAN;
        let ok = [
            Point3::new(0.0, 0.0, 5.0),
            Point3::new(0.5, 0.0, 5.0),
            Point3::new(0.0, 0.5, 5.0),
        ];
        assert!(p3p(&nan, &ok).is_empty());
        assert!(p3p(&[Vector3::zeros(); 3], &ok).is_empty());
        assert!(!p3p(&b, &ok).is_empty());
    }

    #[test]
    fn cubic_roots_are_roots() {
        for (p2, p1, p0) in [
            (-6.0, 11.0, -6.0),
            (0.0, 0.0, -8.0),
            (1.0, 1.0, 1.0),
            (0.0, -3.0, 2.0),
        ] {
            let roots = real_cubic_roots(p2, p1, p0);
            assert!(!roots.is_empty());
            for x in roots {
                assert!((((x + p2) * x + p1) * x + p0).abs() < 1e-9, "{x}");
            }
        }
        assert_eq!(real_cubic_roots(-6.0, 11.0, -6.0).len(), 3);
    }
}
