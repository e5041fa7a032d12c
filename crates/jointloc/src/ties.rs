//! Fixes tied to keyframes (paper §III-C): each used fix is attached to the keyframe that was
//! current at its frame, so it follows the keyframe when the local BA moves it; the SLAM→world
//! similarity is re-fitted from the ties and every keyframe gets its global-position factors.

use std::collections::{BTreeMap, BTreeSet};

use jointloc_geometry::Sim3;
use jointloc_slam::map::{GlobalFix, KeyFrameId, Map, MapPointId};
use nalgebra::{Point3, Vector3};

use crate::alignment::{self, Correspondence, SlamToWorld, Tolerance};
use crate::camera_tilt;
use crate::flight_time;
use crate::system::{JointLoc, Submitted};
use crate::terrain_shift::{TerrainConfig, estimate_shift};

/// A used fix tied to a keyframe: the camera centre and the point on the optical axis at the
/// altimeter range, both in the keyframe's camera frame, so they follow the keyframe when the
/// local BA moves it.
#[derive(Debug, Clone)]
pub(crate) struct Tie {
    pub(crate) record: usize,
    pub(crate) keyframe: KeyFrameId,
    pub(crate) centre_in_kf: Point3<f64>,
    pub(crate) ground_in_kf: Point3<f64>,
    pub(crate) world_camera: Point3<f64>,
    pub(crate) world_ground: Point3<f64>,
    pub(crate) weight: f64,
    /// The altimeter reading at the fix's frame, metres: the nadir pair errs by it × the
    /// camera's tilt ([`crate::JointLocConfig::range_looseness`]).
    pub(crate) altitude: f64,
    /// Last known SLAM positions (kept when the keyframe is culled).
    pub(crate) slam_camera: Point3<f64>,
    pub(crate) slam_ground: Point3<f64>,
}

impl Tie {
    /// SLAM positions from the keyframe's current pose. When that keyframe was culled (a
    /// redundant one: at altitude, where every keyframe sees a wide footprint, one in five
    /// fixes was tied to one), the tie moves to the keyframe nearest in time to its fix
    /// (`timestamp`), its last known SLAM positions expressed in that keyframe's frame, so
    /// the local BA and the global BA at the end keep its factors. A fix older than the
    /// map's oldest keyframe (retired by the map's cap) stays where it was.
    pub(crate) fn refresh(&mut self, map: &Map, timestamp: f64) {
        let oldest = map.keyframes().map(|k| k.timestamp).reduce(f64::min);
        if map.keyframe(self.keyframe).is_none() && oldest.is_some_and(|t0| t0 <= timestamp) {
            let nearest = map.keyframes().min_by(|a, b| {
                (a.timestamp - timestamp)
                    .abs()
                    .total_cmp(&(b.timestamp - timestamp).abs())
            });
            if let Some(kf) = nearest {
                self.keyframe = kf.id;
                self.centre_in_kf = kf.pose.0.transform_point(&self.slam_camera);
                self.ground_in_kf = kf.pose.0.transform_point(&self.slam_ground);
            }
        }
        if let Some(kf) = map.keyframe(self.keyframe) {
            let t_wc = kf.pose.0.inverse();
            self.slam_camera = t_wc.transform_point(&self.centre_in_kf);
            self.slam_ground = t_wc.transform_point(&self.ground_in_kf);
        }
    }
}

