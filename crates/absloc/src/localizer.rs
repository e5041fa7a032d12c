//! The coarse-to-fine search of paper §III-B: candidate tiles around the last best tile (radius
//! from the last confidence), the whole map when there is no prior or the local search fails,
//! or tiles around a predicted position; per tile, match + homography + checks; the tile with
//! the most inliers gives the fix, the confidence and the next radius.
//!
//! The frame is first resampled to the map's GSD (altimeter and focal length) and turned
//! north-up (heading from the caller's prior, else the last fix, else a sweep of
//! `rotation_hypotheses` angles): learned matchers are neither scale- nor rotation-invariant.

use std::path::PathBuf;
use std::sync::{Arc, OnceLock};
use std::time::Instant;

use image::GrayImage;
use jointloc_geometry::PinholeCamera;
use jointloc_geometry::homography::HomographyConfig;
use nalgebra::{Matrix3, Point2};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::cache::{self, CacheStatus};
use crate::candidate::{
    AcceptConfig, Candidate, MatchContext, QueryView, Rejection, evaluate, select,
};
use crate::coarse_places::{CoarsePlaces, ViewSignals};
use crate::confidence::{ConfidenceMode, RADIUS_RANGE, search_radius};
use crate::correlate::{CorrelationConfig, Grid, NoPeak, correlate};
use crate::error::{AbslocError, Result};
use crate::pipeline::FeaturePipeline;
use crate::relight::{RelightConfig, relit_tiles};
use crate::search::{self, SearchInput};
use crate::shortlist::{ShortlistConfig, TileIndex};
use crate::ssim::{SsimConfig, ssim_masked};
use crate::tile_store::TileStore;
use crate::tiles::MapTiles;
use crate::warp::{Lens, NormalisedFrame, normalise_lens, resample, warp_into_map_lens};
use crate::window;

/// Settings of [`AbsLocalizer`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AbsLocConfig {
    /// How the confidence is computed (the paper: `adaptive`).
    pub confidence: ConfidenceMode,
    /// Search only around the last best tile with radius `⌈10^(1−w)⌉` (the paper's area
    /// prediction). Off: every frame searches the whole map.
    pub area_prediction: bool,
    /// Search the whole map when the local search finds nothing.
    pub global_fallback: bool,
    /// Within the local search, first match only the tiles that contain the predicted (or
    /// last) position; the rest of the radius only when none of them gives a fix. The tile
    /// with the most inliers contains the frame, so with a sound prediction the outer tiles
    /// only cost time (7× on medium maps, where a low confidence opens the whole map).
    pub inner_tiles_first: bool,
    /// With a prior position but no heading (a take-off given with `--start`, a failing
    /// streak's sweep), match the tiles of the radius that do not contain the position at
    /// every heading too, before the whole-map search. Off (default): the tiles that contain
    /// it (≤ 4 tiles × the headings), then the whole-map search, which ranks places by a
    /// coarse correlation first; on a small map the radius holds every tile, and its sweep
    /// was 128 pairs, 10 s (`docs/absloc.md` §"A heading sweep around a known position: the
    /// tiles that contain it").
    pub sweep_outer_tiles: bool,
    /// With a prior position and heading (the fused pose in flight), first match the view
    /// against the map's keypoints over its predicted footprint and this margin, metres, on
    /// each side ([`crate::window`]): one matcher input instead of up to four tiles. Its fix
    /// counts when it lies within the margin of the prediction; otherwise the tiles are
    /// searched as before. 0 turns it off.
    pub predicted_window_margin_m: f64,
    /// When the predicted window gives no fix, search the tiles as without it (the local
    /// radius, then the whole map). Off (default): a prior with a heading is trusted, and the
    /// frame does not match where it is predicted to be; the caller leaves the heading out
    /// when it doubts the prediction (JointLoc does every `sweep_after_failing_s` of a failing
    /// streak), and the tiles are searched then.
    /// A failed search costs one matcher call instead of the whole radius (50 tiles, 4 s,
    /// on a medium map).
    pub tiles_after_window: bool,
    /// Camera tilt allowed for between the prior (the camera's x, y) and the fix (the ground
    /// point under the optical axis), degrees: the window's fix counts within the margin plus
    /// altitude × tan(this) of the prediction. At 100 m a 1–2° wobble puts the fix 1.5–3 m
    /// from the camera's x, y, beyond the margin alone (12 of 30 fixes of a 100 m flight).
    pub predicted_window_tilt_deg: f64,
    /// Resample the frame to the map's GSD before matching (off: native scale, as the
    /// reference code). Measured better (`docs/absloc.md` §"Coarse maps"), so on by default.
    pub scale_normalisation: bool,
    /// Angles tried when no heading is known (start, after a failure): 8 gives ≤ 22.5° of
    /// residual rotation.
    pub rotation_hypotheses: usize,
    /// Use the last fix's heading when the caller gives none.
    pub use_last_heading: bool,
    /// Frames whose grey-level standard deviation is below this are failed at once (all black,
    /// all white, lens cap): nothing to match.
    pub min_texture_std: f64,
    /// Evaluate candidate tiles in parallel (rayon).
    pub parallel: bool,
    /// Stop a search once a tile has this many inliers and the image centre maps into its
    /// central 60 % (see [`crate::search`]); candidates are tried nearest to the last fix (or
    /// the prior) first. `None` matches every candidate, as the paper does.
    pub early_stop_inliers: Option<usize>,
    /// Smallest frame-to-map scale matched at. A map so coarse that the frame shrunk to its
    /// GSD would be smaller than this fraction of its size (medium preset: 12.5 cm/px under
    /// 2 cm/px frames, 0.16) is upsampled once, at the first frame's altitude, so that the
    /// scale becomes this; 80-pixel frames give a learned detector almost nothing.
    pub min_match_scale: f64,
    /// The frame resampled to the map's GSD and turned north-up is cropped around its centre
    /// to at most this many tiles a side (0: never). Above about 130 m a 500-pixel frame
    /// covers more ground than a 500-pixel tile of a 25 cm map (at 200 m its view is 800–1130
    /// pixels a side), and only the part near the tile can match it; the rest costs time.
    /// 1.2: 1.4× faster per fix at 200 m with the same mean accuracy, and no crop at
    /// 100 m or below (`docs/absloc.md` §"Latency per fix").
    pub max_view_over_tile: f64,
    /// The predicted window keeps at most this many map keypoints per keypoint of the view,
    /// the strongest by detector score (0: all). Above about 130 m the frame resampled to a
    /// 25 cm map is sparser in keypoints than the map's tiles (at 200 m: 1024 over the
    /// 600-pixel view, about 1900 in the window over it), and LighterGlue's time grows with
    /// both counts: 1.5 takes a fix at 200 m from 380–430 ms to 275–300 ms with the fixes'
    /// error unchanged on six fresh flights (0.093 m), 1.0 to about 230 ms but 0.102 m
    /// (`docs/absloc.md` §"A fix at 200 m: the SSIM row by row, the window capped"). Below
    /// about 130 m the window holds fewer keypoints than the view and nothing changes.
    pub window_keypoints_over_view: f64,
    /// The map relit to the flight's sun with its elevation model (see [`crate::relight`]).
    pub relight: RelightConfig,
    /// Tile feature cache on disk (see [`crate::cache`]). Off, every tile's features are
    /// extracted at the first search that needs them and all kept in memory.
    pub cache: bool,
    /// Memory for tile features read from the cache, MB (least recently used out first,
    /// [`crate::tile_store`]): a local search needs a few tiles, a whole-map search streams the
    /// file. A 2 km map at 25 cm/px holds 264 MB of XFeat tile features (961 tiles).
    pub tile_memory_mb: usize,
    /// Cache folder; default `<map folder>/jointloc-cache`.
    pub cache_dir: Option<PathBuf>,
    /// Acceptance rules per tile.
    pub accept: AcceptConfig,
    /// Homography estimation (threshold in map pixels).
    pub homography: HomographyConfig,
    /// SSIM window and constants.
    pub ssim: SsimConfig,
    /// Registration of virtual frames (mosaics) by correlation.
    pub correlation: CorrelationConfig,
    /// The shortlist of a whole-map search (VLAD ranking of view × tile pairs).
    pub shortlist: ShortlistConfig,
    /// A whole-map search of a single frame first matches the tiles under the best places
    /// of the coarse correlation (gradients and grey levels of the frame against the pooled
    /// map, [`crate::coarse_places`]), and only then the VLAD shortlist. Only where the
    /// shortlist applies (more pairs than [`ShortlistConfig::candidates`], not 0).
    pub coarse_places_first: bool,
}

