//! The UAV image sequence of a dataset folder, in the text layout of TUM RGB-D's `rgb.txt`:
//!
//! - `uav/images.txt`: `timestamp filename`, the file name relative to `uav/`. Required.
//! - `uav/altimeter.txt`: `timestamp altitude_m`, height above the ground below, metres.
//!   Optional: without it the frames have no altitude.
//! - `uav/gt.txt`: TUM `timestamp tx ty tz qx qy qz qw`, camera-to-world in the world frame of
//!   `map.toml`. Optional: ground truth, for evaluation.
//!
//! Timestamps are seconds; `#` lines and blank lines are comments. One rule set, checked when
//! the sequence is opened so that a bad dataset fails before any processing, with the file and
//! line: every line has its columns, every number is finite, timestamps strictly increase in
//! each file, altitudes are positive, every listed image exists, and at least one frame is
//! listed. Altimeter readings and ground-truth poses are joined to the frame whose timestamp is
//! within 1 ms (the nearest one); a frame without one has `None`, a reading without a frame is
//! ignored.
//!
//! [`Sequence::open_tolerant`] reads the same files for a flight that must not stop for one bad
//! sample: instead of failing it skips a bad frame line, drops a bad reading and reports each,
//! with the message the strict reader would have given ([`InputFault`]).
//!
//! The writer writes timestamps with six decimals, altitudes with four (0.1 mm) and poses with
//! round-trip precision, so the reader gives back what was written.

use std::path::{Path, PathBuf};

use image::GrayImage;
use jointloc_geometry::CameraToWorld;
use jointloc_geometry::trajectory::{Trajectory, TumOptions};

use crate::error::{FormatError, Result};
use crate::outputs::{number, read_text, write_text};

/// Readings and poses are joined to a frame whose timestamp is within this, seconds.
pub const JOIN_TOLERANCE_S: f64 = 1e-3;

/// One frame of the sequence.
#[derive(Debug, Clone, PartialEq)]
pub struct SequenceFrame {
    pub timestamp: f64,
    /// The image file (the dataset folder joined with `uav/` and the listed name).
    pub path: PathBuf,
    /// Altimeter reading at this timestamp (within 1 ms), if any.
    pub altitude: Option<f64>,
    /// Ground-truth camera-to-world pose at this timestamp (within 1 ms), if any.
    pub ground_truth: Option<CameraToWorld>,
}

/// The frames of a dataset, in order, with their altitudes and ground truth.
#[derive(Debug, Clone, PartialEq)]
pub struct Sequence {
    /// The dataset folder.
    pub root: PathBuf,
    pub frames: Vec<SequenceFrame>,
    /// Whether `uav/altimeter.txt` exists.
    pub has_altimeter: bool,
    /// Whether `uav/gt.txt` exists.
    pub has_ground_truth: bool,
}

/// `(line number, fields)` of the non-comment lines.
fn records(text: &str) -> impl Iterator<Item = (usize, Vec<&str>)> {
    text.lines().enumerate().filter_map(|(i, l)| {
        let l = l.trim();
        (!l.is_empty() && !l.starts_with('#')).then(|| (i + 1, l.split_whitespace().collect()))
    })
}

/// Checks that `t` is after `prev`.
fn increasing(path: &Path, line: usize, prev: Option<f64>, t: f64) -> Result<()> {
    match prev {
        Some(p) if t <= p => Err(FormatError::parse(
            path,
            line,
            format!("timestamp {t} is not after the previous one ({p})"),
        )),
        _ => Ok(()),
    }
}

/// Checks the column count.
fn columns(path: &Path, line: usize, fields: &[&str], layout: &str) -> Result<()> {
    if fields.len() == layout.split(' ').count() {
        Ok(())
    } else {
        Err(FormatError::parse(
            path,
            line,
            format!("expected `{layout}`, found {} columns", fields.len()),
        ))
    }
}

/// Index of the value (timestamps sorted) nearest `t` within [`JOIN_TOLERANCE_S`].
fn nearest<T>(values: &[(f64, T)], t: f64) -> Option<usize> {
    let i = values.partition_point(|v| v.0 < t);
    [i.checked_sub(1), Some(i)]
        .into_iter()
        .flatten()
        .filter(|&k| k < values.len() && (values[k].0 - t).abs() <= JOIN_TOLERANCE_S)
        .min_by(|&a, &b| (values[a].0 - t).abs().total_cmp(&(values[b].0 - t).abs()))
}

