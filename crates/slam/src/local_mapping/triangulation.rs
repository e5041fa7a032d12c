//! New map points (ORB-SLAM2's `CreateNewMapPoints`): free keypoints of the new keyframe are
//! matched to free keypoints of its covisible neighbours along the epipolar segment that the
//! plausible depth range projects to, then triangulated and checked for parallax, depth,
//! reprojection error and scale consistency.

use jointloc_features::orb::{hamming, orientation_consistent};
use jointloc_geometry::triangulation::triangulate_linear;
use jointloc_geometry::{PinholeCamera, WorldToCamera};
use nalgebra::{Point2, Point3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::map::{KeyFrame, KeyFrameId, Map, MapPointId};

/// Settings of [`create_new_points`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TriangulationConfig {
    /// Covisible neighbours to triangulate with (ORB-SLAM2 monocular: 20).
    pub neighbours: usize,
    /// Skip a neighbour when baseline / its median scene depth is below this (ORB-SLAM2: 0.01).
    pub min_baseline_ratio: f64,
    /// Depth range searched along each ray, as factors of the keyframe's median depth.
    pub depth_range: (f64, f64),
    /// Largest descriptor distance (ORB-SLAM2: TH_LOW = 50).
    pub max_distance: u32,
    /// Ratio test between the best and second-best candidate on the segment.
    pub ratio: f64,
    /// Rays must differ by more than this angle, degrees (ORB-SLAM2: acos 0.9998 ≈ 1.15°).
    pub min_parallax_deg: f64,
    /// χ² (2 DoF, 95 %) of the reprojection in both views, scaled by the level's σ².
    pub chi2: f64,
}

impl Default for TriangulationConfig {
    fn default() -> Self {
        Self {
            neighbours: 20,
            min_baseline_ratio: 0.01,
            depth_range: (0.3, 3.0),
            max_distance: 50,
            ratio: 0.8,
            min_parallax_deg: 1.146,
            chi2: 5.991,
        }
    }
}

/// Median depth of the keyframe's points in its camera frame.
pub fn median_depth(kf: &KeyFrame, map: &Map) -> Option<f64> {
    let mut z: Vec<f64> = kf
        .points
        .iter()
        .flatten()
        .filter_map(|id| map.point(*id))
        .map(|p| kf.to_camera(&p.position).z)
        .filter(|z| z.is_finite() && *z > 0.0)
        .collect();
    if z.is_empty() {
        return None;
    }
    z.sort_by(f64::total_cmp);
    Some(z[(z.len() - 1) / 2])
}

/// Triangulates new points between keyframe `kf` and its neighbours; returns their ids.
pub fn create_new_points(
    map: &mut Map,
    kf: KeyFrameId,
    camera: &PinholeCamera,
    cfg: &TriangulationConfig,
) -> Vec<MapPointId> {
    let Some(k1) = map.keyframe(kf) else {
        return Vec::new();
    };
    let neighbours = k1.best_covisible(cfg.neighbours);
    let Some(depth1) = median_depth(k1, map) else {
        return Vec::new();
    };
    let mut created = Vec::new();
    for nb in neighbours {
        let pairs = {
            let (Some(k1), Some(k2)) = (map.keyframe(kf), map.keyframe(nb)) else {
                continue;
            };
            let baseline = (k1.centre() - k2.centre()).norm();
            let Some(depth2) = median_depth(k2, map) else {
                continue;
            };
            if baseline / depth2 < cfg.min_baseline_ratio {
                continue;
            }
            match_along_epipolar(k1, k2, camera, depth1, cfg)
        };
        let n_pairs = pairs.len();
        let before = created.len();
        for (i1, i2) in pairs {
            if let Some(id) = triangulate_pair(map, kf, nb, i1, i2, camera, cfg) {
                created.push(id);
            }
        }
        tracing::trace!(keyframe = %kf, neighbour = %nb, pairs = n_pairs, created = created.len() - before, "triangulation");
    }
    created
}

/// A segment in the image (the projection of a ray's depth range).
struct Segment {
    a: Vector2<f64>,
    b: Vector2<f64>,
}

