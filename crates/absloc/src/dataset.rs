//! The UAV side of a dataset folder (DESIGN §3): `uav/images.txt`, `camera.yaml`, and when
//! present `uav/altimeter.txt` and `uav/gt.txt`, joined by timestamp (within 1 ms).
//!
//! A missing altimeter file is not an error here (the caller decides: absolute localisation
//! needs it); a non-finite reading is kept as NaN so that frame fails alone.

use std::path::{Path, PathBuf};

use jointloc_geometry::trajectory::{Trajectory, TumOptions};
use jointloc_geometry::{CameraToWorld, PinholeCamera};
use jointloc_sim::camera_yaml::read_camera_yaml;

use crate::error::{AbslocError, Result, io_err};

/// One frame.
#[derive(Debug, Clone, PartialEq)]
pub struct UavFrame {
    pub timestamp: f64,
    /// The image file.
    pub path: PathBuf,
    /// Altimeter reading (NaN when the file has a non-finite value; None when absent).
    pub altitude: Option<f64>,
    /// Ground-truth camera-to-world pose, when `gt.txt` has this timestamp.
    pub ground_truth: Option<CameraToWorld>,
}

/// The frames of a dataset and its camera.
#[derive(Debug, Clone)]
pub struct UavDataset {
    pub root: PathBuf,
    pub camera: PinholeCamera,
    pub frames: Vec<UavFrame>,
    /// Whether `uav/altimeter.txt` exists.
    pub has_altimeter: bool,
    /// Whether `uav/gt.txt` exists.
    pub has_ground_truth: bool,
}

const TOLERANCE_S: f64 = 1e-3;

fn parse_err(path: &Path, line: usize, message: impl Into<String>) -> AbslocError {
    AbslocError::Parse {
        path: path.to_path_buf(),
        line,
        message: message.into(),
    }
}

/// `(line, fields)` of the non-comment lines.
fn records(text: &str) -> impl Iterator<Item = (usize, Vec<&str>)> {
    text.lines().enumerate().filter_map(|(i, l)| {
        let l = l.trim();
        (!l.is_empty() && !l.starts_with('#')).then(|| (i + 1, l.split_whitespace().collect()))
    })
}

impl UavDataset {
    /// Reads the dataset in `dir`.
    pub fn open(dir: &Path) -> Result<Self> {
        if !dir.is_dir() {
            return Err(AbslocError::Io {
                path: dir.to_path_buf(),
                source: std::io::Error::new(
                    std::io::ErrorKind::NotFound,
                    "dataset folder does not exist",
                ),
            });
        }
        let camera = read_camera_yaml(&dir.join("camera.yaml"))?.camera;
        let uav = dir.join("uav");
        let list = uav.join("images.txt");
        let text = std::fs::read_to_string(&list).map_err(io_err(&list))?;
        let mut frames: Vec<UavFrame> = Vec::new();
        for (line, f) in records(&text) {
            if f.len() < 2 {
                return Err(parse_err(&list, line, "expected `timestamp filename`"));
            }
            let timestamp: f64 = f[0]
                .parse()
                .ok()
                .filter(|t: &f64| t.is_finite())
                .ok_or_else(|| parse_err(&list, line, format!("bad timestamp `{}`", f[0])))?;
            if frames.last().is_some_and(|p| timestamp <= p.timestamp) {
                return Err(parse_err(&list, line, "timestamps must increase"));
            }
            frames.push(UavFrame {
                timestamp,
                path: uav.join(f[1]),
                altitude: None,
                ground_truth: None,
            });
        }
        if frames.is_empty() {
            return Err(parse_err(&list, 0, "no frames"));
        }
        let alt_path = uav.join("altimeter.txt");
        let has_altimeter = alt_path.is_file();
        if has_altimeter {
            let text = std::fs::read_to_string(&alt_path).map_err(io_err(&alt_path))?;
            let mut readings = Vec::new();
            for (line, f) in records(&text) {
                if f.len() < 2 {
                    return Err(parse_err(
                        &alt_path,
                        line,
                        "expected `timestamp altitude_m`",
                    ));
                }
                let t: f64 = f[0]
                    .parse()
                    .map_err(|_| parse_err(&alt_path, line, format!("bad timestamp `{}`", f[0])))?;
                // "nan" parses to NaN on purpose: that frame fails, the others go on.
                let a: f64 = f[1].parse().map_err(|_| {
                    parse_err(
                        &alt_path,
                        line,
                        format!("altitude `{}` is not a number", f[1]),
                    )
                })?;
                readings.push((t, a));
            }
            join(&mut frames, &readings, |fr, a| fr.altitude = Some(a));
        }
        let gt_path = uav.join("gt.txt");
        let has_ground_truth = gt_path.is_file();
        if has_ground_truth {
            let gt = Trajectory::read_tum(&gt_path, &TumOptions::default())?;
            let pairs: Vec<(f64, CameraToWorld)> = gt
                .timestamps
                .iter()
                .copied()
                .zip(gt.poses.iter().copied())
                .collect();
            join(&mut frames, &pairs, |fr, p| fr.ground_truth = Some(p));
        }
        Ok(Self {
            root: dir.to_path_buf(),
            camera,
            frames,
            has_altimeter,
            has_ground_truth,
        })
    }
}

