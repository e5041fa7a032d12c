//! Sim(3) pose-graph optimisation: the core of ORB-SLAM2's `Optimizer::OptimizeEssentialGraph`.
//!
//! After a loop is detected, the keyframe poses are corrected over the essential graph
//! (spanning tree, strong covisibility edges, loop edges) as similarities, so that the scale
//! drift of monocular SLAM is spread along the loop too (Strasdat et al. 2010, "Scale
//! drift-aware large scale monocular SLAM").
//!
//! Each node is a world→camera similarity `S_iw`; each edge measures `S_ij = S_iw · S_jw⁻¹` and
//! has the residual `e = log(S_ij · S_jw · S_iw⁻¹)` of g2o's `EdgeSim3`, with cost
//! `½ Σ w ‖e‖²` and no robust kernel, as in ORB-SLAM2. Levenberg–Marquardt (Nielsen's damping
//! update, `H + λI` as g2o) on the left perturbation `S ← exp(δ) · S`, with analytic Jacobians
//! `∂e/∂δ_j = J_l⁻¹(e) Ad(S_ij)` and `∂e/∂δ_i = −J_l⁻¹(e) Ad(E)`, `E = exp(e)`.
//!
//! The normal equations are solved by a block skyline (envelope) Cholesky over the free nodes in
//! reverse Cuthill–McKee order ([`envelope_order`]), which keeps the rows narrow where a
//! flight's revisits link keyframes far apart in time; Cholesky fill stays inside the
//! envelope and costs `O(N · width²)`. (Conjugate gradients were not used: a chain's condition
//! number grows like N², so they need O(N) iterations and are never exact.)

use jointloc_geometry::Sim3;
use jointloc_geometry::pose::{Vector7, skew};
use nalgebra::{Matrix3, SMatrix, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::{Result, SlamError};

type Matrix7 = SMatrix<f64, 7, 7>;

/// Settings of [`optimise_pose_graph`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PoseGraphConfig {
    /// LM iterations at most (one linearisation each); ORB-SLAM2 runs 20.
    pub iterations: usize,
    /// Rejected (damping-raising) tries per iteration before stopping, as g2o does.
    pub max_rejected_steps: usize,
    /// Initial damping λ relative to the largest diagonal entry of the Hessian (g2o's τ).
    pub initial_damping: f64,
    /// Stop when an accepted step lowers the cost by less than this fraction of it.
    pub function_tolerance: f64,
}

impl Default for PoseGraphConfig {
    fn default() -> Self {
        Self {
            iterations: 20,
            max_rejected_steps: 10,
            initial_damping: 1e-5,
            function_tolerance: 1e-12,
        }
    }
}

impl PoseGraphConfig {
    /// Rejects values the solver cannot work with.
    pub fn validate(&self) -> Result<()> {
        if !(self.initial_damping.is_finite() && self.initial_damping > 0.0) {
            return Err(SlamError::InvalidConfig {
                field: "initial_damping",
                value: self.initial_damping.to_string(),
                reason: "must be finite and > 0",
            });
        }
        if !(self.function_tolerance.is_finite() && self.function_tolerance >= 0.0) {
            return Err(SlamError::InvalidConfig {
                field: "function_tolerance",
                value: self.function_tolerance.to_string(),
                reason: "must be finite and >= 0",
            });
        }
        Ok(())
    }
}

/// One relative constraint: the measured `S_ij = S_iw · S_jw⁻¹` (both world→camera
/// similarities) between nodes `i` and `j`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PoseGraphEdge {
    /// First node.
    pub i: usize,
    /// Second node.
    pub j: usize,
    /// Measured `S_iw · S_jw⁻¹`.
    pub measurement: Sim3,
    /// Information `weight · I₇` (ORB-SLAM2 uses the identity); `0` disables the edge.
    pub weight: f64,
}

/// Outcome of [`optimise_pose_graph`].
#[derive(Debug, Clone, PartialEq)]
pub struct PoseGraphResult {
    /// Optimised `S_iw`, in input order; fixed nodes are returned bit-identical.
    pub poses: Vec<Sim3>,
    /// `½ Σ w ‖e‖²` at the input poses.
    pub initial_cost: f64,
    /// The same at the returned poses.
    pub final_cost: f64,
    /// LM iterations run (linearisations).
    pub iterations: usize,
}

