//! Perspective rendering of the heightfield from the UAV camera by exact ray casting.
//!
//! The surface is the bilinear interpolant of the height samples. A maximum mip-map (level 0:
//! the highest corner of each bilinear patch, which bounds the patch; level k: the maximum of
//! 2^k × 2^k patches) lets a ray skip any block it passes above in one step, so empty space
//! costs O(log n) steps instead of one per cell. Inside a level-0 patch the height along the ray
//! is a quadratic in the ray parameter, so the first crossing is solved in closed form: the
//! image is exact up to floating point, which the marker test relies on.
//!
//! Pixel `(u, v)` samples the ray through its centre, given by [`PinholeCamera::unproject`]
//! (distortion included), so rendering and projection agree by construction.

use jointloc_geometry::{CameraToWorld, Distortion, PinholeCamera};
use nalgebra::{Point2, Point3, Vector3};
use rayon::prelude::*;

use crate::error::{Result, SimError};
use crate::terrain::Terrain;
use jointloc_formats::Grid;

/// Maximum mip-map over the bilinear patches of a heightfield.
#[derive(Debug, Clone)]
pub struct MaxPyramid {
    /// `levels[k]` holds the maximum over blocks of `2^k × 2^k` patches.
    pub levels: Vec<Grid<f32>>,
}

impl MaxPyramid {
    /// Builds the pyramid; the heightfield needs at least 2 × 2 samples.
    pub fn new(height: &Grid<f32>) -> Result<Self> {
        if height.width < 2 || height.height < 2 {
            return Err(SimError::InvalidConfig {
                field: "terrain.height",
                value: format!("{}x{}", height.width, height.height),
                reason: "a heightfield needs at least 2 × 2 samples".into(),
            });
        }
        let (w, h) = (height.width - 1, height.height - 1);
        let mut base = Grid::filled(w, h, 0.0f32);
        base.data
            .par_chunks_mut(w)
            .enumerate()
            .for_each(|(r, row)| {
                let top = &height.data[r * height.width..(r + 1) * height.width];
                let bottom = &height.data[(r + 1) * height.width..(r + 2) * height.width];
                for (c, out) in row.iter_mut().enumerate() {
                    *out = top[c].max(top[c + 1]).max(bottom[c]).max(bottom[c + 1]);
                }
            });
        let mut levels = vec![base];
        loop {
            let prev = levels.last().expect("non-empty");
            if prev.width == 1 && prev.height == 1 {
                break;
            }
            let (pw, ph) = (prev.width, prev.height);
            let (nw, nh) = (pw.div_ceil(2), ph.div_ceil(2));
            let mut next = Grid::filled(nw, nh, f32::NEG_INFINITY);
            next.data
                .par_chunks_mut(nw)
                .enumerate()
                .for_each(|(r, row)| {
                    for (c, out) in row.iter_mut().enumerate() {
                        let mut m = f32::NEG_INFINITY;
                        for rr in 2 * r..(2 * r + 2).min(ph) {
                            for cc in 2 * c..(2 * c + 2).min(pw) {
                                m = m.max(prev.at(cc, rr));
                            }
                        }
                        *out = m;
                    }
                });
            levels.push(next);
        }
        Ok(Self { levels })
    }

    /// Highest point of the surface.
    pub fn max_height(&self) -> f32 {
        self.levels.last().expect("non-empty").data[0]
    }
}

/// Where a ray meets the terrain.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Ray parameter: `point = origin + t · dir`.
    pub t: f64,
    /// World point on the surface.
    pub point: Point3<f64>,
    /// Fractional (col, row) of the point in the terrain grids.
    pub cell: (f64, f64),
}

/// Ray caster over a terrain's heightfield.
#[derive(Debug, Clone)]
pub struct HeightfieldTracer<'a> {
    terrain: &'a Terrain,
    pyramid: MaxPyramid,
    min_height: f64,
}

/// Safety net against pathological rays (never reached in practice: a ray over a 10⁴ × 10⁴
/// grid needs a few hundred steps).
const MAX_STEPS: usize = 1 << 16;

