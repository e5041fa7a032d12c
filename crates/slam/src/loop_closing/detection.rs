//! Loop detection and verification (ORB-SLAM2's `DetectLoop` and `ComputeSim3`).
//!
//! Candidates come from position by default (by appearance with `candidates = "appearance"`,
//! [`super::appearance`]): a downward camera over a planetary surface
//! sees the same ground again only when it comes back over it, so a keyframe is a candidate
//! when its camera centre lies within a footprint of the new keyframe's (the median depth of
//! its points, in SLAM units) plus an allowance for the drift accumulated along the path
//! between the two. ORB-SLAM2 ranks candidates by a bag of words trained on other imagery;
//! here every candidate in reach is checked by brute-force descriptor matching of the two
//! keyframes' map points (≈ 0.5 ms each), which no vocabulary can miss.
//!
//! Verification as ORB-SLAM2: a Sim(3) RANSAC on the matched points (reprojection inliers in
//! both keyframes), then the loop's map points (the candidate's and its covisible keyframes')
//! are projected into the new keyframe with the corrected pose, and enough of them must match.

use std::collections::BTreeSet;

use jointloc_features::orb::{
    Descriptor, MatcherConfig, WindowQuery, hamming, orientation_consistent, search_in_window,
};
use jointloc_geometry::{PinholeCamera, Sim3};
use nalgebra::{Point2, Point3, Vector3};

use super::LoopClosingConfig;
use super::correction::pose_of;
use super::sim3_ransac::{Sim3Pair, estimate_sim3};
use crate::map::{KeyFrame, KeyFrameId, Map, MapPointId};
use crate::tracking::pose_optimization::{PoseOptimizationConfig, optimize_pose_against};

/// A verified loop between the new keyframe and an old one.
#[derive(Debug, Clone, PartialEq)]
pub struct VerifiedLoop {
    /// The old keyframe matched.
    pub loop_keyframe: KeyFrameId,
    /// The new keyframe's corrected world→camera similarity `S_kw` (in the old map's frame).
    pub corrected: Sim3,
    /// Keypoint index of the new keyframe → the loop map point it observes.
    pub matches: Vec<(usize, MapPointId)>,
    /// Pairs supporting the Sim(3) RANSAC.
    pub sim3_inliers: usize,
}

/// Keyframes within reach of `kf` that are not its covisible neighbours, nearest first.
pub fn position_candidates(
    map: &Map,
    kf: KeyFrameId,
    config: &LoopClosingConfig,
) -> Vec<KeyFrameId> {
    let Some(k) = map.keyframe(kf) else {
        return Vec::new();
    };
    let Some(depth) = median_depth(map, k) else {
        return Vec::new();
    };
    let connected: BTreeSet<KeyFrameId> = k
        .covisible()
        .iter()
        .map(|&(id, _)| id)
        .chain([kf])
        .collect();
    // Path length along the keyframes (id order is time order) up to each keyframe.
    let mut path = Vec::with_capacity(map.n_keyframes());
    let mut travelled = 0.0;
    let mut previous: Option<Vector3<f64>> = None;
    for other in map.keyframes() {
        let c = other.centre();
        travelled += previous.map_or(0.0, |p| (c - p).norm());
        previous = Some(c);
        path.push((other.id, c, travelled));
    }
    let Some(&(_, centre, here)) = path.iter().find(|(id, _, _)| *id == kf) else {
        return Vec::new();
    };
    let mut found: Vec<(f64, KeyFrameId)> = path
        .iter()
        .filter(|(id, _, _)| *id < kf && !connected.contains(id))
        .filter(|(_, _, at)| here - at > config.min_path_depths * depth)
        .filter_map(|&(id, c, at)| {
            let reach = config.reach_depths * depth + config.drift_fraction * (here - at);
            let d = (c - centre).norm();
            (d < reach).then_some((d, id))
        })
        .collect();
    found.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    found.truncate(config.max_candidates);
    found.into_iter().map(|(_, id)| id).collect()
}

/// Median depth of a keyframe's map points in its camera.
pub fn median_depth(map: &Map, k: &KeyFrame) -> Option<f64> {
    let mut z: Vec<f64> = k
        .points
        .iter()
        .flatten()
        .filter_map(|id| map.point(*id))
        .map(|p| k.to_camera(&p.position).z)
        .filter(|z| *z > 0.0)
        .collect();
    if z.is_empty() {
        return None;
    }
    z.sort_by(f64::total_cmp);
    Some(z[z.len() / 2])
}

/// Keypoints of `k` that observe a map point: (keypoint index, point).
fn with_points(k: &KeyFrame) -> Vec<(usize, MapPointId)> {
    k.points
        .iter()
        .enumerate()
        .filter_map(|(i, p)| p.map(|p| (i, p)))
        .collect()
}

