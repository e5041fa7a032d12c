//! Where the local map sits on the elevation model: the horizontal shift (and height offset)
//! that puts the geo-referenced map points onto the terrain.
//!
//! The fixes of a flight can share a bias (under another sun, shading and cast shadows over
//! relief move the features the matchers see; `docs/jointloc.md` §"Mountain medium"). A bias
//! common to all fixes moves the alignment with it, and nothing in the fixes themselves can
//! show it. The map points can: over relief, hundreds of them lie on the elevation model only
//! at the true horizontal position, as in terrain-relative navigation. Over flat ground the
//! slopes vanish and so does the information, which [`TerrainShift::information`] carries.

use jointloc_absloc::Ground;
use nalgebra::{Matrix2, Matrix3, Point3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

/// One estimate of the shift of a set of world points onto the elevation model.
#[derive(Debug, Clone, PartialEq)]
pub struct TerrainShift {
    /// (dx, dy, dz), metres: the points moved by it lie on the terrain.
    pub shift: Vector3<f64>,
    /// Gauss–Newton information of the shift, `Σ wᵢ Jᵢᵀ Jᵢ / σ²` (1/m²), over the points kept.
    pub information: Matrix3<f64>,
    /// Points on the model (inside its posts) that were used.
    pub points: usize,
    /// Weighted rms height residual after the shift, metres.
    pub rms_m: f64,
}

/// Settings of the terrain correction of the fixes' common bias.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TerrainConfig {
    /// Share of the estimates taken into the correction per second of flight (0: off): an
    /// estimate `dt` seconds after the one before is taken in by `1 − (1 − gain)^dt`, so the
    /// correction's time constant does not depend on how often fixes come. The map points
    /// are also held on the model by the local BA's ground factors, which take up most of a
    /// shift before it is measured: one estimate sees a third of the bias (2026-12-02) to an
    /// eighth (four medium flights, 2026-12-07; `docs/jointloc.md` §"What one estimate
    /// sees"); the correction converges over successive fixes. 0.08 per second (a time
    /// constant of 12 s), half the pace of the 0.3 per fix every 2 s tuned at a fix every
    /// 10th frame (`docs/jointloc.md` §"Terrain correction"): over gravel, where the fixes
    /// share little bias, a faster correction follows noise (§"The windows in seconds of
    /// flight", §"A robust alignment and a slower terrain correction").
    pub gain: f64,
    /// A camera whose horizontal field of view is wider than this many degrees gets no
    /// correction (gain 0). Over a footprint several times the altitude wide, a tilt of the
    /// SLAM's map of a milliradian puts its points centimetres off the model at the edges,
    /// which the estimate reads as a shift: with a 133° fisheye the correction moved the
    /// fixes 7–15 cm and its outputs were 1.3–4× a pinhole's on gravel, with no correction
    /// 0.8–1.7× (`docs/camera.md`). 90: between the pinholes (≤ 60°) and fisheyes measured.
    pub max_fov_deg: f64,
    /// σ of a map point's height against the model, metres.
    pub sigma_m: f64,
    /// Huber threshold in units of `sigma_m` (rocks stand off a smooth model).
    pub huber: f64,
    /// Directions whose formal σ is well above this many metres get little of the gain: over
    /// flat ground a horizontal shift is not observed, and the correction stays where it is.
    pub tau_m: f64,
    /// The correction never exceeds this, metres: a larger disagreement between the fixes
    /// and the terrain is a wrong map or alignment, not a bias of the matching.
    pub max_offset_m: f64,
    /// The map points seen from the keyframes of the newest fixes, as many as this many
    /// seconds hold at the search rate, are put on the model (0: those of the alignment's
    /// window). 10 s (the last 10 m at 1 m/s): the output is the current frame's pose, and the
    /// alignment's whole window (40 m) gave a correction that suited the older part of the map
    /// better than the newest.
    pub window_s: f64,
    /// Fewer map points on the model give no estimate.
    pub min_points: usize,
    /// Gauss–Newton iterations at most.
    pub iterations: usize,
}

