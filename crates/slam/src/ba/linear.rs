//! The Gauss–Newton system of one LM iteration and its solution by the Schur complement.
//!
//! Unknowns are ordered cameras first (6 per free camera) then points (3 per free point):
//! ```text
//! [ U  W ] [Δc]   [−g_c]        U: block diagonal 6×6 per camera (+ global factors, priors)
//! [ Wᵀ V ] [Δp] = [−g_p]        V: block diagonal 3×3 per point,  W: one 6×3 block per observation
//! ```
//! Points are eliminated: `S = U − W V⁻¹ Wᵀ` (the reduced camera system) is solved for `Δc`, then
//! every `Δp_j = V_j⁻¹ (−g_p,j − Σ W_ijᵀ Δc_i)` by back substitution. A local window has at most a
//! few dozen free keyframes, so `S` (≤ ~180×180) is assembled dense and factorised with a dense
//! Cholesky (nalgebra); the thousands of points only ever need their own 3×3 inverses. This is
//! what makes the LBA cheap: the cost is linear in the number of observations.

use jointloc_geometry::{RobustKernel, WorldToCamera};
use nalgebra::{DMatrix, DVector, Matrix3, Matrix6, Matrix6x3, Vector3, Vector6};

use super::factors::{ground_height_residual, position_prior, reprojection, reprojection_error};
use super::problem::BaProblem;

/// Marquardt scaling: the damping adds `μ · clamp(H_kk)` to each diagonal entry (as Ceres does),
/// which keeps metres and radians comparable and leaves unconstrained directions invertible.
const MIN_DIAGONAL: f64 = 1e-6;
const MAX_DIAGONAL: f64 = 1e32;

/// Which cameras and points are free, and the observations of each free point.
#[derive(Debug)]
pub(crate) struct Layout {
    pub cam_block: Vec<Option<usize>>,
    pub point_block: Vec<Option<usize>>,
    pub free_cams: usize,
    pub free_points: usize,
    /// Per observation, its slot in the `W` blocks when both its camera and point are free.
    w_slot: Vec<Option<usize>>,
    /// `pairs[pair_start[b]..pair_start[b + 1]]`: `(camera block, W slot)` of free point `b`.
    pair_start: Vec<usize>,
    pairs: Vec<(usize, usize)>,
}

impl Layout {
    pub fn new(problem: &BaProblem) -> Self {
        let blocks = |fixed: &mut dyn Iterator<Item = bool>| {
            let mut n = 0;
            let map: Vec<Option<usize>> = fixed
                .map(|f| {
                    (!f).then(|| {
                        n += 1;
                        n - 1
                    })
                })
                .collect();
            (map, n)
        };
        let (cam_block, free_cams) = blocks(&mut problem.cameras.iter().map(|c| c.fixed));
        let (point_block, free_points) = blocks(&mut problem.points.iter().map(|p| p.fixed));
        let both =
            |o: &super::problem::Observation| Some((cam_block[o.camera]?, point_block[o.point]?));
        let mut w_slot = vec![None; problem.observations.len()];
        let mut counts = vec![0usize; free_points + 1];
        let mut slots = 0;
        for (i, o) in problem.observations.iter().enumerate() {
            if let Some((_, b)) = both(o) {
                counts[b + 1] += 1;
                w_slot[i] = Some(slots);
                slots += 1;
            }
        }
        for b in 0..free_points {
            counts[b + 1] += counts[b];
        }
        let pair_start = counts.clone();
        let mut pairs = vec![(0, 0); slots];
        for (i, o) in problem.observations.iter().enumerate() {
            if let (Some((c, b)), Some(slot)) = (both(o), w_slot[i]) {
                pairs[counts[b]] = (c, slot);
                counts[b] += 1;
            }
        }
        Self {
            cam_block,
            point_block,
            free_cams,
            free_points,
            w_slot,
            pair_start,
            pairs,
        }
    }

