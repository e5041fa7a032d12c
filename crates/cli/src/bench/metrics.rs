//! Reading what the subcommands wrote and turning it into table cells: APE against ground
//! truth (through `jointloc_eval`, so the numbers are evo's), fixes, timing, mean ± std.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{Context, bail};
use jointloc_eval::{AlignMode, EvalConfig, Statistics, evaluate};
use jointloc_formats::outputs::read_fixes;
use jointloc_formats::outputs::summary::{Summary, read_json};
use jointloc_geometry::CameraToWorld;
use jointloc_geometry::trajectory::Trajectory;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use serde::Serialize;

/// TUM file whose rows may carry extra columns after the eight TUM ones (`jointloc absloc
/// --out` files do); `#` lines are comments. Every estimate the bench evaluates is read so:
/// `trajectory.tum` (whose frames without a world pose are comment lines),
/// `trajectory-final.tum`, VO's trajectory and the absolute localiser's fixes.
pub fn read_tum_prefix(path: &Path) -> anyhow::Result<Trajectory> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let mut stamps = Vec::new();
    let mut poses = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let v: Vec<f64> = line
            .split_whitespace()
            .take(8)
            .map(str::parse)
            .collect::<Result<_, _>>()
            .with_context(|| format!("{}:{}: not a number", path.display(), n + 1))?;
        if v.len() < 8 {
            bail!("{}:{}: fewer than 8 columns", path.display(), n + 1);
        }
        let q = UnitQuaternion::from_quaternion(Quaternion::new(v[7], v[4], v[5], v[6]));
        stamps.push(v[0]);
        poses.push(CameraToWorld(Isometry3::from_parts(
            Translation3::new(v[1], v[2], v[3]),
            q,
        )));
    }
    Trajectory::new(stamps, poses).with_context(|| format!("{}: not a trajectory", path.display()))
}

/// Confidence column (9th) of a `jointloc absloc --out` file, by timestamp; lines that do not
/// parse are left out.
fn read_fix_confidences(path: &Path) -> anyhow::Result<Vec<(f64, f64)>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let mut out = Vec::new();
    for line in text.lines() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let v: Vec<&str> = line.split_whitespace().collect();
        if let (Some(t), Some(w)) = (v.first(), v.get(8))
            && let (Ok(t), Ok(w)) = (t.parse::<f64>(), w.parse::<f64>())
        {
            out.push((t, w));
        }
    }
    Ok(out)
}

/// The absolute fixes of a flight as the figures show them.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FixSeries {
    /// Map x, y and confidence of each fix (empty when the positions cannot be read).
    pub xyw: Vec<(f64, f64, f64)>,
    /// Confidence of each fix, by timestamp.
    pub confidence: Vec<(f64, f64)>,
}

/// The fixes of `jointloc run`'s `fixes.txt`, through its reader in `jointloc_formats`.
pub fn run_fixes(path: &Path) -> anyhow::Result<FixSeries> {
    let rows = read_fixes(path)?;
    Ok(FixSeries {
        xyw: rows
            .iter()
            .map(|r| (r.position[0], r.position[1], r.confidence))
            .collect(),
        confidence: rows.iter().map(|r| (r.timestamp, r.confidence)).collect(),
    })
}

/// The fixes of a `jointloc absloc --out` file, a layout of its own (not `jointloc run`'s
/// `fixes.txt`): TUM with the fix's orientation, then `confidence tile ssim match_score
/// inliers`; failed frames are comment lines.
pub fn absloc_fixes(path: &Path) -> anyhow::Result<FixSeries> {
    let confidence = read_fix_confidences(path)?;
    let xyw = match read_tum_prefix(path) {
        Ok(t) if t.len() == confidence.len() => t
            .positions()
            .iter()
            .zip(&confidence)
            .map(|(p, &(_, w))| (p.x, p.y, w))
            .collect(),
        _ => Vec::new(),
    };
    Ok(FixSeries { xyw, confidence })
}

