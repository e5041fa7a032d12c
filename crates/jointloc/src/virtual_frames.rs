//! Fixes from more than one frame (issue #29 item 1): when a frame is too small on the map
//! (at 10 m a 500-pixel frame spans 40 pixels of a 25 cm map), the frames of the last
//! [`MosaicConfig::span_m`] of track, placed by their SLAM poses, are rendered into a virtual
//! frame of the newest one that covers `zoom` times more ground per side
//! ([`jointloc_absloc::mosaic`]); the localiser registers it by correlation and its fix is,
//! like any fix, the ground point under the newest frame's optical axis, tied to that frame's
//! keyframe. One factor per fix, as for single frames: the mosaic's internal geometry comes
//! from the same SLAM poses the local BA refines, so a separate mosaic-to-map similarity
//! would count that geometry twice.

use std::collections::VecDeque;
use std::sync::Arc;

use image::GrayImage;
use jointloc_absloc::mosaic::{GroundPlane, Mosaic, MosaicSource, Thumbnail, render};
use jointloc_geometry::{CameraToWorld, PinholeCamera};
use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

/// When and how virtual frames replace single frames.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MosaicConfig {
    /// A frame that spans fewer map pixels than this across (its width × altitude / (focal
    /// length × map GSD)) is localised through a virtual frame; 0: never. 60: a 500-pixel
    /// frame below 15 m over a 25 cm map; the 80 pixels of a 10 m frame over a 12.5 cm map
    /// still go alone, upsampled (`docs/absloc.md`).
    pub below_frame_px: f64,
    /// The virtual frame spans about this many map pixels across (zoom = this / the frame's).
    pub view_px: f64,
    /// Largest zoom.
    pub max_zoom: f64,
    /// Track length whose frames go into the virtual frame, metres.
    pub span_m: f64,
    /// Frames kept for it are at least this share of a frame's footprint apart.
    pub spacing: f64,
    /// Share of the virtual frame that must be covered.
    pub min_coverage: f64,
    /// Keep the terrain correction of the fixes' bias ([`crate::terrain_shift`]) while
    /// virtual frames are in use. Off: on three 10 m flights over a 25 cm map with a 1 m DTM
    /// it moved the output 0.1–0.5 m the wrong way (`docs/jointloc.md`).
    pub terrain_correction: bool,
}

impl Default for MosaicConfig {
    fn default() -> Self {
        Self {
            below_frame_px: 60.0,
            view_px: 200.0,
            max_zoom: 8.0,
            span_m: 40.0,
            spacing: 0.15,
            min_coverage: 0.08,
            terrain_correction: false,
        }
    }
}

/// A frame kept for the virtual frames: its SLAM pose when it was tracked and its thumbnail.
#[derive(Debug)]
struct Kept {
    pose: CameraToWorld,
    /// Shared with the jobs handed to the absolute-localisation thread.
    thumbnail: Arc<Thumbnail>,
    /// Track length from the first kept frame, SLAM units.
    track: f64,
}

/// The recent frames of the current SLAM map, and the rule that decides when to use them.
#[derive(Debug)]
pub(crate) struct VirtualFrames {
    config: MosaicConfig,
    camera: PinholeCamera,
    map_gsd_m: f64,
    kept: VecDeque<Kept>,
    /// Track length so far and the last tracked centre.
    track: f64,
    last_centre: Option<Point3<f64>>,
}

impl VirtualFrames {
    pub(crate) fn new(config: MosaicConfig, camera: PinholeCamera, map_gsd_m: f64) -> Self {
        Self {
            config,
            camera,
            map_gsd_m,
            kept: VecDeque::new(),
            track: 0.0,
            last_centre: None,
        }
    }

    /// The zoom of the virtual frame at `altitude`, `None` when a single frame is matched.
    pub(crate) fn zoom(&self, altitude: f64) -> Option<f64> {
        let f = 0.5 * (self.camera.fx + self.camera.fy);
        let frame_px = self.camera.width as f64 * altitude / (f * self.map_gsd_m);
        (self.config.below_frame_px > 0.0
            && self.map_gsd_m > 0.0
            && frame_px.is_finite()
            && frame_px < self.config.below_frame_px)
            .then(|| (self.config.view_px / frame_px.max(1.0)).clamp(1.0, self.config.max_zoom))
    }

