use jointloc_features::orb::{FeatureGrid, KeyPoint, OrbFeatures};
use jointloc_geometry::WorldToCamera;
use nalgebra::{Isometry3, Vector3};

use super::*;

fn features(n: usize, seed: u8) -> OrbFeatures {
    let keypoints: Vec<KeyPoint> = (0..n)
        .map(|i| KeyPoint {
            x: (i % 20) as f64 * 20.0 + 10.0,
            y: (i / 20) as f64 * 20.0 + 10.0,
            octave: (i % 3) as u32,
            angle: 0.0,
            response: 1.0,
            size: 31.0,
        })
        .collect();
    let descriptors = (0..n)
        .map(|i| {
            let mut d = [0u8; 32];
            d[0] = i as u8;
            d[1] = seed;
            d
        })
        .collect();
    OrbFeatures {
        keypoints,
        descriptors,
        level_scales: (0..8).map(|l| 1.2f64.powi(l)).collect(),
    }
}

fn keyframe(index: usize, x: f64, n: usize) -> KeyFrame {
    let f = features(n, index as u8);
    let grid = FeatureGrid::new(&f.keypoints, 500, 500, 20.0);
    let pose = WorldToCamera(Isometry3::translation(-x, 0.0, 0.0));
    KeyFrame::new(index, index as f64, pose, f, grid)
}

/// Three keyframes; keyframe pairs (0,1) and (1,2) share `shared` points each, (0,2) share
/// `shared / 2`.
fn three_keyframe_map(shared: usize) -> (Map, [KeyFrameId; 3]) {
    let mut map = Map::new(1.2, 8);
    let a = map.insert_keyframe(keyframe(0, 0.0, 200));
    let b = map.insert_keyframe(keyframe(10, 1.0, 200));
    for i in 0..shared {
        let p = map
            .insert_point(Vector3::new(i as f64 * 0.1, 0.0, 10.0), a, i)
            .unwrap();
        assert!(map.add_observation(p, b, i));
    }
    map.update_connections(a);
    map.update_connections(b);
    // c arrives later, as in a sequence: it sees half of the a–b points and new b–c points.
    let c = map.insert_keyframe(keyframe(20, 2.0, 200));
    for i in 0..shared / 2 {
        let p = map.keyframe(a).unwrap().points[i].unwrap();
        assert!(map.add_observation(p, c, i));
    }
    for i in shared..2 * shared {
        let p = map
            .insert_point(Vector3::new(i as f64 * 0.1, 1.0, 10.0), b, i)
            .unwrap();
        assert!(map.add_observation(p, c, i));
    }
    map.update_connections(c);
    (map, [a, b, c])
}

#[test]
fn covisibility_counts_shared_points_and_builds_the_tree() {
    let (map, [a, b, c]) = three_keyframe_map(40);
    let kb = map.keyframe(b).unwrap();
    assert_eq!(kb.covisibility_weight(a), 40);
    assert_eq!(kb.covisibility_weight(c), 40 + 20);
    assert_eq!(kb.best_covisible(1), vec![c]);
    assert_eq!(map.keyframe(a).unwrap().covisibility_weight(c), 20);
    assert_eq!(map.keyframe(a).unwrap().parent(), None);
    assert_eq!(kb.parent(), Some(a));
    assert!(map.keyframe(a).unwrap().children().contains(&b));
    assert_eq!(map.keyframe(c).unwrap().parent(), Some(b));
}

#[test]
fn weak_links_fall_back_to_the_strongest_neighbour() {
    let (map, [a, b, c]) = three_keyframe_map(10);
    // (a, c) share 5 points, (a, b) 10: both below the threshold, so only the best is kept.
    let ka = map.keyframe(a).unwrap();
    assert_eq!(ka.covisible().len(), 1);
    assert_eq!(ka.covisible()[0], (b, 10));
    // c shares 15 with b (5 + 10): an edge at the threshold.
    assert_eq!(map.keyframe(c).unwrap().covisibility_weight(b), 15);
}

#[test]
fn a_point_left_with_one_observation_is_erased() {
    let (mut map, [a, b, _]) = three_keyframe_map(40);
    let p = map.keyframe(a).unwrap().points[39].unwrap();
    assert_eq!(map.point(p).unwrap().n_observations(), 2);
    map.remove_observation(p, b);
    assert!(map.point(p).is_none());
    assert_eq!(map.keyframe(a).unwrap().points[39], None);
    assert_eq!(map.keyframe(b).unwrap().points[39], None);
}

#[test]
fn replacing_a_point_moves_its_observations() {
    let (mut map, [a, b, c]) = three_keyframe_map(40);
    // p0 is seen by a and b; q by b and c at other keypoints.
    let p0 = map.keyframe(a).unwrap().points[30].unwrap();
    let q = map.keyframe(c).unwrap().points[50].unwrap();
    map.replace_point(p0, q);
    assert!(map.point(p0).is_none());
    let qp = map.point(q).unwrap();
    // a gains q; b already sees q, so its observation of p0 is dropped.
    assert_eq!(qp.observations().get(&a), Some(&30));
    assert_eq!(qp.observations().get(&b), Some(&50));
    assert_eq!(map.keyframe(b).unwrap().points[30], None);
    assert_eq!(map.keyframe(a).unwrap().points[30], Some(q));
}

