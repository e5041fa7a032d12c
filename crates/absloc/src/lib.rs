//! Absolute localisation (paper §III-B): the UAV frame, resampled to the map's GSD and turned
//! north-up, is matched against satellite-map tiles; a homography maps the image centre into
//! the map; the confidence `w = SSIM × mean matching score` sets the next search radius
//! `r = ⌈10^(1−w)⌉`.
//!
//! - [`tiles`]: the map, its georeference and tile neighbourhoods;
//! - [`cache`], [`tile_store`]: tile features on disk, keyed by detector, weights, config and
//!   map, read tile by tile within a memory budget;
//! - [`warp`]: scale/rotation normalisation and homography warps (area-filtered);
//! - [`candidate`]: one view against one tile (match, homography, checks);
//! - [`ssim`], [`confidence`]: the confidence and the area prediction;
//! - [`localizer`], [`search`]: the coarse-to-fine search ([`AbsLocalizer`]); `window`: the
//!   map's keypoints around the predicted footprint, matched before any tile in flight;
//! - [`shortlist`]: VLAD ranking of the pairs of a whole-map search;
//! - [`mosaic`]: a virtual frame wider than one frame, from recent frames and their poses;
//! - [`registry`]: matchers by name (`xfeat-lighterglue`, `orb`, ...);
//! - [`orb`]: ORB behind the same traits (binary descriptors as 0/1 floats);
//!
//! The evaluation protocols that need ground truth (true homographies, the matcher benchmark
//! of Table V) are in `jointloc_bench`, off the flight path.

pub mod cache;
pub mod candidate;
pub mod coarse_places;
pub mod confidence;
pub mod correlate;
pub mod error;
pub mod localizer;
pub mod mosaic;
pub mod orb;
pub mod pipeline;
pub mod registry;
pub mod relight;
pub mod search;
pub mod shortlist;
pub mod ssim;
pub mod tile_store;
pub mod tiles;
pub mod warp;
pub mod whole_map;
mod window;

pub use cache::CacheStatus;
pub use confidence::{ConfidenceMode, search_radius};
pub use error::{AbslocError, Result};
pub use localizer::{
    AbsLocConfig, AbsLocalizer, Failure, FailureReason, Fix, FrameView, Outcome, Prior,
    heading_from_rotation,
};
pub use pipeline::FeaturePipeline;
pub use tile_store::TileStore;
pub use tiles::{Ground, MapTile, MapTiles};
