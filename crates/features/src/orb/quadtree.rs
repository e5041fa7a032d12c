//! Spreading keypoints over a level (ORB-SLAM2's "octree", a quadtree): nodes covering the
//! detection region are split into four until there are as many non-empty nodes as keypoints
//! wanted (the most populated nodes first) or no node holds more than one keypoint; each node
//! then keeps its best-response keypoint. Dense texture cannot take the whole quota, so
//! sparse regions keep their few corners.

/// A candidate keypoint in level pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Point {
    pub x: u32,
    pub y: u32,
    pub response: f32,
}

/// The region the root nodes cover (x1, y1 exclusive).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bounds {
    pub x0: f32,
    pub y0: f32,
    pub x1: f32,
    pub y1: f32,
}

#[derive(Debug, Clone)]
struct Node {
    b: Bounds,
    idx: Vec<u32>,
}

impl Node {
    /// Children with at least one point (points on a split line go right / down).
    fn split(&self, pts: &[Point]) -> Vec<Node> {
        let mx = 0.5 * (self.b.x0 + self.b.x1);
        let my = 0.5 * (self.b.y0 + self.b.y1);
        let quads = [
            Bounds {
                x0: self.b.x0,
                y0: self.b.y0,
                x1: mx,
                y1: my,
            },
            Bounds {
                x0: mx,
                y0: self.b.y0,
                x1: self.b.x1,
                y1: my,
            },
            Bounds {
                x0: self.b.x0,
                y0: my,
                x1: mx,
                y1: self.b.y1,
            },
            Bounds {
                x0: mx,
                y0: my,
                x1: self.b.x1,
                y1: self.b.y1,
            },
        ];
        let mut kids: [Vec<u32>; 4] = Default::default();
        for &i in &self.idx {
            let p = &pts[i as usize];
            let q = (p.x as f32 >= mx) as usize + 2 * ((p.y as f32 >= my) as usize);
            kids[q].push(i);
        }
        quads
            .into_iter()
            .zip(kids)
            .filter(|(_, k)| !k.is_empty())
            .map(|(b, idx)| Node { b, idx })
            .collect()
    }

    /// Whether splitting can still separate its points (they are at distinct pixels, so a
    /// node narrower than a pixel in both directions holds at most one).
    fn splittable(&self) -> bool {
        self.idx.len() > 1 && (self.b.x1 - self.b.x0 > 1.0 || self.b.y1 - self.b.y0 > 1.0)
    }
}