impl Default for AbsLocConfig {
    fn default() -> Self {
        Self {
            confidence: ConfidenceMode::Adaptive,
            area_prediction: true,
            global_fallback: true,
            inner_tiles_first: true,
            sweep_outer_tiles: false,
            predicted_window_margin_m: 1.5,
            tiles_after_window: false,
            predicted_window_tilt_deg: 3.0,
            scale_normalisation: true,
            rotation_hypotheses: 8,
            use_last_heading: true,
            min_texture_std: 2.0,
            parallel: true,
            early_stop_inliers: Some(40),
            min_match_scale: 0.4,
            max_view_over_tile: 1.2,
            window_keypoints_over_view: 1.5,
            cache: true,
            tile_memory_mb: 128,
            cache_dir: None,
            accept: AcceptConfig::default(),
            homography: HomographyConfig::default(),
            ssim: SsimConfig::default(),
            correlation: CorrelationConfig::default(),
            shortlist: ShortlistConfig::default(),
            coarse_places_first: true,
            relight: RelightConfig::default(),
        }
    }
}

impl AbsLocConfig {
    /// Checks ranges.
    pub fn validate(&self) -> Result<()> {
        let bad = |field: &'static str, value: String, reason: &str| AbslocError::InvalidConfig {
            field,
            value,
            reason: reason.into(),
        };
        self.relight.validate()?;
        if !(self.min_match_scale.is_finite() && self.min_match_scale > 0.0) {
            return Err(bad(
                "min_match_scale",
                self.min_match_scale.to_string(),
                "must be > 0",
            ));
        }
        if !(self.max_view_over_tile.is_finite() && self.max_view_over_tile >= 0.0) {
            return Err(bad(
                "max_view_over_tile",
                self.max_view_over_tile.to_string(),
                "must be >= 0 (0: no crop)",
            ));
        }
        if !(self.window_keypoints_over_view.is_finite() && self.window_keypoints_over_view >= 0.0)
        {
            return Err(bad(
                "window_keypoints_over_view",
                self.window_keypoints_over_view.to_string(),
                "must be >= 0 (0: every keypoint of the window)",
            ));
        }
        if !(self.predicted_window_margin_m.is_finite() && self.predicted_window_margin_m >= 0.0) {
            return Err(bad(
                "predicted_window_margin_m",
                self.predicted_window_margin_m.to_string(),
                "must be >= 0 (0: off)",
            ));
        }
        if !(0.0..60.0).contains(&self.predicted_window_tilt_deg) {
            return Err(bad(
                "predicted_window_tilt_deg",
                self.predicted_window_tilt_deg.to_string(),
                "must be in [0, 60)",
            ));
        }
        if self.rotation_hypotheses == 0 {
            return Err(bad("rotation_hypotheses", "0".into(), "must be ≥ 1"));
        }
        if !(self.min_texture_std.is_finite() && self.min_texture_std >= 0.0) {
            return Err(bad(
                "min_texture_std",
                self.min_texture_std.to_string(),
                "must be ≥ 0",
            ));
        }
        let wm = &self.correlation.whole_map;
        if wm.coarse_view_px < 4 || !(0.0..=1.0).contains(&wm.min_confidence) {
            return Err(bad(
                "correlation.whole_map",
                format!("{wm:?}"),
                "coarse_view_px ≥ 4, min_confidence in [0, 1]",
            ));
        }
        let a = &self.accept;
        if !(a.max_log_scale_error > 0.0 && a.max_anisotropy >= 1.0 && a.border_margin_px >= 0.0) {
            return Err(bad(
                "accept",
                format!("{a:?}"),
                "scale error > 0, anisotropy ≥ 1, margin ≥ 0",
            ));
        }
        if !(self.ssim.sigma > 0.0 && self.ssim.range > 0.0) {
            return Err(bad(
                "ssim",
                format!("{:?}", self.ssim),
                "sigma and range must be > 0",
            ));
        }
        self.homography.ransac.validate()?;
        Ok(())
    }
}

/// What matching the predicted window gave.
enum WindowOutcome {
    Fix(Candidate),
    /// Nothing accepted where the frame was predicted.
    NoFix,
    /// A fix beyond the margin, or a window off the map: the prediction was off, the tiles
    /// decide.
    BeyondMargin,
}

/// What the caller knows before the search (e.g. from the fused pose).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Prior {
    /// Predicted world `(x, y)`, metres: the search centres on the tile nearest to it.
    pub position: Option<[f64; 2]>,
    /// Heading: the angle (radians) that turns frame axes into map axes (image convention, x
    /// towards y); see [`heading_from_rotation`].
    pub heading: Option<f64>,
}

/// An absolute fix.
#[derive(Debug, Clone, PartialEq)]
pub struct Fix {
    /// World `(x, y, z)`: the map point under the image centre; z = ground height there (the
    /// map's elevation model, else 0) + the altimeter reading.
    pub position: [f64; 3],
    /// `w` under the configured mode, in [0, 1].
    pub confidence: f64,
    /// SSIM between the map and the warped frame (unclamped, in [−1, 1]).
    pub ssim: f64,
    /// Mean matching score of the inliers.
    pub match_score: f64,
    /// Tile index (the `<idx>` of its file name).
    pub tile: usize,
    /// RANSAC inliers of the winning tile.
    pub inliers: usize,
    /// Tiles matched for this fix (all hypotheses and the fallback included).
    pub searched_tiles: usize,
    /// Whether the whole map was searched.
    pub global: bool,
    /// Frame → map pixels.
    pub homography: Matrix3<f64>,
    /// Rotation frame → map (radians) and scale (map pixels per frame pixel) at the centre.
    pub heading: f64,
    pub scale: f64,
    /// Radius of the next search.
    pub next_radius: u32,
    /// Wall time of the call, milliseconds.
    pub ms: f64,
}

impl Fix {
    /// Camera-to-world rotation of a nadir camera with this heading (optical axis straight
    /// down, image x axis along the heading in the map): the absolute fix measures no tilt.
    pub fn orientation(&self) -> nalgebra::UnitQuaternion<f64> {
        nadir_orientation(self.heading)
    }
}

/// Camera-to-world rotation of a nadir camera whose image x axis has `heading` in the map
/// (the inverse of [`heading_from_rotation`] for a nadir view).
pub fn nadir_orientation(heading: f64) -> nalgebra::UnitQuaternion<f64> {
    let (s, c) = heading.sin_cos();
    // Map axes (u east, v south) to world (x east, y north): image x = (c, −s, 0). The matrix
    // is a rotation by construction; `UnitQuaternion::from_matrix` would instead iterate
    // towards it from the identity, and a heading near ±180° (the matrix half a turn from the
    // identity) came out turned by half a turn.
    let m = nalgebra::Matrix3::new(c, -s, 0.0, -s, -c, 0.0, 0.0, 0.0, -1.0);
    nalgebra::UnitQuaternion::from_rotation_matrix(&nalgebra::Rotation3::from_matrix_unchecked(m))
}

/// Why no fix was found.
#[derive(Debug, Clone, PartialEq)]
pub enum FailureReason {
    /// The frame has (almost) no texture.
    Textureless { std: f64 },
    /// No tile passed the checks; the best rejection seen.
    NoMatch { best: Option<Rejection> },
    /// A virtual frame is registered around a prior position, and there was none.
    NoPrior,
    /// A virtual frame's correlation found no placement.
    NoPeak(NoPeak),
}

/// A failed search: confidence 0, never a stale position.
#[derive(Debug, Clone, PartialEq)]
pub struct Failure {
    pub reason: FailureReason,
    pub searched_tiles: usize,
    pub global: bool,
    pub next_radius: u32,
    pub ms: f64,
}

/// Result of [`AbsLocalizer::localize`].
#[derive(Debug, Clone, PartialEq)]
pub enum Outcome {
    Fix(Fix),
    Failed(Failure),
}

impl Outcome {
    /// `w`; 0 for a failure.
    pub fn confidence(&self) -> f64 {
        match self {
            Outcome::Fix(f) => f.confidence,
            Outcome::Failed(_) => 0.0,
        }
    }

    /// The fix, if any.
    pub fn fix(&self) -> Option<&Fix> {
        match self {
            Outcome::Fix(f) => Some(f),
            Outcome::Failed(_) => None,
        }
    }

    /// Milliseconds spent.
    pub fn ms(&self) -> f64 {
        match self {
            Outcome::Fix(f) => f.ms,
            Outcome::Failed(f) => f.ms,
        }
    }

    /// Tiles matched.
    pub fn searched_tiles(&self) -> usize {
        match self {
            Outcome::Fix(f) => f.searched_tiles,
            Outcome::Failed(f) => f.searched_tiles,
        }
    }
}

/// The heading (see [`Prior::heading`]) of a camera with camera-to-world rotation `r_wc`: the
/// angle of its image x axis in map axes (map u = world x, map v = −world y).
pub fn heading_from_rotation(r_wc: &nalgebra::Rotation3<f64>) -> f64 {
    let x = r_wc.matrix().column(0);
    (-x[1]).atan2(x[0])
}

#[derive(Debug, Clone, Default)]
struct SearchState {
    last_tile: Option<usize>,
    /// World (x, y) of the last fix: local candidates are tried nearest to it first.
    last_position: Option<(f64, f64)>,
    radius: u32,
    heading: Option<f64>,
}

