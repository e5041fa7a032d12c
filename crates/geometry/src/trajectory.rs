//! Timestamped camera trajectories and their file formats (TUM, EuRoC ground truth, KITTI).
//!
//! Readers are strict where silence would corrupt an evaluation: every error names the file and
//! the 1-based line, timestamps must increase strictly, and values must be finite. Quaternions
//! are normalised on reading (as evo does) but a zero quaternion is an error.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use nalgebra::{Point3, Quaternion, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::error::{GeometryError, Result};
use crate::pose::CameraToWorld;

/// Order of the four quaternion columns in a TUM-like file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum QuaternionOrder {
    /// Standard TUM: `qx qy qz qw`.
    #[default]
    Xyzw,
    /// Scalar first: `qw qx qy qz` (written by the paper's reference code).
    Wxyz,
}

/// Options of the TUM reader.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct TumOptions {
    /// Column order of the quaternion; standard TUM is `Xyzw`.
    pub quaternion_order: QuaternionOrder,
}

/// A sequence of camera-to-world poses with strictly increasing timestamps in seconds.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Trajectory {
    /// Timestamps in seconds, strictly increasing.
    pub timestamps: Vec<f64>,
    /// Camera-to-world poses, one per timestamp.
    pub poses: Vec<CameraToWorld>,
}

impl Trajectory {
    /// Builds a trajectory, checking equal lengths, finite values and increasing timestamps.
    pub fn new(timestamps: Vec<f64>, poses: Vec<CameraToWorld>) -> Result<Self> {
        if timestamps.len() != poses.len() {
            return Err(GeometryError::LengthMismatch {
                what: "timestamps vs poses",
                left: timestamps.len(),
                right: poses.len(),
            });
        }
        if timestamps.iter().any(|t| !t.is_finite()) {
            return Err(GeometryError::NonFinite("trajectory timestamp"));
        }
        if poses.iter().any(|p| !p.is_finite()) {
            return Err(GeometryError::NonFinite("trajectory pose"));
        }
        if let Some(i) = timestamps.windows(2).position(|w| w[1] <= w[0]) {
            return Err(GeometryError::Degenerate(format!(
                "timestamps not strictly increasing at index {}: {} after {}",
                i + 1,
                timestamps[i + 1],
                timestamps[i]
            )));
        }
        Ok(Self { timestamps, poses })
    }

    /// Number of poses.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// True when there is no pose.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// Camera centres in world coordinates.
    pub fn positions(&self) -> Vec<Point3<f64>> {
        self.poses.iter().map(CameraToWorld::centre).collect()
    }

    /// The sub-trajectory at the given indices (in the given order). Panics on an index out of
    /// range, which is a programming error, never a data error.
    pub fn select(&self, indices: &[usize]) -> Trajectory {
        Trajectory {
            timestamps: indices.iter().map(|&i| self.timestamps[i]).collect(),
            poses: indices.iter().map(|&i| self.poses[i]).collect(),
        }
    }

    /// Reads a TUM file (`timestamp tx ty tz qx qy qz qw`, whitespace separated, `#` comments).
    pub fn read_tum(path: impl AsRef<Path>, options: &TumOptions) -> Result<Self> {
        let path = path.as_ref();
        Self::parse_tum(&read_text(path)?, path, options)
    }

    /// Parses TUM text; `path` only labels errors.
    pub fn parse_tum(text: &str, path: &Path, options: &TumOptions) -> Result<Self> {
        let mut builder = Builder::new(path);
        for (index, raw) in text.lines().enumerate() {
            let line = index + 1;
            let content = raw.trim();
            if content.is_empty() || content.starts_with('#') {
                continue;
            }
            let fields: Vec<&str> = content.split_whitespace().collect();
            if fields.len() != 8 {
                return Err(builder.parse_error(
                    line,
                    format!(
                        "expected 8 columns (timestamp tx ty tz {}), found {}",
                        match options.quaternion_order {
                            QuaternionOrder::Xyzw => "qx qy qz qw",
                            QuaternionOrder::Wxyz => "qw qx qy qz",
                        },
                        fields.len()
                    ),
                ));
            }
            let v = builder.numbers(line, &fields)?;
            let q_xyzw = match options.quaternion_order {
                QuaternionOrder::Xyzw => [v[4], v[5], v[6], v[7]],
                QuaternionOrder::Wxyz => [v[5], v[6], v[7], v[4]],
            };
            builder.push(line, v[0], [v[1], v[2], v[3]], q_xyzw)?;
        }
        builder.finish(text.lines().count())
    }

