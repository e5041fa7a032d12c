//! The simulated datasets of the plan: generated with `jointloc sim` (or reused when already
//! there), with their ground truth read back.

use std::path::Path;

use anyhow::Context;
use jointloc_geometry::trajectory::{Trajectory, TumOptions};

use super::exec::Runner;
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
                if !path.join("uav/gt.txt").exists() {
                    let tmp = root.join(format!(".{t}-{d}-s{s}.partial"));
                    let _ = std::fs::remove_dir_all(&tmp);
                    runner.run_required(
                        &format!("sim-{t}-{d}-s{s}"),
                        &args![
                            "sim",
                            "--terrain",
                            t,
                            "--length-m",
                            plan.length_m,
                            "--seed",
                            s,
                            "--difficulty",
                            d,
                            "--out",
                            tmp.display()
                        ],
                    )?;
                    std::fs::rename(&tmp, &path)
                        .with_context(|| format!("moving {} into place", path.display()))?;
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