impl<'a> HeightfieldTracer<'a> {
    /// Builds the max pyramid of `terrain.height`.
    pub fn new(terrain: &'a Terrain) -> Result<Self> {
        if !(terrain.cell_m.is_finite() && terrain.cell_m > 0.0) {
            return Err(SimError::InvalidConfig {
                field: "terrain.cell_m",
                value: terrain.cell_m.to_string(),
                reason: "must be positive".into(),
            });
        }
        let min_height = terrain
            .height
            .data
            .iter()
            .fold(f32::INFINITY, |a, &b| a.min(b)) as f64;
        Ok(Self {
            terrain,
            pyramid: MaxPyramid::new(&terrain.height)?,
            min_height,
        })
    }

    /// The terrain traced.
    pub fn terrain(&self) -> &Terrain {
        self.terrain
    }

    /// First intersection of the ray `origin + t · dir` (t > 0) with the surface; `None` when
    /// the ray leaves the terrain or points upwards.
    pub fn cast(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<Hit> {
        let top = self.pyramid.levels.len() - 1;
        self.cast_from(origin, dir, self.pyramid.max_height() as f64, top)
            .0
    }

    /// [`cast`](Self::cast) with a start hint, also returning the number of traversal steps.
    /// `z_max` must bound the surface everywhere the ray passes before it hits (use
    /// [`region_max`](Self::region_max) over the ray's footprint); `level` is the pyramid level
    /// the traversal starts at (any level is correct; blocks about the size of the ray's
    /// horizontal travel are fastest).
    pub fn cast_from(
        &self,
        origin: &Point3<f64>,
        dir: &Vector3<f64>,
        z_max: f64,
        level: usize,
    ) -> (Option<Hit>, u32) {
        let tr = self.terrain;
        let dz = dir.z;
        if dz.is_nan() || dz >= 0.0 {
            return (None, 0);
        }
        let c = tr.cell_m;
        // Ray in cell coordinates (p: column, q: row) and height.
        let (p0, q0) = tr.world_to_cell(origin.x, origin.y);
        let (dp, dq) = (dir.x / c, -dir.y / c);
        let z0 = origin.z;
        let inv_dz = 1.0 / -dz;
        let nx = (tr.height.width - 1) as f64;
        let ny = (tr.height.height - 1) as f64;
        // Slab test against [0, nx] × [0, ny].
        let (mut t_in, mut t_out) = (0.0f64, f64::INFINITY);
        for (o, d, hi) in [(p0, dp, nx), (q0, dq, ny)] {
            if d == 0.0 {
                if o < 0.0 || o > hi {
                    return (None, 0);
                }
            } else {
                let (a, b) = ((0.0 - o) / d, (hi - o) / d);
                t_in = t_in.max(a.min(b));
                t_out = t_out.min(a.max(b));
            }
        }
        let top = self.pyramid.levels.len() - 1;
        let mut t = t_in.max((z0 - z_max) * inv_dz);
        let mut level = level.min(top);
        // Exit parameter along one axis: `(border − o) / d` with the border ahead of the ray.
        let axis = |o: f64, d: f64| {
            let inv = if d != 0.0 { 1.0 / d } else { f64::INFINITY };
            (o, inv, d > 0.0)
        };
        let (ap, aq) = (axis(p0, dp), axis(q0, dq));
        let exit = |(o, inv, forward): (f64, f64, bool), lo: f64, size: f64| {
            if inv.is_infinite() {
                f64::INFINITY
            } else if forward {
                (lo + size - o) * inv
            } else {
                (lo - o) * inv
            }
        };
        // A tiny step past block borders so the next lookup lands in the next block.
        let nudge = 1e-7 / dp.abs().max(dq.abs()).max(1e-300);
        let mut steps = 0u32;
        while (steps as usize) < MAX_STEPS {
            steps += 1;
            if t > t_out {
                return (None, steps);
            }
            let (p, q) = (p0 + t * dp, q0 + t * dq);
            let grid = &self.pyramid.levels[level];
            let size = (1usize << level) as f64;
            let inv_size = 1.0 / size;
            let bi = ((p * inv_size).floor().max(0.0) as usize).min(grid.width - 1);
            let bj = ((q * inv_size).floor().max(0.0) as usize).min(grid.height - 1);
            let t_exit = exit(ap, bi as f64 * size, size)
                .min(exit(aq, bj as f64 * size, size))
                .min(t_out);
            let block_max = grid.data[bj * grid.width + bi] as f64;
            let t_reach = (z0 - block_max) * inv_dz;
            if t_reach > t_exit {
                // The ray passes above this whole block.
                t = t_exit + nudge;
                level = (level + 1).min(top);
                continue;
            }
            t = t.max(t_reach);
            if level > 0 {
                level -= 1;
                continue;
            }
            if let Some(th) = self.patch_hit(bi, bj, t, t_exit, (p0, q0, z0), (dp, dq, dz)) {
                let (p, q) = (p0 + th * dp, q0 + th * dq);
                let hit = Hit {
                    t: th,
                    point: origin + th * dir,
                    cell: (p, q),
                };
                return (Some(hit), steps);
            }
            t = t_exit + nudge;
            level = 1.min(top);
        }
        (None, steps)
    }

    /// An upper bound of the surface height over the world rectangle `[x0, x1] × [y0, y1]`
    /// (from the coarsest pyramid level that needs at most 4 × 4 blocks to cover it).
    pub fn region_max(&self, x0: f64, y0: f64, x1: f64, y1: f64) -> f64 {
        let tr = self.terrain;
        let (ca, ra) = tr.world_to_cell(x0.min(x1), y0.max(y1));
        let (cb, rb) = tr.world_to_cell(x0.max(x1), y0.min(y1));
        let span = (cb - ca).max(rb - ra).max(1.0);
        let top = self.pyramid.levels.len() - 1;
        let level = ((span / 3.0).log2().ceil().max(0.0) as usize).min(top);
        let grid = &self.pyramid.levels[level];
        let size = (1usize << level) as f64;
        let idx = |v: f64, n: usize| ((v / size).floor().max(0.0) as usize).min(n - 1);
        let mut m = f32::NEG_INFINITY;
        for j in idx(ra - 1.0, grid.height)..=idx(rb + 1.0, grid.height) {
            for i in idx(ca - 1.0, grid.width)..=idx(cb + 1.0, grid.width) {
                m = m.max(grid.at(i, j));
            }
        }
        m as f64
    }

    /// Lowest and highest height sample.
    pub fn height_range(&self) -> (f64, f64) {
        (self.min_height, self.pyramid.max_height() as f64)
    }

    /// First `t ∈ [t0, t1]` where the ray is at or below the bilinear patch `(i, j)`.
    fn patch_hit(
        &self,
        i: usize,
        j: usize,
        t0: f64,
        t1: f64,
        (p0, q0, z0): (f64, f64, f64),
        (dp, dq, dz): (f64, f64, f64),
    ) -> Option<f64> {
        let h = &self.terrain.height;
        let h00 = h.at(i, j) as f64;
        let h10 = h.at(i + 1, j) as f64;
        let h01 = h.at(i, j + 1) as f64;
        let h11 = h.at(i + 1, j + 1) as f64;
        let (e1, e2, e3) = (h10 - h00, h01 - h00, h00 - h10 - h01 + h11);
        // Local coordinates at t0; f(τ) = z − h along the ray, τ = t − t0: A τ² + B τ + C.
        let a = p0 + t0 * dp - i as f64;
        let b = q0 + t0 * dq - j as f64;
        let h_start = h00 + e1 * a + e2 * b + e3 * a * b;
        let cc = z0 + t0 * dz - h_start;
        if cc <= 0.0 {
            return Some(t0);
        }
        let bb = dz - (e1 * dp + e2 * dq + e3 * (a * dq + b * dp));
        let aa = -e3 * dp * dq;
        let span = t1 - t0;
        let root = smallest_root_in(aa, bb, cc, span)?;
        Some(t0 + root)
    }
}

/// Smallest root of `a τ² + b τ + c` in `[0, span]`, given `c > 0`.
#[inline]
fn smallest_root_in(a: f64, b: f64, c: f64, span: f64) -> Option<f64> {
    let scale = b.abs().max(c.abs()).max(1e-300);
    let in_range = |r: f64| (0.0..=span).contains(&r).then_some(r);
    if a.abs() * span <= 1e-12 * scale {
        return if b < 0.0 { in_range(-c / b) } else { None };
    }
    let disc = b * b - 4.0 * a * c;
    if disc < 0.0 {
        return None;
    }
    let sq = disc.sqrt();
    let q = -0.5 * (b + b.signum() * sq);
    let (r1, r2) = (q / a, if q != 0.0 { c / q } else { f64::INFINITY });
    let (lo, hi) = (r1.min(r2), r1.max(r2));
    in_range(lo).or_else(|| in_range(hi))
}

/// Renders terrain radiance as seen by a pinhole camera.
#[derive(Debug, Clone)]
pub struct UavRenderer<'a> {
    tracer: HeightfieldTracer<'a>,
    radiance: &'a Grid<f32>,
    camera: PinholeCamera,
    /// Camera-frame ray (x, y, 1) through each pixel centre; NaN where undistortion fails.
    rays: Vec<[f64; 2]>,
    /// Radiance of pixels whose ray misses the terrain.
    background: f32,
    /// `tan` of the angle from the vertical that the map's margin covers: a fisheye's rays
    /// beyond it (and those at or beyond 90° off axis) are expected to see the background.
    /// Infinite for a pinhole.
    covered_tan: f64,
}

