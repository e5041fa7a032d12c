//! `camera.yaml`: the UAV camera in ORB-SLAM2's settings layout (OpenCV FileStorage,
//! `%YAML:1.0`, flat `Camera.fx: 500.0` keys), so ORB-SLAM2 and OpenCV read a dataset as it
//! is. The writer and a reader for the `Camera.*` keys (the rest is ignored), so datasets
//! round-trip through [`PinholeCamera`].
//!
//! Values are written with Rust's shortest round-trip formatting, so reading gives back the
//! exact `f64`s used for rendering. Every value read must be a finite number; errors name the
//! file and line.

use std::path::Path;

use jointloc_geometry::{PinholeCamera, RadTan};

use crate::error::{FormatError, Result};
use crate::outputs::{read_text, write_text};

/// ORB extractor settings written alongside the camera (ORB-SLAM2's defaults for a
/// 500 × 500 image).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrbDefaults {
    pub n_features: u32,
    pub scale_factor: f64,
    pub n_levels: u32,
    pub ini_th_fast: u32,
    pub min_th_fast: u32,
}

impl Default for OrbDefaults {
    fn default() -> Self {
        Self {
            n_features: 1000,
            scale_factor: 1.2,
            n_levels: 8,
            ini_th_fast: 20,
            min_th_fast: 7,
        }
    }
}

/// A camera as stored in `camera.yaml`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraYaml {
    pub camera: PinholeCamera,
    /// Frame rate in Hz.
    pub fps: f64,
}

/// `f64` in a form OpenCV reads as a real (always with a `.` or an exponent).
fn real(v: f64) -> String {
    format!("{v:?}")
}

/// The file's text.
pub fn camera_yaml_string(camera: &PinholeCamera, fps: f64, orb: &OrbDefaults) -> String {
    let d = camera.distortion.unwrap_or_default();
    let mut s = String::from("%YAML:1.0\n\n");
    s += "# Camera calibration and distortion parameters (OpenCV): pinhole, radial-tangential.\n";
    s += "# Camera frame x right, y down, z forward; pixel centres at integer coordinates.\n";
    for (key, value) in [
        ("fx", camera.fx),
        ("fy", camera.fy),
        ("cx", camera.cx),
        ("cy", camera.cy),
        ("k1", d.k1),
        ("k2", d.k2),
        ("p1", d.p1),
        ("p2", d.p2),
        ("k3", d.k3),
    ] {
        s += &format!("Camera.{key}: {}\n", real(value));
    }
    s += &format!(
        "\nCamera.width: {}\nCamera.height: {}\n",
        camera.width, camera.height
    );
    s += &format!("\n# Camera frames per second\nCamera.fps: {}\n", real(fps));
    s += "\n# Color order of the images (0: BGR, 1: RGB). Ignored for grayscale images.\nCamera.RGB: 1\n";
    s += "\n# ORB extractor (ORB-SLAM2 defaults)\n";
    s += &format!("ORBextractor.nFeatures: {}\n", orb.n_features);
    s += &format!("ORBextractor.scaleFactor: {}\n", real(orb.scale_factor));
    s += &format!("ORBextractor.nLevels: {}\n", orb.n_levels);
    s += &format!("ORBextractor.iniThFAST: {}\n", orb.ini_th_fast);
    s += &format!("ORBextractor.minThFAST: {}\n", orb.min_th_fast);
    s
}

/// Writes `camera.yaml`.
pub fn write_camera_yaml(path: &Path, camera: &PinholeCamera, fps: f64) -> Result<()> {
    write_text(
        path,
        &camera_yaml_string(camera, fps, &OrbDefaults::default()),
    )
}

/// Reads `camera.yaml` (the `Camera.*` keys; the rest is ignored).
pub fn read_camera_yaml(path: &Path) -> Result<CameraYaml> {
    parse_camera_yaml(&read_text(path)?, path)
}

