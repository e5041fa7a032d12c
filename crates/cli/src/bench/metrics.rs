//! Reading what the subcommands wrote and turning it into table cells: APE against ground
//! truth (through `jointloc_eval`, so the numbers are evo's), fixes, timing, mean ± std.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{Context, bail};
use jointloc_eval::{AlignMode, EvalConfig, Statistics, evaluate};
use jointloc_geometry::CameraToWorld;
use jointloc_geometry::trajectory::Trajectory;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use serde::Serialize;

/// TUM file whose rows may carry extra columns after the eight TUM ones (the fixes files do);
/// `#` lines are comments.
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

/// Confidence column (9th) of a fixes file, by timestamp.
pub fn read_fix_confidences(path: &Path) -> anyhow::Result<Vec<(f64, f64)>> {
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
            "no world-frame pose in {}: no fix came back before the last frame (threaded, \
             the first whole-map search can outlast a short flight; `jointloc run --start X,Y` \
             starts it at the take-off position)",
            estimate.display()
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
    fn fixes_files_read_with_extra_columns_and_comments() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("fixes.txt");
        std::fs::write(
            &p,
            "# header\n0.0 1 2 3 0 0 0 1 0.8 5 0.9 0.9 40\n# 0.2 failed\n0.4 2 2 3 0 0 0 1 0.5 6 0.7 0.7 30\n",
        )
        .unwrap();
        let t = read_tum_prefix(&p).unwrap();
        assert_eq!(t.len(), 2);
        assert_eq!(
            read_fix_confidences(&p).unwrap(),
            vec![(0.0, 0.8), (0.4, 0.5)]
        );
        std::fs::write(&p, "0.0 1 2 x 0 0 0 1\n").unwrap();
        let e = read_tum_prefix(&p).unwrap_err().to_string();
        assert!(e.contains("fixes.txt:1"), "{e}");
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