/// A rendered frame of linear radiance.
#[derive(Debug, Clone)]
pub struct RenderedFrame {
    pub radiance: Grid<f32>,
    /// Pixels whose ray left the terrain inside the covered angle (filled with the
    /// background radiance): the map's margin was too small.
    pub misses: usize,
    /// A fisheye's pixels beyond the angle the map covers ([`crate::config::FISHEYE_MAP_ANGLE_DEG`])
    /// that saw the background, as intended.
    pub beyond_cover: usize,
}

impl<'a> UavRenderer<'a> {
    /// Prepares a renderer; `radiance` must have the terrain's grid size.
    pub fn new(
        terrain: &'a Terrain,
        radiance: &'a Grid<f32>,
        camera: PinholeCamera,
    ) -> Result<Self> {
        if radiance.width != terrain.height.width || radiance.height != terrain.height.height {
            return Err(SimError::InvalidConfig {
                field: "radiance",
                value: format!("{}x{}", radiance.width, radiance.height),
                reason: format!(
                    "must match the terrain grid {}x{}",
                    terrain.height.width, terrain.height.height
                ),
            });
        }
        validate_camera(&camera)?;
        let (w, h) = (camera.width as usize, camera.height as usize);
        let rays = (0..w * h)
            .into_par_iter()
            .map(|k| {
                let uv = Point2::new((k % w) as f64, (k / w) as f64);
                camera.unproject(&uv).map_or([f64::NAN; 2], |r| [r.x, r.y])
            })
            .collect();
        let background = mean(&radiance.data);
        let covered_tan = crate::config::fisheye_cover_tan(&camera).unwrap_or(f64::INFINITY);
        Ok(Self {
            tracer: HeightfieldTracer::new(terrain)?,
            radiance,
            camera,
            rays,
            background,
            covered_tan,
        })
    }

