//! The satellite map cut into tiles of the UAV image size (paper §III-B1), with the
//! georeference of `map.toml` (world `(x, y) = (u·gsd, −v·gsd)` for map pixel `(u, v)`) and
//! the neighbourhood queries of the coarse-to-fine search.
//!
//! Two sources: `map.toml` + its map image (tiles are cut from the image, or read from the
//! tile folder when the image is absent), or a bare tile folder in the paper's
//! `<idx>_<x>_<y>.png` naming plus a GSD given by the caller. The whole map is kept as one
//! image (the confidence's SSIM looks at the map under the warped frame, which may straddle
//! tiles); tiles are windows of it.

use std::path::{Path, PathBuf};

use image::GrayImage;
use jointloc_formats::map_toml::SunInfo;
use jointloc_formats::{ElevationModel, MapInfo};

use crate::error::{AbslocError, Result, read_gray};

/// One tile: a window of the map, and its place in the tile grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MapTile {
    /// Row-major index (the `<idx>` of the file name).
    pub index: usize,
    /// Top-left pixel in the map.
    pub x: u32,
    pub y: u32,
    /// Column and row in the tile grid.
    pub col: u32,
    pub row: u32,
}

/// A georeferenced map and its tiles.
#[derive(Debug, Clone)]
pub struct MapTiles {
    map: GrayImage,
    gsd_m: f64,
    tile_width: u32,
    tile_height: u32,
    cols: u32,
    rows: u32,
    tiles: Vec<MapTile>,
    /// Folder the map came from (the feature cache lives beside it).
    root: PathBuf,
    fingerprint: u64,
    /// The terrain elevation model of `map.toml`'s `[elevation]`, if any.
    ground: Ground,
    /// The sun the map was taken under, if known.
    sun: Option<SunInfo>,
}

impl MapTiles {
    /// Opens a map from a dataset folder (containing `map.toml`) or a `map.toml` path.
    pub fn open(path: &Path) -> Result<Self> {
        let toml = if path.is_dir() {
            path.join("map.toml")
        } else {
            path.to_path_buf()
        };
        if !toml.is_file() {
            let reason = if path.exists() {
                "no map.toml (for a bare tile folder, give the GSD)".to_string()
            } else {
                "path does not exist".to_string()
            };
            return Err(AbslocError::MapMissing {
                path: path.to_path_buf(),
                reason,
            });
        }
        let info = MapInfo::read(&toml)?;
        let root = toml
            .parent()
            .map(Path::to_path_buf)
            .unwrap_or_else(|| PathBuf::from("."));
        Self::from_info(&info, &root)
    }

    /// Builds the tiles of `info`, reading `root/info.image`, or the tile files in
    /// `root/info.tiles.dir` when the map image is absent.
    pub fn from_info(info: &MapInfo, root: &Path) -> Result<Self> {
        let image_path = root.join(&info.image);
        let (w, h) = (info.width_px, info.height_px);
        let tiles: Vec<MapTile> = info
            .tile_list()
            .iter()
            .enumerate()
            .map(|(i, t)| MapTile {
                index: t.index,
                x: t.x,
                y: t.y,
                col: (i % info.tiles.cols.max(1) as usize) as u32,
                row: (i / info.tiles.cols.max(1) as usize) as u32,
            })
            .collect();
        let map = if image_path.is_file() {
            let map = read_gray(&image_path)?;
            if map.dimensions() != (w, h) {
                return Err(AbslocError::Parse {
                    path: image_path,
                    line: 0,
                    message: format!(
                        "image is {}x{} px but map.toml says {w}x{h}",
                        map.width(),
                        map.height()
                    ),
                });
            }
            map
        } else {
            let dir = root.join(&info.tiles.dir);
            if !dir.is_dir() {
                return Err(AbslocError::MapMissing {
                    path: image_path,
                    reason: format!(
                        "neither the map image nor the tile folder {} exists",
                        dir.display()
                    ),
                });
            }
            let (tw, th) = (info.tiles.width_px, info.tiles.height_px);
            let mut map = GrayImage::new(w, h);
            for t in &tiles {
                let file = dir.join(format!("{}_{}_{}.png", t.index, t.x, t.y));
                let img = read_gray(&file)?;
                check_tile_size(&file, &img, tw, th)?;
                image::imageops::replace(&mut map, &img, t.x.into(), t.y.into());
            }
            map
        };
        let elevation = info
            .elevation
            .as_ref()
            .map(|e| ElevationModel::read(e, root))
            .transpose()?;
        let mut out = Self::assemble(
            map,
            info.gsd_m,
            (info.tiles.width_px, info.tiles.height_px),
            (info.tiles.cols, info.tiles.rows),
            tiles,
            root,
        )?;
        out.ground = Ground(elevation);
        out.sun = info.acquisition_sun();
        Ok(out)
    }

