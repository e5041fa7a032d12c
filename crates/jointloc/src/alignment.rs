//! The SLAM→world similarity from (SLAM position, absolute fix) pairs (paper §III-A, the
//! (R, t) alignment): RANSAC over minimal sets, then a weighted Umeyama fit on the inliers with
//! the fixes' confidences as weights. Wrong fixes (tens of metres off) become outliers.

use jointloc_geometry::Sim3;
use jointloc_geometry::umeyama::align;
use nalgebra::Point3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// One correspondence: a point in the SLAM frame and where it is in the world frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Correspondence {
    pub slam: Point3<f64>,
    pub world: Point3<f64>,
    /// Confidence-derived weight (> 0).
    pub weight: f64,
    /// Index of the fix it comes from (a fix gives several correspondences).
    pub fix: usize,
    /// How far its world point may be from the similarity's image of its SLAM point and
    /// still be an inlier.
    pub tolerance: Tolerance,
}

/// An inlier bound: an ellipsoid with the horizontal (x, y) and vertical (z) half-axes,
/// metres. A fix's x, y is what a wrong match gets wrong; its z (elevation model + altimeter)
/// and the x, y of the point above it (a nadir assumption) err with the altitude.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tolerance {
    pub horizontal_m: f64,
    pub vertical_m: f64,
}

impl Tolerance {
    /// A sphere of radius `r`.
    pub fn sphere(r: f64) -> Self {
        Self {
            horizontal_m: r,
            vertical_m: r,
        }
    }

    /// Whether the residual `d` (world minus predicted) lies inside.
    pub fn contains(&self, d: &nalgebra::Vector3<f64>) -> bool {
        let h = (d.x * d.x + d.y * d.y) / (self.horizontal_m * self.horizontal_m);
        let v = d.z * d.z / (self.vertical_m * self.vertical_m);
        h + v <= 1.0
    }
}

/// The fitted similarity and which fixes support it.
#[derive(Debug, Clone, PartialEq)]
pub struct SlamToWorld {
    pub sim3: Sim3,
    /// Fixes whose correspondences are all inliers, sorted.
    pub inlier_fixes: Vec<usize>,
    /// Weighted RMS residual of the inliers, metres.
    pub rms: f64,
}

/// RANSAC (seeded) over minimal sets of 3 correspondences from distinct fixes, scored by the
/// summed weight of inliers within their tolerances, refined by weighted Umeyama on the
/// inliers, then (with `robust_floor_m` > 0) reweighted by [`robust_refit`]. `None` when no
/// hypothesis has at least `min_fixes` inlier fixes.
pub fn fit(
    pairs: &[Correspondence],
    iterations: usize,
    min_fixes: usize,
    seed: u64,
    robust_floor_m: f64,
) -> Option<SlamToWorld> {
    fit_admissible(pairs, iterations, min_fixes, seed, robust_floor_m, &|_| {
        true
    })
}

