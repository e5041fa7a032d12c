//! Loop correction (ORB-SLAM2's `CorrectLoop`): the new keyframe and its covisible neighbours
//! are moved by the loop's similarity, their points with them; the loop's points are fused
//! into them; then the essential graph (spanning tree, loop edges, strong covisibility) is
//! optimised as a Sim(3) pose graph with the loop keyframe fixed, and every point follows the
//! keyframe that corrected it.

use std::collections::{BTreeMap, BTreeSet};

use jointloc_geometry::{PinholeCamera, Sim3, WorldToCamera};
use nalgebra::{Isometry3, Point3, Translation3};

use super::detection::VerifiedLoop;
use super::pose_graph::{PoseGraphConfig, PoseGraphEdge, optimise_pose_graph};
use crate::error::Result;
use crate::local_mapping::fusion::fuse;
use crate::map::{KeyFrameId, Map, MapPointId};

/// Covisibility edges of the essential graph need this many shared points (ORB-SLAM2: 100).
const ESSENTIAL_COVISIBILITY: usize = 100;

/// What a correction changed.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CorrectionStats {
    /// Keyframes moved with the new one before the pose graph.
    pub connected: usize,
    /// Loop points that replaced or joined the new keyframe's.
    pub fused: usize,
    /// New covisibility links across the loop.
    pub loop_links: usize,
    /// Nodes and edges of the essential graph.
    pub nodes: usize,
    pub edges: usize,
    /// Pose-graph cost before and after.
    pub initial_cost: f64,
    pub final_cost: f64,
    /// Wall time of the pose-graph optimisation alone, milliseconds.
    pub pose_graph_ms: f64,
}

/// A world→camera pose as a similarity of scale 1.
pub fn sim3_of(pose: &WorldToCamera) -> Sim3 {
    Sim3::new(1.0, pose.0.rotation, pose.0.translation.vector)
}

/// The rigid pose of a world→camera similarity in its world's units (`t / s`, as ORB-SLAM2).
pub fn pose_of(s: &Sim3) -> WorldToCamera {
    WorldToCamera(Isometry3::from_parts(
        Translation3::from(s.translation / s.scale),
        s.rotation,
    ))
}

/// Corrects the map for `found`, a loop of keyframe `kf`; `loop_edges` are the loops closed
/// before (pairs of keyframes, kept in the essential graph). Returns what changed.
pub fn correct_loop(
    map: &mut Map,
    kf: KeyFrameId,
    found: &VerifiedLoop,
    camera: &PinholeCamera,
    loop_edges: &BTreeSet<(KeyFrameId, KeyFrameId)>,
    pose_graph: &PoseGraphConfig,
) -> Result<CorrectionStats> {
    let (mut stats, graph) = correct_locally(map, kf, found, camera, loop_edges, pose_graph);
    if graph.n_nodes() == 0 {
        return Ok(stats);
    }
    let solved = graph.solve()?;
    stats.initial_cost = solved.initial_cost;
    stats.final_cost = solved.final_cost;
    stats.pose_graph_ms = solved.ms;
    solved.apply(map);
    Ok(stats)
}

/// The essential graph of a loop correction, taken out of the map: solved away from it
/// ([`EssentialGraph::solve`], the expensive part) and applied with
/// [`SolvedEssentialGraph::apply`] to the map as it was when the graph was made (local
/// mapping must not have changed it meanwhile).
#[derive(Debug, Clone)]
pub struct EssentialGraph {
    ids: Vec<KeyFrameId>,
    initial: Vec<Sim3>,
    fixed: Vec<bool>,
    edges: Vec<PoseGraphEdge>,
    /// The connected keyframe each moved point followed.
    corrected_by: BTreeMap<MapPointId, KeyFrameId>,
    config: PoseGraphConfig,
}

/// A solved [`EssentialGraph`].
#[derive(Debug, Clone)]
pub struct SolvedEssentialGraph {
    graph: EssentialGraph,
    poses: Vec<Sim3>,
    pub initial_cost: f64,
    pub final_cost: f64,
    /// Wall time of the optimisation, milliseconds.
    pub ms: f64,
}

impl EssentialGraph {
    /// Keyframes (nodes) in the graph.
    pub fn n_nodes(&self) -> usize {
        self.ids.len()
    }