/// Optimises the free nodes of a Sim(3) pose graph.
///
/// At least one node must be fixed, else the 7-DoF gauge is free and the call fails with
/// [`SlamError::InvalidProblem`]. Free components not linked to any fixed node stay solvable
/// through the LM damping (they move only as far as their own edges ask).
pub fn optimise_pose_graph(
    poses: &[Sim3],
    fixed: &[bool],
    edges: &[PoseGraphEdge],
    config: &PoseGraphConfig,
) -> Result<PoseGraphResult> {
    config.validate()?;
    validate_problem(poses, fixed, edges)?;

    // Block index of each free node in reverse Cuthill–McKee order, `None` when fixed.
    let block = envelope_order(poses.len(), fixed, edges);
    let n_free = block.iter().flatten().count();
    let mut skyline = Skyline::new(
        n_free,
        edges
            .iter()
            .filter(|e| e.weight > 0.0)
            .filter_map(|e| Some((block[e.i]?, block[e.j]?))),
    );

    let mut poses = poses.to_vec();
    let initial_cost = total_cost(&poses, edges);
    if !initial_cost.is_finite() {
        return Err(SlamError::NonFinite("pose-graph residual"));
    }
    let mut cost = initial_cost;
    let mut lambda = 0.0;
    let mut nu = 2.0;
    let mut iterations = 0;
    let mut gradient = vec![Vector7::zeros(); n_free];
    while iterations < config.iterations && n_free > 0 && cost > 0.0 {
        iterations += 1;
        skyline.clear();
        gradient.iter_mut().for_each(|g| *g = Vector7::zeros());
        for e in edges.iter().filter(|e| e.weight > 0.0) {
            let (bi, bj) = (block[e.i], block[e.j]);
            if bi.is_none() && bj.is_none() {
                continue;
            }
            let (r, ji, jj) = edge_jacobians(&e.measurement, &poses[e.i], &poses[e.j]);
            let w = e.weight;
            if let Some(a) = bi {
                *skyline.block_mut(a, a) += ji.tr_mul(&ji, w);
                gradient[a] += ji.tr_mul_vec(&r, w);
            }
            if let Some(b) = bj {
                *skyline.block_mut(b, b) += jj.tr_mul(&jj, w);
                gradient[b] += jj.tr_mul_vec(&r, w);
            }
            if let (Some(a), Some(b)) = (bi, bj) {
                // Lower triangle only: the row is the later block.
                if a > b {
                    *skyline.block_mut(a, b) += ji.tr_mul(&jj, w);
                } else {
                    *skyline.block_mut(b, a) += jj.tr_mul(&ji, w);
                }
            }
        }
        if iterations == 1 {
            lambda = config.initial_damping * skyline.max_diagonal().max(f64::MIN_POSITIVE);
        }

        let mut accepted = None;
        for _ in 0..=config.max_rejected_steps {
            if let Some(step) = skyline.solve_damped(lambda, &gradient) {
                // Predicted decrease of the quadratic model: ½ δᵀ(λδ − g).
                let predicted: f64 = step
                    .iter()
                    .zip(&gradient)
                    .map(|(d, g)| 0.5 * d.dot(&(lambda * d - g)))
                    .sum();
                // NaN-safe: a NaN prediction also ends the retries.
                if predicted.is_nan() || predicted <= f64::EPSILON * cost {
                    // Converged to round-off: no step can be told from noise, stop retrying.
                    break;
                }
                let trial = apply_step(&poses, &block, &step);
                let trial_cost = total_cost(&trial, edges);
                let gain = (cost - trial_cost) / predicted;
                if trial_cost.is_finite() && gain > 0.0 {
                    lambda *= (1.0 - (2.0 * gain - 1.0).powi(3)).max(1.0 / 3.0);
                    nu = 2.0;
                    accepted = Some((trial, trial_cost));
                    break;
                }
            }
            lambda *= nu;
            nu *= 2.0;
        }
        let Some((trial, trial_cost)) = accepted else {
            break;
        };
        let decrease = cost - trial_cost;
        poses = trial;
        cost = trial_cost;
        if decrease <= config.function_tolerance * (cost + decrease) {
            break;
        }
    }
    tracing::debug!(
        nodes = poses.len(),
        free = n_free,
        edges = edges.len(),
        envelope_blocks = skyline.blocks.len(),
        iterations,
        initial_cost,
        final_cost = cost,
        "Sim(3) pose graph optimised"
    );
    Ok(PoseGraphResult {
        poses,
        initial_cost,
        final_cost: cost,
        iterations,
    })
}

/// The block index of each free node (`None`: fixed) in reverse Cuthill–McKee order (George &
/// Liu 1981): each connected part of the graph of free nodes is numbered breadth-first from a
/// pseudo-peripheral node, neighbours by increasing degree, and the numbering reversed. Input
/// order puts every revisit's edges far from the diagonal (a flight that crosses its path many
/// times links keyframes hundreds apart), and the envelope Cholesky costs the square of the
/// rows' widths; this order keeps the rows narrow (on a 1000 m flight that crosses itself
/// often, 455 nodes: 30 209 envelope blocks in input order; `docs/vo.md` §6.1a). Ties go to
/// the lower index, so the order is deterministic.
fn envelope_order(n: usize, fixed: &[bool], edges: &[PoseGraphEdge]) -> Vec<Option<usize>> {
    let mut adjacency: Vec<Vec<usize>> = vec![Vec::new(); n];
    for e in edges.iter().filter(|e| e.weight > 0.0) {
        if e.i != e.j && !fixed[e.i] && !fixed[e.j] {
            adjacency[e.i].push(e.j);
            adjacency[e.j].push(e.i);
        }
    }
    for a in &mut adjacency {
        a.sort_unstable();
        a.dedup();
    }
    let degree = |v: usize| adjacency[v].len();
    // Breadth-first levels from `root` within its part: (order visited, last level).
    let bfs = |root: usize, seen: &mut Vec<bool>| -> (Vec<usize>, Vec<usize>) {
        let mut order = vec![root];
        seen[root] = true;
        let mut level_start = 0;
        let mut last_level = vec![root];
        while level_start < order.len() {
            let level_end = order.len();
            for k in level_start..level_end {
                let mut next: Vec<usize> = adjacency[order[k]]
                    .iter()
                    .copied()
                    .filter(|&v| !seen[v])
                    .collect();
                next.sort_by_key(|&v| (degree(v), v));
                for v in next {
                    if !seen[v] {
                        seen[v] = true;
                        order.push(v);
                    }
                }
            }
            if order.len() > level_end {
                last_level = order[level_end..].to_vec();
            }
            level_start = level_end;
        }
        (order, last_level)
    };
    let mut placed = vec![false; n];
    let mut sequence: Vec<usize> = Vec::with_capacity(n);
    let mut starts: Vec<usize> = (0..n).filter(|&v| !fixed[v]).collect();
    starts.sort_by_key(|&v| (degree(v), v));
    for start in starts {
        if placed[start] {
            continue;
        }
        // Pseudo-peripheral root: the lowest-degree node of the farthest level, twice.
        let mut root = start;
        for _ in 0..2 {
            let mut scratch = placed.clone();
            let (_, last) = bfs(root, &mut scratch);
            root = last
                .into_iter()
                .min_by_key(|&v| (degree(v), v))
                .unwrap_or(root);
        }
        let (order, _) = bfs(root, &mut placed);
        sequence.extend(order);
    }
    sequence.reverse();
    let mut block = vec![None; n];
    for (b, &v) in sequence.iter().enumerate() {
        block[v] = Some(b);
    }
    block
}

