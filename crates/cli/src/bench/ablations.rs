//! The ablations on one dataset: fusion frequency (Table II), confidence (Table IV) and area
//! prediction (Table III).

use std::path::Path;

use jointloc_eval::AlignMode;

use super::exec::Runner;
use super::flights::{jointloc_run, loc_row};
use super::metrics;
use super::plan::Plan;
use super::report::{Dataset, Report};

pub(super) fn ablations(
    plan: &Plan,
    d: &Dataset,
    out: &Path,
    runner: &mut Runner,
    rep: &mut Report,
) -> anyhow::Result<()> {
    // Table II: fusion frequency, the paper's intervals and our default (5).
    let frequencies: &[usize] = if plan.wants("fusion") {
        &[1, 5, 10, 50, 100]
    } else {
        &[]
    };
    let default_every = jointloc_system::JointLocConfig::default().fusion_every;
    for &k in frequencies {
        // The default frequency is the localisation table's run.
        let (tag, extra) = if k == default_every {
            ("default".to_string(), Vec::new())
        } else {
            (format!("every{k}"), args!["--fusion-every", k].to_vec())
        };
        let (done, dir) = jointloc_run(d, out, runner, &tag, &extra, &plan.matcher)?;
        let timing = metrics::timing_medians(&dir.join("timing.json")).ok();
        let (row, _) = loc_row(
            d,
            format!("every {k} frames"),
            &done,
            &dir.join("trajectory.tum"),
            AlignMode::None,
            false,
            timing,
        );
        rep.fusion_frequency.push(row);
    }
    // Table IV: confidence.
    let modes = [
        "fixed:0.2",
        "fixed:0.4",
        "fixed:0.6",
        "fixed:0.8",
        "fixed:1.0",
        "ssim",
        "matching",
        "adaptive",
    ];
    let default_mode = jointloc_system::JointLocConfig::default().absloc.confidence;
    for m in modes.into_iter().filter(|_| plan.wants("confidence")) {
        let (tag, extra) =
            if m.parse::<jointloc_absloc::ConfidenceMode>().ok() == Some(default_mode) {
                ("default".to_string(), Vec::new())
            } else {
                (
                    format!("conf-{}", m.replace([':', '.'], "")),
                    args!["--confidence", m].to_vec(),
                )
            };
        let (done, dir) = jointloc_run(d, out, runner, &tag, &extra, &plan.matcher)?;
        let (row, _) = loc_row(
            d,
            m.to_string(),
            &done,
            &dir.join("trajectory.tum"),
            AlignMode::None,
            false,
            None,
        );
        rep.confidence.push(row);
    }
    // Table III: area prediction, on the absolute localiser (every 10th frame).
    let area = [
        ("with area prediction", Vec::new()),
        (
            "without (global search)",
            args!["--no-area-prediction"].to_vec(),
        ),
    ];
    for (label, extra) in area.into_iter().filter(|_| plan.wants("area")) {
        let tag = if extra.is_empty() { "area" } else { "noarea" };
        let extra: Vec<String> = args!["--every", 10].into_iter().chain(extra).collect();
        let (done, fixes, json) = absloc_run(d, out, runner, &plan.matcher, tag, &extra)?;
        let (mut row, _) = loc_row(
            d,
            label.to_string(),
            &done,
            &fixes,
            AlignMode::None,
            true,
            None,
        );
        if let Ok(text) = std::fs::read_to_string(&json)
            && let Ok(v) = serde_json::from_str::<serde_json::Value>(&text)
        {
            row.hz = None;
            if let Some(ms) = v["ms_per_fix_mean"].as_f64() {
                row.timing.insert("ms per fix (mean)".into(), ms);
            }
            if let Some(t) = v["tiles_per_fix_mean"].as_f64() {
                row.timing.insert("tiles matched per fix".into(), t);
            }
        }
        rep.area_prediction.push(row);
    }
    Ok(())
}

/// One `jointloc absloc` run on `d` with `extra` arguments, its fixes and JSON summary in
/// `runs/<dataset>-absloc-<tag>.{txt,json}`; returns the run and those two paths.
pub(super) fn absloc_run(
    d: &Dataset,
    out: &Path,
    runner: &mut Runner,
    matcher: &str,
    tag: &str,
    extra: &[String],
) -> anyhow::Result<(
    super::exec::Finished,
    std::path::PathBuf,
    std::path::PathBuf,
)> {
    let runs = out.join("runs");
    let fixes = runs.join(format!("{}-absloc-{tag}.txt", d.name()));
    let json = runs.join(format!("{}-absloc-{tag}.json", d.name()));
    let mut a: Vec<String> = args![
        "absloc",
        "--dataset",
        d.path.display(),
        "--matcher",
        matcher,
        "--out",
        fixes.display(),
        "--json",
        json.display(),
        "--force"
    ]
    .to_vec();
    a.extend_from_slice(extra);
    let done = runner.run(&format!("absloc-{}-{tag}", d.name()), &a)?;
    Ok((done, fixes, json))
}