impl Segment {
    fn distance(&self, p: &Vector2<f64>) -> f64 {
        let d = self.b - self.a;
        let len2 = d.norm_squared();
        let t = if len2 > 0.0 {
            ((p - self.a).dot(&d) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        (self.a + t * d - p).norm()
    }
}

/// Projects the ray of keypoint `uv` of camera `pose1` at depths `near..far` into `pose2`.
fn ray_segment(
    uv: &Point2<f64>,
    pose1: &WorldToCamera,
    pose2: &WorldToCamera,
    camera: &PinholeCamera,
    near: f64,
    far: f64,
) -> Option<Segment> {
    let ray = camera.unproject(uv)?;
    let to_world = pose1.inverse();
    let rel = pose2.0 * to_world.0;
    let proj = |d: f64| {
        let pc = rel * Point3::from(ray * d);
        camera.project(&pc).map(|p| p.coords)
    };
    // Clip the near end to stay in front of the second camera.
    let mut n = near;
    let mut a = proj(n);
    while a.is_none() && n < far {
        n *= 1.5;
        a = proj(n);
    }
    Some(Segment {
        a: a?,
        b: proj(far)?,
    })
}

/// Pairs of free keypoints `(i1 in k1, i2 in k2)`.
fn match_along_epipolar(
    k1: &KeyFrame,
    k2: &KeyFrame,
    camera: &PinholeCamera,
    depth1: f64,
    cfg: &TriangulationConfig,
) -> Vec<(usize, usize)> {
    let free2: Vec<usize> = (0..k2.points.len())
        .filter(|&i| k2.points[i].is_none())
        .collect();
    // Epipole of camera 1 in image 2: keypoints near it have almost no parallax.
    let epipole = camera.project(&k2.pose.transform_point(&Point3::from(k1.centre())));
    let sf = k1.features.level_scales.get(1).copied().unwrap_or(1.2);
    let mut best_for2: Vec<Option<(usize, u32)>> = vec![None; k2.points.len()];
    for i1 in (0..k1.points.len()).filter(|&i| k1.points[i].is_none()) {
        let kp1 = &k1.features.keypoints[i1];
        let uv1 = Point2::new(kp1.x, kp1.y);
        let Some(seg) = ray_segment(
            &uv1,
            &k1.pose,
            &k2.pose,
            camera,
            cfg.depth_range.0 * depth1,
            cfg.depth_range.1 * depth1,
        ) else {
            continue;
        };
        let (lo, hi) = (seg.a.inf(&seg.b), seg.a.sup(&seg.b));
        let d1 = &k1.features.descriptors[i1];
        let (mut best, mut best_i, mut second) = (u32::MAX, usize::MAX, u32::MAX);
        for &i2 in &free2 {
            let kp2 = &k2.features.keypoints[i2];
            let sigma = sf.powi(kp2.octave as i32);
            let margin = 1.96 * sigma;
            let p2 = Vector2::new(kp2.x, kp2.y);
            if p2.x < lo.x - margin
                || p2.x > hi.x + margin
                || p2.y < lo.y - margin
                || p2.y > hi.y + margin
            {
                continue;
            }
            if seg.distance(&p2) > margin {
                continue;
            }
            if let Some(e) = epipole
                && (e.coords - p2).norm() < 100.0 * sigma
            {
                continue;
            }
            let d = hamming(d1, &k2.features.descriptors[i2]);
            if d < best {
                second = best;
                best = d;
                best_i = i2;
            } else if d < second {
                second = d;
            }
        }
        if best > cfg.max_distance
            || (second != u32::MAX && best as f64 >= cfg.ratio * second as f64)
        {
            continue;
        }
        match best_for2[best_i] {
            Some((_, d)) if d <= best => {}
            _ => best_for2[best_i] = Some((i1, best)),
        }
    }
    let mut pairs: Vec<(usize, usize)> = best_for2
        .iter()
        .enumerate()
        .filter_map(|(i2, b)| b.map(|(i1, _)| (i1, i2)))
        .collect();
    pairs.sort_unstable();
    let diffs: Vec<f64> = pairs
        .iter()
        .map(|&(i1, i2)| k1.features.keypoints[i1].angle - k2.features.keypoints[i2].angle)
        .collect();
    let keep = orientation_consistent(&diffs, 30);
    pairs
        .into_iter()
        .zip(keep)
        .filter(|(_, k)| *k)
        .map(|(p, _)| p)
        .collect()
}

/// Triangulates and checks one pair; inserts the point on success.
fn triangulate_pair(
    map: &mut Map,
    kf1: KeyFrameId,
    kf2: KeyFrameId,
    i1: usize,
    i2: usize,
    camera: &PinholeCamera,
    cfg: &TriangulationConfig,
) -> Option<MapPointId> {
    let (k1, k2) = (map.keyframe(kf1)?, map.keyframe(kf2)?);
    if k1.points[i1].is_some() || k2.points[i2].is_some() {
        return None;
    }
    let (p1, p2) = (&k1.features.keypoints[i1], &k2.features.keypoints[i2]);
    let (uv1, uv2) = (Point2::new(p1.x, p1.y), Point2::new(p2.x, p2.y));
    let r1 = k1.pose.inverse().0.rotation * camera.unproject(&uv1)?;
    let r2 = k2.pose.inverse().0.rotation * camera.unproject(&uv2)?;
    let cos = r1.dot(&r2) / (r1.norm() * r2.norm());
    if cos > cfg.min_parallax_deg.to_radians().cos() {
        return None;
    }
    let x = triangulate_linear(&[k1.pose, k2.pose], &[uv1, uv2], camera).ok()?;
    let sf = map.scale_factor();
    for (kf, uv, level) in [(k1, uv1, p1.octave), (k2, uv2, p2.octave)] {
        let pc = kf.pose.transform_point(&x);
        let proj = camera.project(&pc)?;
        if (proj - uv).norm_squared() > cfg.chi2 * sf.powi(2 * level as i32) {
            return None;
        }
    }
    let x: Vector3<f64> = x.coords;
    let (d1, d2) = ((x - k1.centre()).norm(), (x - k2.centre()).norm());
    if d1 <= 0.0 || d2 <= 0.0 {
        return None;
    }
    // Scale consistency: the distance ratio must agree with the octave ratio.
    let ratio_dist = d2 / d1;
    let ratio_octave = sf.powi(p1.octave as i32 - p2.octave as i32);
    let factor = 1.5 * sf;
    if ratio_dist * factor < ratio_octave || ratio_dist > ratio_octave * factor {
        return None;
    }
    let id = map.insert_point(x, kf1, i1)?;
    map.add_observation(id, kf2, i2);
    map.update_descriptor(id);
    map.update_normal_and_depth(id);
    Some(id)
}
