//! `camera.yaml`: the UAV camera in ORB-SLAM's settings layout (OpenCV FileStorage,
//! `%YAML:1.0`, flat keys), so ORB-SLAM2/3 and OpenCV read a dataset as it is.
//!
//! - A pinhole (optionally radial-tangential) camera is written in ORB-SLAM2's layout
//!   (`Camera.fx`, ..., `Camera.k1, k2, p1, p2, k3`), which ORB-SLAM3 also reads.
//! - A Kannala-Brandt fisheye is written in ORB-SLAM3's layout (`File.version: "1.0"`,
//!   `Camera.type: "KannalaBrandt8"`, `Camera1.fx, fy, cx, cy, k1..k4`).
//!
//! The reader takes both: `Camera.type` (`"PinHole"` or `"KannalaBrandt8"`, quoted or not;
//! absent means pinhole) and the intrinsics as `Camera1.*` (ORB-SLAM3 1.0) or `Camera.*`
//! (ORB-SLAM2 and ORB-SLAM3 before 1.0); other keys are ignored. Datasets round-trip through
//! [`PinholeCamera`].
//!
//! Values are written with Rust's shortest round-trip formatting, so reading gives back the
//! exact `f64`s used for rendering. Every value read must be a finite number; errors name the
//! file and line.

use std::path::Path;

use jointloc_geometry::{Distortion, KannalaBrandt, PinholeCamera, RadTan};

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
    let mut s = String::from("%YAML:1.0\n\n");
    // ORB-SLAM3 names a fisheye's intrinsics `Camera1.*`; ORB-SLAM2 a pinhole's `Camera.*`.
    let (prefix, coefficients) = match camera.distortion {
        Some(Distortion::KannalaBrandt(d)) => {
            s += "# ORB-SLAM3 settings layout (1.0)\n";
            s += "File.version: \"1.0\"\n\n";
            s += "# Camera calibration (OpenCV fisheye): equidistant Kannala-Brandt,\n";
            s += "# theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8).\n";
            s += "# Camera frame x right, y down, z forward; pixel centres at integer coordinates.\n";
            s += "Camera.type: \"KannalaBrandt8\"\n";
            (
                "Camera1",
                [("k1", d.k1), ("k2", d.k2), ("k3", d.k3), ("k4", d.k4)].to_vec(),
            )
        }
        other => {
            let d = match other {
                Some(Distortion::RadTan(d)) => d,
                _ => RadTan::default(),
            };
            s += "# Camera calibration and distortion parameters (OpenCV): pinhole, radial-tangential.\n";
            s += "# Camera frame x right, y down, z forward; pixel centres at integer coordinates.\n";
            let c = [
                ("k1", d.k1),
                ("k2", d.k2),
                ("p1", d.p1),
                ("p2", d.p2),
                ("k3", d.k3),
            ];
            ("Camera", c.to_vec())
        }
    };
    let intrinsics = [
        ("fx", camera.fx),
        ("fy", camera.fy),
        ("cx", camera.cx),
        ("cy", camera.cy),
    ];
    for (key, value) in intrinsics.into_iter().chain(coefficients) {
        s += &format!("{prefix}.{key}: {}\n", real(value));
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

/// Lens model named by `Camera.type`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum CameraType {
    PinHole,
    KannalaBrandt8,
}