/// A line or a frame of the input that a tolerant read ([`Sequence::open_tolerant`]) or a
/// tolerant frame source skipped, dropped or flagged instead of failing, by kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum InputFaultKind {
    /// A listed image that cannot be decoded (e.g. a truncated PNG): the frame is skipped.
    FramesUnreadable,
    /// A listed image of another size than the camera's: the frame is skipped.
    FramesWrongSize,
    /// An `images.txt` line whose timestamp is not after the previous frame's: skipped.
    FramesOutOfOrder,
    /// An `images.txt` line naming an image that does not exist: skipped.
    FramesMissing,
    /// An `images.txt` line that does not parse (columns, timestamp): skipped.
    ImagesTxtMalformed,
    /// An `altimeter.txt` line that does not parse, or is out of order: dropped.
    AltimeterMalformed,
    /// An altimeter reading that is not finite or not positive: dropped.
    AltimeterInvalid,
    /// An altimeter reading that jumps from the last accepted one faster than the UAV can
    /// climb or sink (the fused system's gate): dropped.
    AltimeterJump,
    /// A frame without an altimeter line within 1 ms, when `altimeter.txt` exists.
    AltimeterMissing,
    /// A frame interval longer than 3× the median one (kept: the SLAM copes or recovers).
    TimeGaps,
}

impl InputFaultKind {
    /// The name in `summary.json`'s `input_faults`.
    pub fn name(self) -> &'static str {
        match self {
            Self::FramesUnreadable => "frames_unreadable",
            Self::FramesWrongSize => "frames_wrong_size",
            Self::FramesOutOfOrder => "frames_out_of_order",
            Self::FramesMissing => "frames_missing",
            Self::ImagesTxtMalformed => "images_txt_malformed",
            Self::AltimeterMalformed => "altimeter_malformed",
            Self::AltimeterInvalid => "altimeter_invalid",
            Self::AltimeterJump => "altimeter_jump",
            Self::AltimeterMissing => "altimeter_missing",
            Self::TimeGaps => "time_gaps",
        }
    }
}

/// One fault of the input: its kind and what the strict reader would have said (the file and
/// line or frame).
#[derive(Debug, Clone, PartialEq)]
pub struct InputFault {
    pub kind: InputFaultKind,
    pub message: String,
}

/// A frame interval longer than this many times the median one is a gap in time.
pub const GAP_FACTOR: f64 = 3.0;

/// Where the faults of a read go: `None` (strict) makes each an error.
struct Faults<'a>(Option<&'a mut Vec<InputFault>>);

impl Faults<'_> {
    /// `error` in a strict read; recorded as a fault of `kind` in a tolerant one.
    fn skip(&mut self, kind: InputFaultKind, error: FormatError) -> Result<()> {
        match &mut self.0 {
            None => Err(error),
            Some(faults) => {
                faults.push(InputFault {
                    kind,
                    message: error.to_string(),
                });
                Ok(())
            }
        }
    }

    fn tolerant(&self) -> bool {
        self.0.is_some()
    }
}

/// Reads `uav/images.txt` of `dir`.
fn read_images(dir: &Path, faults: &mut Faults) -> Result<Vec<SequenceFrame>> {
    use InputFaultKind as K;
    let uav = dir.join("uav");
    let list = uav.join("images.txt");
    let text = read_text(&list)?;
    let mut frames: Vec<SequenceFrame> = Vec::new();
    for (line, f) in records(&text) {
        let timestamp = match columns(&list, line, &f, "timestamp filename")
            .and_then(|()| number(&list, line, "timestamp", f[0]))
        {
            Ok(t) => t,
            Err(e) => {
                faults.skip(K::ImagesTxtMalformed, e)?;
                continue;
            }
        };
        if let Err(e) = increasing(&list, line, frames.last().map(|p| p.timestamp), timestamp) {
            faults.skip(K::FramesOutOfOrder, e)?;
            continue;
        }
        let path = uav.join(f[1]);
        if !path.is_file() {
            let message = format!("image {} does not exist", path.display());
            faults.skip(K::FramesMissing, FormatError::parse(&list, line, message))?;
            continue;
        }
        frames.push(SequenceFrame {
            timestamp,
            path,
            altitude: None,
            ground_truth: None,
        });
    }
    if frames.is_empty() {
        return Err(FormatError::invalid(&list, "no frames listed"));
    }
    if faults.tolerant() {
        let mut dt: Vec<f64> = frames
            .windows(2)
            .map(|w| w[1].timestamp - w[0].timestamp)
            .collect();
        dt.sort_unstable_by(f64::total_cmp);
        if let Some(&median) = dt.get(dt.len() / 2) {
            for w in frames.windows(2) {
                let gap = w[1].timestamp - w[0].timestamp;
                if gap > GAP_FACTOR * median {
                    let message = format!(
                        "gap of {gap:.3} s before frame {} ({}), {GAP_FACTOR}× the median \
                         interval {median:.3} s",
                        w[1].timestamp,
                        w[1].path.display()
                    );
                    faults.skip(K::TimeGaps, FormatError::invalid(&list, message))?;
                }
            }
        }
    }
    Ok(frames)
}

