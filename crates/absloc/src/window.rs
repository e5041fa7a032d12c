//! The map's keypoints around a predicted footprint, gathered from the tiles that cover it.
//!
//! In flight the fused pose predicts where the frame lies to a few centimetres, yet the
//! tile search matches whole tiles: up to four overlapping ones that contain the predicted
//! position, each with keypoints over four times the footprint's area. On a coarse map
//! (12.5 cm/px, upsampled) few tiles reach the early stop's 40 inliers and a fix matched
//! 3.2 tiles on average, 137–270 ms each (`docs/absloc.md` §"Where a fix's time goes").
//!
//! A window is one matcher input instead: the keypoints over the predicted footprint (the
//! caller's test, within a rectangle around it), each taken from the tile whose centre is
//! nearest to it. With tiles
//! overlapping by half, that tile has the keypoint well inside it (its descriptor saw no
//! tile border), and the window is seamless where a single tile would cut the footprint.

use jointloc_features::Features;

use crate::error::Result;
use crate::tile_store::TileStore;
use crate::tiles::{MapTile, MapTiles};

/// Keypoints of a map rectangle, in its own pixels (top-left at `tile.x`, `tile.y`).
#[derive(Debug, Clone)]
pub(crate) struct Window {
    /// Position in [`MapTiles::tiles`] of the tile nearest to the window's centre (what the
    /// fix reports as its tile).
    pub tile_index: usize,
    /// That tile's grid place and index, with the window's top-left as its offset.
    pub tile: MapTile,
    pub features: Features,
}

/// Gathers the keypoints within `half` map pixels (each axis) of map pixel `centre`, clipped
/// to the map, that `keep` (map pixels) accepts: the caller's footprint, a turned frame
/// filling only part of its bounding box. `None` when the rectangle misses the map or no tile
/// covers it.
pub(crate) fn gather(
    tiles: &MapTiles,
    store: &TileStore,
    centre: (f64, f64),
    half: (f64, f64),
    keep: impl Fn(f64, f64) -> bool,
) -> Result<Option<Window>> {
    let (mw, mh) = tiles.map().dimensions();
    let x0 = (centre.0 - half.0).floor().max(0.0);
    let y0 = (centre.1 - half.1).floor().max(0.0);
    let x1 = (centre.0 + half.0).ceil().min(mw as f64);
    let y1 = (centre.1 + half.1).ceil().min(mh as f64);
    if !(x1 - x0 >= 1.0 && y1 - y0 >= 1.0) {
        return Ok(None);
    }
    let (tw, th) = tiles.tile_size();
    let (tw, th) = (tw as f64, th as f64);
    let covering: Vec<usize> = (0..tiles.len())
        .filter(|&i| {
            let t = &tiles.tiles()[i];
            let (tx, ty) = (t.x as f64, t.y as f64);
            tx < x1 && tx + tw > x0 && ty < y1 && ty + th > y0
        })
        .collect();
    // The tile of a map point: the nearest centre among the tiles containing it (lowest
    // position on a tie).
    let owner = |u: f64, v: f64| -> Option<usize> {
        covering
            .iter()
            .copied()
            .filter(|&i| {
                let t = &tiles.tiles()[i];
                let (tx, ty) = (t.x as f64, t.y as f64);
                u >= tx && u < tx + tw && v >= ty && v < ty + th
            })
            .min_by(|&a, &b| {
                let d = |i: usize| {
                    let (cu, cv) = tiles.tile_centre_px(i);
                    (cu - u).powi(2) + (cv - v).powi(2)
                };
                d(a).total_cmp(&d(b)).then(a.cmp(&b))
            })
    };
    let Some(centre_tile) = owner(centre.0.clamp(x0, x1 - 1.0), centre.1.clamp(y0, y1 - 1.0))
    else {
        return Ok(None);
    };
    let mut features = Features {
        image_size: ((x1 - x0) as u32, (y1 - y0) as u32),
        ..Default::default()
    };
    for &i in &covering {
        let f = store.get(tiles, i)?;
        features.descriptor_dim = f.descriptor_dim;
        let t = &tiles.tiles()[i];
        for k in 0..f.len() {
            let [ku, kv] = f.keypoints[k];
            let (u, v) = (ku as f64 + t.x as f64, kv as f64 + t.y as f64);
            if u < x0 || u >= x1 || v < y0 || v >= y1 || !keep(u, v) || owner(u, v) != Some(i) {
                continue;
            }
            features.keypoints.push([(u - x0) as f32, (v - y0) as f32]);
            features
                .scores
                .push(f.scores.get(k).copied().unwrap_or(0.0));
            features.descriptors.extend_from_slice(f.descriptor(k));
        }
    }
    let t = tiles.tiles()[centre_tile];
    Ok(Some(Window {
        tile_index: centre_tile,
        tile: MapTile {
            x: x0 as u32,
            y: y0 as u32,
            ..t
        },
        features,
    }))
}

