//! A tracked frame: its ORB features in undistorted pixels, the map points its keypoints are
//! matched to, its pose, and the grey-level entropy the keyframe decision uses.
//!
//! Keypoints are rectified on extraction ([`Undistorter`]): the tracker, the triangulation
//! and every bundle adjustment work in the pixels of a distortion-free pinhole with the
//! camera's focal lengths. With a lens model that pinhole's image rectangle is the bounding
//! box of the undistorted image (ORB-SLAM2's `mnMinX..mnMaxY`), so a fisheye's periphery,
//! whose undistorted keypoints land far outside the original rectangle, stays inside the
//! feature grid and the tracker's `contains` checks. A fisheye's rays reach 90° and beyond;
//! keypoints further than a set angle off axis are dropped (`tan θ` grows without bound).

use jointloc_features::orb::{FeatureGrid, GrayImageView, OrbFeatures};
use jointloc_geometry::{PinholeCamera, WorldToCamera};
use nalgebra::{Matrix2, Point2, Point3, Vector3};

use crate::map::{KeyFrameId, MapPointId};

/// Side of the cells of a frame's [`FeatureGrid`], pixels (ORB-SLAM2 uses ~10 px cells).
pub const GRID_CELL_PX: f64 = 10.0;

/// Default of `SystemConfig::max_off_axis_deg`.
pub const DEFAULT_MAX_OFF_AXIS_DEG: f64 = 70.0;

/// Image pixels → the tracker's pixels: the camera's lens model undone, into a
/// distortion-free pinhole (`ideal`) whose image covers the undistorted image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Undistorter {
    /// The real camera (with its lens model).
    pub camera: PinholeCamera,
    /// The tracker's camera: no distortion, the same focal lengths; for a camera with a lens
    /// model the principal point and size are those of the undistorted image's bounding box
    /// (up to `max_off_axis`); otherwise the camera itself.
    pub ideal: PinholeCamera,
    /// `tan` of the largest off-axis angle kept.
    max_tan: f64,
}

impl Undistorter {
    /// The rectification of `camera`, keeping keypoints up to `max_off_axis_deg` off axis
    /// (clamped to [1°, 89°]; a camera without distortion keeps everything).
    pub fn new(camera: &PinholeCamera, max_off_axis_deg: f64) -> Self {
        let max = max_off_axis_deg.clamp(1.0, 89.0).to_radians();
        if !camera.has_distortion() {
            return Self {
                camera: *camera,
                ideal: camera.without_distortion(),
                max_tan: f64::INFINITY,
            };
        }
        let [u0, v0, u1, v1] = camera.undistorted_bounds(max);
        // Pixel u of the undistorted image is u − u0 − 0.5 in the tracker's: its edge u0 is
        // the left edge −0.5 of the rectangle.
        let (du, dv) = (-u0 - 0.5, -v0 - 0.5);
        let ideal = PinholeCamera {
            cx: camera.cx + du,
            cy: camera.cy + dv,
            width: (u1 - u0).ceil().max(1.0) as u32,
            height: (v1 - v0).ceil().max(1.0) as u32,
            distortion: None,
            ..*camera
        };
        tracing::debug!(
            width = ideal.width,
            height = ideal.height,
            cx = ideal.cx,
            cy = ideal.cy,
            "rectified tracker camera"
        );
        Self {
            camera: *camera,
            ideal,
            max_tan: max.tan(),
        }
    }

    /// How much a keypoint's pixel noise grows on its way into the tracker's pixels at
    /// tracker pixel `uv`: the largest singular value of ∂(tracker px)/∂(image px). 1 without
    /// a lens model; for a 133° Kannala–Brandt fisheye `≈ 1/cos²θ` radially, 8.5 at 70° off
    /// axis, where the octave's σ alone over-states how well a peripheral keypoint is placed.
    pub fn noise_stretch(&self, uv: &Point2<f64>) -> f64 {
        if !self.camera.has_distortion() {
            return 1.0;
        }
        let (fx, fy) = (self.ideal.fx, self.ideal.fy);
        let ray = Point3::new(
            (uv.x - self.ideal.cx) / fx,
            (uv.y - self.ideal.cy) / fy,
            1.0,
        );
        let Some((_, j)) = self.camera.project_with_jacobian(&ray) else {
            return 1.0;
        };
        // ∂(image px)/∂(tracker px) at depth 1: the projection's x, y columns over f.
        let m = Matrix2::new(
            j[(0, 0)] / fx,
            j[(0, 1)] / fy,
            j[(1, 0)] / fx,
            j[(1, 1)] / fy,
        );
        let smallest = m.singular_values().min();
        if smallest.is_finite() && smallest > 0.0 {
            1.0 / smallest
        } else {
            1.0
        }
    }