    fn pairs_of(&self, block: usize) -> &[(usize, usize)] {
        &self.pairs[self.pair_start[block]..self.pair_start[block + 1]]
    }
}

/// Inverse of a symmetric 3×3 matrix, `None` unless it is positive definite (Sylvester's
/// criterion). Closed form: this runs once per point per LM try.
fn spd_inverse3(m: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    let (a, b, c) = (m[(0, 0)], m[(0, 1)], m[(0, 2)]);
    let (d, e, f) = (m[(1, 1)], m[(1, 2)], m[(2, 2)]);
    let c00 = d * f - e * e;
    let c01 = c * e - b * f;
    let c02 = b * e - c * d;
    let det = a * c00 + b * c01 + c * c02;
    if !(a > 0.0 && a * d - b * b > 0.0 && det > 0.0) {
        return None;
    }
    let c11 = a * f - c * c;
    let c12 = b * c - a * e;
    let c22 = a * d - b * b;
    let inv = Matrix3::new(c00, c01, c02, c01, c11, c12, c02, c12, c22) / det;
    inv.iter().all(|v| v.is_finite()).then_some(inv)
}

/// The current estimate.
#[derive(Debug, Clone)]
pub(crate) struct State {
    pub poses: Vec<WorldToCamera>,
    pub points: Vec<Vector3<f64>>,
}

impl State {
    fn rotations(&self) -> Vec<Matrix3<f64>> {
        self.poses.iter().map(|p| p.rotation_matrix()).collect()
    }

    /// `exp(δ_i) · T_i` for free cameras and `X_j + Δ_j` for free points.
    pub fn updated(&self, layout: &Layout, step: &Step) -> State {
        let mut next = self.clone();
        for (pose, block) in next.poses.iter_mut().zip(&layout.cam_block) {
            if let Some(b) = *block {
                *pose = WorldToCamera(WorldToCamera::exp(&step.cams[b]).0 * pose.0);
            }
        }
        for (x, block) in next.points.iter_mut().zip(&layout.point_block) {
            if let Some(b) = *block {
                *x += step.points[b];
            }
        }
        next
    }

    /// Squared norm of the free translations and points, for the relative step test.
    pub fn free_norm_squared(&self, layout: &Layout) -> f64 {
        let cams: f64 = self
            .poses
            .iter()
            .zip(&layout.cam_block)
            .filter(|(_, b)| b.is_some())
            .map(|(p, _)| p.translation().norm_squared())
            .sum();
        let points: f64 = self
            .points
            .iter()
            .zip(&layout.point_block)
            .filter(|(_, b)| b.is_some())
            .map(|(x, _)| x.norm_squared())
            .sum();
        cams + points
    }
}

/// A solved LM step.
#[derive(Debug)]
pub(crate) struct Step {
    pub cams: Vec<Vector6<f64>>,
    pub points: Vec<Vector3<f64>>,
    /// `L(0) − L(h)` of the quadratic model, for the gain ratio.
    pub predicted_decrease: f64,
}

impl Step {
    pub fn norm_squared(&self) -> f64 {
        self.cams.iter().map(|c| c.norm_squared()).sum::<f64>()
            + self.points.iter().map(|p| p.norm_squared()).sum::<f64>()
    }
}

/// Cost `½ Σ ρ(χ²)` of every term, skipping observations not valid at the linearisation point.
/// Returns `None` when an observation that was valid falls behind its camera, so that LM rejects
/// the step instead of "improving" by losing a term.
pub(crate) fn evaluate_cost(
    problem: &BaProblem,
    kernel: &RobustKernel,
    state: &State,
    valid: &[bool],
) -> Option<f64> {
    let rot = state.rotations();
    let mut cost = 0.0;
    for (o, &ok) in problem.observations.iter().zip(valid) {
        if !ok {
            continue;
        }
        let e = reprojection_error(
            &problem.intrinsics,
            &rot[o.camera],
            &state.poses[o.camera].translation(),
            &state.points[o.point],
            &o.pixel,
        )?;
        cost += kernel.rho(o.information * e.norm_squared());
    }
    Some(0.5 * (cost + camera_terms_cost(problem, state, &rot) + ground_cost(problem, state)))
}