    /// Reads EuRoC ground truth CSV (`#timestamp [ns], p_x, p_y, p_z, q_w, q_x, q_y, q_z, ...`);
    /// nanoseconds become seconds, extra columns (velocities, biases) are ignored.
    pub fn read_euroc(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        Self::parse_euroc(&read_text(path)?, path)
    }

    /// Parses EuRoC CSV text; `path` only labels errors.
    pub fn parse_euroc(text: &str, path: &Path) -> Result<Self> {
        let mut builder = Builder::new(path);
        for (index, raw) in text.lines().enumerate() {
            let line = index + 1;
            let content = raw.trim().trim_start_matches('\u{feff}');
            if content.is_empty() || content.starts_with('#') {
                continue;
            }
            let fields: Vec<&str> = content.split(',').map(str::trim).collect();
            if fields.len() < 8 {
                return Err(builder.parse_error(
                    line,
                    format!(
                        "expected at least 8 comma-separated columns (timestamp_ns, p_x, p_y, \
                         p_z, q_w, q_x, q_y, q_z), found {}",
                        fields.len()
                    ),
                ));
            }
            let v = builder.numbers(line, &fields[..8])?;
            builder.push(
                line,
                v[0] / 1e9,
                [v[1], v[2], v[3]],
                [v[5], v[6], v[7], v[4]],
            )?;
        }
        builder.finish(text.lines().count())
    }

    /// TUM text: one `timestamp tx ty tz qx qy qz qw` line per pose, numbers in the shortest
    /// representation that reads back to the same f64.
    pub fn to_tum_string(&self) -> String {
        let mut out = String::with_capacity(self.len() * 120);
        for (t, pose) in self.timestamps.iter().zip(&self.poses) {
            let (p, q) = pose.to_translation_quaternion();
            let _ = writeln!(
                out,
                "{t} {} {} {} {} {} {} {}",
                p[0], p[1], p[2], q[0], q[1], q[2], q[3]
            );
        }
        out
    }

    /// Writes a standard TUM file (quaternion `qx qy qz qw`).
    pub fn write_tum(&self, path: impl AsRef<Path>) -> Result<()> {
        write_text(path.as_ref(), &self.to_tum_string())
    }

    /// KITTI text: the 3×4 matrix `[R | t]` of each pose, row-major, 12 numbers per line.
    pub fn to_kitti_string(&self) -> String {
        let mut out = String::with_capacity(self.len() * 200);
        for pose in &self.poses {
            let r = pose.rotation_matrix();
            let t = pose.translation();
            let row = |i: usize| format!("{} {} {} {}", r[(i, 0)], r[(i, 1)], r[(i, 2)], t[i]);
            let _ = writeln!(out, "{} {} {}", row(0), row(1), row(2));
        }
        out
    }

    /// Writes a KITTI pose file (no timestamps, as KITTI keeps them in a separate file).
    pub fn write_kitti(&self, path: impl AsRef<Path>) -> Result<()> {
        write_text(path.as_ref(), &self.to_kitti_string())
    }
}

fn read_text(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).map_err(|source| GeometryError::Io {
        path: path.to_path_buf(),
        source,
    })
}