    /// Optimises the graph's similarities.
    pub fn solve(self) -> Result<SolvedEssentialGraph> {
        let clock = std::time::Instant::now();
        let result = optimise_pose_graph(&self.initial, &self.fixed, &self.edges, &self.config)?;
        Ok(SolvedEssentialGraph {
            poses: result.poses,
            initial_cost: result.initial_cost,
            final_cost: result.final_cost,
            ms: clock.elapsed().as_secs_f64() * 1e3,
            graph: self,
        })
    }
}

impl SolvedEssentialGraph {
    /// Moves every keyframe to its optimised similarity and every point with the keyframe
    /// that corrected it (or its reference keyframe).
    pub fn apply(self, map: &mut Map) {
        let g = self.graph;
        let optimised: BTreeMap<KeyFrameId, (Sim3, Sim3)> = g
            .ids
            .iter()
            .enumerate()
            .map(|(i, &id)| (id, (g.initial[i], self.poses[i])))
            .collect();
        let points: Vec<MapPointId> = map.points().map(|p| p.id).collect();
        for p in points {
            let Some(mp) = map.point(p) else {
                continue;
            };
            let by = g.corrected_by.get(&p).copied().unwrap_or(mp.reference);
            let Some((s_start, s_end)) = optimised.get(&by) else {
                continue;
            };
            let x = s_start.transform_point(&Point3::from(mp.position));
            let moved = s_end.inverse().transform_point(&x).coords;
            if let Some(mp) = map.point_mut(p) {
                mp.position = moved;
            }
            map.update_normal_and_depth(p);
        }
        for (id, (_, s)) in &optimised {
            if let Some(o) = map.keyframe_mut(*id) {
                o.pose = pose_of(s);
            }
        }
    }
}