/// `Σ ρ(r²/σ²)` of the ground-height factors (without the ½).
fn ground_cost(problem: &BaProblem, state: &State) -> f64 {
    problem
        .ground_factors
        .iter()
        .map(|g| {
            let (r, _) =
                ground_height_residual(&state.points[g.point], &g.slam_to_world, &g.ground);
            g.kernel.rho(r * r / (g.sigma * g.sigma))
        })
        .sum()
}

/// `Σ w ρ(‖r‖²/σ²) + Σ ‖C − C_prior‖²/σ²` (without the ½).
fn camera_terms_cost(problem: &BaProblem, state: &State, rot: &[Matrix3<f64>]) -> f64 {
    let mut cost = 0.0;
    for g in &problem.global_factors {
        if g.weight == 0.0 {
            continue;
        }
        let t = state.poses[g.camera].translation();
        let (r, _) = g.whitened_residual(&rot[g.camera], &t);
        cost += g.weight * g.kernel.rho(r.norm_squared() / (g.sigma * g.sigma));
    }
    for p in &problem.position_priors {
        let t = state.poses[p.camera].translation();
        let (r, _) = position_prior(&rot[p.camera], &t, &p.position);
        cost += r.norm_squared() / (p.sigma * p.sigma);
    }
    cost
}

/// The robustified Gauss–Newton blocks at one state.
#[derive(Debug)]
pub(crate) struct Linearization {
    u: Vec<Matrix6<f64>>,
    gc: Vec<Vector6<f64>>,
    v: Vec<Matrix3<f64>>,
    gp: Vec<Vector3<f64>>,
    /// `W_ij` per [`Layout`] slot (zero for observations behind their camera).
    w: Vec<Matrix6x3<f64>>,
    /// Observation in front of its camera at this state.
    pub valid: Vec<bool>,
    /// `½ Σ ρ(χ²)` at this state.
    pub cost: f64,
}

impl Linearization {
    /// Linearises at `state`; see [`Linearization::relinearize`].
    pub fn new(problem: &BaProblem, layout: &Layout, kernel: &RobustKernel, state: &State) -> Self {
        let mut lin = Self {
            u: vec![Matrix6::zeros(); layout.free_cams],
            gc: vec![Vector6::zeros(); layout.free_cams],
            v: vec![Matrix3::zeros(); layout.free_points],
            gp: vec![Vector3::zeros(); layout.free_points],
            w: vec![Matrix6x3::zeros(); layout.pairs.len()],
            valid: vec![false; problem.observations.len()],
            cost: 0.0,
        };
        lin.relinearize(problem, layout, kernel, state);
        lin
    }