    /// The ray caster (for ground-truth look-ups).
    pub fn tracer(&self) -> &HeightfieldTracer<'a> {
        &self.tracer
    }

    /// The camera rendered.
    pub fn camera(&self) -> &PinholeCamera {
        &self.camera
    }

    /// Start of every ray of a frame: a bound of the surface over the frame's footprint (the
    /// image border's rays between the highest and lowest terrain heights, which enclose every
    /// other ray there) and a pyramid level matching the rays' horizontal travel below it.
    pub fn frame_start(&self, pose: &CameraToWorld) -> (f64, usize) {
        let (z_lo, z_hi) = self.tracer.height_range();
        let top = self.tracer.pyramid.levels.len() - 1;
        let origin = pose.centre();
        let r = pose.rotation_matrix();
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        let z_top = z_hi.min(origin.z);
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        let mut max_slope: f64 = 0.0;
        let border = (0..w)
            .step_by(4)
            .chain([w - 1])
            .flat_map(|u| [(u, 0), (u, h - 1)])
            .chain(
                (0..h)
                    .step_by(4)
                    .chain([h - 1])
                    .flat_map(|v| [(0, v), (w - 1, v)]),
            );
        for (u, v) in border {
            let [x, y] = self.rays[v * w + u];
            if x.is_nan() {
                continue;
            }
            let d = r * Vector3::new(x, y, 1.0);
            if d.z >= -1e-9 {
                // A ray at or above the horizon: no useful bound.
                return (z_hi, top);
            }
            max_slope = max_slope.max(d.xy().norm() / -d.z);
            for z in [z_top, z_lo] {
                let t = (origin.z - z) / -d.z;
                let p = origin + t * d;
                lo = [lo[0].min(p.x), lo[1].min(p.y)];
                hi = [hi[0].max(p.x), hi[1].max(p.y)];
            }
        }
        if !lo[0].is_finite() {
            return (z_hi, top);
        }
        // Border rays are sampled every 4 pixels; a few cells of margin cover the gaps.
        let m = 4.0 * self.tracer.terrain.cell_m + 0.01 * (hi[0] - lo[0] + hi[1] - lo[1]);
        let z_max = self
            .tracer
            .region_max(lo[0] - m, lo[1] - m, hi[0] + m, hi[1] + m)
            .min(z_hi);
        // Horizontal travel (cells) of the steepest ray over a quarter of the local relief.
        let travel = 0.25 * (z_max - z_lo).max(0.0) * max_slope / self.tracer.terrain.cell_m;
        let level = (travel.max(1.0).log2().ceil() as usize).min(top);
        (z_max, level)
    }

    /// Renders the radiance seen from `pose`, rows in parallel.
    pub fn render(&self, pose: &CameraToWorld) -> RenderedFrame {
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        let r = pose.rotation_matrix();
        let origin = pose.centre();
        let (z_max, start_level) = self.frame_start(pose);
        let mut image = Grid::filled(w, h, self.background);
        let fisheye = self.covered_tan.is_finite();
        let (misses, beyond_cover) = image
            .data
            .par_chunks_mut(w)
            .enumerate()
            .map(|(v, row)| {
                let (mut misses, mut beyond) = (0, 0);
                for (u, out) in row.iter_mut().enumerate() {
                    let [x, y] = self.rays[v * w + u];
                    if x.is_nan() {
                        // A fisheye pixel at or beyond 90° off axis; otherwise a lens model
                        // that cannot be inverted there.
                        if fisheye {
                            beyond += 1
                        } else {
                            misses += 1
                        }
                        continue;
                    }
                    let dir = r * Vector3::new(x, y, 1.0);
                    match self.tracer.cast_from(&origin, &dir, z_max, start_level).0 {
                        Some(hit) => *out = self.radiance.bilinear(hit.cell.0, hit.cell.1),
                        // Past the covered angle from the vertical (the map's margin is
                        // set in world terms, and the camera may be tilted).
                        None if dir.xy().norm() > -dir.z * self.covered_tan => beyond += 1,
                        None => misses += 1,
                    }
                }
                (misses, beyond)
            })
            .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
        RenderedFrame {
            radiance: image,
            misses,
            beyond_cover,
        }
    }
}

