//! The envelope table: JointLoc over the HiRISE-class preset (`jointloc sim --difficulty
//! mars`: 25 cm/px map, 1 m stereo DTM) at each flight altitude × change of the sun's azimuth
//! between the map and the flight. One `jointloc run --sequential --start X,Y` per flight (the
//! take-off is given: the search without a prior is another question) and what a user of a
//! Mars helicopter asks of it: how much of the flight is in the map's frame, how many fixes
//! are right, the error online and at the end, the rate. Where single frames are matched (not
//! virtual frames), one `jointloc absloc --no-area-prediction` more times the search with no
//! prior position and no heading: the first fix without `--start`, or after a long loss.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::Context;
use jointloc_absloc::tiles::Ground;
use jointloc_bench::ground_truth::optical_axis_ground_point;
use jointloc_eval::{AlignMode, Statistics};
use jointloc_formats::elevation::ElevationModel;
use jointloc_formats::map_toml::MapInfo;
use jointloc_formats::outputs::fixes::read_fixes;
use jointloc_formats::outputs::summary::{Summary, read_json};
use jointloc_geometry::trajectory::{Trajectory, TumOptions};
use serde::Serialize;

use super::ablations::absloc_run;
use super::datasets::sim_into_place;
use super::exec::Runner;
use super::flights::jointloc_run;
use super::metrics::{self, fmt_ms};
use super::plan::Plan;
use super::report::Dataset;

/// A fix is right when it lies within this distance of the true ground point it measures.
pub(super) const FIX_RIGHT_M: f64 = 1.0;

/// Frames between two timed whole-map searches.
const WHOLE_MAP_EVERY: usize = 100;
/// Fixes after which the timed whole-map searches stop.
const WHOLE_MAP_FIXES: usize = 5;

/// One flight of the envelope table.
#[derive(Debug, Clone, Serialize)]
pub struct EnvelopeRow {
    pub terrain: String,
    pub seed: u64,
    pub altitude_m: f64,
    pub sun_change_deg: f64,
    /// Side of the simulated map, metres.
    pub map_size_m: f64,
    pub frames: usize,
    /// Fraction of frames with a world pose online.
    pub geo_referenced: Option<f64>,
    pub fixes_found: usize,
    /// Fraction of the found fixes within [`FIX_RIGHT_M`] of the true ground point under the
    /// image centre (what a fix measures).
    pub fixes_right: Option<f64>,
    /// World-frame APE, no alignment: online (`trajectory.tum`) and as known at the end.
    pub online: Option<Statistics>,
    pub end: Option<Statistics>,
    /// What the frame loop sustains (`capacity_hz`).
    pub hz: Option<f64>,
    /// Whole-map searches with no prior (every [`WHOLE_MAP_EVERY`]-th frame, at most
    /// [`WHOLE_MAP_FIXES`] fixes): median seconds per search, and the fraction of the searches
    /// that gave a right fix. `None` where virtual frames are matched (they need a prior).
    pub whole_map_s: Option<f64>,
    pub whole_map_right: Option<f64>,
    /// `jointloc sim …` and `jointloc run …`, as the report shows them.
    pub commands: Vec<String>,
    pub failed: Option<String>,
}

/// The flights of the table, in the plan's order: terrain, seed, altitude, sun change.
pub(super) fn envelope_rows(
    plan: &Plan,
    root: &Path,
    out: &Path,
    runner: &mut Runner,
) -> anyhow::Result<Vec<EnvelopeRow>> {
    let mut rows = Vec::new();
    for t in &plan.terrains {
        for &seed in &plan.seeds {
            for &alt in &plan.envelope.altitudes_m {
                for &sun in &plan.envelope.sun_changes_deg {
                    rows.push(flight(plan, root, out, runner, t, seed, alt, sun)?);
                }
            }
        }
    }
    Ok(rows)
}