fn validate_problem(poses: &[Sim3], fixed: &[bool], edges: &[PoseGraphEdge]) -> Result<()> {
    if poses.is_empty() {
        return Err(SlamError::InvalidProblem("pose graph has no nodes".into()));
    }
    if fixed.len() != poses.len() {
        return Err(SlamError::InvalidProblem(format!(
            "{} fixed flags for {} poses",
            fixed.len(),
            poses.len()
        )));
    }
    if !fixed.iter().any(|&f| f) {
        return Err(SlamError::InvalidProblem(
            "no fixed node: the Sim(3) gauge is free".into(),
        ));
    }
    for p in poses {
        check_sim3(p, "pose-graph node pose")?;
    }
    for (k, e) in edges.iter().enumerate() {
        if e.i >= poses.len() || e.j >= poses.len() {
            return Err(SlamError::InvalidProblem(format!(
                "edge {k} links node {} to {} but there are {} nodes",
                e.i,
                e.j,
                poses.len()
            )));
        }
        if e.i == e.j {
            return Err(SlamError::InvalidProblem(format!(
                "edge {k} links node {} to itself",
                e.i
            )));
        }
        check_sim3(&e.measurement, "pose-graph edge measurement")?;
        if !e.weight.is_finite() {
            return Err(SlamError::NonFinite("pose-graph edge weight"));
        }
        if e.weight < 0.0 {
            return Err(SlamError::InvalidProblem(format!(
                "edge {k} has negative weight {}",
                e.weight
            )));
        }
    }
    Ok(())
}

fn check_sim3(s: &Sim3, what: &'static str) -> Result<()> {
    let q = s.rotation.coords;
    let finite = s.scale.is_finite()
        && q.iter().all(|v| v.is_finite())
        && s.translation.iter().all(|v| v.is_finite());
    if !finite {
        return Err(SlamError::NonFinite(what));
    }
    if s.scale <= 0.0 {
        return Err(SlamError::InvalidProblem(format!(
            "{what} has scale {} (must be > 0)",
            s.scale
        )));
    }
    if (q.norm() - 1.0).abs() > 1e-6 {
        return Err(SlamError::InvalidProblem(format!(
            "{what} has a non-unit quaternion (norm {})",
            q.norm()
        )));
    }
    Ok(())
}

/// The error similarity `E = S_ij · S_jw · S_iw⁻¹` (identity when consistent).
fn edge_error(measurement: &Sim3, s_iw: &Sim3, s_jw: &Sim3) -> Sim3 {
    measurement.compose(s_jw).compose(&s_iw.inverse())
}

fn total_cost(poses: &[Sim3], edges: &[PoseGraphEdge]) -> f64 {
    edges
        .iter()
        .map(|e| {
            let r = edge_error(&e.measurement, &poses[e.i], &poses[e.j]).log();
            0.5 * e.weight * r.norm_squared()
        })
        .sum()
}

/// `S ← exp(δ) · S` on the free nodes; unit quaternions are renormalised against drift.
fn apply_step(poses: &[Sim3], block: &[Option<usize>], step: &[Vector7]) -> Vec<Sim3> {
    poses
        .iter()
        .zip(block)
        .map(|(p, b)| match b {
            Some(b) => {
                let s = Sim3::exp(&step[*b]).compose(p);
                Sim3::new(
                    s.scale,
                    UnitQuaternion::new_normalize(s.rotation.into_inner()),
                    s.translation,
                )
            }
            None => *p,
        })
        .collect()
}

/// Residual and its Jacobians with respect to left perturbations of `S_iw` and `S_jw`.
///
/// `S_jw → exp(δ) S_jw` gives `E → exp(Ad(S_ij) δ) E`; `S_iw → exp(δ) S_iw` gives
/// `E → E exp(−δ) = exp(−Ad(E) δ) E`; and `log(exp(a) E) ≈ e + J_l(e)⁻¹ a`.
fn edge_jacobians(measurement: &Sim3, s_iw: &Sim3, s_jw: &Sim3) -> (Vector7, Tri, Tri) {
    let err = edge_error(measurement, s_iw, s_jw);
    let r = err.log();
    let jl_inv = left_jacobian(&r).inverse();
    let mut ji = jl_inv.mul(&Tri::adjoint(&err));
    ji.scale_by(-1.0);
    (r, ji, jl_inv.mul(&Tri::adjoint(measurement)))
}

/// Left Jacobian `J_l(ξ) = Σ_k ad(ξ)^k / (k+1)!`. The series is entire and, because `ρ` enters
/// `ad` nilpotently, its terms shrink like `|(σ, θ)|^k / k!`; it is summed until they vanish.
fn left_jacobian(xi: &Vector7) -> Tri {
    let phi_x = skew(&xi.fixed_rows::<3>(3).into_owned());
    let rho = xi.fixed_rows::<3>(0).into_owned();
    // ad(ξ) = [[σI + [φ]×, [ρ]×, −ρ], [0, [φ]×, 0], [0, 0, 0]].
    let ad = Tri {
        p: phi_x + xi[6] * Matrix3::identity(),
        q: skew(&rho),
        u: -rho,
        d: phi_x,
        z: 0.0,
    };
    let mut term = Tri::identity();
    let mut sum = Tri::identity();
    for k in 1..80 {
        term = term.mul(&ad);
        term.scale_by(1.0 / (k as f64 + 1.0));
        sum.add(&term);
        if term.amax() <= 1e-17 * sum.amax() {
            break;
        }
    }
    sum
}