/// APE (translation) of an estimate file against ground truth.
#[derive(Debug, Clone, Serialize)]
pub struct Ape {
    pub stats: Statistics,
    pub poses: usize,
    /// Per-pose errors and their timestamps (for the error-over-time figure).
    #[serde(skip)]
    pub series: Vec<(f64, f64)>,
    /// The estimate after alignment (for the trajectory figure).
    #[serde(skip)]
    pub aligned_xy: Vec<(f64, f64)>,
}

/// Why a run wrote no world pose, from the `summary.json` beside its trajectory: how many
/// searches found a fix, and for a threaded run the hint that matters there.
fn why_no_world_pose(estimate: &Path) -> String {
    let summary = estimate
        .parent()
        .map(|d| d.join("summary.json"))
        .and_then(|p| read_json::<Summary>(&p).ok());
    let Some(s) = summary else {
        return "no fix came back before the last frame".into();
    };
    let mut why = format!(
        "{} of {} absolute searches found a fix, {} used ({})",
        s.fixes_found, s.absolute_attempts, s.fixes_used, s.mode
    );
    if s.mode != "sequential" && s.fixes_found == 0 {
        why.push_str(
            "; threaded, the first whole-map search can outlast a short flight: \
             `jointloc run --start X,Y` starts it at the take-off position",
        );
    }
    why
}

/// APE translation of `estimate` against `gt` with `align`; `xy_only` drops z first (for
/// 2-DoF absolute fixes).
pub fn ape(
    gt: &Trajectory,
    estimate: &Path,
    align: AlignMode,
    xy_only: bool,
) -> anyhow::Result<Ape> {
    let mut est = read_tum_prefix(estimate)?;
    if est.timestamps.is_empty() {
        anyhow::bail!(
            "no world-frame pose in {}: {}",
            estimate.display(),
            why_no_world_pose(estimate)
        );
    }
    let mut reference = gt.clone();
    if xy_only {
        flatten(&mut est);
        flatten(&mut reference);
    }
    let config = EvalConfig {
        align,
        ..Default::default()
    };
    let report = evaluate(&reference, &est, &config)
        .with_context(|| format!("evaluating {}", estimate.display()))?;
    let metric = &report.ape_translation;
    Ok(Ape {
        stats: metric.stats,
        poses: report.associated_poses,
        series: metric
            .timestamps
            .iter()
            .copied()
            .zip(metric.errors.iter().copied())
            .collect(),
        aligned_xy: report
            .aligned_estimate
            .positions()
            .iter()
            .map(|p| (p.x, p.y))
            .collect(),
    })
}

fn flatten(t: &mut Trajectory) {
    for p in &mut t.poses {
        p.0.translation.vector.z = 0.0;
    }
}

/// Medians of every numeric array (and plain numbers) of a timing JSON, by key path.
pub fn timing_medians(path: &Path) -> anyhow::Result<BTreeMap<String, f64>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let value: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{}: not JSON", path.display()))?;
    let mut out = BTreeMap::new();
    collect(&value, String::new(), &mut out);
    Ok(out)
}

fn collect(v: &serde_json::Value, key: String, out: &mut BTreeMap<String, f64>) {
    match v {
        serde_json::Value::Number(n) => {
            if let Some(x) = n.as_f64() {
                out.insert(key, x);
            }
        }
        serde_json::Value::Array(a) => {
            let mut xs: Vec<f64> = a.iter().filter_map(serde_json::Value::as_f64).collect();
            if !xs.is_empty() {
                xs.sort_by(f64::total_cmp);
                out.insert(format!("{key} (median)"), xs[xs.len() / 2]);
            }
        }
        serde_json::Value::Object(m) => {
            for (k, v) in m {
                let key = if key.is_empty() {
                    k.clone()
                } else {
                    format!("{key}.{k}")
                };
                collect(v, key, out);
            }
        }
        _ => {}
    }
}

/// `mean ± std` over seeds (population std), or the single value.
pub fn mean_std(values: &[f64]) -> Option<(f64, f64)> {
    if values.is_empty() {
        return None;
    }
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
    Some((mean, var.sqrt()))
}