/// Reads an `altimeter.txt`: `(timestamp, altitude)` pairs, increasing.
pub fn read_altimeter(path: &Path) -> Result<Vec<(f64, f64)>> {
    let readings = read_altimeter_with(path, &mut Faults(None))?;
    Ok(readings
        .into_iter()
        .filter_map(|(t, a)| Some((t, a?)))
        .collect())
}

/// [`read_altimeter`]; a tolerant read keeps the timestamp of a reading it drops (`None`), so
/// that its frame does not count as missing a line.
fn read_altimeter_with(path: &Path, faults: &mut Faults) -> Result<Vec<(f64, Option<f64>)>> {
    use InputFaultKind as K;
    let text = read_text(path)?;
    let mut readings: Vec<(f64, Option<f64>)> = Vec::new();
    for (line, f) in records(&text) {
        let t = match columns(path, line, &f, "timestamp altitude_m")
            .and_then(|()| number(path, line, "timestamp", f[0]))
            .and_then(|t| increasing(path, line, readings.last().map(|r| r.0), t).map(|()| t))
        {
            Ok(t) => t,
            Err(e) => {
                faults.skip(K::AltimeterMalformed, e)?;
                continue;
            }
        };
        let a = match number(path, line, "altitude", f[1]) {
            Ok(a) => a,
            Err(e) => {
                let kind = if f[1].parse::<f64>().is_ok() {
                    K::AltimeterInvalid
                } else {
                    K::AltimeterMalformed
                };
                faults.skip(kind, e)?;
                readings.push((t, None));
                continue;
            }
        };
        if a <= 0.0 {
            let message = format!("altitude {a} m is not positive");
            faults.skip(K::AltimeterInvalid, FormatError::parse(path, line, message))?;
            readings.push((t, None));
            continue;
        }
        readings.push((t, Some(a)));
    }
    Ok(readings)
}

/// Reads a `gt.txt` (TUM, camera-to-world): `(timestamp, pose)` pairs, increasing.
pub fn read_ground_truth(path: &Path) -> Result<Vec<(f64, CameraToWorld)>> {
    use jointloc_geometry::GeometryError;
    let gt = Trajectory::read_tum(path, &TumOptions::default()).map_err(|e| match e {
        GeometryError::Io { path, source } => FormatError::Io { path, source },
        GeometryError::Parse {
            path,
            line,
            message,
        } => FormatError::Parse {
            path,
            line,
            message,
        },
        other => FormatError::invalid(path, other.to_string()),
    })?;
    Ok(gt.timestamps.into_iter().zip(gt.poses).collect())
}

impl Sequence {
    /// Reads and checks the sequence of the dataset folder `dir` (see the module's rules).
    pub fn open(dir: &Path) -> Result<Self> {
        Self::read(dir, &mut Faults(None))
    }

    /// Reads the sequence of `dir` leniently, for a flight that must not stop for one bad
    /// sample: an `images.txt` line that does not parse, is not after the previous frame or
    /// names an absent image is skipped; an `altimeter.txt` line that does not parse, is out of
    /// order, not finite or not positive is dropped (its frame has no altitude); frames
    /// without a reading (when `altimeter.txt` exists) and gaps longer than [`GAP_FACTOR`]×
    /// the median frame interval are reported. Each fault carries the strict reader's message.
    /// Still errors: no `images.txt`, no usable frame, an unreadable file, a bad `gt.txt`
    /// (evaluation only).
    pub fn open_tolerant(dir: &Path) -> Result<(Self, Vec<InputFault>)> {
        let mut faults = Vec::new();
        let sequence = Self::read(dir, &mut Faults(Some(&mut faults)))?;
        Ok((sequence, faults))
    }