    /// Reads a bare tile folder `<idx>_<x>_<y>.png` (the paper's layout). `gsd_m` is required:
    /// without it, map pixels cannot become metres ([`AbslocError::GsdMissing`]).
    pub fn from_tile_folder(dir: &Path, gsd_m: Option<f64>) -> Result<Self> {
        let gsd_m = gsd_m.ok_or_else(|| AbslocError::GsdMissing {
            path: dir.to_path_buf(),
        })?;
        let entries = std::fs::read_dir(dir).map_err(|source| AbslocError::MapMissing {
            path: dir.to_path_buf(),
            reason: source.to_string(),
        })?;
        let mut found: Vec<(usize, u32, u32, PathBuf)> = Vec::new();
        for entry in entries.flatten() {
            let path = entry.path();
            if let Some(parsed) = parse_tile_name(&path) {
                found.push((parsed.0, parsed.1, parsed.2, path));
            }
        }
        if found.is_empty() {
            return Err(AbslocError::MapMissing {
                path: dir.to_path_buf(),
                reason: "no <idx>_<x>_<y>.png tiles".into(),
            });
        }
        found.sort();
        let first = read_gray(&found[0].3)?;
        let (tw, th) = first.dimensions();
        let mut xs: Vec<u32> = found.iter().map(|f| f.1).collect();
        let mut ys: Vec<u32> = found.iter().map(|f| f.2).collect();
        xs.sort_unstable();
        xs.dedup();
        ys.sort_unstable();
        ys.dedup();
        let (w, h) = (xs[xs.len() - 1] + tw, ys[ys.len() - 1] + th);
        let mut map = GrayImage::new(w, h);
        let mut tiles = Vec::with_capacity(found.len());
        for (index, x, y, path) in &found {
            let img = read_gray(path)?;
            check_tile_size(path, &img, tw, th)?;
            image::imageops::replace(&mut map, &img, (*x).into(), (*y).into());
            tiles.push(MapTile {
                index: *index,
                x: *x,
                y: *y,
                col: xs.binary_search(x).unwrap_or(0) as u32,
                row: ys.binary_search(y).unwrap_or(0) as u32,
            });
        }
        let parent = dir.parent().unwrap_or(dir).to_path_buf();
        Self::assemble(
            map,
            gsd_m,
            (tw, th),
            (xs.len() as u32, ys.len() as u32),
            tiles,
            &parent,
        )
    }

    /// A map from an in-memory image (tests, callers with their own loaders), tiled with
    /// `tile` windows and the given `overlap`.
    pub fn from_image(
        map: GrayImage,
        gsd_m: f64,
        tile: (u32, u32),
        overlap: f64,
        root: &Path,
    ) -> Result<Self> {
        let info = MapInfo::new(gsd_m, map.width(), map.height(), tile.0, tile.1, overlap)?;
        let tiles = info
            .tile_list()
            .iter()
            .enumerate()
            .map(|(i, t)| MapTile {
                index: t.index,
                x: t.x,
                y: t.y,
                col: (i % info.tiles.cols as usize) as u32,
                row: (i / info.tiles.cols as usize) as u32,
            })
            .collect();
        Self::assemble(
            map,
            gsd_m,
            tile,
            (info.tiles.cols, info.tiles.rows),
            tiles,
            root,
        )
    }

    fn assemble(
        map: GrayImage,
        gsd_m: f64,
        (tile_width, tile_height): (u32, u32),
        (cols, rows): (u32, u32),
        tiles: Vec<MapTile>,
        root: &Path,
    ) -> Result<Self> {
        if !(gsd_m.is_finite() && gsd_m > 0.0) {
            return Err(AbslocError::InvalidConfig {
                field: "gsd_m",
                value: gsd_m.to_string(),
                reason: "must be finite and > 0".into(),
            });
        }
        if tiles.is_empty() {
            return Err(AbslocError::MapMissing {
                path: root.to_path_buf(),
                reason: "the map has no tiles".into(),
            });
        }
        let fingerprint = fingerprint(&map, gsd_m, &tiles, (tile_width, tile_height));
        Ok(Self {
            map,
            gsd_m,
            tile_width,
            tile_height,
            cols,
            rows,
            tiles,
            root: root.to_path_buf(),
            fingerprint,
            ground: Ground::default(),
            sun: None,
        })
    }