#[allow(clippy::too_many_arguments)]
fn flight(
    plan: &Plan,
    root: &Path,
    out: &Path,
    runner: &mut Runner,
    terrain: &str,
    seed: u64,
    altitude_m: f64,
    sun_change_deg: f64,
) -> anyhow::Result<EnvelopeRow> {
    let map_size_m = plan.envelope.map_size_m;
    // The name is also the run's: `crater-mars-a100-sun90-s201`.
    let case = format!("mars-a{altitude_m}-sun{sun_change_deg}");
    let path = root.join(format!(
        "{terrain}-{case}-s{seed}-{}m-map{map_size_m}m",
        plan.length_m
    ));
    let mut row = EnvelopeRow {
        terrain: terrain.to_string(),
        seed,
        altitude_m,
        sun_change_deg,
        map_size_m,
        frames: 0,
        geo_referenced: None,
        fixes_found: 0,
        fixes_right: None,
        online: None,
        end: None,
        hz: None,
        whole_map_s: None,
        whole_map_right: None,
        commands: Vec::new(),
        failed: None,
    };
    let sim_args = args![
        "sim",
        "--terrain",
        terrain,
        "--difficulty",
        "mars",
        "--altitude",
        altitude_m,
        "--sun-azimuth-change-deg",
        sun_change_deg,
        "--map-size-m",
        map_size_m,
        "--length-m",
        plan.length_m,
        "--seed",
        seed
    ];
    if let Some(done) = sim_into_place(
        runner,
        &format!("{terrain}-{case}-s{seed}"),
        &path,
        &sim_args,
    )? {
        row.commands.push(done.command.clone());
        if let Err(reason) = done.outcome {
            row.failed = Some(format!("sim: {reason}"));
            return Ok(row);
        }
    }
    let gt = Trajectory::read_tum(path.join("uav/gt.txt"), &TumOptions::default())
        .with_context(|| format!("reading {}", path.join("uav/gt.txt").display()))?;
    row.frames = gt.len();
    let take_off = gt.poses[0].centre();
    let d = Dataset {
        terrain: terrain.to_string(),
        difficulty: case,
        seed,
        path: path.clone(),
        gt,
    };
    let start = format!("{:.3},{:.3}", take_off.x, take_off.y);
    let (done, dir) = jointloc_run(
        &d,
        out,
        runner,
        "envelope",
        &args!["--start", start],
        &plan.matcher,
    )?;
    row.commands.push(done.command.clone());
    if let Err(reason) = done.outcome {
        row.failed = Some(reason);
        return Ok(row);
    }
    let summary: Summary = read_json(&dir.join("summary.json"))?;
    row.geo_referenced = Some(summary.world_poses as f64 / summary.frames.max(1) as f64);
    row.hz = Some(summary.capacity_hz);
    let ape = |file: &str| metrics::ape(&d.gt, &dir.join(file), AlignMode::None, false);
    // A run with no world pose has no APE: the row says so instead of failing the table.
    match ape("trajectory.tum") {
        Ok(a) => row.online = Some(a.stats),
        Err(e) => row.failed = Some(format!("online: {e:#}")),
    }
    row.end = ape("trajectory-final.tum").ok().map(|a| a.stats);
    let (found, right) = fixes_right(&path, &dir.join("fixes.txt"), &d.gt)?;
    row.fixes_found = found;
    row.fixes_right = (found > 0).then(|| right as f64 / found as f64);
    if single_frames(&path, altitude_m)? {
        whole_map(&d, out, runner, &plan.matcher, &mut row)?;
    }
    Ok(row)
}

/// Whether a frame at `altitude_m` spans enough map pixels to be matched alone (else virtual
/// frames are, see `jointloc_system::MosaicConfig::below_frame_px`).
fn single_frames(dataset: &Path, altitude_m: f64) -> anyhow::Result<bool> {
    let camera = jointloc_formats::UavDataset::open(dataset)?.camera;
    let info = MapInfo::read(&dataset.join("map.toml"))?;
    let frame_px = camera.width as f64 * altitude_m / (0.5 * (camera.fx + camera.fy) * info.gsd_m);
    let below = jointloc_system::JointLocConfig::default()
        .mosaic
        .below_frame_px;
    Ok(frame_px >= below)
}

/// Times whole-map searches with neither position nor heading known (`jointloc absloc
/// --no-area-prediction`, the last fix's heading forgotten).
fn whole_map(
    d: &Dataset,
    out: &Path,
    runner: &mut Runner,
    matcher: &str,
    row: &mut EnvelopeRow,
) -> anyhow::Result<()> {
    let runs = out.join("runs");
    std::fs::create_dir_all(&runs).with_context(|| format!("creating {}", runs.display()))?;
    let name = format!("{}-whole-map", d.name());
    let config = runs.join(format!("{name}.toml"));
    std::fs::write(&config, "use_last_heading = false\n")
        .with_context(|| format!("writing {}", config.display()))?;
    let extra: Vec<String> = args![
        "--every",
        WHOLE_MAP_EVERY,
        "--limit",
        WHOLE_MAP_FIXES,
        "--no-area-prediction",
        "--config",
        config.display()
    ]
    .to_vec();
    let (done, fixes, json) = absloc_run(d, out, runner, matcher, "whole-map", &extra)?;
    row.commands.push(done.command.clone());
    if done.outcome.is_err() {
        return Ok(());
    }
    let text =
        std::fs::read_to_string(&json).with_context(|| format!("reading {}", json.display()))?;
    let v: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{}: not JSON", json.display()))?;
    row.whole_map_s = v["ms_per_fix_median"].as_f64().map(|ms| ms / 1e3);
    let tried = v["frames"].as_u64().unwrap_or(0) as usize;
    // `jointloc absloc --out` is TUM with more columns; failed frames are comments.
    let est = metrics::read_tum_prefix(&fixes)?;
    let found: Vec<(f64, [f64; 2])> = est
        .timestamps
        .iter()
        .zip(&est.poses)
        .map(|(&t, p)| {
            let c = p.centre();
            (t, [c.x, c.y])
        })
        .collect();
    let right = right_count(&d.path, &found, &d.gt)?;
    row.whole_map_right = (tried > 0).then(|| right as f64 / tried as f64);
    Ok(())
}