/// A 7×7 matrix `[[p, q, u], [0, d, 0], [0, 0, z]]` on `[ρ; φ; σ]`: the shape shared by the
/// Sim(3) adjoints, `ad`, `J_l`, their inverses and products, kept in 3×3 blocks for speed.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Tri {
    p: Matrix3<f64>,
    q: Matrix3<f64>,
    u: Vector3<f64>,
    d: Matrix3<f64>,
    z: f64,
}

impl Tri {
    fn identity() -> Self {
        Self {
            p: Matrix3::identity(),
            q: Matrix3::zeros(),
            u: Vector3::zeros(),
            d: Matrix3::identity(),
            z: 1.0,
        }
    }

    /// `Ad(S) ξ = log(S exp(ξ) S⁻¹)` for `S = (s, R, t)`: `[[sR, [t]×R, −t], [0, R, 0], [0, 0, 1]]`.
    fn adjoint(s: &Sim3) -> Self {
        let r = s.rotation_matrix();
        Self {
            p: s.scale * r,
            q: skew(&s.translation) * r,
            u: -s.translation,
            d: r,
            z: 1.0,
        }
    }

    fn mul(&self, b: &Tri) -> Tri {
        Tri {
            p: self.p * b.p,
            q: self.p * b.q + self.q * b.d,
            u: self.p * b.u + self.u * b.z,
            d: self.d * b.d,
            z: self.z * b.z,
        }
    }

    /// Block inverse; the identity only if `p` or `d` is singular, which `J_l` and the adjoints
    /// never are for finite input (θ ≤ π).
    fn inverse(&self) -> Tri {
        let (Some(p), Some(d)) = (self.p.try_inverse(), self.d.try_inverse()) else {
            return Tri::identity();
        };
        Tri {
            p,
            q: -p * self.q * d,
            u: -p * self.u / self.z,
            d,
            z: 1.0 / self.z,
        }
    }

    fn scale_by(&mut self, f: f64) {
        self.p *= f;
        self.q *= f;
        self.u *= f;
        self.d *= f;
        self.z *= f;
    }

    fn add(&mut self, b: &Tri) {
        self.p += b.p;
        self.q += b.q;
        self.u += b.u;
        self.d += b.d;
        self.z += b.z;
    }

    fn amax(&self) -> f64 {
        [
            self.p.amax(),
            self.q.amax(),
            self.u.amax(),
            self.d.amax(),
            self.z.abs(),
        ]
        .into_iter()
        .fold(0.0, f64::max)
    }

    /// `w · selfᵀ b`, block by block.
    fn tr_mul(&self, b: &Tri, w: f64) -> Matrix7 {
        let mut m = Matrix7::zeros();
        let pt = self.p.transpose() * w;
        let qt = self.q.transpose() * w;
        let ut = self.u.transpose() * w;
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&(pt * b.p));
        m.fixed_view_mut::<3, 3>(0, 3).copy_from(&(pt * b.q));
        m.fixed_view_mut::<3, 1>(0, 6).copy_from(&(pt * b.u));
        m.fixed_view_mut::<3, 3>(3, 0).copy_from(&(qt * b.p));
        m.fixed_view_mut::<3, 3>(3, 3)
            .copy_from(&(qt * b.q + w * self.d.transpose() * b.d));
        m.fixed_view_mut::<3, 1>(3, 6).copy_from(&(qt * b.u));
        m.fixed_view_mut::<1, 3>(6, 0).copy_from(&(ut * b.p));
        m.fixed_view_mut::<1, 3>(6, 3).copy_from(&(ut * b.q));
        m[(6, 6)] = (ut * b.u)[0] + w * self.z * b.z;
        m
    }

    /// `w · selfᵀ r`.
    fn tr_mul_vec(&self, r: &Vector7, w: f64) -> Vector7 {
        let (rr, rp) = (r.fixed_rows::<3>(0), r.fixed_rows::<3>(3));
        let mut g = Vector7::zeros();
        g.fixed_rows_mut::<3>(0)
            .copy_from(&(self.p.tr_mul(&rr) * w));
        g.fixed_rows_mut::<3>(3)
            .copy_from(&((self.q.tr_mul(&rr) + self.d.tr_mul(&rp)) * w));
        g[6] = w * (self.u.dot(&rr) + self.z * r[6]);
        g
    }

    #[cfg(test)]
    fn to_matrix(self) -> Matrix7 {
        let mut m = Matrix7::zeros();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&self.p);
        m.fixed_view_mut::<3, 3>(0, 3).copy_from(&self.q);
        m.fixed_view_mut::<3, 1>(0, 6).copy_from(&self.u);
        m.fixed_view_mut::<3, 3>(3, 3).copy_from(&self.d);
        m[(6, 6)] = self.z;
        m
    }
}

/// Symmetric block matrix stored as the lower envelope of 7×7 blocks, factored in place by a
/// row-oriented (Crout) block Cholesky: fill never leaves the envelope.
#[derive(Debug)]
struct Skyline {
    /// First column of each block row.
    first: Vec<usize>,
    /// Offset of each block row in `blocks`.
    offset: Vec<usize>,
    /// The assembled matrix (lower envelope, row-major).
    blocks: Vec<Matrix7>,
    /// `L` in the same layout, flat: 49 column-major values per block, so that a run of blocks
    /// of one row is a 7 × 7k column-major strip.
    factor: Vec<f64>,
    /// `L_ii⁻¹` per block row.
    diag_inv: Vec<Matrix7>,
}