/// The part of [`correct_loop`] that needs the map and is quick: the connected keyframes and
/// their points moved by the loop's similarity, the loop's points fused, the new links made;
/// returns the essential graph to optimise.
pub fn correct_locally(
    map: &mut Map,
    kf: KeyFrameId,
    found: &VerifiedLoop,
    camera: &PinholeCamera,
    loop_edges: &BTreeSet<(KeyFrameId, KeyFrameId)>,
    pose_graph: &PoseGraphConfig,
) -> (CorrectionStats, EssentialGraph) {
    let mut stats = CorrectionStats::default();
    map.update_connections(kf);
    let Some(k) = map.keyframe(kf) else {
        let empty = EssentialGraph {
            ids: Vec::new(),
            initial: Vec::new(),
            fixed: Vec::new(),
            edges: Vec::new(),
            corrected_by: BTreeMap::new(),
            config: *pose_graph,
        };
        return (stats, empty);
    };
    let t_kw = k.pose;
    let connected: Vec<KeyFrameId> = std::iter::once(kf)
        .chain(k.covisible().iter().map(|&(id, _)| id))
        .collect();
    let before: BTreeMap<KeyFrameId, Sim3> =
        map.keyframes().map(|k| (k.id, sim3_of(&k.pose))).collect();
    // Corrected similarities of the connected keyframes: their pose relative to kf kept.
    let mut corrected: BTreeMap<KeyFrameId, Sim3> = BTreeMap::new();
    for &id in &connected {
        let Some(o) = map.keyframe(id) else {
            continue;
        };
        let t_ik = o.pose.0 * t_kw.0.inverse();
        corrected.insert(id, sim3_of(&WorldToCamera(t_ik)).compose(&found.corrected));
    }
    stats.connected = corrected.len();
    // Points of the connected keyframes follow the first of them (in id order) that sees them.
    let mut corrected_by: BTreeMap<MapPointId, KeyFrameId> = BTreeMap::new();
    for (&id, s_corr) in &corrected {
        let s_inv = s_corr.inverse();
        let s_before = before[&id];
        let observed: Vec<MapPointId> = map
            .keyframe(id)
            .map_or(Vec::new(), |o| o.points.iter().flatten().copied().collect());
        for p in observed {
            if corrected_by.contains_key(&p) {
                continue;
            }
            if let Some(mp) = map.point_mut(p) {
                let x = s_before.transform_point(&Point3::from(mp.position));
                mp.position = s_inv.transform_point(&x).coords;
                corrected_by.insert(p, id);
            }
        }
    }
    for (&id, s) in &corrected {
        if let Some(o) = map.keyframe_mut(id) {
            o.pose = pose_of(s);
        }
    }
    for &p in corrected_by.keys() {
        map.update_normal_and_depth(p);
    }
    // Loop fusion: the loop's points replace the new keyframe's duplicates, then the loop's
    // local map is fused into every connected keyframe at its corrected pose.
    for &(index, loop_point) in &found.matches {
        let existing = map
            .keyframe(kf)
            .and_then(|k| k.points.get(index).copied().flatten());
        match existing {
            Some(p) if p == loop_point => {}
            Some(p) => {
                map.replace_point(p, loop_point);
                stats.fused += 1;
            }
            None => {
                if map.add_observation(loop_point, kf, index) {
                    stats.fused += 1;
                }
            }
        }
    }
    let loop_points: Vec<MapPointId> = {
        let mut s = BTreeSet::new();
        if let Some(l) = map.keyframe(found.loop_keyframe) {
            for id in
                std::iter::once(found.loop_keyframe).chain(l.covisible().iter().map(|&(i, _)| i))
            {
                if let Some(o) = map.keyframe(id) {
                    s.extend(o.points.iter().flatten().copied());
                }
            }
        }
        s.into_iter().collect()
    };
    for &id in corrected.keys() {
        stats.fused += fuse(map, id, &loop_points, camera);
    }
    // New links across the loop: covisible now, not before, not among the connected.
    let connected_set: BTreeSet<KeyFrameId> = corrected.keys().copied().collect();
    let mut links: BTreeSet<(KeyFrameId, KeyFrameId)> = BTreeSet::new();
    for &id in corrected.keys() {
        let previous: BTreeSet<KeyFrameId> = map.keyframe(id).map_or(BTreeSet::new(), |o| {
            o.covisible().iter().map(|&(i, _)| i).collect()
        });
        map.update_connections(id);
        if let Some(o) = map.keyframe(id) {
            for &(n, _) in o.covisible() {
                if !previous.contains(&n) && !connected_set.contains(&n) {
                    links.insert((id, n));
                }
            }
        }
    }
    links.insert((kf, found.loop_keyframe));
    stats.loop_links = links.len();
    // The essential graph.
    let ids: Vec<KeyFrameId> = map.keyframes().map(|k| k.id).collect();
    let node: BTreeMap<KeyFrameId, usize> =
        ids.iter().enumerate().map(|(i, &id)| (id, i)).collect();
    let initial: Vec<Sim3> = ids
        .iter()
        .map(|id| corrected.get(id).copied().unwrap_or(before[id]))
        .collect();
    let fixed: Vec<bool> = ids.iter().map(|&id| id == found.loop_keyframe).collect();
    let mut pairs: BTreeSet<(KeyFrameId, KeyFrameId)> = BTreeSet::new();
    let mut edges = Vec::new();
    let mut edge =
        |a: KeyFrameId, b: KeyFrameId, sa: &Sim3, sb: &Sim3, edges: &mut Vec<PoseGraphEdge>| {
            let key = (a.min(b), a.max(b));
            if a == b || !pairs.insert(key) {
                return;
            }
            if let (Some(&i), Some(&j)) = (node.get(&a), node.get(&b)) {
                edges.push(PoseGraphEdge {
                    i,
                    j,
                    measurement: sa.compose(&sb.inverse()),
                    weight: 1.0,
                });
            }
        };
    for &(a, b) in &links {
        if let (Some(sa), Some(sb)) = (
            node.get(&a).map(|&i| initial[i]),
            node.get(&b).map(|&i| initial[i]),
        ) {
            edge(a, b, &sa, &sb, &mut edges);
        }
    }
    for k in map.keyframes() {
        let sa = before[&k.id];
        let mut others: Vec<KeyFrameId> = k.parent().into_iter().collect();
        others.extend(loop_edges.iter().filter_map(|&(x, y)| {
            if x == k.id {
                Some(y)
            } else if y == k.id {
                Some(x)
            } else {
                None
            }
        }));
        others.extend(
            k.covisible()
                .iter()
                .filter(|&&(n, w)| w >= ESSENTIAL_COVISIBILITY && n < k.id)
                .map(|&(n, _)| n),
        );
        for o in others {
            if let Some(sb) = before.get(&o) {
                edge(k.id, o, &sa, sb, &mut edges);
            }
        }
    }
    stats.nodes = ids.len();
    stats.edges = edges.len();
    let graph = EssentialGraph {
        ids,
        initial,
        fixed,
        edges,
        corrected_by,
        config: *pose_graph,
    };
    (stats, graph)
}