    /// The map resampled `factor` times finer (bilinear, `factor` ≥ 1) and re-tiled with
    /// frame-size tiles at `overlap`: for maps much coarser than the frames, where the frame
    /// shrunk to the map's GSD would be too small to match. Pixel `u'` of the result is pixel
    /// `u'/factor` of this map, so the georeference stays exact (GSD / factor, same origin).
    pub fn upsampled(&self, factor: f64, overlap: f64) -> Result<Self> {
        if !(factor.is_finite() && factor >= 1.0) {
            return Err(AbslocError::InvalidConfig {
                field: "upsample factor",
                value: factor.to_string(),
                reason: "must be finite and >= 1".into(),
            });
        }
        let (w, h) = self.map.dimensions();
        let nw = ((w - 1) as f64 * factor).floor() as u32 + 1;
        let nh = ((h - 1) as f64 * factor).floor() as u32 + 1;
        let src = &self.map;
        let sample = |x: f64, y: f64| -> u8 {
            let (x0, y0) = (x.floor() as u32, y.floor() as u32);
            let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
            let (fx, fy) = (x - x0 as f64, y - y0 as f64);
            let p = |a: u32, b: u32| src.get_pixel(a, b).0[0] as f64;
            let top = p(x0, y0) * (1.0 - fx) + p(x1, y0) * fx;
            let bottom = p(x0, y1) * (1.0 - fx) + p(x1, y1) * fx;
            (top * (1.0 - fy) + bottom * fy).round().clamp(0.0, 255.0) as u8
        };
        let map = GrayImage::from_fn(nw, nh, |u, v| {
            image::Luma([sample(
                (u as f64 / factor).min((w - 1) as f64),
                (v as f64 / factor).min((h - 1) as f64),
            )])
        });
        let mut out = Self::from_image(
            map,
            self.gsd_m / factor,
            (self.tile_width, self.tile_height),
            overlap,
            &self.root,
        )?;
        out.ground = self.ground.clone();
        out.sun = self.sun;
        Ok(out)
    }

    /// The same map and tiling with other pixels (a relit map): its fingerprint, and so its
    /// tile feature cache, changes with them.
    pub fn with_pixels(&self, map: GrayImage) -> Result<Self> {
        if map.dimensions() != self.map.dimensions() {
            return Err(AbslocError::InvalidConfig {
                field: "map pixels",
                value: format!("{}x{}", map.width(), map.height()),
                reason: format!(
                    "must keep the map's size {}x{}",
                    self.map.width(),
                    self.map.height()
                ),
            });
        }
        let fingerprint = fingerprint(
            &map,
            self.gsd_m,
            &self.tiles,
            (self.tile_width, self.tile_height),
        );
        Ok(Self {
            map,
            gsd_m: self.gsd_m,
            tile_width: self.tile_width,
            tile_height: self.tile_height,
            cols: self.cols,
            rows: self.rows,
            tiles: self.tiles.clone(),
            root: self.root.clone(),
            fingerprint,
            ground: self.ground.clone(),
            sun: self.sun,
        })
    }

    /// The sun the map was taken under (`map.toml`'s `[sun]`), if known.
    pub fn sun(&self) -> Option<SunInfo> {
        self.sun
    }

    /// The map with its sun set (maps read from images or tile folders know none).
    pub fn with_sun(mut self, sun: Option<SunInfo>) -> Self {
        self.sun = sun;
        self
    }

    /// Terrain height at world `(x, y)` from the map's elevation model; 0 (flat ground at the
    /// datum, z = 0 of the world frame) when the map has none.
    pub fn ground_height(&self, x: f64, y: f64) -> f64 {
        self.ground.height_at(x, y)
    }

    /// The ground under the map (its elevation model, or flat ground at 0) on its own, for a
    /// caller that needs heights but not the map.
    pub fn ground(&self) -> Ground {
        self.ground.clone()
    }