    fn read(dir: &Path, faults: &mut Faults) -> Result<Self> {
        let mut frames = read_images(dir, faults)?;
        let uav = dir.join("uav");
        let alt_path = uav.join("altimeter.txt");
        let has_altimeter = alt_path.is_file();
        if has_altimeter {
            let readings = read_altimeter_with(&alt_path, faults)?;
            for f in &mut frames {
                match nearest(&readings, f.timestamp) {
                    Some(k) => f.altitude = readings[k].1,
                    None if faults.tolerant() => {
                        let message = format!(
                            "no reading within 1 ms of frame {} ({})",
                            f.timestamp,
                            f.path.display()
                        );
                        faults.skip(
                            InputFaultKind::AltimeterMissing,
                            FormatError::invalid(&alt_path, message),
                        )?;
                    }
                    None => {}
                }
            }
        }
        let gt_path = uav.join("gt.txt");
        let has_ground_truth = gt_path.is_file();
        if has_ground_truth {
            let poses = read_ground_truth(&gt_path)?;
            for f in &mut frames {
                f.ground_truth = nearest(&poses, f.timestamp).map(|k| poses[k].1);
            }
        }
        Ok(Self {
            root: dir.to_path_buf(),
            frames,
            has_altimeter,
            has_ground_truth,
        })
    }

    pub fn len(&self) -> usize {
        self.frames.len()
    }

    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// `uav/images.txt` of this sequence (what errors about the frame list name).
    pub fn list_path(&self) -> PathBuf {
        self.root.join("uav").join("images.txt")
    }

    /// Decodes frame `i` as an 8-bit grey image (colour images are converted); errors name the
    /// image file.
    pub fn load_image(&self, i: usize) -> Result<GrayImage> {
        let frame = self.frames.get(i).ok_or_else(|| {
            FormatError::invalid(
                self.list_path(),
                format!(
                    "no frame {i}: the sequence has {} frames",
                    self.frames.len()
                ),
            )
        })?;
        load_gray(&frame.path)
    }

    /// [`Self::load_image`], checking that the image is `width × height` pixels (the camera's).
    pub fn load_image_sized(&self, i: usize, width: u32, height: u32) -> Result<GrayImage> {
        let image = self.load_image(i)?;
        if image.dimensions() != (width, height) {
            return Err(FormatError::invalid(
                &self.frames[i].path,
                format!(
                    "image is {}x{} px but the camera is {width}x{height} px",
                    image.width(),
                    image.height()
                ),
            ));
        }
        Ok(image)
    }
}

/// Decodes an image file as 8-bit grey.
pub fn load_gray(path: &Path) -> Result<GrayImage> {
    let image = image::open(path).map_err(|e| match e {
        image::ImageError::IoError(source) => FormatError::io(path, source),
        other => FormatError::invalid(path, format!("cannot decode image: {other}")),
    })?;
    Ok(image.into_luma8())
}

/// One frame to write.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameRecord {
    pub timestamp: f64,
    /// The image file name, relative to `uav/`.
    pub image: String,
    /// Altimeter reading, metres (`None`: no line in `altimeter.txt`).
    pub altitude: Option<f64>,
    /// Camera-to-world pose (`None`: no line in `gt.txt`).
    pub ground_truth: Option<CameraToWorld>,
}

/// Text of the three files of a sequence; `gt` and `altimeter` are `None` when no frame has a
/// pose or a reading.
#[derive(Debug, Clone, PartialEq)]
pub struct SequenceTexts {
    pub images: String,
    pub ground_truth: Option<String>,
    pub altimeter: Option<String>,
}

