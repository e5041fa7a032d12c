//! The UAV side of a dataset folder read at once: `camera.yaml` and the sequence
//! (`uav/images.txt`, with `uav/altimeter.txt` and `uav/gt.txt` when present), under the
//! rules of [`crate::camera_yaml`] and [`crate::sequence`]. What evaluation and the absolute
//! localisation read; a consumer that needs only the frames opens the [`Sequence`].

use std::ops::Deref;
use std::path::{Path, PathBuf};

use jointloc_geometry::PinholeCamera;

use crate::camera_yaml::read_camera_yaml;
use crate::error::{FormatError, Result};
use crate::sequence::Sequence;

/// The camera and the frames of a dataset; derefs to its [`Sequence`] (`frames`,
/// `has_altimeter`, `load_image`, …).
#[derive(Debug, Clone)]
pub struct UavDataset {
    /// The dataset folder.
    pub root: PathBuf,
    pub camera: PinholeCamera,
    /// Frame rate stated in `camera.yaml`, Hz (0 when absent).
    pub fps: f64,
    pub sequence: Sequence,
}

impl UavDataset {
    /// Reads `dir/camera.yaml` and the sequence of `dir`.
    pub fn open(dir: &Path) -> Result<Self> {
        if !dir.is_dir() {
            return Err(FormatError::io(
                dir,
                std::io::Error::new(
                    std::io::ErrorKind::NotFound,
                    "dataset folder does not exist",
                ),
            ));
        }
        let camera = read_camera_yaml(&dir.join("camera.yaml"))?;
        let sequence = Sequence::open(dir)?;
        Ok(Self {
            root: dir.to_path_buf(),
            camera: camera.camera,
            fps: camera.fps,
            sequence,
        })
    }

    /// `camera.yaml` of this dataset.
    pub fn camera_path(&self) -> PathBuf {
        self.root.join("camera.yaml")
    }

    /// [`Sequence::load_image_sized`] at the camera's size.
    pub fn load_frame(&self, i: usize) -> Result<image::GrayImage> {
        self.sequence
            .load_image_sized(i, self.camera.width, self.camera.height)
    }
}

impl Deref for UavDataset {
    type Target = Sequence;

    fn deref(&self) -> &Sequence {
        &self.sequence
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera_yaml::write_camera_yaml;
    use crate::sequence::{FrameRecord, write_sequence};

    #[test]
    fn bundles_camera_and_sequence() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let cam = PinholeCamera::ideal(4.0, 4, 3);
        write_camera_yaml(&d.join("camera.yaml"), &cam, 5.0).unwrap();
        std::fs::create_dir_all(d.join("uav")).unwrap();
        image::GrayImage::new(4, 3)
            .save(d.join("uav/a.png"))
            .unwrap();
        image::GrayImage::new(5, 3)
            .save(d.join("uav/b.png"))
            .unwrap();
        let frames: Vec<FrameRecord> = ["a.png", "b.png"]
            .iter()
            .enumerate()
            .map(|(i, name)| FrameRecord {
                timestamp: i as f64,
                image: name.to_string(),
                altitude: Some(10.0),
                ground_truth: None,
            })
            .collect();
        write_sequence(&d.join("uav"), &frames).unwrap();
        let ds = UavDataset::open(d).unwrap();
        assert_eq!((ds.camera, ds.fps), (cam, 5.0));
        assert_eq!(ds.frames.len(), 2);
        assert!(ds.has_altimeter && !ds.has_ground_truth);
        assert!(ds.load_frame(0).is_ok());
        let e = ds.load_frame(1).unwrap_err().to_string();
        assert!(e.contains("b.png") && e.contains("5x3"), "{e}");
        // Each file's errors name it.
        std::fs::remove_file(d.join("camera.yaml")).unwrap();
        let e = UavDataset::open(d).unwrap_err().to_string();
        assert!(e.contains("camera.yaml"), "{e}");
        let e = UavDataset::open(&d.join("missing"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("missing"), "{e}");
    }
}