    /// Whether the map has an elevation model.
    pub fn has_elevation(&self) -> bool {
        self.ground.0.is_some()
    }

    /// The whole map.
    pub fn map(&self) -> &GrayImage {
        &self.map
    }

    /// Metres per map pixel.
    pub fn gsd_m(&self) -> f64 {
        self.gsd_m
    }

    /// Tile size in pixels.
    pub fn tile_size(&self) -> (u32, u32) {
        (self.tile_width, self.tile_height)
    }

    /// Tiles per row and per column.
    pub fn grid(&self) -> (u32, u32) {
        (self.cols, self.rows)
    }

    /// All tiles, in index order of the grid (row-major).
    pub fn tiles(&self) -> &[MapTile] {
        &self.tiles
    }

    /// Number of tiles.
    pub fn len(&self) -> usize {
        self.tiles.len()
    }

    /// Whether there is no tile (never true for a constructed map).
    pub fn is_empty(&self) -> bool {
        self.tiles.is_empty()
    }

    /// Folder the map was read from (the feature cache goes beside it).
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// Hash of the map pixels, GSD and tiling: the feature cache is invalid when it changes.
    pub fn fingerprint(&self) -> u64 {
        self.fingerprint
    }

    /// Pixels of tile `i` (position in [`MapTiles::tiles`]).
    pub fn tile_image(&self, i: usize) -> GrayImage {
        let t = &self.tiles[i];
        image::imageops::crop_imm(&self.map, t.x, t.y, self.tile_width, self.tile_height).to_image()
    }

    /// Errors unless a frame of `width × height` has the tile size.
    pub fn check_frame_size(&self, width: u32, height: u32) -> Result<()> {
        if (width, height) != (self.tile_width, self.tile_height) {
            return Err(AbslocError::TileSizeMismatch {
                tile_width: self.tile_width,
                tile_height: self.tile_height,
                frame_width: width,
                frame_height: height,
            });
        }
        Ok(())
    }

    /// World `(x, y)` of map pixel `(u, v)`.
    pub fn pixel_to_world(&self, u: f64, v: f64) -> (f64, f64) {
        (u * self.gsd_m, -v * self.gsd_m)
    }

    /// Map pixel `(u, v)` of world `(x, y)`.
    pub fn world_to_pixel(&self, x: f64, y: f64) -> (f64, f64) {
        (x / self.gsd_m, -y / self.gsd_m)
    }

    /// Map pixel of the centre of tile `i`.
    pub fn tile_centre_px(&self, i: usize) -> (f64, f64) {
        let t = &self.tiles[i];
        (
            t.x as f64 + (self.tile_width as f64 - 1.0) / 2.0,
            t.y as f64 + (self.tile_height as f64 - 1.0) / 2.0,
        )
    }

    /// Tiles within `radius` grid steps of tile `centre` (Chebyshev distance on the grid, so
    /// radius 1 is the 3×3 block around it), `centre` first, then by distance of tile centres.
    pub fn neighbourhood(&self, centre: usize, radius: u32) -> Vec<usize> {
        let Some(c) = self.tiles.get(centre) else {
            return Vec::new();
        };
        let mut out: Vec<usize> = (0..self.tiles.len())
            .filter(|&i| {
                let t = &self.tiles[i];
                t.col.abs_diff(c.col) <= radius && t.row.abs_diff(c.row) <= radius
            })
            .collect();
        self.sort_by_distance(&mut out, self.tile_centre_px(centre));
        out
    }

    /// The `k` tiles whose centres are nearest to world `(x, y)`, nearest first.
    pub fn nearest(&self, x: f64, y: f64, k: usize) -> Vec<usize> {
        let mut all: Vec<usize> = (0..self.tiles.len()).collect();
        self.sort_by_distance(&mut all, self.world_to_pixel(x, y));
        all.truncate(k);
        all
    }

    /// Tiles within `radius` grid steps of the tile nearest to world `(x, y)`, nearest first.
    pub fn around_world(&self, x: f64, y: f64, radius: u32) -> Vec<usize> {
        match self.nearest(x, y, 1).first() {
            Some(&c) => {
                let mut out = self.neighbourhood(c, radius);
                self.sort_by_distance(&mut out, self.world_to_pixel(x, y));
                out
            }
            None => Vec::new(),
        }
    }