/// [`fit`] among the similarities that `admissible` accepts (an outside check such as the
/// take-off position): a hypothesis it refuses scores nothing, and a refined fit it refuses
/// gives `None`.
pub fn fit_admissible(
    pairs: &[Correspondence],
    iterations: usize,
    min_fixes: usize,
    seed: u64,
    robust_floor_m: f64,
    admissible: &dyn Fn(&Sim3) -> bool,
) -> Option<SlamToWorld> {
    let n_fixes = pairs.iter().map(|c| c.fix + 1).max().unwrap_or(0);
    if pairs.len() < 3 || n_fixes < 2 {
        return None;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let inliers_of = |s: &Sim3| -> Vec<bool> {
        // A fix is an inlier when all its correspondences are.
        let mut ok = vec![true; n_fixes];
        for c in pairs {
            if !c
                .tolerance
                .contains(&(s.transform_point(&c.slam) - c.world))
            {
                ok[c.fix] = false;
            }
        }
        ok
    };
    let score = |ok: &[bool]| -> f64 { pairs.iter().filter(|c| ok[c.fix]).map(|c| c.weight).sum() };
    let mut best: Option<(f64, Vec<bool>)> = None;
    // Always try the all-pairs fit first: with few pairs it is the natural hypothesis.
    let mut hypotheses: Vec<Sim3> = Vec::new();
    let ones = vec![1.0; n_fixes];
    if let Some(s) = weighted_fit(pairs, None, &ones) {
        hypotheses.push(s);
    }
    for _ in 0..iterations {
        let idx = rand::seq::index::sample(&mut rng, pairs.len(), 3.min(pairs.len())).into_vec();
        let sample: Vec<Correspondence> = idx.iter().map(|&i| pairs[i]).collect();
        if let Some(s) = weighted_fit(&sample, None, &ones) {
            hypotheses.push(s);
        }
    }
    for s in hypotheses.iter().filter(|s| admissible(s)) {
        let ok = inliers_of(s);
        let sc = score(&ok);
        if best.as_ref().is_none_or(|(b, _)| sc > *b) {
            best = Some((sc, ok));
        }
    }
    let (_, mut ok) = best?;
    // Refine on the inliers, then re-select once with the refined model.
    let mut sim3 = weighted_fit(pairs, Some(&ok), &ones)?;
    for _ in 0..2 {
        ok = inliers_of(&sim3);
        sim3 = weighted_fit(pairs, Some(&ok), &ones)?;
    }
    let inlier_fixes: Vec<usize> = (0..n_fixes)
        .filter(|&f| ok[f] && pairs.iter().any(|c| c.fix == f))
        .collect();
    if inlier_fixes.len() < min_fixes {
        return None;
    }
    if robust_floor_m > 0.0 {
        sim3 = robust_refit(pairs, &ok, sim3, robust_floor_m);
    }
    if !admissible(&sim3) {
        return None;
    }
    let (mut num, mut den) = (0.0, 0.0);
    for c in pairs.iter().filter(|c| ok[c.fix]) {
        num += c.weight * (sim3.transform_point(&c.slam) - c.world).norm_squared();
        den += c.weight;
    }
    Some(SlamToWorld {
        sim3,
        inlier_fixes,
        rms: (num / den.max(1e-12)).sqrt(),
    })
}

/// The largest distance between two of `points`, metres (0 for fewer than two).
pub fn spread_m(points: &[[f64; 2]]) -> f64 {
    let mut best = 0f64;
    for (i, a) in points.iter().enumerate() {
        for b in &points[i + 1..] {
            best = best.max((a[0] - b[0]).hypot(a[1] - b[1]));
        }
    }
    best
}

/// Iteratively reweighted refit of the inliers: each fix's weight times a Cauchy factor
/// `1 / (1 + (r / c)²)` of its horizontal residual `r` (of the fix's first correspondence,
/// which the caller makes its ground point: the x, y a wrong match gets wrong), `c` = 3 × the
/// residuals' robust σ (1.4826 × median), at least `floor_m`. The 2 m inlier bound keeps
/// fixes a metre off whose weight, among the few fixes of a young alignment, pulls it by
/// decimetres; at the default floor of 0.5 m such a fix keeps a fifth of its weight once the
/// others agree to a decimetre.
fn robust_refit(pairs: &[Correspondence], ok: &[bool], start: Sim3, floor_m: f64) -> Sim3 {
    let mut sim3 = start;
    for _ in 0..4 {
        let mut residual = vec![f64::NAN; ok.len()];
        for c in pairs.iter().filter(|c| ok[c.fix]) {
            if residual[c.fix].is_nan() {
                let d = c.world - sim3.transform_point(&c.slam);
                residual[c.fix] = d.x.hypot(d.y);
            }
        }
        let mut sorted: Vec<f64> = residual.iter().copied().filter(|r| !r.is_nan()).collect();
        if sorted.is_empty() {
            return sim3;
        }
        sorted.sort_by(f64::total_cmp);
        let sigma = 1.4826 * sorted[sorted.len() / 2];
        let c = (3.0 * sigma).max(floor_m);
        let factors: Vec<f64> = residual
            .iter()
            .map(|r| {
                if r.is_nan() {
                    0.0
                } else {
                    1.0 / (1.0 + (r / c).powi(2))
                }
            })
            .collect();
        match weighted_fit(pairs, Some(ok), &factors) {
            Some(s) => sim3 = s,
            None => return sim3,
        }
    }
    sim3
}

/// Weighted Umeyama on the correspondences of the fixes `keep` selects, each weight times
/// its fix's `factor`.
fn weighted_fit(pairs: &[Correspondence], keep: Option<&[bool]>, factor: &[f64]) -> Option<Sim3> {
    let chosen: Vec<&Correspondence> = pairs
        .iter()
        .filter(|c| keep.is_none_or(|k| k[c.fix]))
        .collect();
    if chosen.len() < 3 {
        return None;
    }
    let src: Vec<Point3<f64>> = chosen.iter().map(|c| c.slam).collect();
    let dst: Vec<Point3<f64>> = chosen.iter().map(|c| c.world).collect();
    let w: Vec<f64> = chosen.iter().map(|c| c.weight * factor[c.fix]).collect();
    let a = align(&src, &dst, Some(&w), true).ok()?;
    (a.sim3.scale.is_finite() && a.sim3.scale > 0.0).then_some(a.sim3)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{UnitQuaternion, Vector3};
    use rand::Rng;

    fn truth() -> Sim3 {
        Sim3 {
            scale: 1.3,
            rotation: UnitQuaternion::from_euler_angles(0.1, -0.05, 1.2),
            translation: Vector3::new(40.0, -25.0, 10.0),
        }
    }

    /// Fixes along a gently curving track, each with a point below it; some fixes wrong by
    /// 10–50 m.
    fn pairs(seed: u64, outlier_fraction: f64, noise: f64) -> (Vec<Correspondence>, Vec<bool>) {
        let s = truth();
        let inv = s.inverse();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut out = Vec::new();
        let mut wrong = Vec::new();
        for f in 0..30 {
            let t = f as f64 * 2.0;
            let world = Point3::new(t, 0.02 * t * t, 10.0);
            let bad = rng.random_bool(outlier_fraction);
            wrong.push(bad);
            let shift = if bad {
                let r = rng.random_range(10.0..50.0);
                let a: f64 = rng.random_range(0.0..std::f64::consts::TAU);
                Vector3::new(r * a.cos(), r * a.sin(), 0.0)
            } else if noise > 0.0 {
                Vector3::new(
                    rng.random_range(-noise..noise),
                    rng.random_range(-noise..noise),
                    0.0,
                )
            } else {
                Vector3::zeros()
            };
            for (p, w) in [(world, 0.6), (world - Vector3::new(0.0, 0.0, 10.0), 0.2)] {
                out.push(Correspondence {
                    slam: inv.transform_point(&p),
                    world: p + shift,
                    weight: w,
                    fix: f,
                    tolerance: Tolerance::sphere(2.0),
                });
            }
        }
        (out, wrong)
    }

    /// A consistent chain of wrong fixes that outnumbers the right ones (the track turned
    /// half a turn about a point 10 m off): plain RANSAC takes the chain; an admissibility
    /// check on where a similarity puts one known point (the take-off) takes the right fixes.
    #[test]
    fn an_admissibility_check_refuses_a_consistent_chain_of_wrong_fixes() {
        let s = truth();
        let inv = s.inverse();
        let turned = UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::PI);
        let pivot = Point3::new(8.0, 6.0, 10.0);
        let mut pairs = Vec::new();
        for f in 0..14 {
            let t = f as f64 * 2.0;
            let world = Point3::new(t, 0.02 * t * t, 10.0);
            let wrong = f < 9;
            let reported = if wrong {
                pivot + turned * (world - Point3::new(0.0, 0.0, 10.0))
            } else {
                world
            };
            pairs.push(Correspondence {
                slam: inv.transform_point(&world),
                world: reported,
                weight: 0.5,
                fix: f,
                tolerance: Tolerance::sphere(2.0),
            });
        }
        let takeoff_slam = inv.transform_point(&Point3::new(0.0, 0.0, 10.0));
        let near_takeoff = |c: &Sim3| {
            (c.transform_point(&takeoff_slam) - Point3::new(0.0, 0.0, 10.0)).norm() < 3.0
        };
        let plain = fit(&pairs, 200, 3, 1, 0.0).expect("fit");
        assert_eq!(plain.inlier_fixes, (0..9).collect::<Vec<_>>());
        assert!(!near_takeoff(&plain.sim3));
        let checked = fit_admissible(&pairs, 200, 3, 1, 0.0, &near_takeoff).expect("fit");
        assert_eq!(checked.inlier_fixes, (9..14).collect::<Vec<_>>());
        assert!(checked.sim3.rotation.angle_to(&s.rotation) < 1e-6);
        // Nothing admissible: no alignment.
        assert_eq!(fit_admissible(&pairs, 200, 3, 1, 0.0, &|_| false), None);
    }

    #[test]
    fn recovers_the_similarity_despite_wrong_fixes() {
        for seed in 0..5 {
            let (p, wrong) = pairs(seed, 0.2, 0.3);
            let fit = fit(&p, 200, 2, seed, 0.0).expect("fit");
            let t = truth();
            assert!(
                (fit.sim3.scale / t.scale - 1.0).abs() < 0.01,
                "seed {seed}: scale {}",
                fit.sim3.scale
            );
            assert!(
                fit.sim3.rotation.angle_to(&t.rotation) < 0.01,
                "seed {seed}"
            );
            for (f, &bad) in wrong.iter().enumerate() {
                assert_eq!(fit.inlier_fixes.contains(&f), !bad, "seed {seed} fix {f}");
            }
            let probe = Point3::new(1.0, 2.0, 3.0);
            let e = (fit.sim3.transform_point(&probe) - t.transform_point(&probe)).norm();
            assert!(e < 0.3, "seed {seed}: {e}");
        }
    }

    /// At altitude the point above a fix (a nadir assumption) is off by altitude × tilt:
    /// with the bound widened for it the fix stays an inlier, and its x, y still gates a
    /// wrong fix.
    #[test]
    fn a_wide_bound_keeps_tilted_nadir_pairs_and_still_drops_wrong_fixes() {
        let (mut p, _) = pairs(3, 0.0, 0.05);
        for c in p.iter_mut().filter(|c| c.weight < 0.5) {
            // The camera pair: 1.5–4 m off sideways, as 100 m × 1–2° of tilt.
            c.world.x += 1.5 + 2.5 * ((c.fix % 5) as f64 / 4.0);
        }
        let wrong = 7;
        for c in p.iter_mut().filter(|c| c.fix == wrong) {
            c.world.y += 3.0;
        }
        let strict = fit(&p, 200, 2, 0, 0.0).expect("fit");
        assert!(strict.inlier_fixes.len() < 20, "{:?}", strict.inlier_fixes);
        for c in p.iter_mut() {
            c.tolerance = if c.weight < 0.5 {
                Tolerance::sphere(20.0)
            } else {
                Tolerance {
                    horizontal_m: 2.0,
                    vertical_m: 20.0,
                }
            };
        }
        let wide = fit(&p, 200, 2, 0, 0.0).expect("fit");
        assert_eq!(wide.inlier_fixes.len(), 29, "{:?}", wide.inlier_fixes);
        assert!(!wide.inlier_fixes.contains(&wrong));
    }

    /// A young alignment: 6 fixes over 10 m with 3 cm of noise, one of them 1 m off (inside
    /// the 2 m bound). Plain, the one pulls the similarity by decimetres at the newest fix
    /// (0.36 m, the worst of 5 seeds); reweighted at the default floor of 0.5 m, by 0.12 m.
    /// With every fix as good, the reweighted fit is the plain one to 3 cm.
    #[test]
    fn a_fix_a_metre_off_among_a_few_good_ones_is_weighted_down() {
        let t = truth();
        let ahead = t.inverse().transform_point(&Point3::new(10.0, 0.0, 10.0));
        let (mut worst_plain, mut worst_robust) = (0f64, 0f64);
        for seed in 0..5 {
            let (p, _) = pairs(seed, 0.0, 0.03);
            let mut p: Vec<_> = p.into_iter().filter(|c| c.fix < 6).collect();
            let clean = fit(&p, 200, 3, seed, 0.5).expect("fit");
            let plain_clean = fit(&p, 200, 3, seed, 0.0).expect("fit");
            let d = clean.sim3.transform_point(&ahead) - plain_clean.sim3.transform_point(&ahead);
            assert!(d.norm() < 0.03, "seed {seed}: {}", d.norm());
            for c in p.iter_mut().filter(|c| c.fix == 4) {
                c.world.x += 0.6;
                c.world.y -= 0.8;
            }
            let err = |floor: f64| {
                let f = fit(&p, 200, 3, seed, floor).expect("fit");
                assert_eq!(f.inlier_fixes.len(), 6, "seed {seed}: still an inlier");
                (f.sim3.transform_point(&ahead) - t.transform_point(&ahead)).norm()
            };
            worst_plain = worst_plain.max(err(0.0));
            worst_robust = worst_robust.max(err(0.5));
        }
        assert!(worst_plain > 0.2, "plain {worst_plain}");
        assert!(
            worst_robust < 0.4 * worst_plain,
            "{worst_robust} vs {worst_plain}"
        );
    }

    #[test]
    fn too_few_fixes_give_nothing() {
        let (p, _) = pairs(1, 0.0, 0.0);
        assert!(fit(&p[..2], 50, 2, 0, 0.0).is_none());
        assert!(fit(&p[..4], 50, 3, 0, 0.0).is_none());
        assert!(fit(&p[..4], 50, 2, 0, 0.0).is_some());
        assert!(fit(&[], 50, 2, 0, 0.0).is_none());
    }

    #[test]
    fn the_spread_is_the_largest_distance_between_two_points() {
        assert_eq!(spread_m(&[]), 0.0);
        assert_eq!(spread_m(&[[3.0, 4.0]]), 0.0);
        let d = spread_m(&[[0.0, 0.0], [3.0, 4.0], [1.0, 1.0], [-3.0, 0.0]]);
        assert!((d - (36.0f64 + 16.0).sqrt()).abs() < 1e-12);
    }
}