/// Absolute localisation against one map with one matching pipeline.
#[derive(Debug)]
pub struct AbsLocalizer {
    tiles: MapTiles,
    camera: PinholeCamera,
    pipeline: FeaturePipeline,
    config: AbsLocConfig,
    /// The tile features, opened (or extracted and cached) by the first search that matches
    /// features: virtual frames, registered by correlation, never need them.
    store: Option<Arc<TileStore>>,
    state: SearchState,
    /// Map upsampling chosen at the first frame (1: none), see
    /// [`AbsLocConfig::min_match_scale`].
    upsample: Option<f64>,
    /// Vocabulary and the words of the tile keypoints, built at the first whole-map search
    /// that needs them.
    shortlist: OnceLock<Option<TileIndex>>,
    /// The map pooled for the whole-map correlation of virtual frames, built at the first one
    /// with no prior.
    coarse_map: OnceLock<Option<CoarsePlaces>>,
}

impl AbsLocalizer {
    /// Prepares the search: checks the configuration and that the frame size equals the tile
    /// size. The tile features are opened (or extracted and cached) when first needed, or by
    /// [`Self::prepare`].
    pub fn new(
        tiles: MapTiles,
        camera: PinholeCamera,
        pipeline: FeaturePipeline,
        config: AbsLocConfig,
    ) -> Result<Self> {
        config.validate()?;
        tiles.check_frame_size(camera.width, camera.height)?;
        let t = Instant::now();
        let tiles = match relit_tiles(&tiles, &config.relight)? {
            Ok(relit) => {
                tracing::info!(
                    seconds = t.elapsed().as_secs_f64(),
                    "map relit to the flight's sun"
                );
                relit
            }
            Err(why) => {
                tracing::info!(%why, "map matched as it was taken");
                tiles
            }
        };
        if !(camera.fx.is_finite() && camera.fx > 0.0 && camera.fy.is_finite() && camera.fy > 0.0) {
            return Err(AbslocError::InvalidConfig {
                field: "camera",
                value: format!("fx {} fy {}", camera.fx, camera.fy),
                reason: "focal lengths must be finite and > 0".into(),
            });
        }
        Ok(Self {
            tiles,
            camera,
            pipeline,
            config,
            store: None,
            state: SearchState {
                radius: RADIUS_RANGE.1,
                ..Default::default()
            },
            upsample: None,
            shortlist: OnceLock::new(),
            coarse_map: OnceLock::new(),
        })
    }

    /// Upsamples the map once, at the first frame, when it is too coarse for the frames at
    /// this altitude (see [`AbsLocConfig::min_match_scale`]).
    fn adapt_map_scale(&mut self, altitude: f64) -> Result<()> {
        if self.upsample.is_some() {
            return Ok(());
        }
        let factor =
            map_upsample_factor(self.expected_scale(altitude), self.config.min_match_scale);
        if factor == 1.0 {
            self.upsample = Some(1.0);
            return Ok(());
        }
        let t = Instant::now();
        // The paper's tiling: frame-size tiles overlapping by half.
        let tiles = self.tiles.upsampled(factor, 0.5)?;
        tracing::info!(
            factor,
            gsd_m = tiles.gsd_m(),
            tiles = tiles.len(),
            seconds = t.elapsed().as_secs_f64(),
            "coarse map upsampled for matching"
        );
        self.tiles = tiles;
        self.store = None;
        self.upsample = Some(factor);
        self.shortlist = OnceLock::new();
        self.coarse_map = OnceLock::new();
        self.reset();
        Ok(())
    }

    /// The map upsampling in use (1: none; `None` before the first frame).
    pub fn upsample_factor(&self) -> Option<f64> {
        self.upsample
    }

    /// The map.
    pub fn tiles(&self) -> &MapTiles {
        &self.tiles
    }

    /// The configuration.
    pub fn config(&self) -> &AbsLocConfig {
        &self.config
    }

    /// The matching pipeline.
    pub fn pipeline(&self) -> &FeaturePipeline {
        &self.pipeline
    }

    /// How the tile features were obtained; `None` before they were first needed.
    pub fn cache_status(&self) -> Option<CacheStatus> {
        self.store.as_ref().map(|s| s.status())
    }

    /// The tile features; `None` before they were first needed.
    pub fn tile_store(&self) -> Option<&TileStore> {
        self.store.as_deref()
    }

    /// Upsamples the map as a frame at `altitude` needs (see
    /// [`AbsLocConfig::min_match_scale`]) and opens, or extracts and caches, its tile features
    /// now rather than at the first search.
    pub fn prepare(&mut self, altitude: f64) -> Result<CacheStatus> {
        if !(altitude.is_finite() && altitude > 0.0) {
            return Err(AbslocError::InvalidAltitude { value: altitude });
        }
        self.adapt_map_scale(altitude)?;
        Ok(self.ensure_store()?.status())
    }

    /// The tile features of the map in use, opened on first use.
    fn ensure_store(&mut self) -> Result<Arc<TileStore>> {
        if let Some(s) = &self.store {
            return Ok(s.clone());
        }
        let id = match self.upsample {
            Some(f) if f != 1.0 => format!("{}-up{f:.2}", self.pipeline.detector_id),
            _ => self.pipeline.detector_id.clone(),
        };
        let t = Instant::now();
        let key = cache::cache_key(&self.tiles, &self.pipeline.detector_key);
        let path = self
            .config
            .cache
            .then(|| cache::cache_path(&self.tiles, self.config.cache_dir.as_deref(), &id));
        let store = Arc::new(TileStore::open(
            &self.tiles,
            self.pipeline.detector.clone(),
            &key,
            path.as_deref(),
            self.config.tile_memory_mb.saturating_mul(1 << 20),
        )?);
        tracing::info!(
            tiles = self.tiles.len(),
            status = ?store.status(),
            matcher = %self.pipeline.name,
            seconds = t.elapsed().as_secs_f64(),
            "tile features ready"
        );
        self.shortlist = OnceLock::new();
        self.store = Some(store.clone());
        Ok(store)
    }

    /// Forgets the last tile, radius and heading (the next search is global).
    pub fn reset(&mut self) {
        self.state = SearchState {
            radius: RADIUS_RANGE.1,
            ..Default::default()
        };
    }

    /// The largest query view, from [`AbsLocConfig::max_view_over_tile`].
    fn max_view_size(&self) -> Option<(usize, usize)> {
        let f = self.config.max_view_over_tile;
        let (w, h) = self.tiles.tile_size();
        (f > 0.0).then(|| {
            (
                (w as f64 * f).round() as usize,
                (h as f64 * f).round() as usize,
            )
        })
    }

    /// Frame-to-map scale (map pixels per frame pixel at the image centre) at `altitude`.
    pub fn expected_scale(&self, altitude: f64) -> f64 {
        let f = 0.5 * (self.camera.fx + self.camera.fy);
        altitude / (f * self.tiles.gsd_m())
    }

    /// Localises one frame. Errors on unusable input (frame size, altitude); a search that
    /// finds nothing returns [`Outcome::Failed`] (confidence 0) and widens the next search.
    pub fn localize(&mut self, frame: &GrayImage, altitude: f64, prior: &Prior) -> Result<Outcome> {
        self.localize_view(&FrameView::frame(frame, altitude), prior)
    }