/// The text of the files for `frames` (see [`write_sequence`]); `uav_dir` only labels errors.
pub fn sequence_texts(uav_dir: &Path, frames: &[FrameRecord]) -> Result<SequenceTexts> {
    let list = uav_dir.join("images.txt");
    let mut images = String::from("# timestamp filename (relative to this folder)\n");
    let mut gt = String::from(
        "# timestamp tx ty tz qx qy qz qw (camera-to-world, world frame of map.toml)\n",
    );
    let mut alt =
        String::from("# timestamp altitude_m (height above the terrain directly below, noisy)\n");
    let (mut any_gt, mut any_alt) = (false, false);
    let mut prev: Option<f64> = None;
    for (i, f) in frames.iter().enumerate() {
        let bad = |message: String| FormatError::invalid(&list, format!("frame {i}: {message}"));
        if !f.timestamp.is_finite() || prev.is_some_and(|p| f.timestamp <= p) {
            return Err(bad(format!(
                "timestamp {} is not finite or not after the previous one",
                f.timestamp
            )));
        }
        prev = Some(f.timestamp);
        if f.image.is_empty() || f.image.contains(char::is_whitespace) {
            return Err(bad(format!(
                "image name `{}` is empty or has spaces",
                f.image
            )));
        }
        let ts = format!("{:.6}", f.timestamp);
        images += &format!("{ts} {}\n", f.image);
        if let Some(pose) = &f.ground_truth {
            if !pose.is_finite() {
                return Err(bad("pose is not finite".into()));
            }
            let (t, q) = pose.to_translation_quaternion();
            gt += &format!(
                "{ts} {} {} {} {} {} {} {}\n",
                t[0], t[1], t[2], q[0], q[1], q[2], q[3]
            );
            any_gt = true;
        }
        if let Some(a) = f.altitude {
            if !(a.is_finite() && a > 0.0) {
                return Err(bad(format!("altitude {a} m is not finite and positive")));
            }
            alt += &format!("{ts} {a:.4}\n");
            any_alt = true;
        }
    }
    Ok(SequenceTexts {
        images,
        ground_truth: any_gt.then_some(gt),
        altimeter: any_alt.then_some(alt),
    })
}

