//! `trajectory.tum`: the world-frame pose of every frame as it was known at that frame.
//!
//! Geo-referenced frames are TUM lines (`timestamp tx ty tz qx qy qz qw`, camera-to-world);
//! the others are comment lines `# timestamp not geo-referenced` (tracked, but no SLAM→world
//! alignment yet) or `# timestamp not tracked`, which TUM readers such as `evo` skip.

use std::fmt::Write as _;
use std::path::Path;

use jointloc_geometry::CameraToWorld;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

use super::{lines, number, read_text, write_text};
use crate::error::{FormatError, Result};

/// The header line written first.
pub const HEADER: &str =
    "# timestamp tx ty tz qx qy qz qw (camera-to-world, world frame of map.toml, as known online)";

/// What was known of one frame online.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum OnlineStatus {
    /// Tracked and geo-referenced: the world pose.
    World(CameraToWorld),
    /// Tracked by the SLAM, but no SLAM→world alignment yet.
    NotGeoReferenced,
    /// Not tracked (lost, or before the SLAM initialised).
    NotTracked,
}

/// One line of `trajectory.tum`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OnlineFrame {
    pub timestamp: f64,
    pub status: OnlineStatus,
}

impl OnlineFrame {
    /// The world pose, when the frame was geo-referenced.
    pub fn world_pose(&self) -> Option<CameraToWorld> {
        match self.status {
            OnlineStatus::World(p) => Some(p),
            _ => None,
        }
    }

    /// The line as written (no newline).
    pub fn to_line(&self) -> String {
        match &self.status {
            OnlineStatus::World(p) => {
                let t = p.0.translation.vector;
                let q = p.0.rotation;
                format!(
                    "{:.6} {:.6} {:.6} {:.6} {:.9} {:.9} {:.9} {:.9}",
                    self.timestamp, t.x, t.y, t.z, q.i, q.j, q.k, q.w
                )
            }
            OnlineStatus::NotGeoReferenced => format!("# {:.6} not geo-referenced", self.timestamp),
            OnlineStatus::NotTracked => format!("# {:.6} not tracked", self.timestamp),
        }
    }
}

/// Writes `frames` to `path`, header first.
pub fn write_online_tum(path: &Path, frames: &[OnlineFrame]) -> Result<()> {
    let mut text = String::with_capacity(80 * (frames.len() + 1));
    text.push_str(HEADER);
    text.push('\n');
    for f in frames {
        let _ = writeln!(text, "{}", f.to_line());
    }
    write_text(path, &text)
}

/// Reads a file written by [`write_online_tum`] (any other comment line is skipped).
pub fn read_online_tum(path: &Path) -> Result<Vec<OnlineFrame>> {
    let text = read_text(path)?;
    let mut frames: Vec<OnlineFrame> = Vec::new();
    for (line, content) in lines(&text) {
        let frame = match content.strip_prefix('#') {
            Some(comment) => {
                let mut parts = comment.trim().splitn(2, ' ');
                let (Some(stamp), Some(what)) = (parts.next(), parts.next()) else {
                    continue;
                };
                let status = match what.trim() {
                    "not geo-referenced" => OnlineStatus::NotGeoReferenced,
                    "not tracked" => OnlineStatus::NotTracked,
                    _ => continue,
                };
                OnlineFrame {
                    timestamp: number(path, line, "timestamp", stamp)?,
                    status,
                }
            }
            None => parse_pose_line(path, line, content)?,
        };
        if let Some(prev) = frames.last()
            && frame.timestamp <= prev.timestamp
        {
            return Err(FormatError::parse(
                path,
                line,
                format!("timestamp {} not after {}", frame.timestamp, prev.timestamp),
            ));
        }
        frames.push(frame);
    }
    Ok(frames)
}

fn parse_pose_line(path: &Path, line: usize, content: &str) -> Result<OnlineFrame> {
    let fields: Vec<&str> = content.split_whitespace().collect();
    if fields.len() != 8 {
        return Err(FormatError::parse(
            path,
            line,
            format!(
                "expected 8 columns (timestamp tx ty tz qx qy qz qw), found {}",
                fields.len()
            ),
        ));
    }
    const NAMES: [&str; 8] = ["timestamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw"];
    let mut v = [0.0; 8];
    for (i, (field, name)) in fields.iter().zip(NAMES).enumerate() {
        v[i] = number(path, line, name, field)?;
    }
    let q = Quaternion::new(v[7], v[4], v[5], v[6]);
    if (q.norm() - 1.0).abs() > 1e-3 {
        return Err(FormatError::parse(
            path,
            line,
            format!("quaternion norm {:.6} is not 1", q.norm()),
        ));
    }
    let pose = Isometry3::from_parts(
        Translation3::new(v[1], v[2], v[3]),
        UnitQuaternion::from_quaternion(q),
    );
    Ok(OnlineFrame {
        timestamp: v[0],
        status: OnlineStatus::World(CameraToWorld(pose)),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(x: f64) -> CameraToWorld {
        CameraToWorld(Isometry3::from_parts(
            Translation3::new(x, -2.5, 10.25),
            UnitQuaternion::from_euler_angles(3.1, 0.02, 0.7),
        ))
    }

    #[test]
    fn round_trip_keeps_every_frame_and_its_status() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("trajectory.tum");
        let frames = vec![
            OnlineFrame {
                timestamp: 0.0,
                status: OnlineStatus::NotTracked,
            },
            OnlineFrame {
                timestamp: 0.2,
                status: OnlineStatus::NotGeoReferenced,
            },
            OnlineFrame {
                timestamp: 0.4,
                status: OnlineStatus::World(pose(1.0)),
            },
            OnlineFrame {
                timestamp: 0.6,
                status: OnlineStatus::World(pose(1.2)),
            },
        ];
        write_online_tum(&path, &frames).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.starts_with(HEADER));
        assert!(text.contains("# 0.200000 not geo-referenced\n"), "{text}");
        let back = read_online_tum(&path).unwrap();
        assert_eq!(back.len(), 4);
        assert_eq!(back[0].status, OnlineStatus::NotTracked);
        assert_eq!(back[1].status, OnlineStatus::NotGeoReferenced);
        let (OnlineStatus::World(a), OnlineStatus::World(b)) = (back[3].status, frames[3].status)
        else {
            panic!("not a pose: {:?}", back[3]);
        };
        assert!((a.0.translation.vector - b.0.translation.vector).norm() < 1e-6);
        assert!(a.0.rotation.angle_to(&b.0.rotation) < 1e-8);
    }

    #[test]
    fn malformed_lines_name_the_file_and_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("trajectory.tum");
        let cases = [
            ("# header\n0.0 1 2 3 0 0 0\n", ":2: expected 8 columns"),
            (
                "0.0 1 2 3 0 0 0 1\n0.2 nan 2 3 0 0 0 1\n",
                ":2: tx `nan` is not finite",
            ),
            (
                "0.2 1 2 3 0 0 0 1\n0.1 1 2 3 0 0 0 1\n",
                ":2: timestamp 0.1 not after 0.2",
            ),
            ("0.0 1 2 3 0 0 0 2\n", ":1: quaternion norm"),
            ("# x not tracked\n", ":1: timestamp `x` is not a number"),
        ];
        for (text, expected) in cases {
            std::fs::write(&path, text).unwrap();
            let e = read_online_tum(&path).unwrap_err().to_string();
            assert!(
                e.contains("trajectory.tum") && e.contains(expected),
                "{text:?}: {e}"
            );
        }
        let e = read_online_tum(&dir.path().join("missing.tum"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("missing.tum"), "{e}");
    }
}