    /// Rebuilds the blocks at `state`, reusing the buffers. Robust terms use the IRLS weighting
    /// `ρ'(χ²) JᵀΩJ`, `ρ'(χ²) JᵀΩe` (as g2o).
    pub fn relinearize(
        &mut self,
        problem: &BaProblem,
        layout: &Layout,
        kernel: &RobustKernel,
        state: &State,
    ) {
        self.u.fill(Matrix6::zeros());
        self.gc.fill(Vector6::zeros());
        self.v.fill(Matrix3::zeros());
        self.gp.fill(Vector3::zeros());
        let rot = state.rotations();
        let trans: Vec<Vector3<f64>> = state.poses.iter().map(|p| p.translation()).collect();
        let mut cost = 0.0;
        for (i, o) in problem.observations.iter().enumerate() {
            let cb = layout.cam_block[o.camera];
            let pb = layout.point_block[o.point];
            let Some((e, jc, jp)) = reprojection(
                &problem.intrinsics,
                &rot[o.camera],
                &trans[o.camera],
                &state.points[o.point],
                &o.pixel,
            ) else {
                self.valid[i] = false;
                if let Some(slot) = layout.w_slot[i] {
                    self.w[slot] = Matrix6x3::zeros();
                }
                continue;
            };
            self.valid[i] = true;
            let chi2 = o.information * e.norm_squared();
            cost += kernel.rho(chi2);
            let omega = kernel.weight(chi2) * o.information;
            if let Some(c) = cb {
                let jct = jc.transpose() * omega;
                self.u[c] += jct * jc;
                self.gc[c] += jct * e;
                if let Some(slot) = layout.w_slot[i] {
                    self.w[slot] = jct * jp;
                }
            }
            if let Some(p) = pb {
                let jpt = jp.transpose() * omega;
                self.v[p] += jpt * jp;
                self.gp[p] += jpt * e;
            }
        }
        for g in &problem.global_factors {
            let Some(c) = layout.cam_block[g.camera] else {
                continue;
            };
            if g.weight == 0.0 {
                continue;
            }
            let (r, j) = g.whitened_residual(&rot[g.camera], &trans[g.camera]);
            let inv_var = 1.0 / (g.sigma * g.sigma);
            let omega = g.weight * g.kernel.weight(r.norm_squared() * inv_var) * inv_var;
            let jt = j.transpose() * omega;
            self.u[c] += jt * j;
            self.gc[c] += jt * r;
        }
        for p in &problem.position_priors {
            let Some(c) = layout.cam_block[p.camera] else {
                continue;
            };
            let (r, j) = position_prior(&rot[p.camera], &trans[p.camera], &p.position);
            let jt = j.transpose() / (p.sigma * p.sigma);
            self.u[c] += jt * j;
            self.gc[c] += jt * r;
        }
        for g in &problem.ground_factors {
            let Some(p) = layout.point_block[g.point] else {
                continue;
            };
            let (r, j) =
                ground_height_residual(&state.points[g.point], &g.slam_to_world, &g.ground);
            let inv_var = 1.0 / (g.sigma * g.sigma);
            let omega = g.kernel.weight(r * r * inv_var) * inv_var;
            let jt = j.transpose() * omega;
            self.v[p] += jt * j;
            self.gp[p] += jt * r;
        }
        self.cost =
            0.5 * (cost + camera_terms_cost(problem, state, &rot) + ground_cost(problem, state));
    }

    /// `‖g‖∞`, for the first-order optimality test.
    pub fn gradient_max_norm(&self) -> f64 {
        let c = self.gc.iter().map(|g| g.amax()).fold(0.0, f64::max);
        let p = self.gp.iter().map(|g| g.amax()).fold(0.0, f64::max);
        c.max(p)
    }