/// Descriptor matches between the map points of `a` and `b` (ORB-SLAM2's `SearchByBoW`
/// thresholds: Hamming ≤ 50, ratio 0.75, one match per keypoint, rotation histogram).
fn match_map_points(a: &KeyFrame, b: &KeyFrame) -> Vec<(usize, usize)> {
    let pa = with_points(a);
    let pb = with_points(b);
    let db: Vec<Descriptor> = pb.iter().map(|&(j, _)| b.features.descriptors[j]).collect();
    let mut owner: Vec<Option<(u32, usize)>> = vec![None; pb.len()];
    for (qi, &(i, _)) in pa.iter().enumerate() {
        let d = &a.features.descriptors[i];
        let (mut best, mut bj, mut second) = (u32::MAX, usize::MAX, u32::MAX);
        for (j, o) in db.iter().enumerate() {
            let h = hamming(d, o);
            if h < best {
                second = best;
                best = h;
                bj = j;
            } else if h < second {
                second = h;
            }
        }
        if bj == usize::MAX
            || best > 50
            || (second != u32::MAX && best as f64 >= 0.75 * second as f64)
        {
            continue;
        }
        if owner[bj].is_none_or(|(d0, _)| best < d0) {
            owner[bj] = Some((best, qi));
        }
    }
    let matches: Vec<(usize, usize)> = owner
        .iter()
        .enumerate()
        .filter_map(|(j, o)| o.map(|(_, qi)| (pa[qi].0, pb[j].0)))
        .collect();
    let diffs: Vec<f64> = matches
        .iter()
        .map(|&(i, j)| a.features.keypoints[i].angle - b.features.keypoints[j].angle)
        .collect();
    let keep = orientation_consistent(&diffs, 30);
    let mut out: Vec<(usize, usize)> = matches
        .into_iter()
        .zip(keep)
        .filter_map(|(m, k)| k.then_some(m))
        .collect();
    out.sort_unstable();
    out
}

/// Verifies `candidate` as a loop of `kf`; `None` when the geometry does not hold.
pub fn verify(
    map: &Map,
    kf: KeyFrameId,
    candidate: KeyFrameId,
    camera: &PinholeCamera,
    config: &LoopClosingConfig,
) -> Option<VerifiedLoop> {
    let (k, c) = (map.keyframe(kf)?, map.keyframe(candidate)?);
    let sf = map.scale_factor();
    let matches = match_map_points(k, c);
    if matches.len() < config.min_matches {
        tracing::trace!(
            ?kf,
            ?candidate,
            matches = matches.len(),
            "loop: too few matches"
        );
        return None;
    }
    let pairs: Vec<Sim3Pair> = matches
        .iter()
        .filter_map(|&(i, j)| {
            let (p, q) = (map.point(k.points[i]?)?, map.point(c.points[j]?)?);
            let (ki, cj) = (&k.features.keypoints[i], &c.features.keypoints[j]);
            Some(Sim3Pair {
                in_camera1: Point3::from(k.to_camera(&p.position)),
                pixel1: Point2::new(ki.x, ki.y),
                sigma2_1: sf.powi(2 * ki.octave as i32),
                in_camera2: Point3::from(c.to_camera(&q.position)),
                pixel2: Point2::new(cj.x, cj.y),
                sigma2_2: sf.powi(2 * cj.octave as i32),
            })
        })
        .collect();
    let seed = kf.0.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ candidate.0;
    let fit = estimate_sim3(
        &pairs,
        camera,
        config.ransac_iterations,
        config.min_sim3_inliers,
        seed,
    )?;
    let s12 = fit.s12;
    if s12.scale.ln().abs() > config.max_scale_change.ln_1p() {
        tracing::debug!(
            ?kf,
            ?candidate,
            scale = s12.scale,
            "loop: scale change too large"
        );
        return None;
    }
    let c_pose = Sim3::new(1.0, c.pose.0.rotation, c.pose.0.translation.vector);
    let corrected = s12.compose(&c_pose);
    // The correction is the drift the map accumulated between the two keyframes: a
    // hypothesis that moves or turns the keyframe further than that drift is a false match
    // (a planar, repetitive ground lets a few dozen pairs fit a wrong similarity).
    let moved = (centre_of(&corrected) - k.centre()).norm();
    let depth = median_depth(map, k)?;
    let allowed =
        config.correction_depths * depth + config.drift_fraction * path_between(map, candidate, kf);
    let turn = corrected.rotation.angle_to(&k.pose.0.rotation).to_degrees();
    if moved > allowed || turn > config.max_turn_deg {
        tracing::debug!(
            ?kf,
            ?candidate,
            moved,
            allowed,
            turn,
            "loop: correction beyond the drift allowed"
        );
        return None;
    }
    // The 3D–3D fit inherits the points' depth errors (a few degrees of tilt from a few
    // dozen pairs); the loop's points seen in this keyframe's pixels pin the pose down
    // (ORB-SLAM2's `OptimizeSim3` does this with the pairs alone).
    let mut corrected = corrected;
    let mut found = Vec::new();
    for _ in 0..2 {
        let matched = search_loop_points(map, k, candidate, &corrected, camera);
        let (world, pixels, info): (Vec<_>, Vec<_>, Vec<_>) = matched
            .iter()
            .filter_map(|&(i, id)| {
                let p = map.point(id)?;
                let kp = &k.features.keypoints[i];
                Some((
                    Point3::from(p.position),
                    Point2::new(kp.x, kp.y),
                    1.0 / sf.powi(2 * kp.octave as i32),
                ))
            })
            .fold(
                (Vec::new(), Vec::new(), Vec::new()),
                |mut acc, (w, p, i)| {
                    acc.0.push(w);
                    acc.1.push(p);
                    acc.2.push(i);
                    acc
                },
            );
        if world.len() < config.min_projected_matches {
            found = matched;
            break;
        }
        let (pose, outlier) = optimize_pose_against(
            &world,
            &pixels,
            &info,
            camera,
            pose_of(&corrected),
            &PoseOptimizationConfig::default(),
        );
        let s = corrected.scale;
        corrected = Sim3::new(s, pose.0.rotation, s * pose.0.translation.vector);
        found = matched
            .into_iter()
            .zip(outlier)
            .filter_map(|(m, o)| (!o).then_some(m))
            .collect();
    }
    let moved = (centre_of(&corrected) - k.centre()).norm();
    let turn = corrected.rotation.angle_to(&k.pose.0.rotation).to_degrees();
    tracing::debug!(
        ?kf,
        ?candidate,
        moved,
        turn,
        matches = matches.len(),
        inliers = fit.n_inliers,
        projected = found.len(),
        scale = s12.scale,
        "loop candidate verified by Sim(3)"
    );
    (found.len() >= config.min_projected_matches && moved <= allowed && turn <= config.max_turn_deg)
        .then_some(VerifiedLoop {
            loop_keyframe: candidate,
            corrected,
            matches: found,
            sim3_inliers: fit.n_inliers,
        })
}

