//! Running one flight (`jointloc run`) and turning any run's estimate into a table row.

use std::path::{Path, PathBuf};

use jointloc_eval::AlignMode;

use super::exec::{Finished, Runner};
use super::metrics;
use super::report::{Dataset, LocRow};

/// Frames per second of a run: what its frame loop sustains (`capacity_hz`: frames over the
/// time spent processing them, which a real-time replay's waits do not count), else its own
/// frames-over-wall figure, else frames over process wall time (start-up included).
fn hz_of(
    done: &Finished,
    frames: usize,
    timing: Option<&std::collections::BTreeMap<String, f64>>,
) -> f64 {
    timing
        .and_then(|t| t.get("capacity_hz").or_else(|| t.get("hz")).copied())
        .unwrap_or(frames as f64 / done.wall_s.max(1e-9))
}

pub(super) fn jointloc_run(
    d: &Dataset,
    out: &Path,
    runner: &mut Runner,
    tag: &str,
    extra: &[String],
    matcher: &str,
) -> anyhow::Result<(Finished, PathBuf)> {
    let dir = out
        .join("runs")
        .join(format!("{}-jointloc-{tag}", d.name()));
    let mut a: Vec<String> = args![
        "run",
        "--dataset",
        d.path.display(),
        "--out",
        dir.display(),
        "--matcher",
        matcher,
        "--force"
    ]
    .to_vec();
    // Deterministic unless the row is about the real-time mode.
    if tag != "realtime" {
        a.push("--sequential".into());
    }
    a.extend_from_slice(extra);
    let done = runner.run(&format!("run-{}-{tag}", d.name()), &a)?;
    Ok((done, dir))
}

pub(super) fn loc_row(
    d: &Dataset,
    method: String,
    done: &Finished,
    estimate: &Path,
    align: AlignMode,
    xy_only: bool,
    timing: Option<std::collections::BTreeMap<String, f64>>,
) -> (LocRow, Option<metrics::Ape>) {
    let ape = done
        .outcome
        .clone()
        .and_then(|()| metrics::ape(&d.gt, estimate, align, xy_only).map_err(|e| format!("{e:#}")));
    let hz = hz_of(done, d.gt.len(), timing.as_ref());
    match ape {
        Ok(a) => (
            LocRow {
                dataset: d.key(),
                method,
                stats: Some(a.stats),
                poses: a.poses,
                hz: Some(hz),
                timing: timing.unwrap_or_default(),
                command: done.command.clone(),
                failed: None,
            },
            Some(a),
        ),
        Err(reason) => (
            LocRow {
                dataset: d.key(),
                method,
                stats: None,
                poses: 0,
                hz: None,
                timing: Default::default(),
                command: done.command.clone(),
                failed: Some(reason),
            },
            None,
        ),
    }
}