fn write_text(path: &Path, text: &str) -> Result<()> {
    std::fs::write(path, text).map_err(|source| GeometryError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Accumulates parsed lines and enforces the per-line rules shared by every text format.
struct Builder<'a> {
    path: &'a Path,
    timestamps: Vec<f64>,
    poses: Vec<CameraToWorld>,
}

impl<'a> Builder<'a> {
    fn new(path: &'a Path) -> Self {
        Self {
            path,
            timestamps: Vec::new(),
            poses: Vec::new(),
        }
    }

    fn parse_error(&self, line: usize, message: String) -> GeometryError {
        GeometryError::Parse {
            path: PathBuf::from(self.path),
            line,
            message,
        }
    }

    fn numbers(&self, line: usize, fields: &[&str]) -> Result<Vec<f64>> {
        fields
            .iter()
            .enumerate()
            .map(|(col, s)| {
                let v: f64 = s.parse().map_err(|_| {
                    self.parse_error(line, format!("column {}: '{s}' is not a number", col + 1))
                })?;
                if v.is_finite() {
                    Ok(v)
                } else {
                    Err(self.parse_error(line, format!("column {}: '{s}' is not finite", col + 1)))
                }
            })
            .collect()
    }

    fn push(&mut self, line: usize, t: f64, p: [f64; 3], q_xyzw: [f64; 4]) -> Result<()> {
        if let Some(&prev) = self.timestamps.last()
            && t <= prev
        {
            return Err(self.parse_error(
                line,
                format!("timestamp {t} is not greater than the previous one ({prev})"),
            ));
        }
        let q = Quaternion::new(q_xyzw[3], q_xyzw[0], q_xyzw[1], q_xyzw[2]);
        let norm = q.norm();
        if norm <= 1e-12 {
            return Err(self.parse_error(line, "quaternion has zero norm".to_string()));
        }
        // Components near f64::MAX overflow the norm: normalising would give zeros or NaN.
        if !norm.is_finite() {
            return Err(self.parse_error(line, "quaternion norm overflows".to_string()));
        }
        let rotation = UnitQuaternion::from_quaternion(q);
        self.timestamps.push(t);
        self.poses.push(CameraToWorld::from_rotation_translation(
            rotation,
            Vector3::from(p),
        ));
        Ok(())
    }

    /// `lines` is the number of lines read, so that an empty file points at its end.
    fn finish(self, lines: usize) -> Result<Trajectory> {
        if self.poses.is_empty() {
            return Err(self.parse_error(
                lines.max(1),
                "trajectory is empty (no pose lines)".to_string(),
            ));
        }
        Ok(Trajectory {
            timestamps: self.timestamps,
            poses: self.poses,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Trajectory> {
        Trajectory::parse_tum(text, Path::new("t.txt"), &TumOptions::default())
    }

    fn parse_err(text: &str) -> (usize, String) {
        match parse(text) {
            Err(GeometryError::Parse { line, message, .. }) => (line, message),
            other => panic!("expected a parse error, got {other:?}"),
        }
    }

    #[test]
    fn reads_tum_with_comments_and_blank_lines() {
        let text = "# header\n\n1.0 1 2 3 0 0 0 1\n  \n2.5 4 5 6 0 0 0.7071067811865476 0.7071067811865476\n";
        let traj = parse(text).unwrap();
        assert_eq!(traj.timestamps, vec![1.0, 2.5]);
        assert_eq!(traj.poses[0].translation(), Vector3::new(1.0, 2.0, 3.0));
        let expected = UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2);
        assert!(
            (traj.poses[1].rotation_matrix() - expected.to_rotation_matrix().into_inner()).norm()
                < 1e-12
        );
    }

    #[test]
    fn qw_first_option_reorders_columns() {
        let xyzw = parse("0 0 0 0 0.1 0.2 0.3 0.9\n").unwrap();
        let wxyz = Trajectory::parse_tum(
            "0 0 0 0 0.9 0.1 0.2 0.3\n",
            Path::new("t"),
            &TumOptions {
                quaternion_order: QuaternionOrder::Wxyz,
            },
        )
        .unwrap();
        assert!((xyzw.poses[0].rotation_matrix() - wxyz.poses[0].rotation_matrix()).norm() < 1e-15);
    }

    #[test]
    fn malformed_lines_name_the_line() {
        assert_eq!(parse_err("0 0 0 0 0 0 0 1\n1 0 0 0 0 0 1\n").0, 2);
        let (line, msg) = parse_err("# c\n0 0 0 x 0 0 0 1\n");
        assert_eq!(line, 2);
        assert!(msg.contains("not a number"), "{msg}");
        let (line, msg) = parse_err("0 0 0 0 0 0 0 1\n1 NaN 0 0 0 0 0 1\n");
        assert_eq!(line, 2);
        assert!(msg.contains("not finite"), "{msg}");
        assert!(
            parse_err("0 0 0 0 0 0 0 1\n1 inf 0 0 0 0 0 1\n")
                .1
                .contains("finite")
        );
        let (line, msg) = parse_err("1 0 0 0 0 0 0 1\n\n1 0 0 0 0 0 0 1\n");
        assert_eq!(line, 3);
        assert!(msg.contains("previous"), "{msg}");
        assert!(
            parse_err("2 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n")
                .1
                .contains("previous")
        );
        let (line, msg) = parse_err("1 0 0 0 0 0 0 0\n");
        assert_eq!(line, 1);
        assert!(msg.contains("zero norm"), "{msg}");
        assert!(parse_err("# only a comment\n\n").1.contains("empty"));
        assert!(parse_err("0 0 0 0 0 0 0 1 5\n").1.contains("8 columns"));
    }

    #[test]
    fn missing_file_is_an_io_error_naming_the_path() {
        let err =
            Trajectory::read_tum("/nonexistent/traj.txt", &TumOptions::default()).unwrap_err();
        assert!(matches!(err, GeometryError::Io { .. }));
        assert!(err.to_string().contains("/nonexistent/traj.txt"));
    }

    #[test]
    fn euroc_converts_nanoseconds_and_scalar_first_quaternion() {
        let text = "#timestamp [ns], p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], v_x\n\
                    1403636579758555392,4.688,-1.786,0.783,0.534,-0.153,-0.827,-0.082,0.1\n\
                    1403636579763555584,4.688,-1.786,0.787,0.534,-0.152,-0.827,-0.082,0.1\n";
        let traj = Trajectory::parse_euroc(text, Path::new("data.csv")).unwrap();
        assert_eq!(traj.len(), 2);
        assert_eq!(traj.timestamps[0], 1403636579758555392.0 / 1e9);
        let q = traj.poses[0].rotation();
        let n = (0.534f64.powi(2) + 0.153f64.powi(2) + 0.827f64.powi(2) + 0.082f64.powi(2)).sqrt();
        assert!((q.w - 0.534 / n).abs() < 1e-12 && (q.j + 0.827 / n).abs() < 1e-12);
        let err = Trajectory::parse_euroc("1,2,3\n", Path::new("d.csv")).unwrap_err();
        assert!(err.to_string().starts_with("d.csv:1:"), "{err}");
    }

    #[test]
    fn tum_and_kitti_writers_round_trip_exactly() {
        let mut poses = Vec::new();
        let mut stamps = Vec::new();
        for i in 0..20 {
            let a = i as f64 * 0.37;
            poses.push(CameraToWorld::from_rotation_translation(
                UnitQuaternion::from_euler_angles(a.sin(), 0.3 * a, a.cos() * 1.7),
                Vector3::new(a.sin() * 1e3, a.cos() / 7.0, 1e-9 * a),
            ));
            stamps.push(1.7e9 + i as f64 / 30.0);
        }
        let traj = Trajectory::new(stamps, poses).unwrap();
        let back = parse(&traj.to_tum_string()).unwrap();
        assert_eq!(back.timestamps, traj.timestamps);
        for (a, b) in traj.poses.iter().zip(&back.poses) {
            assert_eq!(a.translation(), b.translation());
            assert!((a.rotation_matrix() - b.rotation_matrix()).norm() < 1e-15);
        }
        let kitti = traj.to_kitti_string();
        let lines: Vec<&str> = kitti.lines().collect();
        assert_eq!(lines.len(), 20);
        for (line, pose) in lines.iter().zip(&traj.poses) {
            let v: Vec<f64> = line.split(' ').map(|s| s.parse().unwrap()).collect();
            assert_eq!(v.len(), 12);
            let m = pose.0.to_homogeneous();
            for r in 0..3 {
                for c in 0..4 {
                    assert_eq!(v[r * 4 + c], m[(r, c)]);
                }
            }
        }
        let dir = std::env::temp_dir().join(format!("jointloc-traj-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("t.txt");
        traj.write_tum(&file).unwrap();
        assert_eq!(
            Trajectory::read_tum(&file, &TumOptions::default())
                .unwrap()
                .timestamps,
            traj.timestamps
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn new_rejects_inconsistent_input() {
        let p = CameraToWorld::identity();
        assert!(Trajectory::new(vec![0.0], vec![]).is_err());
        assert!(Trajectory::new(vec![1.0, 1.0], vec![p, p]).is_err());
        assert!(Trajectory::new(vec![f64::NAN], vec![p]).is_err());
        assert!(Trajectory::new(vec![0.0, 1.0], vec![p, p]).is_ok());
    }
}