    /// The tracker's pixel of image pixel `uv`; `None` beyond the largest off-axis angle or
    /// where the lens model cannot be inverted.
    pub fn undistort(&self, uv: &Point2<f64>) -> Option<Point2<f64>> {
        if self.max_tan.is_infinite() {
            return Some(*uv);
        }
        let x = self.camera.unproject(uv)?;
        (x.xy().norm() <= self.max_tan).then(|| {
            Point2::new(
                self.ideal.fx * x.x + self.ideal.cx,
                self.ideal.fy * x.y + self.ideal.cy,
            )
        })
    }
}

/// One image of the sequence as the tracker sees it.
#[derive(Debug, Clone)]
pub struct Frame {
    /// Index in the sequence.
    pub index: usize,
    pub timestamp: f64,
    /// Keypoints in undistorted pixel coordinates (the tracker's camera has no distortion).
    pub features: OrbFeatures,
    pub grid: FeatureGrid,
    /// Map point matched to each keypoint.
    pub points: Vec<Option<MapPointId>>,
    /// Per keypoint: the match was rejected by the last pose optimisation.
    pub outliers: Vec<bool>,
    /// Estimated `T_cw` in the SLAM frame, once tracked.
    pub pose: Option<WorldToCamera>,
    /// Altimeter reading, metres above ground.
    pub altitude: Option<f64>,
    /// Grey-level entropy of the image, bits (see [`image_entropy`]).
    pub entropy: f64,
    /// Keyframe this frame's pose is expressed against for the final trajectory.
    pub reference: Option<KeyFrameId>,
}

impl Frame {
    /// Wraps extracted features; keypoints are undistorted through `camera` when it has a
    /// distortion model, as [`Frame::rectified`] with [`DEFAULT_MAX_OFF_AXIS_DEG`].
    pub fn new(
        index: usize,
        timestamp: f64,
        features: OrbFeatures,
        camera: &PinholeCamera,
        altitude: Option<f64>,
        entropy: f64,
    ) -> Self {
        let undistorter = Undistorter::new(camera, DEFAULT_MAX_OFF_AXIS_DEG);
        Self::rectified(index, timestamp, features, &undistorter, altitude, entropy)
    }

    /// Wraps extracted features; keypoints are moved into the tracker's pixels by
    /// `undistorter` (those it cannot move, beyond its largest off-axis angle, are dropped).
    pub fn rectified(
        index: usize,
        timestamp: f64,
        mut features: OrbFeatures,
        undistorter: &Undistorter,
        altitude: Option<f64>,
        entropy: f64,
    ) -> Self {
        let camera = &undistorter.ideal;
        if undistorter.camera.has_distortion() {
            let mut keep = Vec::with_capacity(features.len());
            for k in &mut features.keypoints {
                let p = undistorter.undistort(&Point2::new(k.x, k.y));
                if let Some(p) = p {
                    k.x = p.x;
                    k.y = p.y;
                }
                keep.push(p.is_some());
            }
            if keep.iter().any(|k| !k) {
                let mut i = 0;
                features.keypoints.retain(|_| {
                    i += 1;
                    keep[i - 1]
                });
                let mut i = 0;
                features.descriptors.retain(|_| {
                    i += 1;
                    keep[i - 1]
                });
            }
        }
        let grid = FeatureGrid::new(
            &features.keypoints,
            camera.width as usize,
            camera.height as usize,
            GRID_CELL_PX,
        );
        let n = features.len();
        Self {
            index,
            timestamp,
            features,
            grid,
            points: vec![None; n],
            outliers: vec![false; n],
            pose: None,
            altitude,
            entropy,
            reference: None,
        }
    }

    /// Keypoint `i` as a pixel.
    pub fn pixel(&self, i: usize) -> Point2<f64> {
        let k = &self.features.keypoints[i];
        Point2::new(k.x, k.y)
    }