    /// Localises a frame or a virtual frame (a [`crate::mosaic::Mosaic`]); see
    /// [`Self::localize`]. The fix is the ground point under the principal point, at the true
    /// altitude above it.
    pub fn localize_view(&mut self, view: &FrameView<'_>, prior: &Prior) -> Result<Outcome> {
        let start = Instant::now();
        let frame = view.image;
        let altitude = view.altitude;
        self.tiles.check_frame_size(frame.width(), frame.height())?;
        if !(altitude.is_finite() && altitude > 0.0) {
            return Err(AbslocError::InvalidAltitude { value: altitude });
        }
        if !(view.zoom.is_finite() && view.zoom >= 1.0) {
            return Err(AbslocError::InvalidConfig {
                field: "zoom",
                value: view.zoom.to_string(),
                reason: "a virtual frame's zoom must be finite and >= 1".into(),
            });
        }
        let coverage = match view.valid {
            Some(v) if v.len() != (frame.width() * frame.height()) as usize => {
                return Err(AbslocError::InvalidConfig {
                    field: "valid",
                    value: v.len().to_string(),
                    reason: "the validity mask must have one entry per pixel".into(),
                });
            }
            Some(v) => Some(Coverage::eroded(
                v,
                frame.width() as usize,
                frame.height() as usize,
                self.config.accept.border_margin_px.ceil() as usize,
            )),
            None => None,
        };
        if view.zoom > 1.0 {
            let outcome = self.correlate_view(view, coverage.as_ref(), prior, start);
            match &outcome {
                Outcome::Fix(f) if f.global => {
                    tracing::info!(ms = f.ms, position = ?f.position, "whole-map search of a virtual frame: fix");
                }
                Outcome::Failed(f) if f.global => {
                    tracing::info!(ms = f.ms, reason = ?f.reason, "whole-map search of a virtual frame: no fix");
                }
                _ => {}
            }
            return Ok(outcome);
        }
        self.adapt_map_scale(altitude)?;
        let std = grey_std(frame);
        if std < self.config.min_texture_std {
            tracing::debug!(std, "frame without texture: no fix");
            return Ok(self.fail(FailureReason::Textureless { std }, 0, false, start));
        }
        let store = self.ensure_store()?;
        let expected = self.expected_scale(altitude);
        // A masked frame is a virtual one, an ideal pinhole.
        let ctx = ViewContext {
            lens: if view.valid.is_some() {
                None
            } else {
                Lens::of(&self.camera, self.config.accept.max_off_axis_deg)
            },
            coverage: coverage.as_ref(),
        };
        let scale = if self.config.scale_normalisation {
            expected
        } else {
            1.0
        };
        let own_heading = self
            .config
            .use_last_heading
            .then_some(self.state.heading)
            .flatten();
        let heading = prior.heading.or(own_heading);
        let sweep = self.sweep_angles();
        let first_angles = heading.map_or_else(|| sweep.clone(), |h| vec![h]);

        let all: Vec<usize> = self.tiles.all(prior.position.map(|p| (p[0], p[1])));
        let predicted = prior
            .position
            .map(|[x, y]| (x, y))
            .or(self.state.last_position);
        let local = if !self.config.area_prediction {
            None
        } else if let Some([x, y]) = prior.position {
            Some(self.tiles.around_world(x, y, self.state.radius))
        } else {
            self.state.last_tile.map(|t| {
                let mut near = self.tiles.neighbourhood(t, self.state.radius);
                if let Some((x, y)) = self.state.last_position {
                    self.tiles.order_by_distance(&mut near, x, y);
                }
                near
            })
        };
        let mut views: Vec<(f64, QueryView)> = Vec::new();
        let mut searched = 0usize;
        let mut best_rejection: Option<Rejection> = None;
        let local_is_all = local.as_ref().is_none_or(|l| l.len() >= all.len());
        let first = local.clone().unwrap_or_else(|| all.clone());
        // Inner tiles (those containing the predicted position) first, then the rest.
        let inner = match (&local, predicted) {
            (Some(l), Some((x, y))) if self.config.inner_tiles_first => {
                self.tiles.containing(l, x, y)
            }
            _ => Vec::new(),
        };
        let split = !inner.is_empty() && inner.len() < first.len();
        // A sweep around a position leaves the outer tiles to the whole-map search.
        let skip_outer = split && heading.is_none() && !self.config.sweep_outer_tiles;
        let passes: Vec<Vec<usize>> = if !split {
            vec![first]
        } else if skip_outer {
            vec![inner]
        } else {
            let outer = first
                .iter()
                .copied()
                .filter(|t| !inner.contains(t))
                .collect();
            vec![inner, outer]
        };
        let mut from_window = false;
        let (mut found, mut shortlisted) = if local.is_none() {
            self.search_whole_map(
                &store,
                frame,
                &ctx,
                &all,
                (heading, &first_angles),
                (scale, expected),
                (&mut views, &mut searched, &mut best_rejection),
            )?
        } else {
            let mut found = None;
            let mut window_failed = false;
            if let (Some([x, y]), Some(h)) = (prior.position, prior.heading)
                && self.config.predicted_window_margin_m > 0.0
            {
                match self.search_window(
                    &store,
                    frame,
                    &ctx,
                    ((x, y), altitude),
                    h,
                    (scale, expected),
                    &mut views,
                    &mut searched,
                    &mut best_rejection,
                )? {
                    WindowOutcome::Fix(c) => {
                        found = Some(c);
                        from_window = true;
                    }
                    WindowOutcome::NoFix => window_failed = true,
                    WindowOutcome::BeyondMargin => {}
                }
            }
            if window_failed && !self.config.tiles_after_window {
                return Ok(self.fail(
                    FailureReason::NoMatch {
                        best: best_rejection,
                    },
                    searched,
                    false,
                    start,
                ));
            }
            let tile_passes = if found.is_some() {
                &passes[..0]
            } else {
                &passes[..]
            };
            for tiles in tile_passes.iter().filter(|p| !p.is_empty()) {
                found = self.search(
                    &store,
                    frame,
                    &ctx,
                    tiles,
                    &first_angles,
                    scale,
                    expected,
                    None,
                    &mut views,
                    &mut searched,
                    &mut best_rejection,
                )?;
                if found.is_some() {
                    break;
                }
            }
            (found, false)
        };
        let mut global = local_is_all && !from_window;
        // Retry everywhere, with the rotation sweep unless the caller fixed the heading; not
        // when that is exactly what was just searched.
        let same_again =
            local_is_all && !skip_outer && (heading.is_none() || prior.heading.is_some());
        if found.is_none() && self.config.global_fallback && !same_again {
            let angles = if prior.heading.is_some() {
                first_angles.clone()
            } else {
                sweep
            };
            tracing::debug!(
                tiles = all.len(),
                angles = angles.len(),
                "local search failed: global search"
            );
            (found, shortlisted) = self.search_whole_map(
                &store,
                frame,
                &ctx,
                &all,
                (prior.heading, &angles),
                (scale, expected),
                (&mut views, &mut searched, &mut best_rejection),
            )?;
            global = true;
        }
        let found = match found {
            Some(best) if shortlisted => Some(self.refine(
                &store,
                frame,
                (&ctx, scale, expected),
                best,
                &all,
                &mut views,
                &mut searched,
            )?),
            other => other,
        };
        let Some(best) = found else {
            return Ok(self.fail(
                FailureReason::NoMatch {
                    best: best_rejection,
                },
                searched,
                global,
                start,
            ));
        };
        let fix = self.finish(frame, &ctx, &best, altitude, searched, global, start);
        Ok(Outcome::Fix(fix))
    }