/// Parses the text of a `camera.yaml`; `path` is only used in error messages.
pub fn parse_camera_yaml(text: &str, path: &Path) -> Result<CameraYaml> {
    let err = |line: usize, message: String| FormatError::parse(path, line, message);
    let mut values: Vec<(String, f64, usize)> = Vec::new();
    let mut kind: Option<(CameraType, usize)> = None;
    for (k, raw) in text.lines().enumerate() {
        let line = raw.split('#').next().unwrap_or("").trim();
        if line.is_empty() || line.starts_with('%') || line == "---" {
            continue;
        }
        let Some((key, value)) = line.split_once(':') else {
            return Err(err(k + 1, format!("expected `key: value`, got `{line}`")));
        };
        let key = key.trim();
        let value = value.trim();
        if key == "Camera.type" {
            let name = value.trim_matches(|c| c == '"' || c == '\'');
            let t = match name {
                "PinHole" => CameraType::PinHole,
                "KannalaBrandt8" => CameraType::KannalaBrandt8,
                _ => {
                    return Err(err(
                        k + 1,
                        format!(
                            "Camera.type: `{value}` is not a supported model \
                             (\"PinHole\" or \"KannalaBrandt8\")"
                        ),
                    ));
                }
            };
            if let Some((_, first)) = kind {
                return Err(err(
                    k + 1,
                    format!("Camera.type given twice (first on line {first})"),
                ));
            }
            kind = Some((t, k + 1));
            continue;
        }
        // ORB-SLAM3 1.0 names the first camera's intrinsics `Camera1.*`; ORB-SLAM2 `Camera.*`.
        let Some(name) = key
            .strip_prefix("Camera1.")
            .or_else(|| key.strip_prefix("Camera."))
        else {
            continue;
        };
        let v: f64 = value
            .parse()
            .map_err(|_| err(k + 1, format!("{key}: `{value}` is not a number")))?;
        if !v.is_finite() {
            return Err(err(k + 1, format!("{key}: `{value}` is not finite")));
        }
        if let Some((_, _, first)) = values.iter().find(|(n, _, _)| n == name) {
            return Err(err(
                k + 1,
                format!("{key}: camera parameter `{name}` given twice (first on line {first})"),
            ));
        }
        values.push((name.to_string(), v, k + 1));
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
            .ok_or_else(|| err(0, format!("missing Camera.{key} (or Camera1.{key})")))
    };
    let size = |key: &str| -> Result<u32> {
        let (v, line) = get(key).ok_or_else(|| err(0, format!("missing Camera.{key}")))?;
        if v.fract() != 0.0 || !(1.0..=1e6).contains(&v) {
            return Err(err(
                line,
                format!("Camera.{key} must be a positive integer, got {v}"),
            ));
        }
        Ok(v as u32)
    };
    let opt = |key: &str| get(key).map_or(0.0, |(v, _)| v);
    let distortion = match kind.map(|(t, _)| t) {
        Some(CameraType::KannalaBrandt8) => {
            for key in ["p1", "p2"] {
                if let Some((_, line)) = get(key) {
                    return Err(err(
                        line,
                        format!("{key}: a KannalaBrandt8 camera has k1..k4 only"),
                    ));
                }
            }
            Some(Distortion::KannalaBrandt(KannalaBrandt {
                k1: opt("k1"),
                k2: opt("k2"),
                k3: opt("k3"),
                k4: opt("k4"),
            }))
        }
        _ => {
            if let Some((_, line)) = get("k4") {
                return Err(err(
                    line,
                    "k4: a pinhole camera has k1, k2, p1, p2, k3 (Camera.type: \"KannalaBrandt8\" \
                     for a fisheye)"
                        .into(),
                ));
            }
            let d = RadTan {
                k1: opt("k1"),
                k2: opt("k2"),
                p1: opt("p1"),
                p2: opt("p2"),
                k3: opt("k3"),
            };
            (!d.is_zero()).then_some(Distortion::RadTan(d))
        }
    };
    let camera = PinholeCamera {
        fx: need("fx")?,
        fy: need("fy")?,
        cx: need("cx")?,
        cy: need("cy")?,
        width: size("width")?,
        height: size("height")?,
        distortion,
    };
    for (key, v) in [("fx", camera.fx), ("fy", camera.fy)] {
        if v <= 0.0 {
            let line = get(key).map_or(0, |(_, l)| l);
            return Err(err(line, format!("{key} must be positive, got {v}")));
        }
    }
    Ok(CameraYaml {
        camera,
        fps: get("fps").map_or(0.0, |(v, _)| v),
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
                distortion: Some(
                    RadTan {
                        k1: -0.12,
                        k2: 0.031,
                        p1: 1e-4,
                        p2: -2.5e-5,
                        k3: 0.0,
                    }
                    .into(),
                ),
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

    fn fisheye() -> PinholeCamera {
        PinholeCamera {
            fx: 215.39,
            fy: 215.41,
            cx: 249.5,
            cy: 249.25,
            width: 500,
            height: 500,
            distortion: Some(Distortion::KannalaBrandt(KannalaBrandt {
                k1: 0.0034823894022493434,
                k2: 0.0007150348452162257,
                k3: -0.0020532361418706202,
                k4: 0.00020293673591811182,
            })),
        }
    }

    #[test]
    fn fisheye_round_trips_in_orb_slam3_layout() {
        let cam = fisheye();
        let text = camera_yaml_string(&cam, 5.0, &OrbDefaults::default());
        // What ORB-SLAM3's Settings reads for a fisheye.
        for key in [
            "File.version: \"1.0\"",
            "Camera.type: \"KannalaBrandt8\"",
            "Camera1.fx: 215.39",
            "Camera1.k4: 0.00020293673591811182",
            "Camera.width: 500",
            "Camera.fps: 5.0",
        ] {
            assert!(text.lines().any(|l| l == key), "{key} in\n{text}");
        }
        assert!(!text.contains("p1"), "{text}");
        let back = parse_camera_yaml(&text, Path::new("camera.yaml")).unwrap();
        assert_eq!(back.camera, cam);
        // A pure equidistant lens (all k zero) stays a fisheye.
        let pure = PinholeCamera {
            distortion: Some(Distortion::KannalaBrandt(KannalaBrandt::default())),
            ..cam
        };
        let text = camera_yaml_string(&pure, 5.0, &OrbDefaults::default());
        let back = parse_camera_yaml(&text, Path::new("camera.yaml")).unwrap();
        assert_eq!(back.camera, pure);
    }

    #[test]
    fn reads_orb_slam3_files_in_both_key_styles() {
        // ORB-SLAM3 1.0 (as its TUM-VI example), unquoted type, and pre-1.0 `Camera.*` keys.
        let v1 = "%YAML:1.0\nFile.version: \"1.0\"\nCamera.type: \"KannalaBrandt8\"\n\
                  Camera1.fx: 190.97847715128717\nCamera1.fy: 190.9733070521226\n\
                  Camera1.cx: 254.93170605935475\nCamera1.cy: 256.8974428996504\n\
                  Camera1.k1: 0.0034823894022493434\nCamera1.k2: 0.0007150348452162257\n\
                  Camera1.k3: -0.0020532361418706202\nCamera1.k4: 0.00020293673591811182\n\
                  Camera.width: 512\nCamera.height: 512\nCamera.fps: 20\nCamera.RGB: 1\n\
                  Camera2.fx: 1.0\nIMU.NoiseGyro: 0.00016\n";
        let old = v1
            .replace("Camera1.", "Camera.")
            .replace("\"KannalaBrandt8\"", "KannalaBrandt8")
            .replace("File.version: \"1.0\"\n", "");
        for text in [v1.to_string(), old] {
            let c = parse_camera_yaml(&text, Path::new("tumvi.yaml")).unwrap();
            assert_eq!(c.camera.fx, 190.97847715128717);
            assert_eq!((c.camera.width, c.fps), (512, 20.0));
            let Some(Distortion::KannalaBrandt(kb)) = c.camera.distortion else {
                panic!("{:?}", c.camera.distortion)
            };
            assert_eq!(kb.k4, 0.00020293673591811182);
        }
        let pin = "Camera.type: \"PinHole\"\nCamera1.fx: 500.0\nCamera1.fy: 500.0\n\
                   Camera1.cx: 249.5\nCamera1.cy: 249.5\nCamera1.k1: -0.1\n\
                   Camera.width: 500\nCamera.height: 500\n";
        let c = parse_camera_yaml(pin, Path::new("p.yaml")).unwrap();
        assert!(matches!(c.camera.distortion, Some(Distortion::RadTan(d)) if d.k1 == -0.1));
    }

    #[test]
    fn camera_type_errors_name_the_file_and_line() {
        let good = camera_yaml_string(&fisheye(), 5.0, &OrbDefaults::default());
        let line_of =
            |text: &str, key: &str| text.lines().position(|l| l.starts_with(key)).unwrap() + 1;
        let cases = [
            (
                good.replace("\"KannalaBrandt8\"", "\"Rectified\""),
                "Camera.type",
                "not a supported model",
            ),
            (
                good.replace("Camera1.k4:", "Camera1.p1:"),
                "Camera1.p1",
                "k1..k4 only",
            ),
            (
                good.replace("Camera1.k4:", "Camera.fx:"),
                "Camera.fx",
                "given twice",
            ),
            (
                good.replace("Camera.type: \"KannalaBrandt8\"", "Camera.type: PinHole"),
                "Camera1.k4",
                "pinhole camera has",
            ),
            (
                good.replace("Camera1.fy: 215.41", "Camera1.fy: -2.0"),
                "Camera1.fy",
                "must be positive",
            ),
        ];
        for (bad, key, what) in cases {
            assert_ne!(bad, good, "{key}");
            let e = parse_camera_yaml(&bad, Path::new("fish.yaml"))
                .unwrap_err()
                .to_string();
            let want = format!("fish.yaml:{}:", line_of(&bad, key));
            assert!(e.contains(&want) && e.contains(what), "{key}: {e}");
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