/// Found fixes of a run and how many lie within [`FIX_RIGHT_M`] of the true ground point
/// under the image centre, on the dataset's elevation model.
fn fixes_right(dataset: &Path, fixes: &Path, gt: &Trajectory) -> anyhow::Result<(usize, usize)> {
    let rows: Vec<(f64, [f64; 2])> = read_fixes(fixes)?
        .iter()
        .map(|f| (f.timestamp, [f.position[0], f.position[1]]))
        .collect();
    Ok((rows.len(), right_count(dataset, &rows, gt)?))
}

/// How many of `(timestamp, [x, y])` lie within [`FIX_RIGHT_M`] of the true ground point under
/// the image centre.
fn right_count(dataset: &Path, rows: &[(f64, [f64; 2])], gt: &Trajectory) -> anyhow::Result<usize> {
    let toml = dataset.join("map.toml");
    let info = MapInfo::read(&toml)?;
    let Some(elevation) = &info.elevation else {
        anyhow::bail!(
            "{}: no [elevation]; the envelope needs the DTM",
            toml.display()
        );
    };
    let ground = Ground::from_model(ElevationModel::read(elevation, dataset)?);
    let mut right = 0;
    for &(t, [fx, fy]) in rows {
        let Some(k) = gt.timestamps.iter().position(|&g| (g - t).abs() < 1e-4) else {
            continue;
        };
        if let Some((x, y)) = optical_axis_ground_point(&gt.poses[k], &ground)
            && (fx - x).hypot(fy - y) <= FIX_RIGHT_M
        {
            right += 1;
        }
    }
    Ok(right)
}