impl JointLoc {
    /// Ties a fix to the keyframe that was current at its frame (or, when that keyframe was
    /// culled while the fix was being searched, as happens on its own thread, to the keyframe
    /// nearest in time, as [`Tie::refresh`] does for older fixes); false when it cannot be
    /// used (low confidence, frame not tracked).
    pub(crate) fn tie_fix(&mut self, fix: &jointloc_absloc::Fix, at: &Submitted) -> bool {
        if fix.confidence < self.config.min_confidence {
            return false;
        }
        let (Some(pose), Some((kf_id, t_cw))) = (at.pose, at.keyframe) else {
            return false;
        };
        let altitude = at.altitude;
        // SLAM units per metre: the current alignment's inverse scale, else 1 (the SLAM map is
        // metric from the altimeter at initialisation).
        let per_metre = self.alignment.as_ref().map_or(1.0, |a| 1.0 / a.sim3.scale);
        let centre = pose.centre();
        let ground = pose
            .0
            .transform_point(&Point3::new(0.0, 0.0, altitude * per_metre));
        let [x, y, z] = fix.position;
        self.ties.push(Tie {
            record: self.fixes.len(),
            keyframe: kf_id,
            centre_in_kf: t_cw.transform_point(&centre),
            ground_in_kf: t_cw.transform_point(&ground),
            world_camera: Point3::new(x, y, z),
            world_ground: Point3::new(x, y, z - altitude),
            weight: fix.confidence,
            altitude,
            slam_camera: centre,
            slam_ground: ground,
        });
        if self.slam.map().keyframe(kf_id).is_none()
            && let Some(t) = self.ties.last_mut()
        {
            t.refresh(self.slam.map(), at.timestamp);
            if self.slam.map().keyframe(t.keyframe).is_none() {
                self.ties.pop();
                return false;
            }
        }
        true
    }

    /// Refreshes the tie points from the keyframes' current poses, re-fits the alignment and
    /// updates every keyframe's global-position factor.
    pub(crate) fn refit(&mut self) {
        let map = self.slam.map();
        for t in &mut self.ties {
            t.refresh(map, self.fixes[t.record].timestamp);
        }
        self.refresh_takeoff();
        let first = match self.alignment_window_fixes() {
            0 => 0,
            n => self.ties.len().saturating_sub(n),
        };
        if let (true, Some(previous)) = (
            self.places_nadir_cameras(),
            self.alignment.as_ref().map(|a| a.sim3),
        ) {
            self.place_nadir_cameras(&previous, first);
        }
        let fitted = self.fit_ties(&self.ties, first..self.ties.len());
        let Some(fitted) = fitted else {
            return;
        };
        if self.alignment.is_none() && !self.first_alignment_spans(&fitted) {
            return;
        }
        for r in &mut self.fixes {
            r.inlier = false;
        }
        let s = fitted.sim3;
        if self.config.estimate_camera_tilt {
            self.estimate_camera_tilt(&s, &fitted.inlier_fixes);
        }
        if self.places_nadir_cameras() {
            self.place_nadir_cameras(&s, first);
        }
        // Global factors per keyframe, one pair per inlier fix tied to it: the fix's ground
        // point as the point on the tied frame's optical axis (what a map fix measures), and
        // the camera above it (a nadir view, `nadir_sigma_scale`). The SLAM's tilt is its
        // weakest direction (a tilt and a sideways shift look alike over flat ground), so the
        // lever arm from the ground point to the camera must not be taken from it alone.
        let mut per_kf: BTreeMap<KeyFrameId, Vec<GlobalFix>> = BTreeMap::new();
        for &i in &fitted.inlier_fixes {
            let t = &self.ties[i];
            self.fixes[t.record].inlier = true;
            let fixes = per_kf.entry(t.keyframe).or_default();
            fixes.push(GlobalFix {
                point_in_camera: t.ground_in_kf.coords,
                position: self.corrected(&t.world_ground).coords,
                weight: t.weight,
                sigma_scale: 1.0,
            });
            if self.config.nadir_sigma_scale > 0.0 {
                fixes.push(GlobalFix {
                    point_in_camera: t.centre_in_kf.coords,
                    position: self.corrected(&t.world_camera).coords,
                    weight: t.weight,
                    sigma_scale: self.nadir_sigma_scale(t),
                });
            }
        }
        self.slam.set_global_fixes(per_kf);
        self.slam.set_slam_to_world(Some(s));
        self.alignment = Some(fitted);
        self.correct_by_terrain(first);
        if self.merge_earlier_maps(false) {
            self.refit();
        }
    }