    /// The tiles of `list` whose extent contains world `(x, y)` (at most 4 with overlap 0.5),
    /// in `list`'s order.
    pub fn containing(&self, list: &[usize], x: f64, y: f64) -> Vec<usize> {
        let (u, v) = self.world_to_pixel(x, y);
        list.iter()
            .copied()
            .filter(|&i| {
                let t = &self.tiles[i];
                let (x0, y0) = (t.x as f64, t.y as f64);
                (x0..x0 + self.tile_width as f64).contains(&u)
                    && (y0..y0 + self.tile_height as f64).contains(&v)
            })
            .collect()
    }

    /// Every tile, nearest to world `(x, y)` first when a point is given.
    pub fn all(&self, near: Option<(f64, f64)>) -> Vec<usize> {
        let mut all: Vec<usize> = (0..self.tiles.len()).collect();
        if let Some((x, y)) = near {
            self.sort_by_distance(&mut all, self.world_to_pixel(x, y));
        }
        all
    }

    /// Orders `list` by the distance of tile centres to world `(x, y)`, nearest first.
    pub fn order_by_distance(&self, list: &mut [usize], x: f64, y: f64) {
        self.sort_by_distance(list, self.world_to_pixel(x, y));
    }

    fn sort_by_distance(&self, list: &mut [usize], (u, v): (f64, f64)) {
        let d = |i: usize| {
            let (cu, cv) = self.tile_centre_px(i);
            (cu - u).powi(2) + (cv - v).powi(2)
        };
        list.sort_by(|&a, &b| d(a).total_cmp(&d(b)).then(a.cmp(&b)));
    }
}

fn check_tile_size(path: &Path, img: &GrayImage, w: u32, h: u32) -> Result<()> {
    if img.dimensions() != (w, h) {
        return Err(AbslocError::Parse {
            path: path.to_path_buf(),
            line: 0,
            message: format!(
                "tile is {}x{} px, expected {w}x{h} like the others",
                img.width(),
                img.height()
            ),
        });
    }
    Ok(())
}

/// `(idx, x, y)` of a file named `<idx>_<x>_<y>.png`.
fn parse_tile_name(path: &Path) -> Option<(usize, u32, u32)> {
    if !path.extension()?.to_str()?.eq_ignore_ascii_case("png") {
        return None;
    }
    let stem = path.file_stem()?.to_str()?;
    let mut it = stem.split('_');
    let idx = it.next()?.parse().ok()?;
    let x = it.next()?.parse().ok()?;
    let y = it.next()?.parse().ok()?;
    it.next().is_none().then_some((idx, x, y))
}

/// FNV-1a over the pixels, GSD and tile layout.
fn fingerprint(map: &GrayImage, gsd: f64, tiles: &[MapTile], tile: (u32, u32)) -> u64 {
    let mut h = crate::cache::Fnv64::new();
    h.write(&map.width().to_le_bytes());
    h.write(&map.height().to_le_bytes());
    h.write(&gsd.to_le_bytes());
    h.write(&tile.0.to_le_bytes());
    h.write(&tile.1.to_le_bytes());
    for t in tiles {
        h.write(&(t.index as u64).to_le_bytes());
        h.write(&t.x.to_le_bytes());
        h.write(&t.y.to_le_bytes());
    }
    h.write(map.as_raw());
    h.finish()
}

/// Terrain heights of a map: its elevation model, or flat ground at the datum (z = 0).
#[derive(Debug, Clone, Default)]
pub struct Ground(Option<ElevationModel>);

impl Ground {
    /// Terrain heights from an elevation model.
    pub fn from_model(model: ElevationModel) -> Self {
        Self(Some(model))
    }

    /// Height at world `(x, y)`, metres.
    pub fn height_at(&self, x: f64, y: f64) -> f64 {
        self.0.as_ref().map_or(0.0, |e| e.height_at(x, y))
    }

    /// The elevation model, if any.
    pub fn model(&self) -> Option<&ElevationModel> {
        self.0.as_ref()
    }

    /// Whether this is an elevation model (not the flat-ground fallback).
    pub fn has_model(&self) -> bool {
        self.0.is_some()
    }

    /// The elevation model's stated vertical precision (`[elevation] sigma_m`), metres; `None`
    /// without a model.
    pub fn stated_sigma_m(&self) -> Option<f64> {
        self.0.as_ref().map(|e| e.info.sigma_m)
    }