/// Parses the text of a `camera.yaml`; `path` is only used in error messages.
pub fn parse_camera_yaml(text: &str, path: &Path) -> Result<CameraYaml> {
    let err = |line: usize, message: String| FormatError::parse(path, line, message);
    let mut values: Vec<(String, f64, usize)> = Vec::new();
    for (k, raw) in text.lines().enumerate() {
        let line = raw.split('#').next().unwrap_or("").trim();
        if line.is_empty() || line.starts_with('%') || line == "---" {
            continue;
        }
        let Some((key, value)) = line.split_once(':') else {
            return Err(err(k + 1, format!("expected `key: value`, got `{line}`")));
        };
        let key = key.trim();
        if !key.starts_with("Camera.") {
            continue;
        }
        let value = value.trim();
        let v: f64 = value
            .parse()
            .map_err(|_| err(k + 1, format!("{key}: `{value}` is not a number")))?;
        if !v.is_finite() {
            return Err(err(k + 1, format!("{key}: `{value}` is not finite")));
        }
        values.push((key.to_string(), v, k + 1));
    }
    let get = |key: &str| {
        values
            .iter()
            .find(|(k, _, _)| k == key)
            .map(|&(_, v, l)| (v, l))
    };
    let need = |key: &str| {
        get(key)
            .map(|(v, _)| v)
            .ok_or_else(|| err(0, format!("missing {key}")))
    };
    let size = |key: &str| -> Result<u32> {
        let (v, line) = get(key).ok_or_else(|| err(0, format!("missing {key}")))?;
        if v.fract() != 0.0 || !(1.0..=1e6).contains(&v) {
            return Err(err(
                line,
                format!("{key} must be a positive integer, got {v}"),
            ));
        }
        Ok(v as u32)
    };
    let opt = |key: &str| get(key).map_or(0.0, |(v, _)| v);
    let distortion = RadTan {
        k1: opt("Camera.k1"),
        k2: opt("Camera.k2"),
        p1: opt("Camera.p1"),
        p2: opt("Camera.p2"),
        k3: opt("Camera.k3"),
    };
    let camera = PinholeCamera {
        fx: need("Camera.fx")?,
        fy: need("Camera.fy")?,
        cx: need("Camera.cx")?,
        cy: need("Camera.cy")?,
        width: size("Camera.width")?,
        height: size("Camera.height")?,
        distortion: (!distortion.is_zero()).then_some(distortion),
    };
    Ok(CameraYaml {
        camera,
        fps: get("Camera.fps").map_or(0.0, |(v, _)| v),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_exactly() {
        let cams = [
            PinholeCamera::ideal(500.0, 500, 500),
            PinholeCamera {
                fx: 512.123456789,
                fy: 498.1,
                cx: 251.3,
                cy: 247.0 + 1e-9,
                width: 640,
                height: 480,
                distortion: Some(RadTan {
                    k1: -0.12,
                    k2: 0.031,
                    p1: 1e-4,
                    p2: -2.5e-5,
                    k3: 0.0,
                }),
            },
        ];
        for cam in cams {
            let text = camera_yaml_string(&cam, 5.0, &OrbDefaults::default());
            assert!(text.starts_with("%YAML:1.0\n"));
            let back = parse_camera_yaml(&text, Path::new("camera.yaml")).unwrap();
            assert_eq!(back.camera, cam);
            assert_eq!(back.fps, 5.0);
        }
    }

    #[test]
    fn missing_or_bad_values_are_errors() {
        let good = camera_yaml_string(
            &PinholeCamera::ideal(500.0, 500, 500),
            5.0,
            &OrbDefaults::default(),
        );
        let no_fx: String = good
            .lines()
            .filter(|l| !l.starts_with("Camera.fx"))
            .collect::<Vec<_>>()
            .join("\n");
        assert!(parse_camera_yaml(&no_fx, Path::new("c.yaml")).is_err());
        let bad = good.replace("Camera.width: 500", "Camera.width: 5x0");
        let e = parse_camera_yaml(&bad, Path::new("c.yaml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("Camera.width"), "{e}");
        let frac = good.replace("Camera.height: 500", "Camera.height: 12.5");
        assert!(parse_camera_yaml(&frac, Path::new("c.yaml")).is_err());
    }

    #[test]
    fn file_round_trips_and_errors_name_the_file_and_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("camera.yaml");
        let cam = PinholeCamera::ideal(500.0, 500, 500);
        write_camera_yaml(&path, &cam, 5.0).unwrap();
        let back = read_camera_yaml(&path).unwrap();
        assert_eq!((back.camera, back.fps), (cam, 5.0));
        let good = std::fs::read_to_string(&path).unwrap();
        let line_of = |key: &str| good.lines().position(|l| l.starts_with(key)).unwrap() + 1;
        for (bad, key) in [
            (
                good.replace("Camera.fx: 500.0", "Camera.fx: five"),
                "Camera.fx",
            ),
            (
                good.replace("Camera.cy: 249.5", "Camera.cy: nan"),
                "Camera.cy",
            ),
            (
                good.replace("Camera.k1: 0.0", "Camera.k1: inf"),
                "Camera.k1",
            ),
        ] {
            assert_ne!(bad, good, "{key}");
            std::fs::write(&path, bad).unwrap();
            let e = read_camera_yaml(&path).unwrap_err();
            assert!(matches!(e, FormatError::Parse { .. }), "{e}");
            let want = format!("camera.yaml:{}:", line_of(key));
            assert!(e.to_string().contains(&want), "{e}");
        }
        let e = read_camera_yaml(&dir.path().join("absent.yaml")).unwrap_err();
        assert!(matches!(e, FormatError::Io { .. }), "{e}");
        assert!(e.to_string().contains("absent.yaml"), "{e}");
    }
}
