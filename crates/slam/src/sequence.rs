//! An image sequence in the dataset layout of DESIGN §3: `uav/images.txt` (`timestamp
//! filename`, relative to `uav/`) and, optionally, `uav/altimeter.txt` (`timestamp altitude_m`).
//! Everything is checked when the sequence is opened (files present, numbers finite, timestamps
//! increasing) so a bad dataset fails before any processing, with the file and line.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::error::{Result, SlamError};

/// One frame of the sequence.
#[derive(Debug, Clone, PartialEq)]
pub struct SequenceFrame {
    pub timestamp: f64,
    pub path: PathBuf,
    /// Altimeter reading at this timestamp (within 1 ms), if any.
    pub altitude: Option<f64>,
}

/// The frames of a dataset, in order.
#[derive(Debug, Clone, PartialEq)]
pub struct Sequence {
    pub frames: Vec<SequenceFrame>,
}

fn parse_err(path: &Path, line: usize, message: impl Into<String>) -> SlamError {
    SlamError::Parse {
        path: path.to_path_buf(),
        line,
        message: message.into(),
    }
}

fn read(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).map_err(|source| SlamError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// `(line number, fields)` of the non-comment lines.
fn records(text: &str) -> impl Iterator<Item = (usize, Vec<&str>)> {
    text.lines().enumerate().filter_map(|(i, l)| {
        let l = l.trim();
        (!l.is_empty() && !l.starts_with('#')).then(|| (i + 1, l.split_whitespace().collect()))
    })
}

fn number(path: &Path, line: usize, what: &str, s: &str) -> Result<f64> {
    let v: f64 = s
        .parse()
        .map_err(|_| parse_err(path, line, format!("{what} `{s}` is not a number")))?;
    if !v.is_finite() {
        return Err(parse_err(path, line, format!("{what} `{s}` is not finite")));
    }
    Ok(v)
}

impl Sequence {
    /// Reads the sequence of the dataset folder `dir`.
    pub fn open(dir: &Path) -> Result<Self> {
        let uav = dir.join("uav");
        let list = uav.join("images.txt");
        let text = read(&list)?;
        let mut frames: Vec<SequenceFrame> = Vec::new();
        for (line, f) in records(&text) {
            if f.len() < 2 {
                return Err(parse_err(&list, line, "expected `timestamp filename`"));
            }
            let timestamp = number(&list, line, "timestamp", f[0])?;
            if let Some(prev) = frames.last()
                && timestamp <= prev.timestamp
            {
                return Err(parse_err(
                    &list,
                    line,
                    format!("timestamp {timestamp} not after {}", prev.timestamp),
                ));
            }
            let path = uav.join(f[1]);
            if !path.is_file() {
                return Err(parse_err(
                    &list,
                    line,
                    format!("image {} does not exist", path.display()),
                ));
            }
            frames.push(SequenceFrame {
                timestamp,
                path,
                altitude: None,
            });
        }
        if frames.is_empty() {
            return Err(parse_err(&list, 0, "no frames listed"));
        }
        let alt_path = uav.join("altimeter.txt");
        if alt_path.is_file() {
            let text = read(&alt_path)?;
            // Keyed by microseconds so that timestamps written with 6 decimals match exactly.
            let mut readings: BTreeMap<i64, f64> = BTreeMap::new();
            for (line, f) in records(&text) {
                if f.len() < 2 {
                    return Err(parse_err(
                        &alt_path,
                        line,
                        "expected `timestamp altitude_m`",
                    ));
                }
                let t = number(&alt_path, line, "timestamp", f[0])?;
                let a = number(&alt_path, line, "altitude", f[1])?;
                if a <= 0.0 {
                    return Err(parse_err(
                        &alt_path,
                        line,
                        format!("altitude {a} m is not positive"),
                    ));
                }
                readings.insert((t * 1e6).round() as i64, a);
            }
            for fr in &mut frames {
                let key = (fr.timestamp * 1e6).round() as i64;
                fr.altitude = readings
                    .range(key - 1000..=key + 1000)
                    .next()
                    .map(|(_, &a)| a);
            }
        }
        Ok(Self { frames })
    }

    pub fn len(&self) -> usize {
        self.frames.len()
    }

    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Decodes frame `i` as an 8-bit grey image (colour images are converted).
    pub fn load_image(&self, i: usize) -> Result<image::GrayImage> {
        let frame = self.frames.get(i).ok_or_else(|| SlamError::InvalidFrame {
            index: i,
            reason: format!("the sequence has {} frames", self.frames.len()),
        })?;
        let img = image::open(&frame.path).map_err(|e| SlamError::ImageDecode {
            path: frame.path.clone(),
            message: e.to_string(),
        })?;
        Ok(img.into_luma8())
    }
}