    /// Height and slope `(∂h/∂x, ∂h/∂y)` at world `(x, y)` from the elevation model (slope by
    /// central differences over one post); `None` without a model or outside its posts.
    pub fn height_and_slope(&self, x: f64, y: f64) -> Option<(f64, [f64; 2])> {
        let e = self.0.as_ref()?;
        let i = &e.info;
        let (col, row) = ((x - i.origin_x_m) / i.gsd_m, (i.origin_y_m - y) / i.gsd_m);
        let inside = |v: f64, n: u32| v >= 1.0 && v <= n as f64 - 2.0;
        if !(inside(col, i.width_px) && inside(row, i.height_px)) {
            return None;
        }
        let d = i.gsd_m;
        let gx = (e.height_at(x + d, y) - e.height_at(x - d, y)) / (2.0 * d);
        let gy = (e.height_at(x, y + d) - e.height_at(x, y - d)) / (2.0 * d);
        Some((e.height_at(x, y), [gx, gy]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn upsampling_keeps_the_georeference() {
        let mut img = GrayImage::new(1000, 750);
        for (u, v, p) in img.enumerate_pixels_mut() {
            p.0[0] = ((u * 7 + v * 3) % 251) as u8;
        }
        let tiles = MapTiles::from_image(img, 0.125, (500, 500), 0.5, Path::new(".")).unwrap();
        let up = tiles.upsampled(2.5, 0.5).unwrap();
        assert!((up.gsd_m() - 0.05).abs() < 1e-12);
        assert_eq!(up.map().dimensions(), (2498, 1873));
        // The same world point has the same grey level (bilinear, on integer source pixels).
        for (u, v) in [(0u32, 0u32), (10, 20), (998, 748), (400, 300)] {
            let (x, y) = tiles.pixel_to_world(u as f64, v as f64);
            let (u2, v2) = up.world_to_pixel(x, y);
            assert!((u2 - u2.round()).abs() < 1e-9 && (v2 - v2.round()).abs() < 1e-9);
            assert_eq!(
                up.map().get_pixel(u2.round() as u32, v2.round() as u32),
                tiles.map().get_pixel(u, v)
            );
        }
        assert!(up.len() > tiles.len());
        assert!(tiles.upsampled(0.5, 0.5).is_err());
    }

    fn grid_map(w: u32, h: u32) -> MapTiles {
        let img = GrayImage::from_fn(w, h, |x, y| image::Luma([((x * 7 + y * 13) % 251) as u8]));
        MapTiles::from_image(img, 0.05, (100, 100), 0.5, Path::new(".")).unwrap()
    }

    #[test]
    fn neighbourhoods_follow_the_grid() {
        // 400x300 with 100 px tiles at stride 50: 7 columns, 5 rows.
        let m = grid_map(400, 300);
        assert_eq!(m.grid(), (7, 5));
        assert_eq!(m.len(), 35);
        let centre = 2 * 7 + 3; // col 3, row 2
        let n1 = m.neighbourhood(centre, 1);
        assert_eq!(n1.len(), 9);
        assert_eq!(n1[0], centre);
        for &i in &n1 {
            let t = m.tiles()[i];
            assert!(t.col.abs_diff(3) <= 1 && t.row.abs_diff(2) <= 1);
        }
        assert_eq!(m.neighbourhood(centre, 2).len(), 25);
        assert_eq!(m.neighbourhood(centre, 10).len(), 35);
        // Corners are clipped by the map edge.
        assert_eq!(m.neighbourhood(0, 1).len(), 4);
        assert_eq!(m.neighbourhood(34, 2).len(), 9);
        assert_eq!(m.neighbourhood(0, 0), vec![0]);
        assert!(m.neighbourhood(99, 1).is_empty());
    }

    #[test]
    fn nearest_tiles_contain_the_point() {
        let m = grid_map(400, 300);
        for (u, v) in [(10.0, 10.0), (205.0, 140.0), (399.0, 299.0), (120.0, 260.0)] {
            let (x, y) = m.pixel_to_world(u, v);
            let best = m.nearest(x, y, 1)[0];
            let t = m.tiles()[best];
            assert!(
                u >= t.x as f64 && u < (t.x + 100) as f64,
                "{u} in tile {t:?}"
            );
            assert!(
                v >= t.y as f64 && v < (t.y + 100) as f64,
                "{v} in tile {t:?}"
            );
            let around = m.around_world(x, y, 1);
            assert!(around.contains(&best) && around.len() <= 9);
        }
        assert_eq!(m.all(None).len(), 35);
    }

    #[test]
    fn containing_tiles_are_those_over_the_point() {
        let m = grid_map(400, 300);
        let all = m.all(None);
        // Interior point at stride 50: the four overlapping tiles; an edge point: fewer.
        for ((u, v), n) in [((205.0, 140.0), 4), ((10.0, 10.0), 1), ((205.0, 10.0), 2)] {
            let (x, y) = m.pixel_to_world(u, v);
            let inside = m.containing(&all, x, y);
            assert_eq!(inside.len(), n, "({u}, {v}): {inside:?}");
            for &i in &inside {
                let t = m.tiles()[i];
                assert!((t.x as f64..(t.x + 100) as f64).contains(&u));
                assert!((t.y as f64..(t.y + 100) as f64).contains(&v));
            }
            // Restricted to the given list, in its order.
            let near = m.around_world(x, y, 1);
            let sub = m.containing(&near, x, y);
            assert!(sub.windows(2).all(|w| {
                near.iter().position(|&a| a == w[0]) < near.iter().position(|&a| a == w[1])
            }));
        }
        let (x, y) = m.pixel_to_world(-50.0, 10.0);
        assert!(m.containing(&all, x, y).is_empty());
    }

    #[test]
    fn world_and_pixels_round_trip() {
        let m = grid_map(400, 300);
        let (x, y) = m.pixel_to_world(123.25, 45.5);
        assert!((x - 6.1625).abs() < 1e-12 && (y + 2.275).abs() < 1e-12);
        let (u, v) = m.world_to_pixel(x, y);
        assert!((u - 123.25).abs() < 1e-9 && (v - 45.5).abs() < 1e-9);
    }

    #[test]
    fn tile_names_parse_strictly() {
        assert_eq!(
            parse_tile_name(Path::new("a/3_250_0.png")),
            Some((3, 250, 0))
        );
        assert_eq!(parse_tile_name(Path::new("3_250_0.PNG")), Some((3, 250, 0)));
        assert_eq!(parse_tile_name(Path::new("3_250.png")), None);
        assert_eq!(parse_tile_name(Path::new("3_250_0_1.png")), None);
        assert_eq!(parse_tile_name(Path::new("3_250_0.jpg")), None);
        assert_eq!(parse_tile_name(Path::new("x_250_0.png")), None);
    }

    #[test]
    fn tile_folders_round_trip_and_need_a_gsd() {
        let dir = tempfile::tempdir().unwrap();
        let m = grid_map(200, 200);
        let tiles_dir = dir.path().join("tiles");
        std::fs::create_dir(&tiles_dir).unwrap();
        for (i, t) in m.tiles().iter().enumerate() {
            m.tile_image(i)
                .save(tiles_dir.join(format!("{}_{}_{}.png", t.index, t.x, t.y)))
                .unwrap();
        }
        let err = MapTiles::from_tile_folder(&tiles_dir, None).unwrap_err();
        assert!(matches!(err, AbslocError::GsdMissing { .. }), "{err}");
        let back = MapTiles::from_tile_folder(&tiles_dir, Some(0.05)).unwrap();
        assert_eq!(back.grid(), m.grid());
        assert_eq!(back.tiles(), m.tiles());
        assert_eq!(back.map(), m.map());
        assert_eq!(back.fingerprint(), m.fingerprint());
        // A tile of another size is a clear error.
        GrayImage::new(50, 50)
            .save(tiles_dir.join("9_300_300.png"))
            .unwrap();
        assert!(MapTiles::from_tile_folder(&tiles_dir, Some(0.05)).is_err());
    }

    #[test]
    fn missing_maps_are_clear_errors() {
        let dir = tempfile::tempdir().unwrap();
        let err = MapTiles::open(&dir.path().join("nope")).unwrap_err();
        assert!(matches!(err, AbslocError::MapMissing { .. }), "{err}");
        let err = MapTiles::open(dir.path()).unwrap_err();
        assert!(err.to_string().contains("map.toml"), "{err}");
        let m = grid_map(200, 200);
        assert!(matches!(
            m.check_frame_size(120, 100),
            Err(AbslocError::TileSizeMismatch { .. })
        ));
        assert!(m.check_frame_size(100, 100).is_ok());
    }
}