/// Indices into `pts` of at most `target` keypoints spread over `bounds`, in ascending order.
///
/// Starts from `round(width / height)` side-by-side root nodes (one for square regions), as
/// ORB-SLAM2. Points must lie inside `bounds` at distinct pixels.
pub fn distribute(pts: &[Point], bounds: Bounds, target: usize) -> Vec<usize> {
    if pts.is_empty() || target == 0 {
        return Vec::new();
    }
    let (bw, bh) = (bounds.x1 - bounds.x0, bounds.y1 - bounds.y0);
    let n_roots = ((bw / bh).round() as usize).max(1);
    let step = bw / n_roots as f32;
    let mut nodes: Vec<Node> = (0..n_roots)
        .map(|r| Node {
            b: Bounds {
                x0: bounds.x0 + r as f32 * step,
                x1: if r + 1 == n_roots {
                    bounds.x1
                } else {
                    bounds.x0 + (r + 1) as f32 * step
                },
                ..bounds
            },
            idx: Vec::new(),
        })
        .collect();
    for (i, p) in pts.iter().enumerate() {
        let r = (((p.x as f32 - bounds.x0) / step) as usize).min(n_roots - 1);
        nodes[r].idx.push(i as u32);
    }
    nodes.retain(|n| !n.idx.is_empty());

    'rounds: while nodes.len() < target {
        // Split the most populated nodes first (ties: original order), so that when the
        // target is reached mid-round the densest regions got the extra nodes.
        let mut order: Vec<usize> = (0..nodes.len())
            .filter(|&i| nodes[i].splittable())
            .collect();
        if order.is_empty() {
            break;
        }
        order.sort_by(|&a, &b| nodes[b].idx.len().cmp(&nodes[a].idx.len()).then(a.cmp(&b)));
        let mut split = vec![false; nodes.len()];
        let mut next: Vec<Node> = Vec::with_capacity(nodes.len() + 3 * order.len());
        let mut count = nodes.len();
        let mut reached = false;
        for &i in &order {
            if count >= target {
                reached = true;
                break;
            }
            let kids = nodes[i].split(pts);
            count += kids.len() - 1;
            split[i] = true;
            next.extend(kids);
        }
        for (i, n) in nodes.into_iter().enumerate() {
            if !split[i] {
                next.push(n);
            }
        }
        nodes = next;
        if reached {
            break 'rounds;
        }
    }

    let mut keep: Vec<usize> = nodes
        .iter()
        .map(|n| {
            *n.idx
                .iter()
                .max_by(|&&a, &&b| {
                    let (pa, pb) = (&pts[a as usize], &pts[b as usize]);
                    pa.response
                        .total_cmp(&pb.response)
                        // Ties: prefer the earlier pixel (raster order).
                        .then((pb.y, pb.x).cmp(&(pa.y, pa.x)))
                })
                .expect("nodes are non-empty") as usize
        })
        .collect();
    // Splitting can overshoot by up to 3 nodes: drop the weakest.
    if keep.len() > target {
        keep.sort_by(|&a, &b| pts[b].response.total_cmp(&pts[a].response).then(a.cmp(&b)));
        keep.truncate(target);
    }
    keep.sort_unstable();
    keep
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bounds(w: f32, h: f32) -> Bounds {
        Bounds {
            x0: 0.0,
            y0: 0.0,
            x1: w,
            y1: h,
        }
    }

    #[test]
    fn keeps_all_points_when_fewer_than_the_target() {
        let pts: Vec<Point> = (0..10)
            .map(|i| Point {
                x: i * 7,
                y: i * 3,
                response: i as f32,
            })
            .collect();
        assert_eq!(
            distribute(&pts, bounds(100.0, 100.0), 50),
            (0..10).collect::<Vec<_>>()
        );
    }

    #[test]
    fn a_dense_cluster_cannot_take_the_whole_quota() {
        // 400 strong points packed in one 20×20 corner, three weak ones alone in the other
        // quarters of the region.
        let mut pts = Vec::new();
        for y in 0..20 {
            for x in 0..20 {
                pts.push(Point {
                    x,
                    y,
                    response: 100.0 + (x + y) as f32,
                });
            }
        }
        for &(x, y) in &[(225, 75), (75, 225), (225, 225)] {
            pts.push(Point {
                x,
                y,
                response: 1.0,
            });
        }
        let keep = distribute(&pts, bounds(300.0, 300.0), 40);
        assert_eq!(keep.len(), 40);
        // Every isolated point survives although all cluster points respond more strongly.
        for i in 400..403 {
            assert!(keep.contains(&i), "isolated point {i} dropped");
        }
        // A plain top-40 by response would have taken only cluster points.
        assert_eq!(keep.iter().filter(|&&i| i < 400).count(), 37);
    }

    #[test]
    fn picks_the_best_response_per_node_and_exactly_the_target() {
        // A uniform 30×30 lattice of points: the result is spread (every 100×100 quarter of
        // the image gets a fair share) and has exactly `target` points.
        let mut pts = Vec::new();
        for y in 0..30u32 {
            for x in 0..30u32 {
                pts.push(Point {
                    x: x * 10 + 5,
                    y: y * 10 + 5,
                    response: ((x * 7 + y * 13) % 17) as f32,
                });
            }
        }
        for target in [1usize, 5, 37, 100, 300] {
            let keep = distribute(&pts, bounds(300.0, 300.0), target);
            assert_eq!(keep.len(), target, "target {target}");
        }
        let keep = distribute(&pts, bounds(300.0, 300.0), 100);
        for qy in 0..3 {
            for qx in 0..3 {
                let n = keep
                    .iter()
                    .filter(|&&i| pts[i].x / 100 == qx && pts[i].y / 100 == qy)
                    .count();
                assert!((6..=16).contains(&n), "cell ({qx}, {qy}) has {n}");
            }
        }
        // With one point wanted, the root keeps the strongest.
        let best = distribute(&pts, bounds(300.0, 300.0), 1)[0];
        let max = pts.iter().map(|p| p.response).fold(f32::MIN, f32::max);
        assert_eq!(pts[best].response, max);
    }

    #[test]
    fn wide_regions_start_with_several_roots() {
        // Two points far apart in a 4:1 region are both kept with target 2, even though
        // a single root could only be split once.
        let pts = vec![
            Point {
                x: 10,
                y: 10,
                response: 1.0,
            },
            Point {
                x: 390,
                y: 90,
                response: 2.0,
            },
        ];
        assert_eq!(distribute(&pts, bounds(400.0, 100.0), 2), vec![0, 1]);
    }
}