    /// Camera centre in the SLAM frame, once tracked.
    pub fn centre(&self) -> Option<Vector3<f64>> {
        self.pose.map(|p| p.inverse().0.translation.vector)
    }

    /// A SLAM-frame point in this camera's frame, once tracked.
    pub fn to_camera(&self, p: &Vector3<f64>) -> Option<Vector3<f64>> {
        self.pose
            .map(|t| t.transform_point(&Point3::from(*p)).coords)
    }

    /// Matched keypoints that are not outliers.
    pub fn n_inliers(&self) -> usize {
        self.points
            .iter()
            .zip(&self.outliers)
            .filter(|(p, o)| p.is_some() && !**o)
            .count()
    }

    /// Forgets matches flagged as outliers.
    pub fn drop_outliers(&mut self) {
        for (p, o) in self.points.iter_mut().zip(self.outliers.iter_mut()) {
            if *o {
                *p = None;
                *o = false;
            }
        }
    }

    /// Forgets every match.
    pub fn clear_matches(&mut self) {
        self.points.iter_mut().for_each(|p| *p = None);
        self.outliers.iter_mut().for_each(|o| *o = false);
    }
}

/// Shannon entropy of the 256-bin grey-level histogram, `H = −Σ p_i log2 p_i` with
/// `p_i = n_i / (W·H)`, in bits: 0 for a constant image, 8 for a uniform histogram.
///
/// The paper's formula (§III-C) is garbled (a double sum with a division by the log); this is
/// the standard image information entropy it names. Its threshold of 0.5 reads naturally as a
/// fraction of the 8-bit maximum, i.e. 4 bits (see `TrackingConfig::min_entropy_bits`).
pub fn image_entropy(image: &GrayImageView<'_>) -> f64 {
    let data = image.data();
    if data.is_empty() {
        return 0.0;
    }
    let mut hist = [0u64; 256];
    for &v in data {
        hist[v as usize] += 1;
    }
    let n = data.len() as f64;
    hist.iter()
        .filter(|&&c| c > 0)
        .map(|&c| {
            let p = c as f64 / n;
            -p * p.log2()
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn entropy_of_known_histograms() {
        let constant = vec![7u8; 100];
        let view = GrayImageView::new(10, 10, &constant).unwrap();
        assert_eq!(image_entropy(&view), 0.0);
        let two: Vec<u8> = (0..100).map(|i| if i % 2 == 0 { 0 } else { 255 }).collect();
        let view = GrayImageView::new(10, 10, &two).unwrap();
        assert!((image_entropy(&view) - 1.0).abs() < 1e-12);
        let all: Vec<u8> = (0..256 * 4).map(|i| (i % 256) as u8).collect();
        let view = GrayImageView::new(32, 32, &all).unwrap();
        assert!((image_entropy(&view) - 8.0).abs() < 1e-12);
    }

    #[test]
    fn noise_stretch_follows_the_lens() {
        use jointloc_geometry::KannalaBrandt;
        let pin = Undistorter::new(&PinholeCamera::ideal(500.0, 500, 500), 70.0);
        assert_eq!(pin.noise_stretch(&Point2::new(3.0, 480.0)), 1.0);
        // A pure equidistant fisheye (θ_d = θ): radially ∂(f tanθ)/∂(f θ) = 1/cos²θ, the
        // largest of the two stretches (tangentially tanθ/θ).
        let fish = PinholeCamera::fisheye(133.0, 500, 500, KannalaBrandt::default()).unwrap();
        let u = Undistorter::new(&fish, 70.0);
        let at = |deg: f64, azimuth: f64| {
            let r = u.ideal.fx * deg.to_radians().tan();
            let p = Point2::new(
                u.ideal.cx + r * azimuth.cos(),
                u.ideal.cy + r * azimuth.sin(),
            );
            u.noise_stretch(&p)
        };
        assert!((at(0.0, 0.0) - 1.0).abs() < 1e-9);
        for deg in [20.0f64, 45.0, 70.0] {
            let expected = 1.0 / deg.to_radians().cos().powi(2);
            for azimuth in [0.0, 0.7, 2.0] {
                let s = at(deg, azimuth);
                assert!(
                    (s - expected).abs() < 1e-6 * expected,
                    "{deg}° {azimuth}: {s}"
                );
            }
        }
    }
}