/// The table, one line per altitude × sun change × terrain (terrains differ too much under a
/// change of sun for a mean over them to say anything), mean ± std over seeds.
pub(super) fn envelope_md(s: &mut String, rows: &[EnvelopeRow]) {
    let _ = writeln!(s, "## 8. The Mars envelope (HiRISE-class maps)\n");
    if rows.is_empty() {
        let _ = writeln!(s, "Not run (`--tables envelope`).\n");
        return;
    }
    let _ = writeln!(
        s,
        "`jointloc sim --difficulty mars` (25 cm/px map of {} m, 1 m DTM) at each altitude and \
         change of the sun's azimuth between map and flight; `jointloc run --sequential --start` \
         at the true take-off. Geo-referenced: frames with a world pose online. Fixes right: \
         found fixes within {FIX_RIGHT_M} m of the true ground point under the image centre. APE \
         in the world frame, no alignment. Whole-map search: `jointloc absloc \
         --no-area-prediction` every {WHOLE_MAP_EVERY}th frame with no prior position or heading \
         (median s per search; right: searches that gave a right fix), where single frames are \
         matched. Mean ± std over seeds.\n",
        rows[0].map_size_m
    );
    let _ = writeln!(
        s,
        "| altitude m | sun change ° | terrain | flights | geo-referenced % | fixes right % | online APE rmse m | end APE rmse m | Hz | whole-map search s | right % |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|---|");
    // Altitude × sun change in the order flown, each with its terrains in the order flown.
    let mut cases: Vec<(f64, f64)> = Vec::new();
    for r in rows {
        if !cases.contains(&(r.altitude_m, r.sun_change_deg)) {
            cases.push((r.altitude_m, r.sun_change_deg));
        }
    }
    let mut lines: Vec<(f64, f64, &str)> = Vec::new();
    for &(alt, sun) in &cases {
        for r in rows
            .iter()
            .filter(|r| r.altitude_m == alt && r.sun_change_deg == sun)
        {
            if !lines.contains(&(alt, sun, r.terrain.as_str())) {
                lines.push((alt, sun, r.terrain.as_str()));
            }
        }
    }
    for (alt, sun, terrain) in lines {
        let group: Vec<&EnvelopeRow> = rows
            .iter()
            .filter(|r| r.altitude_m == alt && r.sun_change_deg == sun && r.terrain == terrain)
            .collect();
        let failed: Vec<&str> = group.iter().filter_map(|r| r.failed.as_deref()).collect();
        let flights = if failed.is_empty() {
            group.len().to_string()
        } else {
            format!(
                "{}, {} failed: {}",
                group.len(),
                failed.len(),
                failed[0].replace('|', "/")
            )
        };
        let pct = |f: fn(&EnvelopeRow) -> Option<f64>| {
            fmt_ms(
                &group
                    .iter()
                    .filter_map(|r| f(r))
                    .map(|v| 100.0 * v)
                    .collect::<Vec<_>>(),
                0,
            )
        };
        let ape = |f: fn(&EnvelopeRow) -> Option<&Statistics>| {
            fmt_ms(
                &group
                    .iter()
                    .filter_map(|r| f(r).map(|st| st.rmse))
                    .collect::<Vec<_>>(),
                3,
            )
        };
        let hz: Vec<f64> = group.iter().filter_map(|r| r.hz).collect();
        let whole: Vec<f64> = group.iter().filter_map(|r| r.whole_map_s).collect();
        let _ = writeln!(
            s,
            "| {alt} | {sun} | {terrain} | {flights} | {} | {} | {} | {} | {} | {} | {} |",
            pct(|r| r.geo_referenced),
            pct(|r| r.fixes_right),
            ape(|r| r.online.as_ref()),
            ape(|r| r.end.as_ref()),
            fmt_ms(&hz, 1),
            fmt_ms(&whole, 1),
            pct(|r| r.whole_map_right)
        );
    }
    let _ = writeln!(
        s,
        "\n<details><summary>Commands (first flight of each row)</summary>\n\n```sh"
    );
    let mut seen = Vec::new();
    for r in rows {
        let key = (r.altitude_m, r.sun_change_deg);
        if !seen.contains(&key) {
            seen.push(key);
            for c in &r.commands {
                let _ = writeln!(s, "{c}");
            }
        }
    }
    let _ = writeln!(s, "```\n</details>\n");
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(alt: f64, sun: f64, online: f64, right: Option<f64>) -> EnvelopeRow {
        terrain_row("crater", alt, sun, online, right)
    }

    fn terrain_row(
        terrain: &str,
        alt: f64,
        sun: f64,
        online: f64,
        right: Option<f64>,
    ) -> EnvelopeRow {
        let stats = |rmse| Statistics {
            rmse,
            mean: rmse,
            median: rmse,
            std: 0.0,
            min: 0.0,
            max: rmse,
            sse: 0.0,
            count: 1,
        };
        EnvelopeRow {
            terrain: terrain.into(),
            seed: 1,
            altitude_m: alt,
            sun_change_deg: sun,
            map_size_m: 500.0,
            frames: 10,
            geo_referenced: Some(0.5),
            fixes_found: 4,
            fixes_right: right,
            online: Some(stats(online)),
            end: Some(stats(online / 2.0)),
            hz: Some(20.0),
            whole_map_s: (alt >= 100.0).then_some(2.0),
            whole_map_right: (alt >= 100.0).then_some(0.8),
            commands: vec![format!("jointloc sim --altitude {alt}")],
            failed: None,
        }
    }

    #[test]
    fn one_line_per_case_and_terrain_in_the_order_flown() {
        let mut s = String::new();
        let mut failed = row(100.0, 90.0, 0.0, None);
        failed.online = None;
        failed.failed = Some("no world pose".into());
        envelope_md(
            &mut s,
            &[
                row(10.0, 30.0, 0.2, Some(0.75)),
                row(10.0, 30.0, 0.4, Some(0.25)),
                row(100.0, 90.0, 0.3, Some(1.0)),
                failed,
                terrain_row("gravel", 10.0, 30.0, 0.9, Some(1.0)),
            ],
        );
        // Mean ± std over the seeds of one terrain, never over terrains.
        assert!(
            s.contains(
                "| 10 | 30 | crater | 2 | 50 ± 0 | 50 ± 25 | 0.300 ± 0.100 | 0.150 ± 0.050 | 20.0 ± 0.0 | - | - |"
            ),
            "{s}"
        );
        assert!(
            s.contains("| 10 | 30 | gravel | 1 | 50 | 100 | 0.900 | 0.450 | 20.0 | - | - |"),
            "{s}"
        );
        assert!(
            s.contains("| 100 | 90 | crater | 2, 1 failed: no world pose |"),
            "{s}"
        );
        assert!(s.contains("| 2.0 ± 0.0 | 80 ± 0 |"), "{s}");
        let at = |k: &str| s.find(k).unwrap();
        assert!(at("| 10 | 30 | crater") < at("| 10 | 30 | gravel"));
        assert!(at("| 10 | 30 | gravel") < at("| 100 | 90"));
        assert_eq!(s.matches("jointloc sim --altitude").count(), 2, "{s}");
    }
}