    /// When every inlier fix of the current alignment is weak (below
    /// [`crate::JointLocConfig::strong_fix_confidence`]): the time of the newest (see
    /// [`crate::JointLocConfig::unconfirmed_weak_alignment_s`]). `None` without an alignment
    /// or with a strong inlier.
    pub(crate) fn newest_inlier_if_all_weak(&self) -> Option<f64> {
        let strong = self.config.strong_fix_confidence;
        let inliers = self
            .alignment
            .as_ref()?
            .inlier_fixes
            .iter()
            .map(|&i| &self.fixes[self.ties[i].record]);
        if inliers.clone().any(|r| r.confidence >= strong) {
            return None;
        }
        inliers.map(|r| r.timestamp).reduce(f64::max)
    }

    /// Whether a first alignment may rest on `fitted`'s inlier fixes: always, unless the
    /// flight has had no world pose and no take-off position, flies on virtual frames, and one
    /// of the fixes is weak (`first_fix_span_m`); then only when they lie far enough apart to
    /// have seen different ground. Weak fixes of local searches count too: before the first
    /// world pose a local search runs only around a strong fix, to confirm it.
    fn first_alignment_spans(&self, fitted: &SlamToWorld) -> bool {
        let c = &self.config;
        let weak =
            |i: &usize| self.fixes[self.ties[*i].record].confidence < c.strong_fix_confidence;
        if c.first_fix_span_m <= 0.0
            || !self.unanchored()
            || !self.virtual_frames.in_use()
            || !fitted.inlier_fixes.iter().any(weak)
        {
            return true;
        }
        let points: Vec<[f64; 2]> = fitted
            .inlier_fixes
            .iter()
            .map(|&i| {
                let p = &self.ties[i].world_ground;
                [p.x, p.y]
            })
            .collect();
        let span = alignment::spread_m(&points);
        if span < c.first_fix_span_m {
            tracing::debug!(
                span,
                fixes = points.len(),
                "first alignment held back: weak whole-map fixes too close together"
            );
        }
        span >= c.first_fix_span_m
    }

    /// How many fixes the alignment's window holds: those `alignment_window_s` holds at the
    /// flight's search rate when none fails, and at least `alignment_window_min_fixes`; 0:
    /// all. Failed searches make it reach further back, as a window of that many fixes.
    pub(crate) fn alignment_window_fixes(&self) -> usize {
        self.fixes_in(
            self.config.alignment_window_s,
            self.config.alignment_window_min_fixes,
        )
    }

    /// The fixes a span of `span_s` seconds holds at the search rate (`fusion_every` frames
    /// at the flight's frame rate so far), at least `min`; 0 when `span_s` is 0.
    pub(crate) fn fixes_in(&self, span_s: f64, min: usize) -> usize {
        flight_time::fixes_in(span_s, self.search_interval_s(), min)
    }

    /// Seconds between due searches: `fusion_every` frames at the flight's frame rate so far;
    /// `None` before two frames with distinct times.
    pub(crate) fn search_interval_s(&self) -> Option<f64> {
        self.clock
            .frame_period_s()
            .map(|p| p * self.config.fusion_every as f64)
    }

    /// Where the window's map points sit on the elevation model through the new alignment:
    /// the residual of the fixes' common bias, taken into the correction that the next refits
    /// add to every fix (see [`crate::terrain_shift`]).
    fn correct_by_terrain(&mut self, first: usize) {
        // A point is never held closer to the model than the model's stated precision (a
        // HiRISE-class DTM: 0.25 m against the 0.1 m default), as the ground factors:
        // with 0.1 m the estimate over-trusted the model's noise at 100 m and moved the fixes
        // 0.4 m the wrong way on flat gravel (`docs/jointloc.md` §"At altitude").
        let config = &TerrainConfig {
            sigma_m: self
                .config
                .terrain
                .sigma_m
                .max(self.altitude.ground().stated_sigma_m().unwrap_or(0.0)),
            ..self.config.terrain
        };
        let (Some(a), true) = (&self.alignment, config.gain > 0.0) else {
            return;
        };
        // Low over a coarse map (virtual frames): the points of the last fixes span a few
        // posts of a smoothed DTM, and the estimate follows its noise and the rocks it smooths
        // away (`docs/jointloc.md` §"10 m over a 25 cm map").
        if self.virtual_frames.in_use() && !self.config.mosaic.terrain_correction {
            return;
        }
        if !self.altitude.ground().has_model() {
            return;
        }
        let map = self.slam.map();
        let first = match self.fixes_in(config.window_s, 1) {
            0 => first,
            n => self.ties.len().saturating_sub(n),
        };
        // The window keyframes' points, in id order.
        let ids: BTreeSet<MapPointId> = self.ties[first..]
            .iter()
            .filter_map(|t| map.keyframe(t.keyframe))
            .flat_map(|kf| kf.points.iter().flatten().copied())
            .collect();
        // Points seen from at least 3 keyframes: triangulated, not fresh two-view guesses.
        let points: Vec<Point3<f64>> = ids
            .into_iter()
            .filter_map(|id| map.point(id))
            .filter(|p| p.n_observations() >= 3)
            .map(|p| a.sim3.transform_point(&Point3::from(p.position)))
            .collect();
        if let Some(estimate) = estimate_shift(&points, self.altitude.ground(), config) {
            let at = self
                .ties
                .last()
                .map_or(0.0, |t| self.fixes[t.record].timestamp);
            self.terrain.update(&estimate, config, at);
            tracing::debug!(
                at,
                shift = ?estimate.shift.as_slice(),
                points = estimate.points,
                offset = ?self.terrain.offset.as_slice(),
                "terrain shift"
            );
        }
    }