/// Writes `images.txt`, and `gt.txt` and `altimeter.txt` when some frame has a pose or a
/// reading, into `uav_dir` (the images themselves are the caller's). Refuses what the reader
/// would refuse, except that the images need not exist yet.
pub fn write_sequence(uav_dir: &Path, frames: &[FrameRecord]) -> Result<()> {
    let texts = sequence_texts(uav_dir, frames)?;
    write_text(&uav_dir.join("images.txt"), &texts.images)?;
    if let Some(gt) = &texts.ground_truth {
        write_text(&uav_dir.join("gt.txt"), gt)?;
    }
    if let Some(alt) = &texts.altimeter {
        write_text(&uav_dir.join("altimeter.txt"), alt)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(x: f64) -> CameraToWorld {
        CameraToWorld::from_translation_quaternion([x, 2.0, 10.0], [0.0, 0.0, 0.6, 0.8])
    }

    /// A three-frame dataset written by the writer, with blank 4 × 3 images.
    fn dataset(dir: &Path) -> Vec<FrameRecord> {
        let uav = dir.join("uav");
        std::fs::create_dir_all(uav.join("images")).unwrap();
        let frames: Vec<FrameRecord> = (0..3)
            .map(|i| FrameRecord {
                timestamp: i as f64 / 5.0,
                image: format!("images/{i:06}.png"),
                altitude: (i != 1).then_some(10.0 + i as f64 / 8.0),
                ground_truth: Some(pose(i as f64 * 0.1 + 1.0 / 3.0)),
            })
            .collect();
        for f in &frames {
            GrayImage::new(4, 3).save(uav.join(&f.image)).unwrap();
        }
        write_sequence(&uav, &frames).unwrap();
        frames
    }

    fn set(dir: &Path, file: &str, text: &str) {
        std::fs::write(dir.join("uav").join(file), text).unwrap();
    }

    /// The error of opening `dir`, checked to name `file` at `line`.
    fn fails_at(dir: &Path, file: &str, line: usize) -> String {
        let e = Sequence::open(dir).unwrap_err();
        let msg = e.to_string();
        assert!(matches!(e, FormatError::Parse { .. }), "{msg}");
        assert!(msg.contains(&format!("{file}:{line}:")), "{msg}");
        msg
    }

    #[test]
    fn writer_and_reader_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let written = dataset(d);
        let seq = Sequence::open(d).unwrap();
        assert!(seq.has_altimeter && seq.has_ground_truth);
        assert_eq!(seq.len(), 3);
        for (f, w) in seq.frames.iter().zip(&written) {
            assert_eq!(f.timestamp, w.timestamp);
            assert_eq!(f.path, d.join("uav").join(&w.image));
            assert_eq!(f.altitude, w.altitude);
            // Round-trip precision.
            let (a, b) = (f.ground_truth.unwrap(), w.ground_truth.unwrap());
            assert_eq!(
                a.to_translation_quaternion().0,
                b.to_translation_quaternion().0
            );
        }
        let text = std::fs::read_to_string(d.join("uav/altimeter.txt")).unwrap();
        assert!(text.contains("\n0.400000 10.2500\n"), "{text}");
        assert_eq!(seq.load_image(2).unwrap().dimensions(), (4, 3));
        assert_eq!(seq.load_image_sized(0, 4, 3).unwrap().dimensions(), (4, 3));
        // Optional files.
        std::fs::remove_file(d.join("uav/gt.txt")).unwrap();
        std::fs::remove_file(d.join("uav/altimeter.txt")).unwrap();
        let seq = Sequence::open(d).unwrap();
        assert!(!seq.has_altimeter && !seq.has_ground_truth);
        assert!(
            seq.frames
                .iter()
                .all(|f| f.altitude.is_none() && f.ground_truth.is_none())
        );
    }

    #[test]
    fn readings_join_the_nearest_frame_within_a_millisecond() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        dataset(d);
        set(
            d,
            "altimeter.txt",
            "# t a\n0.0009 9.5\n0.1999 11.0\n0.2004 12.0\n0.4020 13.0\n",
        );
        set(d, "gt.txt", "0.4 1 2 3 0 0 0 1\n");
        let seq = Sequence::open(d).unwrap();
        let alt: Vec<Option<f64>> = seq.frames.iter().map(|f| f.altitude).collect();
        assert_eq!(alt, [Some(9.5), Some(11.0), None]);
        assert!(seq.frames[0].ground_truth.is_none());
        let p = seq.frames[2].ground_truth.unwrap();
        assert!((p.0.translation.vector.y - 2.0).abs() < 1e-12);
    }

    #[test]
    fn malformed_lines_name_the_file_and_line() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        dataset(d);
        let good_images = std::fs::read_to_string(d.join("uav/images.txt")).unwrap();
        let good_alt = std::fs::read_to_string(d.join("uav/altimeter.txt")).unwrap();
        let good_gt = std::fs::read_to_string(d.join("uav/gt.txt")).unwrap();
        let images = [
            (
                "0.0 images/000000.png\nzero images/000001.png\n",
                2,
                "not a number",
            ),
            (
                "0.0 images/000000.png\nNaN images/000001.png\n",
                2,
                "not finite",
            ),
            (
                "0.0 images/000000.png\ninf images/000001.png\n",
                2,
                "not finite",
            ),
            (
                "0.2 images/000000.png\n0.2 images/000001.png\n",
                2,
                "not after",
            ),
            (
                "0.2 images/000000.png\n0.1 images/000001.png\n",
                2,
                "not after",
            ),
            (
                "# c\n0.0 images/000000.png\n0.2 images/absent.png\n",
                3,
                "absent.png",
            ),
            ("0.0\n", 1, "timestamp filename"),
            ("0.0 images/000000.png extra\n", 1, "timestamp filename"),
        ];
        for (text, line, needle) in images {
            set(d, "images.txt", text);
            let msg = fails_at(d, "images.txt", line);
            assert!(msg.contains(needle), "{msg}");
        }
        set(d, "images.txt", &good_images);
        let altimeter = [
            ("0.0 10\n0.2 ten\n", 2, "not a number"),
            ("0.0 10\n0.2 NaN\n", 2, "not finite"),
            ("0.0 10\n0.2 -inf\n", 2, "not finite"),
            ("0.0 10\n0.2 0\n", 2, "not positive"),
            ("0.2 10\n0.2 11\n", 2, "not after"),
            ("# c\n\nx 10\n", 3, "not a number"),
            ("0.0\n", 1, "timestamp altitude_m"),
        ];
        for (text, line, needle) in altimeter {
            set(d, "altimeter.txt", text);
            let msg = fails_at(d, "altimeter.txt", line);
            assert!(msg.contains(needle), "{msg}");
        }
        set(d, "altimeter.txt", &good_alt);
        for (text, line) in [
            ("0.0 1 2 3 0 0 0 1\n0.2 1 2 nan 0 0 0 1\n", 2),
            ("0.2 1 2 3 0 0 0 1\n0.2 1 2 3 0 0 0 1\n", 2),
            ("0.0 1 2 3 0 0 0\n", 1),
        ] {
            set(d, "gt.txt", text);
            fails_at(d, "gt.txt", line);
        }
        set(d, "gt.txt", &good_gt);
        assert!(Sequence::open(d).is_ok());
    }

    #[test]
    fn missing_files_and_images_are_errors_naming_them() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let e = Sequence::open(&d.join("absent")).unwrap_err();
        assert!(matches!(e, FormatError::Io { .. }), "{e}");
        assert!(e.to_string().contains("images.txt"), "{e}");
        dataset(d);
        set(d, "images.txt", "# nothing\n");
        let e = Sequence::open(d).unwrap_err();
        assert!(e.to_string().contains("images.txt") && e.to_string().contains("no frames"));
        // An image that vanished after opening, or that is not an image, or another size.
        set(
            d,
            "images.txt",
            "0.0 images/000000.png\n0.2 images/000001.png\n",
        );
        let seq = Sequence::open(d).unwrap();
        std::fs::remove_file(d.join("uav/images/000000.png")).unwrap();
        let e = seq.load_image(0).unwrap_err();
        assert!(matches!(e, FormatError::Io { .. }), "{e}");
        assert!(e.to_string().contains("000000.png"), "{e}");
        std::fs::write(d.join("uav/images/000001.png"), b"not a png").unwrap();
        let e = seq.load_image(1).unwrap_err();
        assert!(e.to_string().contains("000001.png"), "{e}");
        let e = seq.load_image(5).unwrap_err();
        assert!(e.to_string().contains("images.txt"), "{e}");
        GrayImage::new(4, 3)
            .save(d.join("uav/images/000001.png"))
            .unwrap();
        let e = seq.load_image_sized(1, 5, 3).unwrap_err();
        let msg = e.to_string();
        assert!(msg.contains("000001.png") && msg.contains("4x3") && msg.contains("5x3"));
    }

    /// Faults of a tolerant open, counted by kind.
    fn counts(faults: &[InputFault]) -> Vec<(&'static str, usize)> {
        let mut m = std::collections::BTreeMap::new();
        for f in faults {
            *m.entry(f.kind.name()).or_insert(0) += 1;
        }
        m.into_iter().collect()
    }

    /// Ten frames at 5 Hz, every one with an altimeter reading.
    fn ten_frames(d: &Path) {
        let uav = d.join("uav");
        std::fs::create_dir_all(uav.join("images")).unwrap();
        let frames: Vec<FrameRecord> = (0..10)
            .map(|i| FrameRecord {
                timestamp: i as f64 / 5.0,
                image: format!("images/{i:06}.png"),
                altitude: Some(10.0 + i as f64 / 10.0),
                ground_truth: None,
            })
            .collect();
        for f in &frames {
            GrayImage::new(4, 3).save(uav.join(&f.image)).unwrap();
        }
        write_sequence(&uav, &frames).unwrap();
    }

    #[test]
    fn a_clean_sequence_opens_tolerantly_as_strictly_with_no_fault() {
        let dir = tempfile::tempdir().unwrap();
        ten_frames(dir.path());
        let (seq, faults) = Sequence::open_tolerant(dir.path()).unwrap();
        assert!(faults.is_empty(), "{faults:?}");
        assert_eq!(seq, Sequence::open(dir.path()).unwrap());
    }

    #[test]
    fn bad_frame_lines_are_skipped_and_counted_by_kind() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        ten_frames(d);
        // Line 1 is the header: frame k is on line k + 2.
        set(
            d,
            "images.txt",
            "# t f\n0.0 images/000000.png\n0.2 images/000001.png\nx images/000002.png\n\
             0.6\n0.6 images/000003.png\n0.6 images/000004.png\n0.4 images/000005.png\n\
             0.8 images/absent.png\n1.0 images/000006.png\n1.2 images/000007.png\n\
             1.4 images/000008.png\n",
        );
        let (seq, faults) = Sequence::open_tolerant(d).unwrap();
        let ts: Vec<f64> = seq.frames.iter().map(|f| f.timestamp).collect();
        assert_eq!(ts, [0.0, 0.2, 0.6, 1.0, 1.2, 1.4]);
        assert_eq!(
            counts(&faults),
            [
                ("frames_missing", 1),
                ("frames_out_of_order", 2),
                ("images_txt_malformed", 2),
            ]
        );
        // Each with the strict reader's message: the file and line.
        let missing = faults
            .iter()
            .find(|f| f.kind == InputFaultKind::FramesMissing)
            .unwrap();
        assert!(
            missing.message.contains("images.txt:9:") && missing.message.contains("absent.png"),
            "{missing:?}"
        );
        // The strict open fails at the first one, as before.
        fails_at(d, "images.txt", 4);
        // Nothing usable is still an error.
        set(
            d,
            "images.txt",
            "x images/000000.png\n0.2 images/absent.png\n",
        );
        let e = Sequence::open_tolerant(d).unwrap_err();
        assert!(e.to_string().contains("no frames"), "{e}");
    }

    #[test]
    fn bad_altimeter_lines_are_dropped_and_counted_by_kind() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        ten_frames(d);
        // Frames at 0.0 … 1.8: 0.2 NaN, 0.4 not a number, 0.6 negative, 0.8 zero, 1.0 inf,
        // 1.2 out of order (after 1.4), 1.6 absent, a line of one column.
        set(
            d,
            "altimeter.txt",
            "0.0 10\n0.2 nan\n0.4 ten\n0.6 -1\n0.8 0\n1.0 inf\n1.4 11.4\n1.2 11.2\n\
             1.7\n1.8 11.8\n",
        );
        let (seq, faults) = Sequence::open_tolerant(d).unwrap();
        assert_eq!(seq.len(), 10);
        let alt: Vec<Option<f64>> = seq.frames.iter().map(|f| f.altitude).collect();
        assert_eq!(
            alt,
            [
                Some(10.0),
                None,
                None,
                None,
                None,
                None,
                None,
                Some(11.4),
                None,
                Some(11.8)
            ]
        );
        assert_eq!(
            counts(&faults),
            [
                ("altimeter_invalid", 4),
                ("altimeter_malformed", 3),
                ("altimeter_missing", 2),
            ]
        );
        assert!(
            faults
                .iter()
                .any(|f| f.message.contains("altimeter.txt:2:") && f.message.contains("finite")),
            "{faults:?}"
        );
        fails_at(d, "altimeter.txt", 2);
    }

    #[test]
    fn gaps_in_time_are_counted_and_kept() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        ten_frames(d);
        // 0.0 0.2 0.4 | 1.4 1.6 | 1.8 (0.8 s: 4× the median 0.2 s) — two gaps.
        set(
            d,
            "images.txt",
            "0.0 images/000000.png\n0.2 images/000001.png\n0.4 images/000002.png\n\
             1.4 images/000003.png\n1.6 images/000004.png\n2.4 images/000005.png\n\
             2.6 images/000006.png\n2.8 images/000007.png\n",
        );
        std::fs::remove_file(d.join("uav/altimeter.txt")).unwrap();
        let (seq, faults) = Sequence::open_tolerant(d).unwrap();
        assert_eq!(seq.len(), 8);
        assert_eq!(counts(&faults), [("time_gaps", 2)]);
        assert!(faults[0].message.contains("1.4"), "{faults:?}");
        // Strictly, a gap is no error.
        assert_eq!(Sequence::open(d).unwrap(), seq);
    }

    #[test]
    fn the_writer_refuses_what_the_reader_would() {
        let dir = tempfile::tempdir().unwrap();
        let frame = |t: f64, alt: Option<f64>| FrameRecord {
            timestamp: t,
            image: "a.png".into(),
            altitude: alt,
            ground_truth: None,
        };
        for frames in [
            vec![frame(0.0, None), frame(0.0, None)],
            vec![frame(f64::NAN, None)],
            vec![frame(0.0, Some(f64::NAN))],
            vec![frame(0.0, Some(-1.0))],
        ] {
            let e = write_sequence(dir.path(), &frames).unwrap_err();
            assert!(e.to_string().contains("images.txt"), "{e}");
        }
        assert!(!dir.path().join("images.txt").exists());
    }
}
