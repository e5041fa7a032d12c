//! The simulated datasets of the plan: generated with `jointloc sim` (or reused when already
//! there), with their ground truth read back.

use std::path::Path;

use anyhow::Context;
use jointloc_geometry::trajectory::{Trajectory, TumOptions};

use super::exec::{Finished, Runner};
use super::plan::Plan;
use super::report::Dataset;

pub(super) fn make_datasets(
    plan: &Plan,
    root: &Path,
    runner: &mut Runner,
) -> anyhow::Result<Vec<Dataset>> {
    let mut out = Vec::new();
    for d in &plan.difficulties {
        for t in &plan.terrains {
            for &s in &plan.seeds {
                let path = root.join(format!("{t}-{d}-s{s}-{}m", plan.length_m));
                let name = format!("{t}-{d}-s{s}");
                let sim_args = args![
                    "sim",
                    "--terrain",
                    t,
                    "--length-m",
                    plan.length_m,
                    "--seed",
                    s,
                    "--difficulty",
                    d
                ];
                if let Some(done) = sim_into_place(runner, &name, &path, &sim_args)?
                    && let Err(reason) = done.outcome
                {
                    anyhow::bail!("`{}` failed: {reason}", done.command);
                }
                let gt = Trajectory::read_tum(path.join("uav/gt.txt"), &TumOptions::default())
                    .with_context(|| format!("reading {}", path.join("uav/gt.txt").display()))?;
                out.push(Dataset {
                    terrain: t.clone(),
                    difficulty: d.clone(),
                    seed: s,
                    path,
                    gt,
                });
            }
        }
    }
    Ok(out)
}

/// Renders `jointloc sim <sim_args>` into `root/.<name>.partial` and moves it to `path` once
/// it succeeded, so an interrupted benchmark never leaves a half dataset where a later one
/// would reuse it. `None` when `path` already holds a dataset; a failed run stays where it was.
pub(super) fn sim_into_place(
    runner: &mut Runner,
    name: &str,
    path: &Path,
    sim_args: &[String],
) -> anyhow::Result<Option<Finished>> {
    if path.join("uav/gt.txt").exists() {
        return Ok(None);
    }
    let root = path.parent().unwrap_or(Path::new("."));
    let tmp = root.join(format!(".{name}.partial"));
    let _ = std::fs::remove_dir_all(&tmp);
    let mut a = sim_args.to_vec();
    a.extend(args!["--out", tmp.display()]);
    let done = runner.run(&format!("sim-{name}"), &a)?;
    if done.outcome.is_ok() {
        std::fs::rename(&tmp, path)
            .with_context(|| format!("moving {} into place", path.display()))?;
    }
    Ok(Some(done))
}