    /// Registers a virtual frame by correlation (see [`crate::correlate`]) within
    /// [`CorrelationConfig::search_radius_m`] of the prior position (else over the whole map,
    /// [`crate::whole_map`]), with the prior heading (else the last fix's, else a sweep of
    /// [`CorrelationConfig::rotation_hypotheses`] angles; a whole-map search sweeps unless the
    /// prior has a heading). The map is used as it stands (a virtual frame is never the reason
    /// to upsample it).
    fn correlate_view(
        &mut self,
        view: &FrameView<'_>,
        coverage: Option<&Coverage>,
        prior: &Prior,
        start: Instant,
    ) -> Outcome {
        let cfg = self.config.correlation;
        // No prior position: the whole map, all headings but the prior's. Not the last fix's
        // place or heading: a search around one fix would only confirm it (the caller gives
        // the fused pose as the prior once it trusts one).
        let centre = prior.position.map(|[x, y]| (x, y));
        let own_heading = self
            .config
            .use_last_heading
            .then_some(self.state.heading)
            .flatten()
            .filter(|_| centre.is_some());
        let angles: Vec<f64> = match prior.heading.or(own_heading) {
            Some(h) => vec![h],
            None => sweep(cfg.rotation_hypotheses.max(1)),
        };
        let coverage = coverage.map(Coverage::image);
        let expected = self.expected_scale(view.altitude * view.zoom);
        let principal = (self.camera.cx, self.camera.cy);
        let map = self.tiles.map();
        let global = centre.is_none();
        // (heading, principal point's map pixel, radius in map pixels) to place the view at.
        let seeds: Vec<(f64, (f64, f64), i64)> = match centre {
            Some((px, py)) => {
                let radius = (cfg.search_radius_m / self.tiles.gsd_m()).ceil() as i64;
                let at = self.tiles.world_to_pixel(px, py);
                angles.iter().map(|&a| (a, at, radius)).collect()
            }
            None if cfg.whole_map.candidates == 0 => {
                return self.fail(FailureReason::NoPrior, 0, false, start);
            }
            None => self.whole_map_seeds(view, coverage.as_ref(), &angles, expected),
        };
        let mut best: Option<Placement> = None;
        let mut last_miss = NoPeak::TooSmall { valid_px: 0 };
        let mut searched = 0usize;
        let mut consider = |this: &Self,
                            angle: f64,
                            centre: (f64, f64),
                            radius: i64,
                            best: &mut Option<Placement>| {
            searched += 1;
            let placed = this.place(view, coverage.as_ref(), angle, expected, centre, radius);
            if let (true, Ok(p)) = (global, &placed) {
                let (x, y) = this.placement_world(p);
                tracing::trace!(
                    x,
                    y,
                    heading_deg = angle.to_degrees(),
                    score = p.peak.score,
                    "whole-map seed refined"
                );
            }
            match placed {
                Ok(p) if best.as_ref().is_none_or(|b| p.peak.score > b.peak.score) => {
                    *best = Some(p)
                }
                Ok(_) => {}
                Err(miss) => last_miss = miss,
            }
        };
        for &(angle, at, radius) in &seeds {
            consider(self, angle, at, radius, &mut best);
        }
        // Halve the angle step around the best angle down to the refinement's resolution,
        // within a few pixels of the best placement.
        let mut step = if angles.len() > 1 {
            std::f64::consts::TAU / angles.len() as f64 / 2.0
        } else {
            cfg.heading_step_deg.to_radians()
        };
        while step >= cfg.min_heading_step_deg.to_radians() * 0.999 {
            let Some(b) = &best else { break };
            let angle = b.view.transform.angle;
            let pc = b.view.transform.forward(principal.0, principal.1);
            let centre = (
                b.window[0] as f64 + b.peak.offset[0] + pc.0,
                b.window[1] as f64 + b.peak.offset[1] + pc.1,
            );
            for a in [angle - step, angle + step] {
                consider(self, a, centre, 3, &mut best);
            }
            step /= 2.0;
        }
        let Some(best) = best else {
            return self.fail(FailureReason::NoPeak(last_miss), searched, global, start);
        };
        let (x, y) = self.placement_world(&best);
        let Placement {
            peak,
            view: normalised,
            window: [x0, y0],
            valid,
        } = best;
        let (ox, oy) = (x0 as f64 + peak.offset[0], y0 as f64 + peak.offset[1]);
        let shift = Matrix3::new(1.0, 0.0, ox, 0.0, 1.0, oy, 0.0, 0.0, 1.0);
        let h = shift * normalised.transform.matrix();
        // SSIM of the view's valid pixels against the map under them.
        let (vw, vh) = normalised.image.dimensions();
        let (vw, vh) = (vw as usize, vh as usize);
        let (rx, ry) = (ox.round() as i64, oy.round() as i64);
        let region: Vec<f32> = (0..vw * vh)
            .map(|i| {
                let (u, v) = (rx + (i % vw) as i64, ry + (i / vw) as i64);
                let inside =
                    u >= 0 && v >= 0 && (u as u32) < map.width() && (v as u32) < map.height();
                if inside {
                    map.get_pixel(u as u32, v as u32)[0] as f32
                } else {
                    0.0
                }
            })
            .collect();
        let values: Vec<f32> = normalised
            .image
            .as_raw()
            .iter()
            .map(|&p| p as f32)
            .collect();
        let ssim =
            ssim_masked(&region, &values, vw, vh, Some(&valid), &self.config.ssim).unwrap_or(0.0);
        let match_score = peak.score.clamp(0.0, 1.0);
        let confidence = self.config.confidence.confidence(ssim, match_score);
        let min_confidence = if global {
            cfg.min_confidence.max(cfg.whole_map.min_confidence)
        } else {
            cfg.min_confidence
        };
        if confidence < min_confidence {
            tracing::debug!(
                x,
                y,
                confidence,
                global,
                "virtual frame placed below the confidence gate"
            );
            return self.fail(
                FailureReason::NoPeak(NoPeak::LowConfidence { confidence }),
                searched,
                global,
                start,
            );
        }
        let next_radius = search_radius(confidence);
        let tile_pos = self.tiles.nearest(x, y, 1).first().copied().unwrap_or(0);
        let tile = self.tiles.tiles().get(tile_pos).map_or(0, |t| t.index);
        self.state = SearchState {
            last_tile: Some(tile_pos),
            last_position: Some((x, y)),
            radius: next_radius,
            heading: Some(normalised.transform.angle),
        };
        let fix = Fix {
            position: [x, y, self.tiles.ground_height(x, y) + view.altitude],
            confidence,
            ssim,
            match_score,
            tile,
            inliers: valid.iter().filter(|&&v| v).count(),
            searched_tiles: searched,
            global,
            homography: h,
            heading: normalised.transform.angle,
            scale: expected,
            next_radius,
            ms: start.elapsed().as_secs_f64() * 1e3,
        };
        tracing::debug!(?fix.position, fix.confidence, peak.score, peak.second, "virtual frame fix");
        Outcome::Fix(fix)
    }

    /// World x, y of the principal point of a placed view.
    fn placement_world(&self, p: &Placement) -> (f64, f64) {
        let pc = p.view.transform.forward(self.camera.cx, self.camera.cy);
        let (ox, oy) = (
            p.window[0] as f64 + p.peak.offset[0],
            p.window[1] as f64 + p.peak.offset[1],
        );
        self.tiles.pixel_to_world(ox + pc.0, oy + pc.1)
    }

    /// `view` turned by `angle` and scaled to the map's pixels, its gradient magnitude (the
    /// signal the correlation compares) and which of its pixels are valid; `coverage`:
    /// [`Coverage::image`] of the view's mask.
    fn view_grid(
        &self,
        view: &FrameView<'_>,
        coverage: Option<&GrayImage>,
        angle: f64,
        expected: f64,
    ) -> (NormalisedFrame, Grid, Vec<bool>) {
        let cfg = self.config.correlation;
        let principal = (self.camera.cx, self.camera.cy);
        let normalised = normalise_lens(view.image, None, principal, expected, angle, None);
        let (vw, vh) = normalised.image.dimensions();
        let (vw, vh) = (vw as usize, vh as usize);
        let valid: Vec<bool> = match coverage {
            Some(img) => {
                let (vals, inside) = resample(img, vw, vh, 1, |u, v| {
                    Some(normalised.transform.inverse(u, v))
                });
                vals.iter()
                    .zip(&inside)
                    .map(|(&v, &i)| i && v > 254.5)
                    .collect()
            }
            None => {
                let (w, h) = normalised.frame_size;
                (0..vw * vh)
                    .map(|i| {
                        let (x, y) = normalised
                            .transform
                            .inverse((i % vw) as f64, (i / vw) as f64);
                        x >= 0.0 && y >= 0.0 && x <= w as f64 - 1.0 && y <= h as f64 - 1.0
                    })
                    .collect()
            }
        };
        let grid = Grid::from_image(&normalised.image).gradient_magnitude(cfg.smoothing_px);
        (normalised, grid, valid)
    }

    /// Where on the whole map a virtual frame may lie when there is no prior (see
    /// [`crate::whole_map`]): the best distinct coarse placements over `angles`, each as
    /// (heading, its principal point's map pixel, the radius in map pixels the fine
    /// correlation searches around it).
    fn whole_map_seeds(
        &self,
        view: &FrameView<'_>,
        coverage: Option<&GrayImage>,
        angles: &[f64],
        expected: f64,
    ) -> Vec<(f64, (f64, f64), i64)> {
        // Each placement also at a third of the sweep's step either side: the fine correlation
        // of a 200-pixel view wants its heading within a few degrees.
        let third = if angles.len() > 1 {
            std::f64::consts::TAU / angles.len() as f64 / 3.0
        } else {
            0.0
        };
        let turns: &[f64] = if third > 0.0 {
            &[0.0, -1.0, 1.0]
        } else {
            &[0.0]
        };
        self.whole_map_places(view, coverage, angles, expected)
            .into_iter()
            .flat_map(|(angle, at, radius)| {
                turns.iter().map(move |t| (angle + t * third, at, radius))
            })
            .collect()
    }

    /// The best distinct coarse placements of `view` over the whole map and `angles`, best
    /// first, each as (heading, its principal point's map pixel, a coarse cell in map pixels).
    fn whole_map_places(
        &self,
        view: &FrameView<'_>,
        coverage: Option<&GrayImage>,
        angles: &[f64],
        expected: f64,
    ) -> Vec<(f64, (f64, f64), i64)> {
        let cfg = self.config.correlation;
        let wm = cfg.whole_map;
        let t = Instant::now();
        let views: Vec<(f64, NormalisedFrame, Grid, Vec<bool>)> = angles
            .par_iter()
            .map(|&a| {
                let (n, g, v) = self.view_grid(view, coverage, a, expected);
                (a, n, g, v)
            })
            .collect();
        let width = views.first().map_or(0, |v| v.2.width);
        let coarse = self.coarse_map.get_or_init(|| {
            let factor = (width / wm.coarse_view_px.max(1)).max(1);
            let built = CoarsePlaces::new(self.tiles.map(), factor, cfg.smoothing_px);
            tracing::info!(
                factor,
                seconds = t.elapsed().as_secs_f64(),
                "map pooled for the whole-map correlation"
            );
            built
        });
        let Some(coarse) = coarse.as_ref() else {
            return Vec::new();
        };
        let signals: Vec<ViewSignals> = views
            .iter()
            .map(|(_, normalised, gradient, valid)| {
                let pc = normalised.transform.forward(self.camera.cx, self.camera.cy);
                ViewSignals {
                    gradient: gradient.clone(),
                    intensity: Grid::from_image(&normalised.image),
                    valid: valid.clone(),
                    principal: [pc.0, pc.1],
                }
            })
            .collect();
        let views_ms = t.elapsed().as_secs_f64() * 1e3;
        let kept = coarse.search(&signals, &wm);
        // The fine correlation searches a coarse cell either way around a rescored place.
        let radius = coarse.factor() as i64;
        tracing::debug!(
            best = kept.first().map(|p| p.score),
            candidates = kept.len(),
            views_ms,
            ms = t.elapsed().as_secs_f64() * 1e3,
            "whole-map correlation"
        );
        kept.into_iter()
            .map(|p| {
                let angle = views[p.view].0;
                let at = (p.at[0], p.at[1]);
                let (x, y) = self.tiles.pixel_to_world(at.0, at.1);
                tracing::trace!(
                    x,
                    y,
                    heading_deg = angle.to_degrees(),
                    score = p.score,
                    "whole-map coarse candidate"
                );
                (angle, at, radius)
            })
            .collect()
    }