    /// Solves `(H + μ D) h = −g` by the Schur complement on the points. `None` when the damped
    /// system is not positive definite (LM then raises μ).
    pub fn solve(&self, layout: &Layout, mu: f64) -> Option<Step> {
        let damp = |d: f64| mu * d.clamp(MIN_DIAGONAL, MAX_DIAGONAL);
        // Damped point blocks and their inverses.
        let mut v_inv = Vec::with_capacity(layout.free_points);
        let mut dp = Vec::with_capacity(layout.free_points);
        for v in &self.v {
            let d = Vector3::from_fn(|k, _| damp(v[(k, k)]));
            v_inv.push(spd_inverse3(&(v + Matrix3::from_diagonal(&d)))?);
            dp.push(d);
        }
        let nc = layout.free_cams;
        let n = 6 * nc;
        // S is accumulated as fixed-size 6×6 blocks (upper triangle, `blocks[a * nc + b]`,
        // a ≤ b), which is much faster than writing through views of a dynamic matrix.
        let mut blocks = vec![Matrix6::<f64>::zeros(); nc * nc];
        let mut rhs_blocks: Vec<Vector6<f64>> = self.gc.iter().map(|g| -g).collect();
        let mut dc = Vec::with_capacity(nc);
        for (c, u) in self.u.iter().enumerate() {
            let d = Vector6::from_fn(|k, _| damp(u[(k, k)]));
            blocks[c * nc + c] = u + Matrix6::from_diagonal(&d);
            dc.push(d);
        }
        // S −= W V⁻¹ Wᵀ, rhs −= W V⁻¹ (−g_p), point by point.
        let mut ys: Vec<(usize, Matrix6x3<f64>)> = Vec::new();
        for (pb, vinv) in v_inv.iter().enumerate() {
            let pairs = layout.pairs_of(pb);
            ys.clear();
            ys.extend(pairs.iter().map(|&(c, slot)| (c, self.w[slot] * vinv)));
            let bp = -self.gp[pb];
            for (a, &(ca, ref ya)) in ys.iter().enumerate() {
                rhs_blocks[ca] -= ya * bp;
                for (k, &(cb, slot)) in pairs[a..].iter().enumerate() {
                    let block = ya * self.w[slot].transpose();
                    if ca < cb {
                        blocks[ca * nc + cb] -= block;
                    } else if ca > cb {
                        blocks[cb * nc + ca] -= block.transpose();
                    } else if k == 0 {
                        blocks[ca * nc + ca] -= block;
                    } else {
                        // Same camera twice on one point: the pair and its mirror.
                        blocks[ca * nc + ca] -= block + block.transpose();
                    }
                }
            }
        }
        let mut s = DMatrix::<f64>::zeros(n, n);
        let mut rhs = DVector::<f64>::zeros(n);
        for a in 0..nc {
            rhs.fixed_rows_mut::<6>(6 * a).copy_from(&rhs_blocks[a]);
            for b in a..nc {
                let block = &blocks[a * nc + b];
                s.fixed_view_mut::<6, 6>(6 * a, 6 * b).copy_from(block);
                if b > a {
                    s.fixed_view_mut::<6, 6>(6 * b, 6 * a)
                        .copy_from(&block.transpose());
                }
            }
        }
        let cams_solution = if n > 0 {
            s.cholesky()?.solve(&rhs)
        } else {
            DVector::zeros(0)
        };
        let cams: Vec<Vector6<f64>> = (0..layout.free_cams)
            .map(|c| cams_solution.fixed_rows::<6>(6 * c).into_owned())
            .collect();
        // Back substitution for the points.
        let mut points = Vec::with_capacity(layout.free_points);
        for (pb, vinv) in v_inv.iter().enumerate() {
            let mut b = -self.gp[pb];
            for &(c, slot) in layout.pairs_of(pb) {
                b -= self.w[slot].transpose() * cams[c];
            }
            points.push(vinv * b);
        }
        // L(0) − L(h) = ½ hᵀ(μ D h − g).
        let mut pred = 0.0;
        for ((h, g), d) in cams.iter().zip(&self.gc).zip(&dc) {
            pred += h.dot(&(d.component_mul(h) - g));
        }
        for ((h, g), d) in points.iter().zip(&self.gp).zip(&dp) {
            pred += h.dot(&(d.component_mul(h) - g));
        }
        let step = Step {
            cams,
            points,
            predicted_decrease: 0.5 * pred,
        };
        step.norm_squared().is_finite().then_some(step)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ba::synthetic::{SyntheticSceneConfig, synthetic_scene};
    use crate::ba::{GlobalPositionFactor, PositionPrior};
    use jointloc_geometry::Sim3;

    /// The Schur-complement step equals the step of the full damped system, solved densely.
    #[test]
    fn schur_step_matches_the_dense_solution() {
        for seed in 0..3 {
            let mut p = synthetic_scene(&SyntheticSceneConfig {
                seed,
                rows: 1,
                cols: 4,
                points: 25,
                fixed_cameras: 1,
                ..Default::default()
            })
            .unwrap()
            .problem;
            p.points[0].fixed = true;
            p.points[3].fixed = true;
            // The same camera observing a point twice exercises the diagonal pair blocks.
            let dup = *p
                .observations
                .iter()
                .find(|o| o.camera > 0 && o.point > 3)
                .unwrap();
            p.observations.push(dup);
            p.add_global_factor(GlobalPositionFactor::new(
                2,
                Vector3::new(1.0, 2.0, 50.0),
                Sim3::identity(),
                0.7,
            ));
            p.add_position_prior(PositionPrior {
                camera: 3,
                position: Vector3::new(15.0, 0.0, 49.0),
                sigma: 0.5,
            });
            let layout = Layout::new(&p);
            let state = State {
                poses: p.cameras.iter().map(|c| c.pose).collect(),
                points: p.points.iter().map(|x| x.position).collect(),
            };
            let kernel = RobustKernel::Huber { delta: 2.0 };
            let lin = Linearization::new(&p, &layout, &kernel, &state);
            let (nc, np) = (layout.free_cams, layout.free_points);
            let n = 6 * nc + 3 * np;
            let mut h = DMatrix::<f64>::zeros(n, n);
            let mut g = DVector::<f64>::zeros(n);
            for c in 0..nc {
                h.fixed_view_mut::<6, 6>(6 * c, 6 * c).copy_from(&lin.u[c]);
                g.fixed_rows_mut::<6>(6 * c).copy_from(&lin.gc[c]);
            }
            for b in 0..np {
                let o = 6 * nc + 3 * b;
                h.fixed_view_mut::<3, 3>(o, o).copy_from(&lin.v[b]);
                g.fixed_rows_mut::<3>(o).copy_from(&lin.gp[b]);
                for &(c, slot) in layout.pairs_of(b) {
                    let mut w = h.fixed_view_mut::<6, 3>(6 * c, o);
                    w += lin.w[slot];
                    let mut wt = h.fixed_view_mut::<3, 6>(o, 6 * c);
                    wt += lin.w[slot].transpose();
                }
            }
            for mu in [1e-4, 1.0] {
                let mut damped = h.clone();
                for k in 0..n {
                    damped[(k, k)] += mu * h[(k, k)].clamp(MIN_DIAGONAL, MAX_DIAGONAL);
                }
                let dense = damped.cholesky().unwrap().solve(&(-&g));
                let step = lin.solve(&layout, mu).unwrap();
                let mut schur = DVector::<f64>::zeros(n);
                for (c, d) in step.cams.iter().enumerate() {
                    schur.fixed_rows_mut::<6>(6 * c).copy_from(d);
                }
                for (b, d) in step.points.iter().enumerate() {
                    schur.fixed_rows_mut::<3>(6 * nc + 3 * b).copy_from(d);
                }
                let err = (&schur - &dense).norm() / dense.norm();
                assert!(err < 1e-8, "seed {seed} mu {mu}: {err}");
                // The predicted decrease is the quadratic model's.
                let model = -g.dot(&dense) - 0.5 * dense.dot(&(&h * &dense));
                assert!((step.predicted_decrease - model).abs() < 1e-6 * model.abs());
            }
        }
    }

    #[test]
    fn spd_inverse_rejects_indefinite_matrices() {
        let m = Matrix3::new(4.0, 1.0, 0.5, 1.0, 3.0, 0.2, 0.5, 0.2, 2.0);
        let inv = spd_inverse3(&m).unwrap();
        assert!((inv * m - Matrix3::identity()).norm() < 1e-12);
        assert!(spd_inverse3(&Matrix3::new(1.0, 2.0, 0.0, 2.0, 1.0, 0.0, 0.0, 0.0, 1.0)).is_none());
        assert!(spd_inverse3(&Matrix3::zeros()).is_none());
    }
}