impl Default for TerrainConfig {
    fn default() -> Self {
        Self {
            gain: 0.08,
            max_fov_deg: 90.0,
            sigma_m: 0.1,
            huber: 1.0,
            tau_m: 0.03,
            max_offset_m: 0.5,
            window_s: 10.0,
            min_points: 30,
            iterations: 10,
        }
    }
}

/// Robust Gauss–Newton over `hᵢ(d) = zᵢ + dz − H(xᵢ + dx, yᵢ + dy)`, from d = 0; `None`
/// without an elevation model, with too few points on it, or a singular system (no relief in
/// any direction and no height either).
pub fn estimate_shift(
    points: &[Point3<f64>],
    ground: &Ground,
    config: &TerrainConfig,
) -> Option<TerrainShift> {
    if !ground.has_model() || config.sigma_m.is_nan() || config.sigma_m <= 0.0 {
        return None;
    }
    let mut d = Vector3::zeros();
    let mut last = None;
    for _ in 0..config.iterations.max(1) {
        let (h, g, n, _, _) = normal_equations(points, ground, config, &d);
        if n < config.min_points.max(3) {
            return None;
        }
        // The height alone is always observed; a tiny damping keeps a flat model's horizontal
        // directions at zero instead of failing the solve.
        let damped = h + Matrix3::from_diagonal(&Vector3::new(1e-9, 1e-9, 0.0)) * h.trace();
        let step = damped.cholesky()?.solve(&g);
        d += step;
        last = Some((h, n));
        if step.norm() < 1e-5 {
            break;
        }
    }
    let (h, n) = last?;
    let (_, _, _, sq, wsum) = normal_equations(points, ground, config, &d);
    d.iter().all(|v| v.is_finite()).then(|| TerrainShift {
        shift: d,
        information: h,
        points: n,
        rms_m: (sq / wsum.max(1e-12)).sqrt(),
    })
}

/// `(JᵀWJ, −JᵀWr, points used, Σ w r², Σ w)` at the shift `d`.
fn normal_equations(
    points: &[Point3<f64>],
    ground: &Ground,
    config: &TerrainConfig,
    d: &Vector3<f64>,
) -> (Matrix3<f64>, Vector3<f64>, usize, f64, f64) {
    let inv_var = 1.0 / (config.sigma_m * config.sigma_m);
    let delta = config.huber * config.sigma_m;
    let (mut h, mut g) = (Matrix3::zeros(), Vector3::zeros());
    let (mut n, mut sq, mut wsum) = (0, 0.0, 0.0);
    for p in points {
        if !p.coords.iter().all(|v| v.is_finite()) {
            continue;
        }
        let Some((height, slope)) = ground.height_and_slope(p.x + d.x, p.y + d.y) else {
            continue;
        };
        let r = p.z + d.z - height;
        let w = if r.abs() <= delta {
            1.0
        } else {
            delta / r.abs()
        };
        let j = Vector3::new(-slope[0], -slope[1], 1.0);
        h += j * j.transpose() * (w * inv_var);
        g -= j * (w * inv_var * r);
        n += 1;
        sq += w * r * r;
        wsum += w;
    }
    (h, g, n, sq, wsum)
}

/// The correction added to every fix's x, y: the running estimate of minus the fixes' common
/// bias, fed by one [`TerrainShift`] per alignment refit. The shift is measured with the
/// correction already applied, so each estimate is the residual, and the correction is the
/// fixed point where the map sits on the terrain.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TerrainCorrection {
    /// Metres, world x, y.
    pub offset: Vector2<f64>,
    /// Estimates taken in.
    pub updates: usize,
    /// Frame time of the latest estimate taken in, seconds.
    pub last_update_s: Option<f64>,
}

/// An estimate after a gap counts for at most this many seconds of flight: one estimate
/// scatters by centimetres.
const MAX_STEP_S: f64 = 10.0;