    /// A search of `all` tiles over `angles` (the sweep, or `[h]` where `heading` is `h`)
    /// with no prior position: the coarse places first where the search is ranked (more
    /// pairs than [`ShortlistConfig::candidates`], not 0) and
    /// [`AbsLocConfig::coarse_places_first`] is on (then, when they give nothing,
    /// [`ShortlistConfig::after_coarse_places`] pairs of the VLAD shortlist: none by default),
    /// else the pairs shortlisted by VLAD. Also whether the shortlist cut the search short
    /// (its fix is then refined over the other tiles that contain it).
    #[allow(clippy::too_many_arguments)]
    fn search_whole_map(
        &self,
        store: &TileStore,
        frame: &GrayImage,
        ctx: &ViewContext<'_>,
        all: &[usize],
        (heading, angles): (Option<f64>, &[f64]),
        (scale, expected): (f64, f64),
        (views, searched, best_rejection): (
            &mut Vec<(f64, QueryView)>,
            &mut usize,
            &mut Option<Rejection>,
        ),
    ) -> Result<(Option<Candidate>, bool)> {
        let keep = self.config.shortlist.candidates;
        let ranked = keep > 0 && all.len() * angles.len() > keep;
        let coarse_first = ranked
            && self.config.coarse_places_first
            && self.config.correlation.whole_map.candidates > 0;
        if coarse_first {
            let found = self.coarse_first(
                store,
                frame,
                ctx,
                all,
                heading,
                (scale, expected),
                views,
                searched,
                best_rejection,
            )?;
            if found.is_some() {
                return Ok((found, false));
            }
        }
        let keep = if coarse_first {
            self.config.shortlist.after_coarse_places.min(keep)
        } else {
            keep
        };
        if coarse_first && keep == 0 {
            return Ok((None, false));
        }
        let found = self.search(
            store,
            frame,
            ctx,
            all,
            angles,
            scale,
            expected,
            ranked.then_some(keep),
            views,
            searched,
            best_rejection,
        )?;
        Ok((found, ranked))
    }

    /// A whole-map search of a single frame through the coarse correlation first
    /// ([`AbsLocConfig::coarse_places_first`]): the frame, turned to each of
    /// [`CorrelationConfig::rotation_hypotheses`] headings (or `heading`), is placed on the
    /// pooled map by its gradients and grey levels, and the tile centred nearest each of the
    /// best places is matched at that place's heading, best place first, until one gives a
    /// decisive match (the early-stop rule of [`crate::search`]). `None` when no place gave
    /// an accepted match.
    #[allow(clippy::too_many_arguments)]
    fn coarse_first(
        &self,
        store: &TileStore,
        frame: &GrayImage,
        ctx: &ViewContext<'_>,
        all: &[usize],
        heading: Option<f64>,
        (scale, expected): (f64, f64),
        views: &mut Vec<(f64, QueryView)>,
        searched: &mut usize,
        best_rejection: &mut Option<Rejection>,
    ) -> Result<Option<Candidate>> {
        let t = Instant::now();
        let angles = heading.map_or_else(
            || sweep(self.config.correlation.rotation_hypotheses),
            |h| vec![h],
        );
        let view = FrameView::frame(
            frame,
            expected * 0.5 * (self.camera.fx + self.camera.fy) * self.tiles.gsd_m(),
        );
        let places = self.whole_map_places(&view, None, &angles, expected);
        let mut best: Option<Candidate> = None;
        let decisive = self.config.early_stop_inliers.unwrap_or(usize::MAX);
        for (rank, &(angle, (u, v), _)) in places.iter().enumerate() {
            let (x, y) = self.tiles.pixel_to_world(u, v);
            // The tile centred nearest the place holds most of the frame; its neighbours would
            // multiply the cost of a place that is wrong.
            let mut tiles = self.tiles.containing(all, x, y);
            self.tiles.order_by_distance(&mut tiles, x, y);
            tiles.truncate(1);
            if tiles.is_empty() {
                continue;
            }
            let found = self.search(
                store,
                frame,
                ctx,
                &tiles,
                &[angle],
                scale,
                expected,
                None,
                views,
                searched,
                best_rejection,
            )?;
            if let Some(c) = found {
                tracing::debug!(
                    rank,
                    inliers = c.inliers.len(),
                    ms = t.elapsed().as_secs_f64() * 1e3,
                    "whole-map search: coarse place matched"
                );
                let stop = c.inliers.len() >= decisive;
                if best
                    .as_ref()
                    .is_none_or(|b| c.inliers.len() > b.inliers.len())
                {
                    best = Some(c);
                }
                if stop {
                    break;
                }
            }
        }
        if best.is_none() {
            tracing::debug!(
                places = places.len(),
                ms = t.elapsed().as_secs_f64() * 1e3,
                "whole-map search: no coarse place matched"
            );
        }
        Ok(best)
    }

    /// The best placement of `view` turned by `angle`, its principal point within `radius` map
    /// pixels of map pixel `(pu, pv)`; `coverage`: [`Coverage::image`] of the view's mask.
    #[allow(clippy::too_many_arguments)]
    fn place(
        &self,
        view: &FrameView<'_>,
        coverage: Option<&GrayImage>,
        angle: f64,
        expected: f64,
        (pu, pv): (f64, f64),
        radius: i64,
    ) -> std::result::Result<Placement, NoPeak> {
        let cfg = self.config.correlation;
        let principal = (self.camera.cx, self.camera.cy);
        let map = self.tiles.map();
        let (normalised, grid, valid) = self.view_grid(view, coverage, angle, expected);
        let (vw, vh) = normalised.image.dimensions();
        let (vw, vh) = (vw as usize, vh as usize);
        // The window: the view placed with its principal point at the prior, ± radius.
        let pc = normalised.transform.forward(principal.0, principal.1);
        let x0 = ((pu - pc.0).round() as i64 - radius).max(0);
        let y0 = ((pv - pc.1).round() as i64 - radius).max(0);
        let x1 = ((pu - pc.0).round() as i64 + radius + vw as i64).min(map.width() as i64);
        let y1 = ((pv - pc.1).round() as i64 + radius + vh as i64).min(map.height() as i64);
        if x1 - x0 < vw as i64 || y1 - y0 < vh as i64 {
            return Err(NoPeak::TooSmall { valid_px: 0 });
        }
        let window = Grid {
            width: (x1 - x0) as usize,
            height: (y1 - y0) as usize,
            data: (y0..y1)
                .flat_map(|y| (x0..x1).map(move |x| (x, y)))
                .map(|(x, y)| map.get_pixel(x as u32, y as u32)[0] as f32)
                .collect(),
        }
        .gradient_magnitude(cfg.smoothing_px);
        let peak = correlate(&grid, &valid, &window, &cfg)?;
        Ok(Placement {
            peak,
            view: normalised,
            window: [x0, y0],
            valid,
        })
    }

    /// After a shortlisted whole-map search: the best pair's view matched against the other
    /// tiles that contain its fix, as a local search would, since the shortlist's first
    /// decisive tile may hold the frame near its edge. The most inliers win.
    #[allow(clippy::too_many_arguments)]
    fn refine(
        &self,
        store: &TileStore,
        frame: &GrayImage,
        (ctx, scale, expected): (&ViewContext<'_>, f64, f64),
        best: Candidate,
        all: &[usize],
        views: &mut Vec<(f64, QueryView)>,
        searched: &mut usize,
    ) -> Result<Candidate> {
        let (u, v) = best.map_pixel((self.camera.cx, self.camera.cy));
        let (x, y) = self.tiles.pixel_to_world(u, v);
        let others: Vec<usize> = self
            .tiles
            .containing(all, x, y)
            .into_iter()
            .filter(|&t| t != best.tile)
            .collect();
        if others.is_empty() {
            return Ok(best);
        }
        let angle = views[best.view].0;
        let mut rejection = None;
        let refined = self.search(
            store,
            frame,
            ctx,
            &others,
            &[angle],
            scale,
            expected,
            None,
            views,
            searched,
            &mut rejection,
        )?;
        Ok(match refined {
            Some(r) if r.inliers.len() > best.inliers.len() => r,
            _ => best,
        })
    }

    fn sweep_angles(&self) -> Vec<f64> {
        sweep(self.config.rotation_hypotheses)
    }

    /// What every (view, tile) pair of a search shares: the matcher, the acceptance rules and
    /// the frame-to-map scale expected from the altimeter.
    fn match_context(&self, expected: f64) -> MatchContext<'_> {
        MatchContext {
            matcher: self.pipeline.matcher.as_ref(),
            homography: &self.config.homography,
            accept: &self.config.accept,
            principal: (self.camera.cx, self.camera.cy),
            expected_scale: Some(expected),
        }
    }