/// The centre of a world→camera similarity, in the world.
pub fn centre_of(s: &Sim3) -> Vector3<f64> {
    s.inverse().translation
}

/// Path length along the keyframes from `a` to `b` (id order).
fn path_between(map: &Map, a: KeyFrameId, b: KeyFrameId) -> f64 {
    let centres: Vec<Vector3<f64>> = map
        .keyframes()
        .filter(|k| k.id >= a.min(b) && k.id <= a.max(b))
        .map(KeyFrame::centre)
        .collect();
    centres.windows(2).map(|w| (w[1] - w[0]).norm()).sum()
}

/// The points of the loop keyframe and its covisible neighbours (the loop's local map),
/// projected into keyframe `k` at the corrected pose `s_kw` and matched to its keypoints
/// (ORB-SLAM2's `SearchByProjection` with a Sim(3), window 10 px × level scale, Hamming ≤ 50).
fn search_loop_points(
    map: &Map,
    k: &KeyFrame,
    loop_kf: KeyFrameId,
    s_kw: &Sim3,
    camera: &PinholeCamera,
) -> Vec<(usize, MapPointId)> {
    let Some(l) = map.keyframe(loop_kf) else {
        return Vec::new();
    };
    let mut points = BTreeSet::new();
    for id in std::iter::once(loop_kf).chain(l.covisible().iter().map(|&(id, _)| id)) {
        if let Some(o) = map.keyframe(id) {
            points.extend(o.points.iter().flatten().copied());
        }
    }
    let centre = centre_of(s_kw);
    let sf = map.scale_factor();
    let mut ids = Vec::new();
    let mut queries = Vec::new();
    for id in points {
        let Some(p) = map.point(id) else {
            continue;
        };
        let pc = s_kw.transform_point(&Point3::from(p.position));
        let Some(uv) = camera.project(&pc).filter(|uv| camera.contains(uv, 0.0)) else {
            continue;
        };
        let ray = p.position - centre;
        let distance = ray.norm();
        if distance < 0.8 * p.min_distance
            || distance > 1.2 * p.max_distance
            || ray.dot(&p.normal) < 0.5 * distance
        {
            continue;
        }
        let level = p.predict_level(distance, sf, map.n_levels());
        queries.push(WindowQuery {
            descriptor: p.descriptor,
            x: uv.x,
            y: uv.y,
            radius: 10.0 * sf.powi(level as i32),
            octaves: level.saturating_sub(1)..=level,
            angle: None,
        });
        ids.push(id);
    }
    let matcher = MatcherConfig {
        max_distance: 50,
        ratio: 1.0,
        mutual: false,
        check_orientation: false,
        orientation_bins: 30,
    };
    let mut out: Vec<(usize, MapPointId)> =
        search_in_window(&queries, &k.features, &k.grid, &matcher)
            .into_iter()
            .map(|m| (m.train, ids[m.query]))
            .collect();
    out.sort_unstable();
    out
}