impl TerrainCorrection {
    /// Takes in one estimate made at frame time `at_s`: `g · (I + Σ/τ²)⁻¹ · d` of its
    /// horizontal shift `d` with marginal covariance `Σ`, `g = 1 − (1 − gain)^dt` for the
    /// `dt` seconds since the estimate before (1 s for the first), then clamps the correction
    /// to `max_offset_m`.
    pub fn update(&mut self, estimate: &TerrainShift, config: &TerrainConfig, at_s: f64) {
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !positive(config.gain) || !positive(config.tau_m) {
            return;
        }
        let Some(cov) = estimate.information.try_inverse() else {
            return;
        };
        let sigma = Matrix2::new(cov[(0, 0)], cov[(0, 1)], cov[(1, 0)], cov[(1, 1)]);
        let tau2 = config.tau_m * config.tau_m;
        let Some(shrink) = (Matrix2::identity() + sigma / tau2).try_inverse() else {
            return;
        };
        let dt = self
            .last_update_s
            .map_or(1.0, |t| (at_s - t).clamp(0.0, MAX_STEP_S));
        let share = 1.0 - (1.0 - config.gain.min(1.0)).powf(dt);
        let step = shrink * estimate.shift.xy() * share;
        if !step.iter().all(|v| v.is_finite()) {
            return;
        }
        self.offset += step;
        let norm = self.offset.norm();
        if norm > config.max_offset_m {
            self.offset *= config.max_offset_m / norm;
        }
        self.updates += 1;
        self.last_update_s = Some(at_s);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use jointloc_formats::{ElevationInfo, ElevationModel, Grid};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    const POST_M: f64 = 0.5;
    const POSTS: usize = 120;

    /// A 60 m × 60 m model with 0.5 m posts centred on the origin, heights from `h`.
    fn ground(h: impl Fn(f64, f64) -> f64) -> Ground {
        let half = (POSTS as f64 - 1.0) / 2.0 * POST_M;
        let info = ElevationInfo {
            image: "elevation.png".into(),
            gsd_m: POST_M,
            width_px: POSTS as u32,
            height_px: POSTS as u32,
            origin_x_m: -half,
            origin_y_m: half,
            offset_m: 0.0,
            scale_m: 0.001,
            sigma_m: 0.05,
        };
        let mut data = Vec::with_capacity(POSTS * POSTS);
        for row in 0..POSTS {
            for col in 0..POSTS {
                let (x, y) = (-half + col as f64 * POST_M, half - row as f64 * POST_M);
                data.push(h(x, y) as f32);
            }
        }
        let grid = Grid {
            width: POSTS,
            height: POSTS,
            data,
        };
        Ground::from_model(ElevationModel::from_heights(info, grid).unwrap())
    }

    fn relief(x: f64, y: f64) -> f64 {
        1.5 * (0.31 * x).sin() * (0.23 * y).cos() + 0.8 * (0.17 * x + 0.41 * y).sin()
    }

    /// Points on `g` over a 40 m × 12 m strip, 3 cm height noise, 5 % standing 0.5–1.5 m off
    /// (rocks), all moved by `-shift`.
    fn points(g: &Ground, shift: Vector3<f64>, seed: u64) -> Vec<Point3<f64>> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let noise = Normal::new(0.0, 0.03).unwrap();
        (0..1500)
            .map(|_| {
                let (x, y) = (rng.random_range(-20.0..20.0), rng.random_range(-6.0..6.0));
                let mut z = g.height_at(x, y) + noise.sample(&mut rng);
                if rng.random_bool(0.05) {
                    z += rng.random_range(0.5..1.5);
                }
                Point3::new(x, y, z) - shift
            })
            .collect()
    }

    #[test]
    fn a_shift_over_relief_is_found_despite_rocks() {
        let g = ground(relief);
        for seed in 0..5 {
            let truth = Vector3::new(-0.08 + 0.03 * seed as f64, 0.06, 0.02);
            let e =
                estimate_shift(&points(&g, truth, seed), &g, &TerrainConfig::default()).unwrap();
            // Horizontal to 1 cm; the rocks lift the height a little (Huber, not a redescender).
            assert!(
                (e.shift - truth).xy().norm() < 0.01,
                "seed {seed}: {:?}",
                e.shift
            );
            assert!(
                (e.shift.z - truth.z).abs() < 0.02,
                "seed {seed}: {:?}",
                e.shift
            );
            assert_eq!(e.points, 1500);
            assert!(e.rms_m < 0.1, "{}", e.rms_m);
        }
    }