    /// The query view of `frame` turned by `angle`: its position in `views`, made and added
    /// the first time an angle is asked for.
    fn view_at(
        &self,
        frame: &GrayImage,
        ctx: &ViewContext<'_>,
        angle: f64,
        scale: f64,
        views: &mut Vec<(f64, QueryView)>,
    ) -> Result<usize> {
        if let Some(id) = views.iter().position(|(b, _)| angle_eq(*b, angle)) {
            return Ok(id);
        }
        let mut v = QueryView::through(
            frame,
            ctx.lens,
            self.pipeline.detector.as_ref(),
            (self.camera.cx, self.camera.cy),
            scale,
            angle,
            self.config.accept.border_margin_px,
            self.max_view_size(),
        )?;
        if let Some(c) = ctx.coverage {
            // Keypoints next to the fill of a virtual frame see its edge.
            let keep: Vec<usize> = (0..v.features.len())
                .filter(|&i| {
                    let [u, w] = v.features.keypoints[i];
                    let (x, y) = v.normalised.transform.inverse(u as f64, w as f64);
                    c.covers(x, y)
                })
                .collect();
            v.features = select(&v.features, &keep);
        }
        views.push((angle, v));
        Ok(views.len() - 1)
    }

    /// Matches the view at `angle` against the map's keypoints around the predicted position
    /// ([`crate::window`]): the view's extent plus
    /// [`AbsLocConfig::predicted_window_margin_m`] on each side. Its candidate counts only if
    /// it puts the image centre within the margin (and the tilt's lever arm,
    /// [`AbsLocConfig::predicted_window_tilt_deg`]) of the prediction: farther, the window may
    /// have cut the footprint, and the tile search decides.
    #[allow(clippy::too_many_arguments)]
    fn search_window(
        &self,
        store: &TileStore,
        frame: &GrayImage,
        ctx: &ViewContext<'_>,
        (predicted, altitude): ((f64, f64), f64),
        angle: f64,
        (scale, expected): (f64, f64),
        views: &mut Vec<(f64, QueryView)>,
        searched: &mut usize,
        best_rejection: &mut Option<Rejection>,
    ) -> Result<WindowOutcome> {
        let id = self.view_at(frame, ctx, angle, scale, views)?;
        let view = &views[id].1;
        let principal = (self.camera.cx, self.camera.cy);
        let margin = self.config.predicted_window_margin_m / self.tiles.gsd_m();
        let (vw, vh) = view.normalised.image.dimensions();
        let centre = self.tiles.world_to_pixel(predicted.0, predicted.1);
        let half = (vw as f64 / 2.0 + margin, vh as f64 / 2.0 + margin);
        // The frame turned north-up fills only part of the view's bounding box: keep the map's
        // keypoints over the frame itself, and the margin around it.
        let p = view.normalised.transform.forward(principal.0, principal.1);
        let pad = -margin / view.normalised.transform.scale;
        let footprint = |u: f64, v: f64| {
            view.normalised
                .inside(p.0 + u - centre.0, p.1 + v - centre.1, pad)
        };
        let Some(mut w) = window::gather(&self.tiles, store, centre, half, footprint)? else {
            return Ok(WindowOutcome::BeyondMargin);
        };
        let ratio = self.config.window_keypoints_over_view;
        if ratio > 0.0 {
            let cap = (ratio * view.features.len() as f64).ceil() as usize;
            w.features = window::strongest(std::mem::take(&mut w.features), cap);
        }
        *searched += 1;
        let c = match evaluate(
            &self.match_context(expected),
            id,
            view,
            w.tile_index,
            &w.tile,
            &w.features,
        )? {
            Ok(c) => c,
            Err(r) => {
                tracing::trace!(rejection = ?r, keypoints = w.features.len(), "window: no fix");
                *best_rejection = Some(r);
                return Ok(WindowOutcome::NoFix);
            }
        };
        let (u, v) = c.map_pixel(principal);
        let off = (u - centre.0).hypot(v - centre.1);
        // The prior is the camera's x, y and the fix the ground point under its optical axis:
        // a tilt of the camera moves one from the other by the altitude's lever arm.
        let lever = altitude * self.config.predicted_window_tilt_deg.to_radians().tan();
        let accept = margin + lever / self.tiles.gsd_m();
        if off.is_nan() || off > accept {
            tracing::debug!(
                off_m = off * self.tiles.gsd_m(),
                "window: fix beyond the margin, tiles decide"
            );
            return Ok(WindowOutcome::BeyondMargin);
        }
        Ok(WindowOutcome::Fix(c))
    }

    /// Best accepted candidate over `tiles` × `angles` (views are detected once per angle and
    /// kept in `views` for reuse by a later pass), with the early stop. `rank`: a search with
    /// no prior position, whose pairs are shortlisted by [`crate::shortlist`] to this many.
    #[allow(clippy::too_many_arguments)]
    fn search(
        &self,
        store: &TileStore,
        frame: &GrayImage,
        ctx: &ViewContext<'_>,
        tiles: &[usize],
        angles: &[f64],
        scale: f64,
        expected: f64,
        rank: Option<usize>,
        views: &mut Vec<(f64, QueryView)>,
        searched: &mut usize,
        best_rejection: &mut Option<Rejection>,
    ) -> Result<Option<Candidate>> {
        let view_ids = angles
            .iter()
            .map(|&a| self.view_at(frame, ctx, a, scale, views))
            .collect::<Result<Vec<usize>>>()?;
        let input = SearchInput {
            tiles: &self.tiles,
            store,
            ctx: self.match_context(expected),
            parallel: self.config.parallel,
            early_stop_inliers: self.config.early_stop_inliers,
        };
        // Nearest tiles first, every angle of a tile before the next tile.
        let mut jobs: Vec<(usize, usize)> = tiles
            .iter()
            .flat_map(|&t| view_ids.iter().map(move |&v| (v, t)))
            .collect();
        let view_refs: Vec<&QueryView> = views.iter().map(|(_, v)| v).collect();
        if let Some(keep) = rank.filter(|&k| k > 0 && jobs.len() > k) {
            let t = Instant::now();
            if self.shortlist.get().is_none() {
                let built = TileIndex::build(store, &self.tiles, &self.config.shortlist)?;
                let _ = self.shortlist.set(built);
            }
            if let Some(index) = self.shortlist.get().and_then(Option::as_ref) {
                let vlads: Vec<(usize, Vec<f32>)> = view_ids
                    .iter()
                    .map(|&v| (v, index.vlad(&view_refs[v].features)))
                    .collect();
                // The footprint's window: the smallest of the views' images (the unrotated
                // one, when the sweep has it).
                let window = view_ids
                    .iter()
                    .map(|&v| {
                        let im = &view_refs[v].normalised.image;
                        (im.width() as f32, im.height() as f32)
                    })
                    .min_by(|a, b| (a.0 * a.1).total_cmp(&(b.0 * b.1)))
                    .unwrap_or((1.0, 1.0));
                let pairs = jobs.len();
                jobs = index.rank(store, &self.tiles, &vlads, window, tiles, keep)?;
                tracing::debug!(
                    pairs,
                    kept = jobs.len(),
                    ms = t.elapsed().as_secs_f64() * 1e3,
                    "whole-map search shortlisted"
                );
            }
        }
        let result = search::run(&input, &view_refs, &jobs)?;
        if rank.is_some()
            && let Some(b) = &result.best
        {
            // Where the ranking had the pair that won (how deep the shortlist must reach).
            let at = jobs.iter().position(|&j| j == (b.view, b.tile));
            tracing::debug!(rank = ?at, inliers = b.inliers.len(), "whole-map search: best pair");
        }
        *searched += result.evaluated;
        if let Some(r) = result.best_rejection
            && result.best.is_none()
        {
            *best_rejection = Some(r);
        }
        Ok(result.best)
    }

    #[allow(clippy::too_many_arguments)]
    fn finish(
        &mut self,
        frame: &GrayImage,
        ctx: &ViewContext<'_>,
        best: &Candidate,
        altitude: f64,
        searched: usize,
        global: bool,
        start: Instant,
    ) -> Fix {
        let h = best.h_map_from_frame;
        let (u, v) = best.map_pixel((self.camera.cx, self.camera.cy));
        let (x, y) = self.tiles.pixel_to_world(u, v);
        let ssim = self.ssim_of(frame, ctx, &h, best.scale).unwrap_or(0.0);
        let match_score = if best.inliers.is_empty() {
            0.0
        } else {
            best.inliers
                .iter()
                .map(|&i| best.matches.scores.get(i).copied().unwrap_or(0.0) as f64)
                .sum::<f64>()
                / best.inliers.len() as f64
        };
        let confidence = self.config.confidence.confidence(ssim, match_score);
        let next_radius = search_radius(confidence);
        let tile = self.tiles.tiles()[best.tile].index;
        self.state = SearchState {
            last_tile: Some(best.tile),
            last_position: Some((x, y)),
            radius: next_radius,
            heading: Some(best.heading),
        };
        let fix = Fix {
            position: [x, y, self.tiles.ground_height(x, y) + altitude],
            confidence,
            ssim,
            match_score,
            tile,
            inliers: best.inliers.len(),
            searched_tiles: searched,
            global,
            homography: h,
            heading: best.heading,
            scale: best.scale,
            next_radius,
            ms: start.elapsed().as_secs_f64() * 1e3,
        };
        tracing::debug!(?fix.position, fix.heading, fix.confidence, fix.tile, fix.inliers, fix.searched_tiles, "fix");
        fix
    }

