//! Table VI on one dataset: JointLoc (online, as known at the end, real time), VO only and
//! absolute only, with the figures of the first seed.

use std::path::Path;

use jointloc_eval::AlignMode;

use super::dataset_figures::figures_for;
use super::exec::{Finished, Runner};
use super::flights::{jointloc_run, loc_row};
use super::metrics;
use super::plan::Plan;
use super::report::{Dataset, Report};

pub(super) fn localisation_rows(
    plan: &Plan,
    d: &Dataset,
    out: &Path,
    runner: &mut Runner,
    rep: &mut Report,
) -> anyhow::Result<()> {
    // JointLoc: world frame, no alignment.
    let (done, dir) = jointloc_run(d, out, runner, "default", &[], &plan.matcher)?;
    let timing = metrics::timing_medians(&dir.join("timing.json")).ok();
    let (row, joint) = loc_row(
        d,
        format!("JointLoc ({})", plan.matcher),
        &done,
        &dir.join("trajectory.tum"),
        AlignMode::None,
        false,
        timing,
    );
    rep.localisation.push(row);
    // The same run's output as known at the end (`trajectory-final.tum`: the whole map
    // bundle-adjusted once more with every fix), an after-the-flight figure like VO's.
    let (row, _) = loc_row(
        d,
        format!("JointLoc, as known at the end ({})", plan.matcher),
        &done,
        &dir.join("trajectory-final.tum"),
        AlignMode::None,
        false,
        None,
    );
    rep.localisation.push(row);
    // The same in the real-time mode: absolute localisation on its own thread, frames replayed
    // at their timestamps as the camera delivers them (fixes due while it is busy are skipped).
    let (done, realtime_dir) = jointloc_run(
        d,
        out,
        runner,
        "realtime",
        &args!["--realtime", plan.replay_speed],
        &plan.matcher,
    )?;
    let timing_t = metrics::timing_medians(&realtime_dir.join("timing.json")).ok();
    let speed = if plan.replay_speed == 1.0 {
        "camera rate".to_string()
    } else {
        format!("{}× camera rate", plan.replay_speed)
    };
    let (row, _) = loc_row(
        d,
        format!("JointLoc real time ({}, {speed})", plan.matcher),
        &done,
        &realtime_dir.join("trajectory.tum"),
        AlignMode::None,
        false,
        timing_t,
    );
    rep.localisation.push(row);
    // VO only: Sim(3)-aligned, as monocular SLAM is evaluated.
    let vo_path = out.join("runs").join(format!("{}-vo.tum", d.name()));
    let done = runner.run(
        &format!("vo-{}", d.name()),
        &args![
            "vo",
            "--dataset",
            d.path.display(),
            "--out",
            vo_path.display(),
            "--sequential",
            "--force"
        ],
    )?;
    let (row, vo) = loc_row(
        d,
        "VO only (Sim(3)-aligned)".into(),
        &done,
        &vo_path,
        AlignMode::Sim3,
        false,
        None,
    );
    rep.localisation.push(row);
    // The same SLAM without loop closing, to show what the loops bring.
    let open_path = out.join("runs").join(format!("{}-vo-open.tum", d.name()));
    let done = runner.run(
        &format!("vo-open-{}", d.name()),
        &args![
            "vo",
            "--dataset",
            d.path.display(),
            "--out",
            open_path.display(),
            "--sequential",
            "--no-loop-closing",
            "--force"
        ],
    )?;
    let (row, _) = loc_row(
        d,
        "VO only, no loop closing (Sim(3)-aligned)".into(),
        &done,
        &open_path,
        AlignMode::Sim3,
        false,
        None,
    );
    rep.localisation.push(row);
    // A user's own baselines (ORB-SLAM2/3 …), Sim(3)-aligned as VO.
    for (name, pattern) in &plan.peers {
        let path = std::path::PathBuf::from(pattern.replace("{dataset}", &d.name()));
        let given = Finished {
            command: format!("--peer {name}={}", path.display()),
            wall_s: 0.0,
            outcome: if path.is_file() {
                Ok(())
            } else {
                Err(format!("no file {}", path.display()))
            },
        };
        let (mut row, _) = loc_row(
            d,
            format!("{name} (peer, Sim(3)-aligned)"),
            &given,
            &path,
            AlignMode::Sim3,
            false,
            None,
        );
        row.hz = None;
        rep.localisation.push(row);
    }
    // Absolute only: 2-D error of the fixes.
    let fixes = out.join("runs").join(format!("{}-absloc.txt", d.name()));
    let json = out.join("runs").join(format!("{}-absloc.json", d.name()));
    let done = runner.run(
        &format!("absloc-{}", d.name()),
        &args![
            "absloc",
            "--dataset",
            d.path.display(),
            "--matcher",
            plan.matcher,
            "--every",
            plan.abs_every,
            "--out",
            fixes.display(),
            "--json",
            json.display(),
            "--force"
        ],
    )?;
    let frames = d.gt.len().div_ceil(plan.abs_every);
    let (mut row, abs) = loc_row(
        d,
        format!(
            "Absolute only ({}, every {}, 2-D)",
            plan.matcher, plan.abs_every
        ),
        &done,
        &fixes,
        AlignMode::None,
        true,
        None,
    );
    if row.failed.is_none() {
        row.hz = Some(frames as f64 / done.wall_s.max(1e-9));
    }
    rep.localisation.push(row);

    // Figures for the first seed, from the default run (its fixes with its trajectory).
    if d.seed == plan.seeds[0] {
        figures_for(
            d,
            out,
            &dir,
            joint.as_ref(),
            vo.as_ref(),
            abs.as_ref(),
            &fixes,
            rep,
        )?;
    }
    Ok(())
}