/// Checks intrinsics and image size.
pub fn validate_camera(camera: &PinholeCamera) -> Result<()> {
    let bad = |field: &'static str, value: String, reason: &str| {
        Err(SimError::InvalidConfig {
            field,
            value,
            reason: reason.into(),
        })
    };
    if camera.width < 2 || camera.height < 2 || camera.width > 16384 || camera.height > 16384 {
        return bad(
            "camera.width/height",
            format!("{}x{}", camera.width, camera.height),
            "must be between 2 and 16384 pixels",
        );
    }
    for (field, v) in [("camera.fx", camera.fx), ("camera.fy", camera.fy)] {
        if !(v.is_finite() && v > 0.0) {
            return bad(field, v.to_string(), "must be positive");
        }
    }
    for (field, v) in [("camera.cx", camera.cx), ("camera.cy", camera.cy)] {
        if !v.is_finite() {
            return bad(field, v.to_string(), "must be finite");
        }
    }
    if let Some(d) = camera.distortion
        && !d.coefficients().iter().all(|c| c.is_finite())
    {
        return bad("camera.distortion", format!("{d:?}"), "must be finite");
    }
    if let Some(Distortion::KannalaBrandt(lens)) = camera.distortion {
        // θ_d must increase over the image: up to the farthest corner or 90°.
        let corner = [camera.cx, camera.width as f64 - camera.cx]
            .iter()
            .map(|dx| (dx + 0.5) / camera.fx)
            .fold(0.0, f64::max)
            .hypot(
                [camera.cy, camera.height as f64 - camera.cy]
                    .iter()
                    .map(|dy| (dy + 0.5) / camera.fy)
                    .fold(0.0, f64::max),
            );
        let steps = 256;
        for i in 1..=steps {
            let theta = std::f64::consts::FRAC_PI_2 * i as f64 / steps as f64;
            let (td, dtd) = lens.theta_d(theta);
            if dtd <= 0.0 {
                return bad(
                    "camera.distortion",
                    format!("{lens:?}"),
                    "the Kannala-Brandt polynomial must increase up to 90° off axis",
                );
            }
            if td > corner {
                break;
            }
        }
    }
    Ok(())
}