    #[test]
    fn flat_ground_shows_no_horizontal_shift_and_moves_no_correction() {
        let g = ground(|_, _| 2.0);
        let truth = Vector3::new(0.3, -0.2, 0.05);
        let e = estimate_shift(&points(&g, truth, 7), &g, &TerrainConfig::default()).unwrap();
        assert!((e.shift.z - 0.05).abs() < 0.01, "{:?}", e.shift);
        assert!(e.shift.xy().norm() < 1e-6, "{:?}", e.shift);
        let mut c = TerrainCorrection::default();
        c.update(&e, &TerrainConfig::default(), 0.0);
        assert!(c.offset.norm() < 1e-6, "{:?}", c.offset);
    }

    #[test]
    fn the_correction_converges_to_the_bias_and_is_clamped() {
        let g = ground(relief);
        let config = TerrainConfig::default();
        // The map sits where the biased fixes put it, moved by the correction so far.
        let bias = Vector2::new(0.09, -0.07);
        let mut c = TerrainCorrection::default();
        for i in 0..40 {
            let off = bias + c.offset;
            let e = estimate_shift(
                &points(&g, -Vector3::new(off.x, off.y, 0.0), i),
                &g,
                &config,
            )
            .unwrap();
            c.update(&e, &config, i as f64);
        }
        assert!((c.offset + bias).norm() < 0.01, "{:?}", c.offset);
        assert_eq!(c.updates, 40);
        let mut off = TerrainCorrection::default();
        let far = TerrainConfig {
            gain: 1.0,
            max_offset_m: 0.05,
            ..config
        };
        let e = estimate_shift(&points(&g, Vector3::new(0.2, 0.0, 0.0), 1), &g, &far).unwrap();
        off.update(&e, &far, 0.0);
        assert!((off.offset.norm() - 0.05).abs() < 1e-12, "{:?}", off.offset);
    }

    #[test]
    fn the_correction_converges_at_the_same_pace_whatever_the_fix_rate() {
        // A well observed residual (Σ ≈ 0) of a bias of 0.1 m, taken in every 1 s or every
        // 2 s: after the same time of flight the correction is the same.
        let config = TerrainConfig::default();
        let bias = Vector2::new(0.1, 0.0);
        let after = |every_s: f64| {
            let mut c = TerrainCorrection::default();
            let mut t = 0.0;
            while t < 8.5 {
                let residual = -(bias + c.offset);
                let e = TerrainShift {
                    shift: Vector3::new(residual.x, residual.y, 0.0),
                    information: Matrix3::identity() * 1e16,
                    points: 100,
                    rms_m: 0.0,
                };
                c.update(&e, &config, t);
                t += every_s;
            }
            c.offset
        };
        let (fast, slow) = (after(1.0), after(2.0));
        // The first estimate counts 1 s at either rate, the other 8 s in 8 or 4 steps.
        let expected = -bias * (1.0 - (1.0 - config.gain).powi(9));
        assert!((fast - expected).norm() < 1e-9, "{fast:?} {expected:?}");
        assert!(
            (slow - fast).norm() < 0.01 * bias.norm(),
            "{slow:?} {fast:?}"
        );
    }

    #[test]
    fn no_model_or_too_few_points_give_nothing() {
        let config = TerrainConfig::default();
        let p = vec![Point3::new(0.0, 0.0, 0.0); 100];
        assert!(estimate_shift(&p, &Ground::default(), &config).is_none());
        let g = ground(relief);
        assert!(estimate_shift(&p[..10], &g, &config).is_none());
        let nan = vec![Point3::new(f64::NAN, 0.0, 0.0); 100];
        assert!(estimate_shift(&nan, &g, &config).is_none());
    }
}
