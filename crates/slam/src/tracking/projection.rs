//! Search by projection (ORB-SLAM2's `SearchByProjection`): map points are projected with a
//! predicted pose and matched to keypoints in a window around the projection, at the pyramid
//! level their distance predicts.

use jointloc_features::orb::{Match, MatcherConfig, WindowQuery, search_in_window};
use jointloc_geometry::{PinholeCamera, WorldToCamera};
use nalgebra::{Point2, Point3, Vector3};

use crate::frame::Frame;
use crate::map::{Map, MapPoint, MapPointId};

/// Where and how a map point should appear in a camera (ORB-SLAM2's `isInFrustum`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Visibility {
    pub pixel: Point2<f64>,
    /// Predicted pyramid level.
    pub level: u32,
    /// Cosine between the viewing ray and the point's mean viewing direction.
    pub view_cos: f64,
}

/// Projects `point` into the camera `pose` (centre `centre`); `None` when it falls behind the
/// camera, outside the image, outside its scale-invariance distance range (±20 %) or is seen
/// more than 60° away from its mean viewing direction.
pub fn visibility(
    point: &MapPoint,
    pose: &WorldToCamera,
    centre: &Vector3<f64>,
    camera: &PinholeCamera,
    map: &Map,
) -> Option<Visibility> {
    let pc = pose.transform_point(&Point3::from(point.position));
    let pixel = camera.project(&pc)?;
    if !camera.contains(&pixel, 0.0) {
        return None;
    }
    let ray = point.position - centre;
    let distance = ray.norm();
    if distance < 0.8 * point.min_distance || distance > 1.2 * point.max_distance {
        return None;
    }
    let view_cos = ray.dot(&point.normal) / distance;
    if view_cos < 0.5 {
        return None;
    }
    let level = point.predict_level(distance, map.scale_factor(), map.n_levels());
    Some(Visibility {
        pixel,
        level,
        view_cos,
    })
}

/// Matches the local map points `candidates` (not yet matched in `frame`) to free keypoints of
/// `frame` around their projections. The window is `th · scale^level` times 2.5 px for points
/// seen close to their mean direction, 4 px otherwise. Points predicted visible have their
/// `visible` counter raised. Returns the number of new matches.
pub fn search_local_points(
    frame: &mut Frame,
    map: &mut Map,
    candidates: &[MapPointId],
    camera: &PinholeCamera,
    th: f64,
    matcher: &MatcherConfig,
) -> usize {
    let (Some(pose), Some(centre)) = (frame.pose, frame.centre()) else {
        return 0;
    };
    let mut ids = Vec::new();
    let mut queries = Vec::new();
    let sf = map.scale_factor();
    for &id in candidates {
        let Some(p) = map.point(id) else {
            continue;
        };
        let Some(v) = visibility(p, &pose, &centre, camera, map) else {
            continue;
        };
        let scale = sf.powi(v.level as i32);
        let radius = th * scale * if v.view_cos > 0.998 { 2.5 } else { 4.0 };
        queries.push(WindowQuery {
            descriptor: p.descriptor,
            x: v.pixel.x,
            y: v.pixel.y,
            radius,
            octaves: v.level.saturating_sub(1)..=v.level,
            angle: None,
        });
        ids.push(id);
    }
    for id in &ids {
        if let Some(p) = map.point_mut(*id) {
            p.visible += 1;
        }
    }
    assign(
        frame,
        &ids,
        &search_in_window(&queries, &frame.features, &frame.grid, matcher),
    )
}

/// Matches the points tracked in `last` (inliers only) into `frame` at the pose `frame.pose`
/// (the motion-model prediction), in a window of `th · scale` px at the last octave ± 1, with
/// the rotation-consistency check (ORB-SLAM2's motion-model search).
pub fn search_last_frame(
    frame: &mut Frame,
    last: &Frame,
    map: &Map,
    camera: &PinholeCamera,
    th: f64,
    matcher: &MatcherConfig,
) -> usize {
    let Some(pose) = frame.pose else {
        return 0;
    };
    let sf = map.scale_factor();
    let max_level = map.n_levels().saturating_sub(1) as u32;
    let mut ids = Vec::new();
    let mut queries = Vec::new();
    for (i, (id, outlier)) in last.points.iter().zip(&last.outliers).enumerate() {
        let (Some(id), false) = (id, outlier) else {
            continue;
        };
        let Some(p) = map.point(*id) else {
            continue;
        };
        let Some(uv) = camera.project(&pose.transform_point(&Point3::from(p.position))) else {
            continue;
        };
        if !camera.contains(&uv, 0.0) {
            continue;
        }
        let k = &last.features.keypoints[i];
        queries.push(WindowQuery {
            descriptor: p.descriptor,
            x: uv.x,
            y: uv.y,
            radius: th * sf.powi(k.octave as i32),
            octaves: k.octave.saturating_sub(1)..=(k.octave + 1).min(max_level),
            angle: Some(k.angle),
        });
        ids.push(*id);
    }
    assign(
        frame,
        &ids,
        &search_in_window(&queries, &frame.features, &frame.grid, matcher),
    )
}

/// Writes matches into free keypoints of `frame`; returns how many were written.
fn assign(frame: &mut Frame, ids: &[MapPointId], matches: &[Match]) -> usize {
    let mut taken: std::collections::BTreeSet<MapPointId> =
        frame.points.iter().flatten().copied().collect();
    let mut n = 0;
    for m in matches {
        if frame.points[m.train].is_none() && taken.insert(ids[m.query]) {
            frame.points[m.train] = Some(ids[m.query]);
            frame.outliers[m.train] = false;
            n += 1;
        }
    }
    n
}