#[test]
fn erasing_a_keyframe_reattaches_its_children() {
    let (mut map, [a, b, c]) = three_keyframe_map(40);
    assert!(!map.erase_keyframe(a), "the first keyframe stays");
    assert!(map.erase_keyframe(b));
    assert!(map.keyframe(b).is_none());
    assert_eq!(map.keyframe(c).unwrap().parent(), Some(a));
    assert!(map.keyframe(a).unwrap().children().contains(&c));
    assert_eq!(map.keyframe(a).unwrap().covisibility_weight(b), 0);
    // Points seen only by a and b lost an observation and are gone; a–c points survive.
    for p in map.points() {
        assert!(
            p.n_observations() >= 2,
            "{} kept with one observation",
            p.id
        );
        assert!(!p.observations().contains_key(&b));
    }
    assert_eq!(map.n_points(), 20);
}

#[test]
fn descriptor_is_the_medoid_of_the_observations() {
    let mut map = Map::new(1.2, 8);
    // Byte 1 of keypoint 0's descriptor is the keyframe's seed; nested bit masks make the
    // Hamming distance the difference of their popcounts (0, 2, 3, 4, 8 bits): 0x07 has the
    // smallest median distance to the others.
    let seeds = [0x00u8, 0x03, 0x07, 0x0f, 0xff];
    let ids: Vec<KeyFrameId> = seeds
        .iter()
        .enumerate()
        .map(|(i, &s)| {
            let mut kf = keyframe(i, i as f64, 10);
            kf.features.descriptors[0][1] = s;
            map.insert_keyframe(kf)
        })
        .collect();
    let p = map
        .insert_point(Vector3::new(0.0, 0.0, 5.0), ids[0], 0)
        .unwrap();
    for &id in &ids[1..] {
        map.add_observation(p, id, 0);
    }
    map.update_descriptor(p);
    assert_eq!(map.point(p).unwrap().descriptor[1], 0x07);
}

#[test]
fn normal_and_depth_follow_the_observers() {
    let mut map = Map::new(1.2, 8);
    let a = map.insert_keyframe(keyframe(0, -1.0, 10));
    let b = map.insert_keyframe(keyframe(1, 1.0, 10));
    // Keypoint 2 has octave 2.
    let p = map
        .insert_point(Vector3::new(0.0, 0.0, 10.0), a, 2)
        .unwrap();
    map.add_observation(p, b, 2);
    map.update_normal_and_depth(p);
    let mp = map.point(p).unwrap();
    assert!((mp.normal - Vector3::z()).norm() < 1e-12);
    let dist = (1.0f64 + 100.0).sqrt();
    assert!((mp.max_distance - dist * 1.2f64.powi(2)).abs() < 1e-9);
    assert!((mp.min_distance - mp.max_distance / 1.2f64.powi(7)).abs() < 1e-9);
    assert_eq!(mp.predict_level(mp.max_distance, 1.2, 8), 0);
    assert_eq!(
        mp.predict_level(mp.max_distance / 1.2f64.powi(3), 1.2, 8),
        3
    );
}

#[test]
fn invalid_insertions_are_refused() {
    let mut map = Map::new(1.2, 8);
    let a = map.insert_keyframe(keyframe(0, 0.0, 10));
    assert!(
        map.insert_point(Vector3::new(f64::NAN, 0.0, 1.0), a, 0)
            .is_none()
    );
    assert!(
        map.insert_point(Vector3::new(0.0, 0.0, 1.0), a, 99)
            .is_none()
    );
    assert!(
        map.insert_point(Vector3::new(0.0, 0.0, 1.0), KeyFrameId(7), 0)
            .is_none()
    );
    let p = map.insert_point(Vector3::new(0.0, 0.0, 1.0), a, 0).unwrap();
    assert!(
        map.insert_point(Vector3::new(0.0, 0.0, 2.0), a, 0)
            .is_none(),
        "keypoint taken"
    );
    assert!(
        !map.add_observation(p, a, 1),
        "already observed by this keyframe"
    );
}