    /// Records a processed frame: kept when virtual frames are in use at its altitude and it
    /// is far enough from the last kept one; `pose` `None` (not tracked) forgets them all.
    /// `scale`: metres per SLAM unit.
    pub(crate) fn push(
        &mut self,
        image: &GrayImage,
        pose: Option<CameraToWorld>,
        altitude: Option<f64>,
        scale: f64,
    ) {
        let Some(pose) = pose else {
            self.clear();
            return;
        };
        let c = pose.centre();
        if let Some(last) = self.last_centre {
            self.track += (c - last).norm();
        }
        self.last_centre = Some(c);
        let Some((alt, zoom)) = altitude.and_then(|a| self.zoom(a).map(|z| (a, z))) else {
            return;
        };
        let spacing = self.config.spacing * alt * self.camera.width as f64
            / (0.5 * (self.camera.fx + self.camera.fy));
        if self
            .kept
            .back()
            .is_some_and(|k| (self.track - k.track) * scale < spacing)
        {
            return;
        }
        let factor = (zoom.floor() as u32).max(1);
        self.kept.push_back(Kept {
            pose,
            thumbnail: Arc::new(Thumbnail::new(image, factor)),
            track: self.track,
        });
        let span = self.config.span_m / scale.max(1e-9);
        while self
            .kept
            .front()
            .is_some_and(|k| self.track - k.track > span)
        {
            self.kept.pop_front();
        }
    }

    /// Whether frames are being kept for virtual frames (the altitude calls for them).
    pub(crate) fn in_use(&self) -> bool {
        !self.kept.is_empty()
    }

    /// Forgets the kept frames (tracking lost, a new map).
    pub(crate) fn clear(&mut self) {
        self.kept.clear();
        self.last_centre = None;
    }

    /// The world's up in the SLAM frame: from the alignment when there is one, else the mean
    /// of the kept frames' backward optical axes (a nadir camera's up).
    pub(crate) fn up(&self, aligned: Option<Vector3<f64>>) -> Option<Vector3<f64>> {
        aligned.or_else(|| {
            let sum: Vector3<f64> = self
                .kept
                .iter()
                .map(|k| -(k.pose.rotation_matrix() * Vector3::z()))
                .sum();
            sum.try_normalize(1e-9)
        })
    }

    /// What it takes to render the virtual frame of the newest frame (`pose`), over the
    /// plane normal to `up` (the SLAM frame's) `altitude` metres below the camera at `scale`
    /// metres per SLAM unit; `None` with fewer than two frames kept. (The plane through the
    /// median of the nearby map points instead: fewer fixes found and no better, measured on
    /// two flights.)
    pub(crate) fn job(
        &self,
        pose: &CameraToWorld,
        altitude: f64,
        zoom: f64,
        scale: f64,
        up: Vector3<f64>,
    ) -> Option<MosaicJob> {
        if self.kept.len() < 2 {
            return None;
        }
        let offset = up.dot(&(pose.centre() - up * (altitude / scale.max(1e-9))).coords);
        Some(MosaicJob {
            camera: self.camera,
            pose: *pose,
            plane: GroundPlane { normal: up, offset },
            zoom,
            sources: self
                .kept
                .iter()
                .map(|k| (k.pose, Arc::clone(&k.thumbnail)))
                .collect(),
            min_coverage: self.config.min_coverage,
        })
    }
}

/// A virtual frame to render: on the tracking thread in the sequential mode, on the
/// absolute-localisation thread in the threaded one (70–120 ms that tracking need not wait).
#[derive(Debug, Clone)]
pub(crate) struct MosaicJob {
    camera: PinholeCamera,
    pose: CameraToWorld,
    plane: GroundPlane,
    zoom: f64,
    sources: Vec<(CameraToWorld, Arc<Thumbnail>)>,
    min_coverage: f64,
}

impl MosaicJob {
    /// The virtual frame; `None` when it covers less than the configured share.
    pub(crate) fn render(&self) -> Option<Mosaic> {
        let sources: Vec<MosaicSource<'_>> = self
            .sources
            .iter()
            .map(|(pose, t)| MosaicSource {
                pose: *pose,
                thumbnail: t,
            })
            .collect();
        let mosaic = render(
            &self.camera,
            &self.pose,
            &self.plane,
            self.zoom,
            &sources,
            4.0,
        );
        (mosaic.coverage >= self.min_coverage).then_some(mosaic)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn virtual_frames_only_where_a_frame_is_small_on_the_map() {
        let camera = PinholeCamera::ideal(500.0, 500, 500);
        let hirise = VirtualFrames::new(MosaicConfig::default(), camera, 0.25);
        // 10 m: 40 map pixels → zoom 5; 20 m: 80 pixels → single frames.
        assert_eq!(hirise.zoom(10.0), Some(5.0));
        assert_eq!(hirise.zoom(20.0), None);
        // 5 m: 20 pixels → capped at 8.
        assert_eq!(hirise.zoom(5.0), Some(8.0));
        // A 12.5 cm map at 10 m: 80 pixels, single frames as before.
        assert_eq!(
            VirtualFrames::new(MosaicConfig::default(), camera, 0.125).zoom(10.0),
            None
        );
        let off = MosaicConfig {
            below_frame_px: 0.0,
            ..Default::default()
        };
        assert_eq!(VirtualFrames::new(off, camera, 0.25).zoom(10.0), None);
    }
}