/// The `max` strongest keypoints of `features` by detector score (the earlier on a tie), in
/// their order; `features` as they are when they are no more.
pub(crate) fn strongest(features: Features, max: usize) -> Features {
    if features.len() <= max {
        return features;
    }
    let score = |i: usize| features.scores.get(i).copied().unwrap_or(0.0);
    let mut order: Vec<usize> = (0..features.len()).collect();
    order.sort_by(|&a, &b| score(b).total_cmp(&score(a)).then(a.cmp(&b)));
    order.truncate(max);
    order.sort_unstable();
    crate::candidate::select(&features, &order)
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::GrayImage;

    /// A 1000 × 750 map of 500-pixel tiles at overlap 0.5, each tile's features a keypoint
    /// every 10 pixels whose descriptor is the tile's position: the window must hold each map
    /// point once, from the tile whose centre is nearest.
    fn fixture() -> (MapTiles, TileStore) {
        let map = GrayImage::from_pixel(1000, 750, image::Luma([128]));
        let tiles =
            MapTiles::from_image(map, 0.1, (500, 500), 0.5, std::path::Path::new(".")).unwrap();
        let features = (0..tiles.len())
            .map(|i| {
                let mut f = Features {
                    descriptor_dim: 1,
                    image_size: (500, 500),
                    ..Default::default()
                };
                for y in (5..500).step_by(10) {
                    for x in (5..500).step_by(10) {
                        f.keypoints.push([x as f32, y as f32]);
                        f.scores.push(1.0);
                        f.descriptors.push(i as f32);
                    }
                }
                f
            })
            .collect();
        (tiles, TileStore::from_features(features))
    }

    #[test]
    fn each_point_once_from_the_nearest_tile() {
        let (tiles, store) = fixture();
        assert_eq!(tiles.len(), 6, "3 × 2 tiles");
        let w = gather(&tiles, &store, (500.0, 375.0), (200.0, 150.0), |_, _| true)
            .unwrap()
            .unwrap();
        assert_eq!((w.tile.x, w.tile.y), (300, 225));
        assert_eq!(w.features.image_size, (400, 300));
        // One keypoint per 10 × 10 cell of the window, none twice.
        assert_eq!(w.features.len(), 40 * 30);
        let mut seen: Vec<[i32; 2]> = w
            .features
            .keypoints
            .iter()
            .map(|k| [k[0] as i32, k[1] as i32])
            .collect();
        seen.sort_unstable();
        seen.dedup();
        assert_eq!(seen.len(), 40 * 30);
        for k in 0..w.features.len() {
            let [u, v] = w.features.keypoints[k];
            let (u, v) = (u as f64 + 300.0, v as f64 + 225.0);
            let from = w.features.descriptors[k] as usize;
            let nearest = (0..tiles.len())
                .min_by(|&a, &b| {
                    let d = |i: usize| {
                        let (cu, cv) = tiles.tile_centre_px(i);
                        (cu - u).powi(2) + (cv - v).powi(2)
                    };
                    d(a).total_cmp(&d(b)).then(a.cmp(&b))
                })
                .unwrap();
            assert_eq!(from, nearest, "keypoint at ({u}, {v})");
        }
    }

    #[test]
    fn only_what_the_footprint_keeps() {
        let (tiles, store) = fixture();
        // A disc of radius 100 around the centre: about π/4 of the 200 × 200 square.
        let keep = |u: f64, v: f64| (u - 500.0).hypot(v - 375.0) <= 100.0;
        let w = gather(&tiles, &store, (500.0, 375.0), (100.0, 100.0), keep)
            .unwrap()
            .unwrap();
        let n = w.features.len() as f64;
        assert!(
            (n / 400.0 - std::f64::consts::FRAC_PI_4).abs() < 0.05,
            "{n}"
        );
        for k in &w.features.keypoints {
            let (u, v) = (k[0] as f64 + 400.0, k[1] as f64 + 275.0);
            assert!(keep(u, v), "({u}, {v})");
        }
    }

    #[test]
    fn the_strongest_keypoints_in_their_order() {
        let mut f = Features {
            descriptor_dim: 1,
            image_size: (10, 10),
            ..Default::default()
        };
        for (i, s) in [0.2f32, 0.9, 0.5, 0.9, 0.1, 0.7].into_iter().enumerate() {
            f.keypoints.push([i as f32, 0.0]);
            f.scores.push(s);
            f.descriptors.push(i as f32 * 10.0);
        }
        let k = strongest(f.clone(), 3);
        // 0.9 (1), 0.9 (3), 0.7 (5): ties go to the earlier, the order is kept.
        assert_eq!(k.keypoints, vec![[1.0, 0.0], [3.0, 0.0], [5.0, 0.0]]);
        assert_eq!(k.scores, vec![0.9, 0.9, 0.7]);
        assert_eq!(k.descriptors, vec![10.0, 30.0, 50.0]);
        let two = strongest(f.clone(), 2);
        assert_eq!(two.keypoints, vec![[1.0, 0.0], [3.0, 0.0]]);
        assert_eq!(strongest(f.clone(), 6).keypoints, f.keypoints);
        assert_eq!(strongest(f.clone(), 100).keypoints, f.keypoints);
        assert!(strongest(f.clone(), 0).is_empty());
    }

    #[test]
    fn clipped_to_the_map_and_none_off_it() {
        let (tiles, store) = fixture();
        let w = gather(&tiles, &store, (20.0, 30.0), (100.0, 100.0), |_, _| true)
            .unwrap()
            .unwrap();
        assert_eq!((w.tile.x, w.tile.y), (0, 0));
        assert_eq!(w.features.image_size, (120, 130));
        assert_eq!(w.tile_index, 0);
        assert!(
            gather(&tiles, &store, (-500.0, 30.0), (100.0, 100.0), |_, _| true)
                .unwrap()
                .is_none()
        );
    }
}
