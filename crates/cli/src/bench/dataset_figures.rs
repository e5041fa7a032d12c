//! The figures of one dataset: trajectories over the satellite map, position error over time
//! and the fixes' confidence with the search radius it gives.

use std::path::Path;

use super::figures;
use super::metrics;
use super::report::{Dataset, Report};

#[allow(clippy::too_many_arguments)]
pub(super) fn figures_for(
    d: &Dataset,
    out: &Path,
    run_dir: &Path,
    joint: Option<&metrics::Ape>,
    vo: Option<&metrics::Ape>,
    abs: Option<&metrics::Ape>,
    abs_fixes: &Path,
    rep: &mut Report,
) -> anyhow::Result<()> {
    let fig = out.join("figures");
    let gt_xy: Vec<(f64, f64)> = d.gt.positions().iter().map(|p| (p.x, p.y)).collect();
    // The run's fixes, else (no fixes.txt in the run) the absolute localiser's, whose file
    // has another layout.
    let run_fixes = run_dir.join("fixes.txt");
    let fixes = if run_fixes.exists() {
        metrics::run_fixes(&run_fixes)
    } else {
        metrics::absloc_fixes(abs_fixes)
    }
    .unwrap_or_default();
    let mut tracks = vec![figures::Track {
        label: "ground truth",
        colour: "black",
        xy: &gt_xy,
    }];
    if let Some(j) = joint {
        tracks.push(figures::Track {
            label: "JointLoc",
            colour: "#1f5fd6",
            xy: &j.aligned_xy,
        });
    }
    if let Some(v) = vo {
        tracks.push(figures::Track {
            label: "VO (Sim(3)-aligned)",
            colour: "#e07b00",
            xy: &v.aligned_xy,
        });
    }
    match jointloc_absloc::MapTiles::open(&d.path) {
        Ok(map) => {
            let name = format!("{}-trajectories.svg", d.name());
            figures::trajectories_over_map(
                &fig.join(&name),
                map.map(),
                map.gsd_m(),
                &tracks,
                Some(&figures::Fixes { xyw: &fixes.xyw }),
                &format!("{} — trajectories over the satellite map", d.key()),
                &rep.machine,
            )?;
            rep.figures.push(name);
        }
        Err(e) => tracing::warn!("{}: no map figure: {e}", d.path.display()),
    }
    let mut series = Vec::new();
    if let Some(j) = joint {
        series.push(figures::Series {
            label: "JointLoc",
            colour: "#1f5fd6",
            points: &j.series,
        });
    }
    if let Some(v) = vo {
        series.push(figures::Series {
            label: "VO (Sim(3))",
            colour: "#e07b00",
            points: &v.series,
        });
    }
    if let Some(a) = abs {
        series.push(figures::Series {
            label: "absolute (2-D)",
            colour: "#2a9d4a",
            points: &a.series,
        });
    }
    let name = format!("{}-error.svg", d.name());
    figures::line_chart(
        &fig.join(&name),
        &format!("{} — position error over time", d.key()),
        "APE (m)",
        &series,
        &rep.machine,
    )?;
    rep.figures.push(name);
    let w = &fixes.confidence;
    if !w.is_empty() {
        let radius: Vec<(f64, f64)> = w
            .iter()
            .map(|&(t, w)| (t, jointloc_absloc::search_radius(w) as f64))
            .collect();
        let name = format!("{}-confidence.svg", d.name());
        figures::line_chart(
            &fig.join(&name),
            &format!(
                "{} — fix confidence w and next search radius r = ⌈10^(1−w)⌉ (tiles)",
                d.key()
            ),
            "w / r",
            &[
                figures::Series {
                    label: "confidence w",
                    colour: "#2a9d4a",
                    points: w,
                },
                figures::Series {
                    label: "search radius r",
                    colour: "#b02a2a",
                    points: &radius,
                },
            ],
            &rep.machine,
        )?;
        rep.figures.push(name);
    }
    Ok(())
}
