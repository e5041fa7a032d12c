//! A tracked frame: its ORB features in undistorted pixels, the map points its keypoints are
//! matched to, its pose, and the grey-level entropy the keyframe decision uses.

use jointloc_features::orb::{FeatureGrid, GrayImageView, OrbFeatures};
use jointloc_geometry::{PinholeCamera, WorldToCamera};
use nalgebra::{Point2, Point3, Vector3};

use crate::map::{KeyFrameId, MapPointId};

/// Side of the cells of a frame's [`FeatureGrid`], pixels (ORB-SLAM2 uses ~10 px cells).
pub const GRID_CELL_PX: f64 = 10.0;

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
    /// distortion model (keypoints that cannot be undistorted keep their position).
    pub fn new(
        index: usize,
        timestamp: f64,
        mut features: OrbFeatures,
        camera: &PinholeCamera,
        altitude: Option<f64>,
        entropy: f64,
    ) -> Self {
        if camera.distortion.is_some_and(|d| !d.is_zero()) {
            for k in &mut features.keypoints {
                if let Some(x) = camera.unproject(&Point2::new(k.x, k.y)) {
                    k.x = camera.fx * x.x + camera.cx;
                    k.y = camera.fy * x.y + camera.cy;
                }
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
}