fn mean(values: &[f32]) -> f32 {
    if values.is_empty() {
        return 0.0;
    }
    (values.iter().map(|&v| v as f64).sum::<f64>() / values.len() as f64) as f32
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn bumpy(seed: u64, w: usize, h: usize) -> Terrain {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let bumps: Vec<(f64, f64, f64, f64)> = (0..40)
            .map(|_| {
                (
                    rng.random_range(0.0..w as f64 * 0.05),
                    rng.random_range(-(h as f64) * 0.05..0.0),
                    rng.random_range(0.1..0.6),
                    rng.random_range(0.2..1.5),
                )
            })
            .collect();
        let mut height = Grid::filled(w, h, 0.0f32);
        for r in 0..h {
            for c in 0..w {
                let (x, y) = (c as f64 * 0.05, -(r as f64) * 0.05);
                let mut z = 0.8 * (x / 3.0).sin() + 0.5 * (y / 2.3).cos();
                for &(bx, by, radius, amp) in &bumps {
                    let d2 = ((x - bx).powi(2) + (y - by).powi(2)) / (radius * radius);
                    z += amp * (-d2).exp();
                }
                *height.at_mut(c, r) = z as f32;
            }
        }
        Terrain {
            cell_m: 0.05,
            origin_x: 0.0,
            origin_y: 0.0,
            albedo: Grid::filled(w, h, 0.3),
            height,
        }
    }

    /// Reference: march with a tiny fixed step and bisect.
    fn brute_force(tr: &Terrain, o: &Point3<f64>, d: &Vector3<f64>) -> Option<f64> {
        let step = 0.002;
        let above = |t: f64| {
            let p = o + t * d;
            p.z - tr.height_at(p.x, p.y)
        };
        let mut t = 0.0;
        while t < 100.0 {
            let p = o + (t + step) * d;
            let (c, r) = tr.world_to_cell(p.x, p.y);
            if c < 0.0
                || r < 0.0
                || c > (tr.height.width - 1) as f64
                || r > (tr.height.height - 1) as f64
            {
                return None;
            }
            if above(t + step) <= 0.0 {
                let (mut lo, mut hi) = (t, t + step);
                for _ in 0..60 {
                    let mid = 0.5 * (lo + hi);
                    if above(mid) > 0.0 {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                return Some(hi);
            }
            t += step;
        }
        None
    }

    #[test]
    fn cast_matches_brute_force_marching() {
        for seed in 0..3 {
            let tr = bumpy(seed, 301, 257);
            let tracer = HeightfieldTracer::new(&tr).unwrap();
            let mut rng = ChaCha8Rng::seed_from_u64(100 + seed);
            for _ in 0..300 {
                let o = Point3::new(
                    rng.random_range(2.0..13.0),
                    rng.random_range(-11.0..-2.0),
                    rng.random_range(3.0..6.0),
                );
                let d = Vector3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    -1.0,
                );
                let fast = tracer.cast(&o, &d);
                let slow = brute_force(&tr, &o, &d);
                match (fast, slow) {
                    (Some(h), Some(t)) => {
                        // The marcher can step over a grazing sliver; otherwise they agree.
                        assert!(h.t <= t + 1e-5, "seed {seed}: fast {} after slow {t}", h.t);
                        if (h.t - t).abs() > 1e-5 {
                            assert!(
                                t - h.t < 0.002 * d.norm() * 2.0,
                                "seed {seed}: {} vs {t}",
                                h.t
                            );
                        }
                        let ground = tr.height_at(h.point.x, h.point.y);
                        assert!((h.point.z - ground).abs() < 1e-5);
                    }
                    (None, None) => {}
                    (f, s) => panic!("seed {seed}: fast {f:?} slow {s:?}"),
                }
            }
        }
    }

    #[test]
    fn frame_start_hint_changes_nothing_but_speed() {
        use jointloc_geometry::RadTan;
        let tr = bumpy(4, 301, 257);
        let radiance = tr.albedo.clone();
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for distortion in [
            None,
            Some(
                RadTan {
                    k1: -0.2,
                    k2: 0.05,
                    ..Default::default()
                }
                .into(),
            ),
            Some(jointloc_geometry::KannalaBrandt::default().into()),
        ] {
            let camera = match distortion {
                Some(Distortion::KannalaBrandt(lens)) => {
                    PinholeCamera::fisheye(133.0, 64, 48, lens).unwrap()
                }
                _ => PinholeCamera {
                    distortion,
                    ..PinholeCamera::ideal(60.0, 64, 48)
                },
            };
            let renderer = UavRenderer::new(&tr, &radiance, camera).unwrap();
            for _ in 0..20 {
                let angle = rng.random_range(-3.0..3.0);
                let tilt = Vector3::new(
                    rng.random_range(-0.2..0.2),
                    rng.random_range(-0.2..0.2),
                    0.0,
                );
                let r = nalgebra::UnitQuaternion::from_rotation_matrix(
                    &crate::trajectory::nadir_rotation(angle),
                ) * nalgebra::UnitQuaternion::from_scaled_axis(tilt);
                let c = Vector3::new(
                    rng.random_range(5.0..10.0),
                    rng.random_range(-8.0..-4.0),
                    rng.random_range(2.0..5.0),
                );
                let pose = CameraToWorld::from_rotation_translation(r, c);
                let (z_max, level) = renderer.frame_start(&pose);
                assert!(z_max <= renderer.tracer().height_range().1);
                for v in 0..48 {
                    for u in 0..64 {
                        let Some(ray) = camera.unproject(&Point2::new(u as f64, v as f64)) else {
                            continue;
                        };
                        let d = pose.rotation_matrix() * ray;
                        let fast = renderer
                            .tracer()
                            .cast_from(&pose.centre(), &d, z_max, level)
                            .0;
                        let plain = renderer.tracer().cast(&pose.centre(), &d);
                        match (fast, plain) {
                            (Some(a), Some(b)) => {
                                assert!((a.t - b.t).abs() < 1e-9, "pixel ({u}, {v})")
                            }
                            (None, None) => {}
                            other => panic!("pixel ({u}, {v}): {other:?}"),
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn smallest_root_handles_degenerate_quadratics() {
        assert_eq!(smallest_root_in(0.0, -2.0, 1.0, 1.0), Some(0.5));
        assert_eq!(smallest_root_in(0.0, 2.0, 1.0, 1.0), None);
        // (τ − 0.25)(τ − 0.75) = τ² − τ + 0.1875
        let r = smallest_root_in(1.0, -1.0, 0.1875, 1.0).unwrap();
        assert!((r - 0.25).abs() < 1e-12);
        assert_eq!(smallest_root_in(1.0, -1.0, 0.1875, 0.2), None);
        // −τ² + τ + 0.75 opens downwards, roots −0.5 and 1.5.
        let r = smallest_root_in(-1.0, 1.0, 0.75, 2.0).unwrap();
        assert!((r - 1.5).abs() < 1e-12);
    }

    #[test]
    fn nadir_view_of_flat_ground_maps_pixels_to_the_expected_ground_points() {
        let mut tr = bumpy(0, 201, 201);
        tr.height = Grid::filled(201, 201, 1.0);
        let tracer = HeightfieldTracer::new(&tr).unwrap();
        let o = Point3::new(5.0, -5.0, 11.0);
        let hit = tracer.cast(&o, &Vector3::new(0.1, -0.05, -1.0)).unwrap();
        assert!((hit.point - Point3::new(6.0, -5.5, 1.0)).norm() < 1e-9);
        assert!(tracer.cast(&o, &Vector3::new(0.0, 0.0, 1.0)).is_none());
        assert!(tracer.cast(&o, &Vector3::new(10.0, 0.0, -1.0)).is_none());
    }
}