#[test]
fn retiring_a_keyframe_keeps_shared_points_and_makes_its_children_roots() {
    let (mut map, [a, b, c]) = three_keyframe_map(40);
    // A point only a sees goes with it; points a shares with b (and c) stay.
    let own = map
        .insert_point(Vector3::new(9.0, 9.0, 10.0), a, 150)
        .unwrap();
    let pose_a = map.keyframe(a).unwrap().pose;
    let r = map.retire_keyframe(a).unwrap();
    assert_eq!(
        (r.id, r.frame_index, r.timestamp, r.pose),
        (a, 0, 0.0, pose_a)
    );
    assert!(map.keyframe(a).is_none() && map.retire_keyframe(a).is_none());
    assert!(map.point(own).is_none());
    assert_eq!(map.n_points(), 80);
    for p in map.points() {
        assert!(!p.observations().contains_key(&a), "{} still sees a", p.id);
        assert_ne!(p.reference, a);
        assert!(p.n_observations() >= 1);
    }
    // Points 20..40 were seen by a and b only: kept with b's observation.
    let p = map.keyframe(b).unwrap().points[30].unwrap();
    assert_eq!(map.point(p).unwrap().n_observations(), 1);
    assert_eq!(map.point(p).unwrap().reference, b);
    // Covisibility edges to a are gone; b (a's child) is a root, c keeps its parent b.
    assert_eq!(map.keyframe(b).unwrap().covisibility_weight(a), 0);
    assert_eq!(map.keyframe(c).unwrap().covisibility_weight(a), 0);
    assert_eq!(map.keyframe(b).unwrap().parent(), None);
    assert_eq!(map.keyframe(c).unwrap().parent(), Some(b));
    // A root is not culled (its culled pose could not be kept relative to a parent), and
    // reconnecting does not give it a parent among its own descendants.
    assert!(!map.erase_keyframe(b));
    map.update_connections(b);
    map.update_connections(c);
    assert_eq!(map.keyframe(b).unwrap().parent(), None);
    assert_eq!(map.keyframe(c).unwrap().parent(), Some(b));
    // A keyframe inserted afterwards joins the tree as before.
    let d = map.insert_keyframe(keyframe(30, 3.0, 200));
    for i in 40..80 {
        let p = map.keyframe(c).unwrap().points[i].unwrap();
        assert!(map.add_observation(p, d, i));
    }
    map.update_connections(d);
    // b and c share those 40 points with d; the tie goes to the lower id.
    assert_eq!(map.keyframe(d).unwrap().parent(), Some(b));
    assert!(map.keyframe(b).unwrap().children().contains(&d));
}

#[test]
fn absorbing_an_earlier_map_moves_it_through_the_similarity() {
    use jointloc_geometry::{Sim3, WorldToCamera};
    use nalgebra::{Point3, UnitQuaternion};
    let (earlier, [a, _, c]) = three_keyframe_map(40);
    let mut current = earlier.successor();
    let d = current.insert_keyframe(keyframe(30, 5.0, 50));
    let fresh = current
        .insert_point(Vector3::new(5.0, 0.0, 10.0), d, 0)
        .unwrap();
    let s = Sim3::new(
        2.0,
        UnitQuaternion::from_euler_angles(0.1, -0.2, 0.7),
        Vector3::new(3.0, -1.0, 0.5),
    );
    let before_centre = earlier.keyframe(c).unwrap().pose.inverse().centre();
    let point = *earlier.keyframe(a).unwrap().points[3].as_ref().unwrap();
    let before_point = earlier.point(point).unwrap().clone();
    let (n_kf, n_pts) = (earlier.n_keyframes(), earlier.n_points());
    let report = current.absorb(earlier.clone(), &s).unwrap();
    assert_eq!((report.keyframes, report.points), (n_kf, n_pts));
    assert_eq!(current.n_keyframes(), n_kf + 1);
    assert_eq!(current.n_points(), n_pts + 1);
    // Keyframe centres and points moved by s; camera-frame coordinates of a point only scaled.
    let centre = current.keyframe(c).unwrap().pose.inverse().centre();
    assert!((centre - s.transform_point(&before_centre)).norm() < 1e-9);
    let moved = current.point(point).unwrap();
    let want = s.transform_point(&Point3::from(before_point.position));
    assert!((moved.position - want.coords).norm() < 1e-9);
    assert!((moved.max_distance - 2.0 * before_point.max_distance).abs() < 1e-9);
    let in_cam = |pose: &WorldToCamera, p: &Vector3<f64>| pose.0.transform_point(&Point3::from(*p));
    let before_cam = in_cam(&earlier.keyframe(a).unwrap().pose, &before_point.position);
    let after_cam = in_cam(&current.keyframe(a).unwrap().pose, &moved.position);
    assert!((after_cam.coords - 2.0 * before_cam.coords).norm() < 1e-9);
    // One spanning tree; new ids continue after both maps'.
    assert_eq!(current.keyframe(d).unwrap().parent(), Some(c));
    assert!(current.point(fresh).is_some());
    let next = current.insert_keyframe(keyframe(40, 6.0, 10));
    assert!(next > d);
    // A map that shares ids, or a similarity that is not one, is refused and changes nothing.
    let before = (current.n_keyframes(), current.n_points());
    assert!(current.absorb(earlier.clone(), &s).is_err());
    let mut other = earlier.successor();
    let bad = Sim3::new(f64::NAN, UnitQuaternion::identity(), Vector3::zeros());
    assert!(other.absorb(earlier, &bad).is_err());
    assert_eq!((current.n_keyframes(), current.n_points()), before);
    assert_eq!(other.n_keyframes(), 0);
}