/// Formats `mean ± std` with `digits` decimals; "-" when there is nothing.
pub fn fmt_ms(values: &[f64], digits: usize) -> String {
    match mean_std(values) {
        None => "-".into(),
        Some((m, _)) if values.len() == 1 => format!("{m:.digits$}"),
        Some((m, s)) => format!("{m:.digits$} ± {s:.digits$}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_std_and_formatting() {
        assert_eq!(mean_std(&[]), None);
        let (m, s) = mean_std(&[1.0, 3.0]).unwrap();
        assert!((m - 2.0).abs() < 1e-12 && (s - 1.0).abs() < 1e-12);
        assert_eq!(fmt_ms(&[0.1234], 3), "0.123");
        assert_eq!(fmt_ms(&[1.0, 3.0], 1), "2.0 ± 1.0");
        assert_eq!(fmt_ms(&[], 1), "-");
    }

    #[test]
    fn run_fixes_read_through_the_formats_reader() {
        use jointloc_formats::outputs::{FixRow, write_fixes};
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("fixes.txt");
        let row = |timestamp, x, confidence| FixRow {
            timestamp,
            position: [x, 2.0, 3.0],
            orientation: [0.0, 0.0, 0.0, 1.0],
            confidence,
            tile: 5,
            ssim: 0.9,
            match_score: 0.9,
            inliers: 40,
            used: true,
            inlier: true,
            injected: false,
        };
        write_fixes(&p, &[row(0.0, 1.0, 0.8), row(0.4, 2.5, 0.5)]).unwrap();
        let f = run_fixes(&p).unwrap();
        assert_eq!(f.xyw, vec![(1.0, 2.0, 0.8), (2.5, 2.0, 0.5)]);
        assert_eq!(f.confidence, vec![(0.0, 0.8), (0.4, 0.5)]);
        // The same file is a trajectory of positions to the TUM reader.
        assert_eq!(read_tum_prefix(&p).unwrap().len(), 2);
        // An absloc line (13 columns) is not a run's fix.
        std::fs::write(&p, "0.0 1 2 3 0 0 0 1 0.8 5 0.9 0.9 40\n").unwrap();
        let e = run_fixes(&p).unwrap_err().to_string();
        assert!(e.contains("fixes.txt:1") && e.contains("16 columns"), "{e}");
    }

    #[test]
    fn absloc_fixes_read_with_extra_columns_and_comments() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("absloc.txt");
        std::fs::write(
            &p,
            "0.0 1 2 3 0 0 0 1 0.8 5 0.9 0.9 40\n# 0.2 failed: NoMatch (9 tiles searched)\n\
             0.4 2 2 3 0 0 0 1 0.5 6 0.7 0.7 30\n",
        )
        .unwrap();
        let t = read_tum_prefix(&p).unwrap();
        assert_eq!(t.len(), 2);
        let f = absloc_fixes(&p).unwrap();
        assert_eq!(f.xyw, vec![(1.0, 2.0, 0.8), (2.0, 2.0, 0.5)]);
        assert_eq!(f.confidence, vec![(0.0, 0.8), (0.4, 0.5)]);
        std::fs::write(&p, "0.0 1 2 x 0 0 0 1\n").unwrap();
        let e = read_tum_prefix(&p).unwrap_err().to_string();
        assert!(e.contains("absloc.txt:1"), "{e}");
        // A line that does not read is no fix; positions that are no trajectory (time going
        // back) leave the confidences.
        assert_eq!(absloc_fixes(&p).unwrap(), FixSeries::default());
        std::fs::write(&p, "0.4 1 2 3 0 0 0 1 0.8\n0.2 1 2 3 0 0 0 1 0.6\n").unwrap();
        let f = absloc_fixes(&p).unwrap();
        assert!(f.xyw.is_empty());
        assert_eq!(f.confidence, vec![(0.4, 0.8), (0.2, 0.6)]);
    }

    #[test]
    fn timing_json_medians() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.json");
        std::fs::write(&p, r#"{"orb_ms":[3,1,2],"lba":{"ms":[5]},"hz":12.5}"#).unwrap();
        let m = timing_medians(&p).unwrap();
        assert_eq!(m["orb_ms (median)"], 2.0);
        assert_eq!(m["lba.ms (median)"], 5.0);
        assert_eq!(m["hz"], 12.5);
    }
}