    /// A tie's image x axis and optical axis in the world through `s` (its keyframe's x axis,
    /// its own frame's optical axis); `None` when its keyframe is gone.
    fn tie_axes(&self, t: &Tie, s: &Sim3) -> Option<(Vector3<f64>, Vector3<f64>)> {
        let kf = self.slam.map().keyframe(t.keyframe)?;
        let to_slam = kf.pose.0.rotation.inverse();
        let x = s.rotation * (to_slam * Vector3::x());
        let axis = s.rotation * (to_slam * (t.ground_in_kf - t.centre_in_kf));
        Some((x, axis))
    }

    /// The camera's mean tilt off nadir (see [`crate::camera_tilt`]) over the ties `inliers`,
    /// their attitudes through `s`.
    fn estimate_camera_tilt(&mut self, s: &Sim3, inliers: &[usize]) {
        let tilts: Vec<[f64; 2]> = inliers
            .iter()
            .filter_map(|&i| {
                let (x, axis) = self.tie_axes(&self.ties[i], s)?;
                camera_tilt::tilt_of(&x, &axis)
            })
            .collect();
        if let Some(mean) = camera_tilt::mean_tilt(&tilts) {
            self.camera_tilt = Some(mean);
            tracing::debug!(
                about_x_deg = mean[0].to_degrees(),
                about_y_deg = mean[1].to_degrees(),
                ties = tilts.len(),
                "camera tilt"
            );
        }
    }

    /// Whether the nadir pairs are placed at each refit (else each stays straight above its
    /// fix): for the camera's tilt, or for the wobble's mean over frames.
    fn places_nadir_cameras(&self) -> bool {
        self.config.estimate_camera_tilt || self.config.nadir_mean_window_s > 0.0
    }