/// Sets `set(frame, value)` for every frame with a value at its timestamp (both sorted).
fn join<T: Copy>(frames: &mut [UavFrame], values: &[(f64, T)], set: impl Fn(&mut UavFrame, T)) {
    let mut sorted: Vec<(f64, T)> = values.to_vec();
    sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
    for fr in frames.iter_mut() {
        let i = sorted.partition_point(|v| v.0 < fr.timestamp - TOLERANCE_S);
        if let Some(&(t, v)) = sorted.get(i)
            && (t - fr.timestamp).abs() <= TOLERANCE_S
        {
            set(fr, v);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, text: &str) {
        let p = dir.join(name);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, text).unwrap();
    }

    #[test]
    fn joins_altimeter_and_ground_truth_by_timestamp() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let cam = PinholeCamera::ideal(500.0, 500, 500);
        jointloc_sim::camera_yaml::write_camera_yaml(&d.join("camera.yaml"), &cam, 5.0).unwrap();
        write(
            d,
            "uav/images.txt",
            "# t f\n0.000000 images/a.png\n0.200000 images/b.png\n0.400000 images/c.png\n",
        );
        write(d, "uav/altimeter.txt", "0.000000 10.5\n0.2000004 nan\n");
        write(d, "uav/gt.txt", "0.4 1 2 3 0 0 0 1\n");
        let ds = UavDataset::open(d).unwrap();
        assert_eq!(ds.camera, cam);
        assert_eq!(ds.frames.len(), 3);
        assert_eq!(ds.frames[0].altitude, Some(10.5));
        assert!(ds.frames[1].altitude.unwrap().is_nan());
        assert_eq!(ds.frames[2].altitude, None);
        assert!(ds.frames[0].ground_truth.is_none());
        let p = ds.frames[2].ground_truth.unwrap();
        assert!((p.0.translation.vector.y - 2.0).abs() < 1e-12);
        assert!(ds.frames[1].path.ends_with("uav/images/b.png"));
        // Errors name the file.
        write(d, "uav/altimeter.txt", "0.0 ten\n");
        let e = UavDataset::open(d).unwrap_err().to_string();
        assert!(e.contains("altimeter.txt:1"), "{e}");
        std::fs::remove_file(d.join("uav/altimeter.txt")).unwrap();
        let ds = UavDataset::open(d).unwrap();
        assert!(!ds.has_altimeter && ds.frames.iter().all(|f| f.altitude.is_none()));
        std::fs::remove_file(d.join("camera.yaml")).unwrap();
        assert!(UavDataset::open(d).is_err());
        assert!(UavDataset::open(&d.join("missing")).is_err());
    }
}
