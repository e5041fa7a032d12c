//! `fixes.txt`: every absolute fix of a run, one line each, TUM-compatible in its first eight
//! columns (so `evo` reads it as a trajectory of positions) and then what the fusion made of
//! it: `timestamp x y z qx qy qz qw confidence tile ssim match_score inliers used inlier
//! injected`. x, y are the map point under the image centre (what a fix measures), z the map
//! elevation there plus the altimeter reading; the quaternion is the camera-to-world rotation
//! of a nadir camera at the fix's heading (the frame's rotation in the map, as matched: a fix
//! measures no tilt); the flags are 0/1.

use std::fmt::Write as _;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::{lines, number, read_text, write_text};
use crate::error::{FormatError, Result};

/// The header line written first.
pub const HEADER: &str = "# timestamp x y z qx qy qz qw confidence tile ssim match_score inliers used inlier injected (x, y: map point under the image centre; z: map elevation there + altimeter; q: camera-to-world of a nadir camera at the matched heading; injected: made wrong on purpose)";

/// One line of `fixes.txt`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FixRow {
    pub timestamp: f64,
    pub position: [f64; 3],
    /// `(qx, qy, qz, qw)`: camera-to-world rotation of a nadir camera at the fix's heading.
    pub orientation: [f64; 4],
    /// The paper's confidence w = SSIM × mean matching score.
    pub confidence: f64,
    /// Index of the map tile the fix came from.
    pub tile: usize,
    pub ssim: f64,
    pub match_score: f64,
    /// Homography inliers.
    pub inliers: usize,
    /// Whether the fusion used the fix, and whether it was an inlier of the last alignment.
    pub used: bool,
    pub inlier: bool,
    /// Made wrong on purpose by fault injection.
    pub injected: bool,
}

impl FixRow {
    /// The line as written (no newline).
    pub fn to_line(&self) -> String {
        format!(
            "{:.6} {:.4} {:.4} {:.4} {:.6} {:.6} {:.6} {:.6} {:.4} {} {:.4} {:.4} {} {} {} {}",
            self.timestamp,
            self.position[0],
            self.position[1],
            self.position[2],
            self.orientation[0],
            self.orientation[1],
            self.orientation[2],
            self.orientation[3],
            self.confidence,
            self.tile,
            self.ssim,
            self.match_score,
            self.inliers,
            u8::from(self.used),
            u8::from(self.inlier),
            u8::from(self.injected)
        )
    }
}

/// Writes `rows` to `path`, header first.
pub fn write_fixes(path: &Path, rows: &[FixRow]) -> Result<()> {
    let mut text = String::with_capacity(100 * (rows.len() + 1));
    text.push_str(HEADER);
    text.push('\n');
    for r in rows {
        let _ = writeln!(text, "{}", r.to_line());
    }
    write_text(path, &text)
}

/// Reads a file written by [`write_fixes`]; comment lines are skipped.
pub fn read_fixes(path: &Path) -> Result<Vec<FixRow>> {
    let text = read_text(path)?;
    let mut rows = Vec::new();
    for (line, content) in lines(&text) {
        if content.starts_with('#') {
            continue;
        }
        let f: Vec<&str> = content.split_whitespace().collect();
        if f.len() != 16 {
            return Err(FormatError::parse(
                path,
                line,
                format!(
                    "expected 16 columns (timestamp x y z qx qy qz qw confidence tile ssim \
                     match_score inliers used inlier injected), found {}",
                    f.len()
                ),
            ));
        }
        let num = |i: usize, what: &str| number(path, line, what, f[i]);
        let count = |i: usize, what: &str| {
            f[i].parse::<usize>().map_err(|_| {
                FormatError::parse(path, line, format!("{what} `{}` is not a count", f[i]))
            })
        };
        let flag = |i: usize, what: &str| match f[i] {
            "0" => Ok(false),
            "1" => Ok(true),
            s => Err(FormatError::parse(
                path,
                line,
                format!("{what} `{s}` is not 0 or 1"),
            )),
        };
        let orientation = [num(4, "qx")?, num(5, "qy")?, num(6, "qz")?, num(7, "qw")?];
        let norm = orientation.iter().map(|q| q * q).sum::<f64>().sqrt();
        if (norm - 1.0).abs() > 1e-3 {
            return Err(FormatError::parse(
                path,
                line,
                format!("qx qy qz qw are not a unit quaternion (norm {norm})"),
            ));
        }
        rows.push(FixRow {
            timestamp: num(0, "timestamp")?,
            position: [num(1, "x")?, num(2, "y")?, num(3, "z")?],
            orientation,
            confidence: num(8, "confidence")?,
            tile: count(9, "tile")?,
            ssim: num(10, "ssim")?,
            match_score: num(11, "match_score")?,
            inliers: count(12, "inliers")?,
            used: flag(13, "used")?,
            inlier: flag(14, "inlier")?,
            injected: flag(15, "injected")?,
        });
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(t: f64) -> FixRow {
        FixRow {
            timestamp: t,
            position: [12.3456, -7.5, 3.25],
            orientation: [0.6, -0.8, 0.0, 0.0],
            confidence: 0.4321,
            tile: 7,
            ssim: 0.61,
            match_score: 0.7083,
            inliers: 153,
            used: true,
            inlier: false,
            injected: true,
        }
    }

    #[test]
    fn round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("fixes.txt");
        let rows = vec![row(0.0), row(2.0)];
        write_fixes(&path, &rows).unwrap();
        assert_eq!(read_fixes(&path).unwrap(), rows);
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.starts_with(HEADER));
        assert!(
            text.contains(
                "2.000000 12.3456 -7.5000 3.2500 0.600000 -0.800000 0.000000 0.000000 0.4321 7 "
            ),
            "{text}"
        );
    }

    #[test]
    fn malformed_lines_name_the_file_and_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("fixes.txt");
        let good = row(1.0).to_line();
        let cases = [
            (
                good.replacen(" 7 ", " x ", 1),
                ":2: tile `x` is not a count",
            ),
            (
                good.replacen("12.3456", "NaN", 1),
                ":2: x `NaN` is not finite",
            ),
            (format!("{good} 5"), ":2: expected 16 columns"),
            (
                good.replacen("0.600000", "0.700000", 1),
                ":2: qx qy qz qw are not a unit quaternion",
            ),
            (
                good.replacen(" 1 0 1", " 2 0 1", 1),
                ":2: used `2` is not 0 or 1",
            ),
        ];
        for (bad, expected) in cases {
            std::fs::write(&path, format!("{HEADER}\n{bad}\n")).unwrap();
            let e = read_fixes(&path).unwrap_err().to_string();
            assert!(
                e.contains("fixes.txt") && e.contains(expected),
                "{bad}: {e}"
            );
        }
    }
}