impl Skyline {
    fn new(n: usize, links: impl Iterator<Item = (usize, usize)>) -> Self {
        let mut first: Vec<usize> = (0..n).collect();
        for (a, b) in links {
            let (row, col) = if a > b { (a, b) } else { (b, a) };
            first[row] = first[row].min(col);
        }
        let mut offset = Vec::with_capacity(n);
        let mut total = 0;
        for (row, &f) in first.iter().enumerate() {
            offset.push(total);
            total += row - f + 1;
        }
        Self {
            first,
            offset,
            blocks: vec![Matrix7::zeros(); total],
            factor: vec![0.0; 49 * total],
            diag_inv: vec![Matrix7::zeros(); n],
        }
    }

    fn clear(&mut self) {
        self.blocks.iter_mut().for_each(|b| *b = Matrix7::zeros());
    }

    /// Block `(row, col)`, `first[row] ≤ col ≤ row` (guaranteed by construction).
    fn block_mut(&mut self, row: usize, col: usize) -> &mut Matrix7 {
        &mut self.blocks[self.offset[row] + col - self.first[row]]
    }

    fn max_diagonal(&self) -> f64 {
        (0..self.first.len())
            .map(|r| {
                let d = &self.blocks[self.offset[r] + r - self.first[r]];
                (0..7).map(|k| d[(k, k)]).fold(0.0, f64::max)
            })
            .fold(0.0, f64::max)
    }

    /// Solves `(H + λI) δ = −g`; `None` when the damped matrix is not positive definite.
    fn solve_damped(&mut self, lambda: f64, gradient: &[Vector7]) -> Option<Vec<Vector7>> {
        let n = self.first.len();
        let strip = |from: usize, to: usize| 49 * from..49 * to;
        for i in 0..n {
            let (fi, oi) = (self.first[i], self.offset[i]);
            for k in fi..i {
                let (fk, ok) = (self.first[k], self.offset[k]);
                let m0 = fi.max(fk);
                let mut s = self.blocks[oi + k - fi];
                sub_a_bt(
                    &mut s,
                    &self.factor[strip(oi + m0 - fi, oi + k - fi)],
                    &self.factor[strip(ok + m0 - fk, ok + k - fk)],
                );
                let l = s * self.diag_inv[k].transpose();
                self.factor[strip(oi + k - fi, oi + k - fi + 1)].copy_from_slice(l.as_slice());
            }
            let mut d = self.blocks[oi + i - fi];
            let row = &self.factor[strip(oi, oi + i - fi)];
            sub_a_bt(&mut d, row, row);
            for k in 0..7 {
                d[(k, k)] += lambda;
            }
            let l = nalgebra::Cholesky::new(d)?.l();
            self.diag_inv[i] = l.solve_lower_triangular(&Matrix7::identity())?;
        }
        let block = |b: usize| Matrix7::from_column_slice(&self.factor[strip(b, b + 1)]);
        // L y = −g, then Lᵀ δ = y (column-oriented so only row envelopes are read).
        let mut y: Vec<Vector7> = gradient.iter().map(|g| -g).collect();
        for i in 0..n {
            let (fi, oi) = (self.first[i], self.offset[i]);
            let mut acc = y[i];
            for (k, yk) in y[fi..i].iter().enumerate() {
                acc -= block(oi + k) * yk;
            }
            y[i] = self.diag_inv[i] * acc;
        }
        for i in (0..n).rev() {
            let (fi, oi) = (self.first[i], self.offset[i]);
            let x = self.diag_inv[i].transpose() * y[i];
            y[i] = x;
            for (k, yk) in y[fi..i].iter_mut().enumerate() {
                *yk -= block(oi + k).tr_mul(&x);
            }
        }
        y.iter()
            .all(|v| v.iter().all(|x| x.is_finite()))
            .then_some(y)
    }
}