    /// Each tie's nadir pair: the camera where it looks at the fix from, the altimeter's range
    /// away along its optical axis at its heading (through `s`) and the estimated tilt; for
    /// the ties of the window (from `first`), with
    /// [`crate::JointLocConfig::nadir_mean_window_s`] and once the window is full, moved by
    /// the range × the tie's axis off the mean axis of every tracked frame within that many
    /// seconds of its fix. The ties before the window keep the place they had in it.
    fn place_nadir_cameras(&mut self, s: &Sim3, first: usize) {
        let tilt = self.used_camera_tilt();
        let half = self.config.nadir_mean_window_s;
        // Only once the window holds its count of fixes: before, the alignment still turns by
        // degrees from one refit to the next, and the pairs placed through it went along
        // (crater s5202 at 200 m: 3.2 m online in the first 30 s, against 1.5 m without).
        let full = self.ties.len().saturating_sub(first) >= self.alignment_window_fixes();
        // The window's frames: their times and the prefix sums of their axes through `s` (the
        // mean over any span in two lookups).
        let around: Option<(Vec<f64>, Vec<Vector3<f64>>)> = (half > 0.0 && full)
            .then(|| self.ties.get(first))
            .flatten()
            .map(|t| {
                let axes = self
                    .slam
                    .optical_axes_since(self.fixes[t.record].timestamp - half);
                let mut sums = vec![Vector3::zeros()];
                for (_, a) in &axes {
                    sums.push(sums[sums.len() - 1] + s.rotation * a);
                }
                (axes.iter().map(|(t, _)| *t).collect(), sums)
            });
        let start = if around.is_some() { first } else { 0 };
        for i in start..self.ties.len() {
            let t = &self.ties[i];
            let at = self.fixes[t.record].timestamp;
            let mean = around.as_ref().and_then(|(times, sums)| {
                let lo = times.partition_point(|&x| x < at - half);
                let hi = times.partition_point(|&x| x <= at + half);
                (hi > lo + 1)
                    .then(|| (sums[hi] - sums[lo]).try_normalize(1e-12))
                    .flatten()
            });
            let placed = self.tie_axes(t, s).and_then(|(x, axis)| {
                let p = camera_tilt::camera_looking_at(&t.world_ground, t.altitude, &x, tilt)?;
                let Some(mean) = mean else {
                    return Some(p);
                };
                let off = axis.try_normalize(1e-12)? - mean;
                Some(p - t.altitude * Vector3::new(off.x, off.y, 0.0))
            });
            if let Some(p) = placed {
                self.ties[i].world_camera = p;
            }
        }
    }

    /// σ of a tie's nadir factor (the camera above the fix) over `global_sigma`: the
    /// configured scale at the reference altitude, growing with the altitude above it, as
    /// the nadir assumption's error does (altitude × tilt).
    pub(crate) fn nadir_sigma_scale(&self, t: &Tie) -> f64 {
        self.config.nadir_sigma_scale * self.config.range_looseness(t.altitude)
    }

    /// The alignment fitted to the ties `range`: the ground point carries the fix's x, y
    /// exactly (the map point under the image centre); the camera centre adds the altimeter's
    /// z with a lower weight (its x, y assume a nadir view). Above the reference altitude
    /// the camera pair's inlier bound widens with the altitude, as does the ground pair's
    /// vertical bound (the altimeter's and the nadir assumption's errors grow with the
    /// range; the fix's x, y, what a wrong match gets wrong, does not). The camera pair's
    /// weight stays: it is what fixes the alignment's roll about a straight track, and
    /// weighting it down by the square of the altitude (as its error) left the roll free
    /// (1.90 m online at 100 m on the development flight, against 0.37 m).
    pub(crate) fn fit_ties(
        &self,
        ties: &[Tie],
        range: std::ops::Range<usize>,
    ) -> Option<SlamToWorld> {
        let mut pairs = Vec::with_capacity(2 * range.len());
        let threshold = self.config.inlier_threshold_m;
        for i in range.clone() {
            let t = &ties[i];
            let loose = self.config.range_looseness(t.altitude);
            // The ground pair first: the robust refit reads a fix's residual from it.
            pairs.push(Correspondence {
                slam: t.slam_ground,
                world: self.corrected(&t.world_ground),
                weight: t.weight,
                fix: i,
                tolerance: Tolerance {
                    horizontal_m: threshold,
                    vertical_m: threshold * loose,
                },
            });
            pairs.push(Correspondence {
                slam: t.slam_camera,
                world: self.corrected(&t.world_camera),
                weight: t.weight * self.config.nadir_weight,
                fix: i,
                tolerance: Tolerance::sphere(threshold * loose),
            });
        }
        // On the flight's first map every alignment must agree with the take-off position, if
        // one is given: a refit may otherwise move to a consensus of wrong fixes that the
        // first alignment was kept from.
        let cameras: Vec<Point3<f64>> = ties[range.clone()].iter().map(|t| t.slam_camera).collect();
        alignment::fit_admissible(
            &pairs,
            self.config.ransac_iterations,
            self.config.min_fixes,
            self.config.seed,
            self.config.alignment_robust_floor_m,
            &|s| self.takeoff_agrees(s, &cameras),
        )
    }
}