    /// SSIM between the map under the warped frame and the warped frame (area-filtered to map
    /// pixels), over the map pixels the frame covers.
    fn ssim_of(
        &self,
        frame: &GrayImage,
        ctx: &ViewContext<'_>,
        h: &Matrix3<f64>,
        scale: f64,
    ) -> Option<f64> {
        let (fw, fh) = (frame.width() as f64, frame.height() as f64);
        let corners: Vec<(f64, f64)> = [
            (0.0, 0.0),
            (fw - 1.0, 0.0),
            (fw - 1.0, fh - 1.0),
            (0.0, fh - 1.0),
        ]
        .iter()
        .map(|&(x, y)| {
            let q = h * Point2::new(x, y).to_homogeneous();
            (q.x / q.z, q.y / q.z)
        })
        .collect();
        let map = self.tiles.map();
        let (mw, mh) = (map.width() as f64, map.height() as f64);
        let lo = |f: fn(&(f64, f64)) -> f64| corners.iter().map(f).fold(f64::INFINITY, f64::min);
        let hi =
            |f: fn(&(f64, f64)) -> f64| corners.iter().map(f).fold(f64::NEG_INFINITY, f64::max);
        let x0 = lo(|c| c.0).floor().max(0.0);
        let y0 = lo(|c| c.1).floor().max(0.0);
        let x1 = hi(|c| c.0).ceil().min(mw - 1.0);
        let y1 = hi(|c| c.1).ceil().min(mh - 1.0);
        if !(x1 > x0 && y1 > y0) {
            return None;
        }
        let (w, hgt) = ((x1 - x0) as usize + 1, (y1 - y0) as usize + 1);
        let k = (1.0 / scale).ceil().max(1.0) as usize;
        let origin = (x0 as u32, y0 as u32);
        let (warped, mut mask) = warp_into_map_lens(frame, ctx.lens, h, origin, (w, hgt), k)?;
        if let Some(c) = ctx.coverage {
            // Only the map pixels the virtual frame's sources cover.
            let (covered, _) = warp_into_map_lens(&c.image(), None, h, origin, (w, hgt), k)?;
            for (m, c) in mask.iter_mut().zip(&covered) {
                *m &= *c > 254.5;
            }
        }
        let region: Vec<f32> = (0..hgt)
            .flat_map(|r| (0..w).map(move |c| (c, r)))
            .map(|(c, r)| map.get_pixel(x0 as u32 + c as u32, y0 as u32 + r as u32)[0] as f32)
            .collect();
        ssim_masked(&region, &warped, w, hgt, Some(&mask), &self.config.ssim)
    }

    fn fail(
        &mut self,
        reason: FailureReason,
        searched: usize,
        global: bool,
        start: Instant,
    ) -> Outcome {
        // w = 0: the widest radius next time; the last tile stays as the search centre.
        let next_radius = search_radius(0.0);
        self.state.radius = next_radius;
        self.state.heading = None;
        tracing::debug!(?reason, searched, "no fix");
        Outcome::Failed(Failure {
            reason,
            searched_tiles: searched,
            global,
            next_radius,
            ms: start.elapsed().as_secs_f64() * 1e3,
        })
    }
}

/// What [`AbsLocalizer::localize_view`] localises: a camera frame (`zoom` 1, every pixel
/// valid) or a virtual frame rendered with the focal lengths divided by `zoom`.
#[derive(Debug, Clone, Copy)]
pub struct FrameView<'a> {
    /// The camera's size.
    pub image: &'a GrayImage,
    /// Altimeter reading of the frame whose ground point is sought, metres.
    pub altitude: f64,
    /// Ground per side relative to a camera frame (≥ 1).
    pub zoom: f64,
    /// Row-major validity of the pixels (a virtual frame's coverage); `None`: all valid.
    pub valid: Option<&'a [bool]>,
}

impl<'a> FrameView<'a> {
    /// A camera frame.
    pub fn frame(image: &'a GrayImage, altitude: f64) -> Self {
        Self {
            image,
            altitude,
            zoom: 1.0,
            valid: None,
        }
    }
}

/// The best placement of a virtual frame: its view and where that sits in the map.
struct Placement {
    peak: crate::correlate::Peak,
    view: crate::warp::NormalisedFrame,
    /// Map pixel of the correlation window's corner.
    window: [i64; 2],
    valid: Vec<bool>,
}

/// How the search reads the frame: its lens (none for a virtual frame, an ideal pinhole)
/// and, for a virtual frame, the pixels it covers.
struct ViewContext<'a> {
    lens: Option<Lens>,
    coverage: Option<&'a Coverage>,
}

/// A validity mask eroded by the keypoint border margin.
struct Coverage {
    width: usize,
    height: usize,
    inner: Vec<bool>,
}

impl Coverage {
    /// `valid` eroded by a square of `margin` pixels each way (two 1-D passes).
    fn eroded(valid: &[bool], width: usize, height: usize, margin: usize) -> Self {
        let run = |get: &dyn Fn(usize) -> bool, n: usize| -> Vec<bool> {
            // Out[i] = all of get(i − m ..= i + m) inside [0, n).
            let mut prefix = vec![0usize; n + 1];
            for i in 0..n {
                prefix[i + 1] = prefix[i] + usize::from(!get(i));
            }
            (0..n)
                .map(|i| {
                    let (a, b) = (i.saturating_sub(margin), (i + margin + 1).min(n));
                    i >= margin && i + margin < n && prefix[b] == prefix[a]
                })
                .collect()
        };
        let mut rows = vec![false; width * height];
        for y in 0..height {
            let r = run(&|x| valid[y * width + x], width);
            rows[y * width..(y + 1) * width].copy_from_slice(&r);
        }
        let mut inner = vec![false; width * height];
        for x in 0..width {
            let c = run(&|y| rows[y * width + x], height);
            for (y, v) in c.into_iter().enumerate() {
                inner[y * width + x] = v;
            }
        }
        Self {
            width,
            height,
            inner,
        }
    }

    /// Whether frame pixel `(x, y)` (nearest) is well inside the covered area.
    fn covers(&self, x: f64, y: f64) -> bool {
        let (u, v) = (x.round(), y.round());
        u >= 0.0
            && v >= 0.0
            && (u as usize) < self.width
            && (v as usize) < self.height
            && self.inner[v as usize * self.width + u as usize]
    }

    /// The eroded mask as an image (255 covered, 0 not), for warping with the frame.
    fn image(&self) -> GrayImage {
        GrayImage::from_fn(self.width as u32, self.height as u32, |u, v| {
            image::Luma([if self.inner[v as usize * self.width + u as usize] {
                255
            } else {
                0
            }])
        })
    }
}

/// `n` headings evenly spread over the full turn.
fn sweep(n: usize) -> Vec<f64> {
    (0..n)
        .map(|i| i as f64 * std::f64::consts::TAU / n as f64)
        .collect()
}

/// Standard deviation of the grey levels.
fn grey_std(img: &GrayImage) -> f64 {
    let raw = img.as_raw();
    let n = raw.len().max(1) as f64;
    let mean = raw.iter().map(|&p| p as f64).sum::<f64>() / n;
    (raw.iter().map(|&p| (p as f64 - mean).powi(2)).sum::<f64>() / n).sqrt()
}

fn angle_eq(a: f64, b: f64) -> bool {
    let d = (a - b).rem_euclid(std::f64::consts::TAU);
    d < 1e-9 || std::f64::consts::TAU - d < 1e-9
}

/// How much to upsample a map whose frame-to-map scale is `expected` so that it becomes
/// `min_match_scale`: quarter steps, and 1 (none) below 1.5, where the frame is big enough.
pub fn map_upsample_factor(expected: f64, min_match_scale: f64) -> f64 {
    let factor = ((min_match_scale / expected) * 4.0).round() / 4.0;
    if factor.is_finite() && factor >= 1.5 {
        factor
    } else {
        1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn the_nadir_orientation_has_its_heading_for_every_heading() {
        for i in 0..720 {
            let heading = -std::f64::consts::PI + (i as f64 + 0.5) * std::f64::consts::TAU / 720.0;
            let q = nadir_orientation(heading);
            let (s, c) = heading.sin_cos();
            assert!(
                (q * Vector3::x() - Vector3::new(c, -s, 0.0)).norm() < 1e-12,
                "heading {heading}: x axis {:?}",
                q * Vector3::x()
            );
            assert!(
                (q * Vector3::z() + Vector3::z()).norm() < 1e-12,
                "heading {heading}"
            );
            let back = heading_from_rotation(&q.to_rotation_matrix());
            assert!(
                (back - heading).abs() < 1e-12,
                "{heading} came back as {back}"
            );
        }
    }
}