/// `s −= A Bᵀ` for 7 × 7k column-major strips `A`, `B`: one rank-1 update per column pair, a
/// loop the compiler vectorises, over contiguous strips with no per-block copies.
fn sub_a_bt(s: &mut Matrix7, a: &[f64], b: &[f64]) {
    let s = s.as_mut_slice();
    for (ca, cb) in a.chunks_exact(7).zip(b.chunks_exact(7)) {
        for (c, &bc) in cb.iter().enumerate() {
            for (sr, &ar) in s[7 * c..7 * c + 7].iter_mut().zip(ca) {
                *sr -= ar * bc;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    fn random_xi(rng: &mut ChaCha8Rng, trans: f64, rot: f64, scale: f64) -> Vector7 {
        let n = Normal::new(0.0, 1.0).expect("unit normal");
        let mut xi = Vector7::zeros();
        for k in 0..7 {
            let sd = [trans, trans, trans, rot, rot, rot, scale][k];
            xi[k] = sd * n.sample(rng);
        }
        xi
    }

    /// World→camera truth on a circle of radius 10 m, looking outwards, gently bobbing.
    fn circle(n: usize) -> Vec<Sim3> {
        (0..n)
            .map(|k| {
                let a = std::f64::consts::TAU * k as f64 / n as f64;
                let centre = Vector3::new(10.0 * a.cos(), 10.0 * a.sin(), 0.5 * (3.0 * a).sin());
                let q_wc = UnitQuaternion::from_euler_angles(-1.2, 0.1 * a.sin(), a);
                Sim3::new(1.0, q_wc, centre).inverse()
            })
            .collect()
    }

    fn edge(truth: &[Sim3], i: usize, j: usize, noise: Option<Vector7>) -> PoseGraphEdge {
        let m = truth[i].compose(&truth[j].inverse());
        PoseGraphEdge {
            i,
            j,
            measurement: noise.map_or(m, |xi| Sim3::exp(&xi).compose(&m)),
            weight: 1.0,
        }
    }

    /// Integrates the true odometry with a constant bias `exp(d)` per step from node 0.
    fn drifted(truth: &[Sim3], d: &Vector7) -> Vec<Sim3> {
        let bias = Sim3::exp(d);
        let mut est = vec![truth[0]];
        for k in 1..truth.len() {
            let rel = truth[k].compose(&truth[k - 1].inverse());
            let prev = est[k - 1];
            est.push(bias.compose(&rel).compose(&prev));
        }
        est
    }

    fn drift_bias() -> Vector7 {
        Vector7::from_column_slice(&[0.004, -0.002, 0.003, 0.002, -0.001, 0.0025, 0.003])
    }

    fn centre(s: &Sim3) -> Point3<f64> {
        s.inverse().transform_point(&Point3::origin())
    }

    /// Largest and RMS camera-centre error, largest rotation error (rad), largest |log scale|.
    type Errors = (f64, f64, f64, f64);

    fn errors(est: &[Sim3], truth: &[Sim3]) -> Errors {
        let (mut max, mut sq, mut rot, mut scale) = (0.0f64, 0.0, 0.0f64, 0.0f64);
        for (e, t) in est.iter().zip(truth) {
            let d = (centre(e) - centre(t)).norm();
            max = max.max(d);
            sq += d * d;
            rot = rot.max(e.rotation.angle_to(&t.rotation));
            scale = scale.max((e.scale / t.scale).ln().abs());
        }
        (max, (sq / est.len() as f64).sqrt(), rot, scale)
    }

    fn bits(s: &Sim3) -> Vec<u64> {
        std::iter::once(s.scale)
            .chain(s.rotation.coords.iter().copied())
            .chain(s.translation.iter().copied())
            .map(f64::to_bits)
            .collect()
    }

    /// Chain, covisibility to the next `covis` nodes and loop edges closing the circle.
    fn graph(truth: &[Sim3], covis: usize, rng: Option<&mut ChaCha8Rng>) -> Vec<PoseGraphEdge> {
        let n = truth.len();
        let mut pairs = Vec::new();
        for i in 0..n {
            for k in 1..=covis {
                if i + k < n {
                    pairs.push((i, i + k));
                }
            }
        }
        pairs.extend([(n - 1, 0), (n - 2, 1), (n - 1, 2)]);
        let mut rng = rng;
        pairs
            .into_iter()
            .map(|(i, j)| {
                let noise = rng
                    .as_deref_mut()
                    .map(|r| random_xi(r, 0.005, 0.001, 0.001));
                edge(truth, i, j, noise)
            })
            .collect()
    }

    fn fixed_first(n: usize) -> Vec<bool> {
        (0..n).map(|k| k == 0).collect()
    }

    #[test]
    fn analytic_jacobians_match_central_differences() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let h = 1e-6;
        for _ in 0..20 {
            let s_iw = Sim3::exp(&random_xi(&mut rng, 3.0, 0.8, 0.4));
            let s_jw = Sim3::exp(&random_xi(&mut rng, 3.0, 0.8, 0.4));
            // A measurement off by a sizeable error, so J_l(e) is far from the identity.
            let m = Sim3::exp(&random_xi(&mut rng, 0.5, 0.4, 0.3))
                .compose(&s_iw)
                .compose(&s_jw.inverse());
            let (r, ji, jj) = edge_jacobians(&m, &s_iw, &s_jw);
            let (ji, jj) = (ji.to_matrix(), jj.to_matrix());
            assert!(r.norm() > 0.1, "residual too small to test J_l: {r}");
            for k in 0..7 {
                let mut d = Vector7::zeros();
                d[k] = h;
                let plus = |s: &Sim3, sign: f64| Sim3::exp(&(sign * d)).compose(s);
                let ni = (edge_error(&m, &plus(&s_iw, 1.0), &s_jw).log()
                    - edge_error(&m, &plus(&s_iw, -1.0), &s_jw).log())
                    / (2.0 * h);
                let nj = (edge_error(&m, &s_iw, &plus(&s_jw, 1.0)).log()
                    - edge_error(&m, &s_iw, &plus(&s_jw, -1.0)).log())
                    / (2.0 * h);
                let (ai, aj) = (ji.column(k), jj.column(k));
                assert!(
                    (ai - ni).amax() < 1e-6 * (1.0 + ni.amax()),
                    "∂e/∂δ_i[{k}]: {ai} vs {ni}"
                );
                assert!(
                    (aj - nj).amax() < 1e-6 * (1.0 + nj.amax()),
                    "∂e/∂δ_j[{k}]: {aj} vs {nj}"
                );
            }
        }
    }

    #[test]
    fn corrects_accumulated_drift_on_noise_free_loop() {
        let truth = circle(200);
        let init = drifted(&truth, &drift_bias());
        let edges = graph(&truth, 1, None);
        let before = errors(&init, &truth);
        assert!(
            before.0 > 5.0 && before.2 > 0.3 && before.3 > 0.5,
            "drift too small: {before:?}"
        );
        let res = optimise_pose_graph(
            &init,
            &fixed_first(200),
            &edges,
            &PoseGraphConfig::default(),
        )
        .expect("optimises");
        let after = errors(&res.poses, &truth);
        assert!(
            res.final_cost < 1e-12 * res.initial_cost,
            "{} → {}",
            res.initial_cost,
            res.final_cost
        );
        assert!(
            after.0 < 1e-6 && after.2 < 1e-8 && after.3 < 1e-8,
            "{after:?} (before {before:?})"
        );
        assert!(before.0 / after.0 > 1e6);
        assert!(res.iterations <= 20);
    }

    #[test]
    fn noisy_edges_bring_error_well_below_drift() {
        let truth = circle(200);
        let init = drifted(&truth, &drift_bias());
        let mut rng = ChaCha8Rng::seed_from_u64(42);
        let edges = graph(&truth, 2, Some(&mut rng));
        let before = errors(&init, &truth);
        let res = optimise_pose_graph(
            &init,
            &fixed_first(200),
            &edges,
            &PoseGraphConfig::default(),
        )
        .expect("optimises");
        let after = errors(&res.poses, &truth);
        assert!(res.final_cost < 1e-3 * res.initial_cost);
        assert!(after.1 < 0.05 * before.1, "RMS {} → {}", before.1, after.1);
        assert!(
            after.0 < 0.5 && after.2 < 0.05 && after.3 < 0.05,
            "{after:?}"
        );
    }

    #[test]
    fn fixed_nodes_stay_bit_identical() {
        let truth = circle(120);
        let init = drifted(&truth, &drift_bias());
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let edges = graph(&truth, 2, Some(&mut rng));
        let fixed: Vec<bool> = (0..120).map(|k| k % 40 == 0 || k == 77).collect();
        let res = optimise_pose_graph(&init, &fixed, &edges, &PoseGraphConfig::default())
            .expect("optimises");
        for (k, f) in fixed.iter().enumerate() {
            if *f {
                assert_eq!(bits(&res.poses[k]), bits(&init[k]), "node {k} moved");
            } else {
                assert_ne!(
                    bits(&res.poses[k]),
                    bits(&init[k]),
                    "free node {k} did not move"
                );
            }
        }
    }

    #[test]
    fn deterministic() {
        let truth = circle(150);
        let init = drifted(&truth, &drift_bias());
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let edges = graph(&truth, 3, Some(&mut rng));
        let run = || {
            optimise_pose_graph(
                &init,
                &fixed_first(150),
                &edges,
                &PoseGraphConfig::default(),
            )
            .expect("optimises")
        };
        let (a, b) = (run(), run());
        assert_eq!(a.final_cost.to_bits(), b.final_cost.to_bits());
        assert_eq!(a.iterations, b.iterations);
        for (p, q) in a.poses.iter().zip(&b.poses) {
            assert_eq!(bits(p), bits(q));
        }
    }

    #[test]
    fn bad_inputs_are_errors() {
        let truth = circle(10);
        let edges = graph(&truth, 1, None);
        let fixed = fixed_first(10);
        let cfg = PoseGraphConfig::default();
        let run = |p: &[Sim3], f: &[bool], e: &[PoseGraphEdge], c: &PoseGraphConfig| {
            optimise_pose_graph(p, f, e, c)
        };
        let invalid = |r: Result<PoseGraphResult>| matches!(r, Err(SlamError::InvalidProblem(_)));
        let non_finite = |r: Result<PoseGraphResult>| matches!(r, Err(SlamError::NonFinite(_)));

        assert!(invalid(run(&[], &[], &[], &cfg)));
        assert!(invalid(run(&truth, &fixed[..9], &edges, &cfg)));
        assert!(invalid(run(&truth, &[false; 10], &edges, &cfg)));
        let mut p = truth.clone();
        p[3].translation.x = f64::NAN;
        assert!(non_finite(run(&p, &fixed, &edges, &cfg)));
        let mut p = truth.clone();
        p[4].scale = f64::INFINITY;
        assert!(non_finite(run(&p, &fixed, &edges, &cfg)));
        let mut p = truth.clone();
        p[5].scale = 0.0;
        assert!(invalid(run(&p, &fixed, &edges, &cfg)));
        p[5].scale = -1.0;
        assert!(invalid(run(&p, &fixed, &edges, &cfg)));
        let mut p = truth.clone();
        p[6].rotation =
            UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(0.0, 0.0, 0.0, 0.0));
        assert!(invalid(run(&p, &fixed, &edges, &cfg)));

        let with = |f: &dyn Fn(&mut PoseGraphEdge)| {
            let mut e = edges.clone();
            f(&mut e[2]);
            run(&truth, &fixed, &e, &cfg)
        };
        assert!(invalid(with(&|e| e.j = 10)));
        assert!(invalid(with(&|e| e.i = usize::MAX)));
        assert!(invalid(with(&|e| e.j = e.i)));
        assert!(invalid(with(&|e| e.weight = -1.0)));
        assert!(invalid(with(&|e| e.measurement.scale = 0.0)));
        assert!(non_finite(with(&|e| e.weight = f64::NAN)));
        assert!(non_finite(with(&|e| e.measurement.rotation =
            UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(
                f64::NAN,
                0.0,
                0.0,
                0.0
            )))));

        for bad in [
            PoseGraphConfig {
                initial_damping: 0.0,
                ..cfg
            },
            PoseGraphConfig {
                initial_damping: f64::NAN,
                ..cfg
            },
            PoseGraphConfig {
                function_tolerance: -1.0,
                ..cfg
            },
        ] {
            assert!(matches!(
                run(&truth, &fixed, &edges, &bad),
                Err(SlamError::InvalidConfig { .. })
            ));
        }
        // Degenerate but valid: no edges, zero-weight edges, all nodes fixed.
        let no_edges = run(&truth, &fixed, &[], &cfg).expect("no edges is fine");
        assert_eq!(no_edges.poses, truth);
        let all_fixed = run(&truth, &[true; 10], &edges, &cfg).expect("all fixed is fine");
        assert_eq!(all_fixed.iterations, 0);
    }

    #[test]
    fn free_component_without_fixed_node_stays_finite() {
        // Nodes 5..10 are linked only among themselves: their gauge is held by the damping.
        let truth = circle(10);
        let init = drifted(&truth, &drift_bias());
        let edges: Vec<_> = [
            (0, 1),
            (1, 2),
            (2, 3),
            (3, 4),
            (5, 6),
            (6, 7),
            (7, 8),
            (8, 9),
        ]
        .iter()
        .map(|&(i, j)| edge(&truth, i, j, None))
        .collect();
        let res = optimise_pose_graph(&init, &fixed_first(10), &edges, &PoseGraphConfig::default())
            .expect("optimises");
        assert!(res.final_cost < 1e-12 * res.initial_cost);
        assert!(
            res.poses
                .iter()
                .all(|p| p.scale.is_finite() && p.translation.iter().all(|v| v.is_finite()))
        );
    }

    /// Times a circle of `n` nodes with edges to the next four nodes and a few long loops.
    fn timed_run(n: usize) -> (Errors, Errors) {
        let truth = circle(n);
        let init = drifted(&truth, &(drift_bias() * 200.0 / n as f64));
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut edges = graph(&truth, 4, Some(&mut rng));
        for (i, j) in [(n / 2, n / 30), (3 * n / 4, n / 4), (29 * n / 30, n / 2)] {
            let noise = random_xi(&mut rng, 0.005, 0.001, 0.001);
            edges.push(edge(&truth, i, j, Some(noise)));
        }
        // Best of five: the machine is shared.
        let mut ms = f64::INFINITY;
        let mut res = None;
        for _ in 0..5 {
            let start = std::time::Instant::now();
            let cfg = PoseGraphConfig::default();
            res =
                Some(optimise_pose_graph(&init, &fixed_first(n), &edges, &cfg).expect("optimises"));
            ms = ms.min(start.elapsed().as_secs_f64() * 1e3);
        }
        let res = res.expect("ran");
        let (before, after) = (errors(&init, &truth), errors(&res.poses, &truth));
        println!(
            "pose graph: {n} nodes, {} edges, {} iterations in {ms:.1} ms ({:.2} ms/iteration); \
             cost {:.3e} → {:.3e}; RMS centre error {:.3} → {:.4} m",
            edges.len(),
            res.iterations,
            ms / res.iterations as f64,
            res.initial_cost,
            res.final_cost,
            before.1,
            after.1
        );
        (before, after)
    }

    #[test]
    fn three_hundred_nodes_with_long_loops_converge() {
        let (before, after) = timed_run(300);
        assert!(after.1 < 0.05 * before.1);
    }

    /// Envelope blocks of the skyline for the free nodes numbered by `block`.
    fn envelope_blocks(block: &[Option<usize>], edges: &[PoseGraphEdge]) -> usize {
        let n_free = block.iter().flatten().count();
        Skyline::new(
            n_free,
            edges
                .iter()
                .filter_map(|e| Some((block[e.i]?, block[e.j]?))),
        )
        .blocks
        .len()
    }

    #[test]
    fn reverse_cuthill_mckee_narrows_the_envelope_of_a_flight_over_its_own_path() {
        // A random walk inside a square, as a long flight's keyframes: a chain, plus an edge
        // between any two nodes within 2 units (covisible on a revisit).
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let n = 400;
        let mut at = Vec::with_capacity(n);
        let (mut x, mut y, mut heading) = (10.0f64, 10.0f64, 0.0f64);
        for _ in 0..n {
            heading += rng.random_range(-0.4..0.4);
            x = (x + heading.cos()).clamp(0.0, 20.0);
            y = (y + heading.sin()).clamp(0.0, 20.0);
            if !(0.5..19.5).contains(&x) || !(0.5..19.5).contains(&y) {
                heading += std::f64::consts::PI;
            }
            at.push((x, y));
        }
        let mut edges = Vec::new();
        for i in 0..n {
            for j in 0..i {
                let d = (at[i].0 - at[j].0).hypot(at[i].1 - at[j].1);
                if j + 1 == i || d < 2.0 {
                    edges.push(PoseGraphEdge {
                        i,
                        j,
                        measurement: Sim3::identity(),
                        weight: 1.0,
                    });
                }
            }
        }
        let mut fixed = vec![false; n];
        fixed[0] = true;
        let rcm = envelope_order(n, &fixed, &edges);
        // A numbering of exactly the free nodes.
        assert_eq!(rcm[0], None);
        let mut seen: Vec<usize> = rcm.iter().flatten().copied().collect();
        seen.sort_unstable();
        assert_eq!(seen, (0..n - 1).collect::<Vec<_>>());
        let input: Vec<Option<usize>> = (0..n).map(|i| i.checked_sub(1)).collect();
        let (ordered, plain) = (
            envelope_blocks(&rcm, &edges),
            envelope_blocks(&input, &edges),
        );
        assert!(
            2 * ordered < plain,
            "reverse Cuthill-McKee {ordered} blocks, input order {plain}"
        );
    }

    #[test]
    #[ignore = "timing only: cargo test --release -- --ignored --nocapture"]
    fn timing_1000_nodes_4000_edges() {
        let (before, after) = timed_run(1000);
        assert!(after.1 < 0.05 * before.1);
    }
}
