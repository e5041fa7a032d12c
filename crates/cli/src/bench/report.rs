//! The rows the benchmark collects, aggregated over seeds (mean ± std) into the Markdown
//! report and written in full as JSON.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context;
use jointloc_eval::Statistics;
use jointloc_geometry::trajectory::Trajectory;
use serde::Serialize;

use super::envelope::{EnvelopeRow, envelope_md};
use super::metrics::fmt_ms;
use super::paths::PathNames;

/// One generated dataset.
#[derive(Debug, Clone)]
pub struct Dataset {
    pub terrain: String,
    pub difficulty: String,
    pub seed: u64,
    pub path: PathBuf,
    pub gt: Trajectory,
}

impl Dataset {
    /// File-name stem.
    pub fn name(&self) -> String {
        format!("{}-{}-s{}", self.terrain, self.difficulty, self.seed)
    }

    pub fn key(&self) -> DatasetKey {
        DatasetKey {
            terrain: self.terrain.clone(),
            difficulty: self.difficulty.clone(),
            seed: self.seed,
        }
    }
}

/// Which dataset a row is from.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Serialize)]
pub struct DatasetKey {
    pub terrain: String,
    pub difficulty: String,
    pub seed: u64,
}

impl std::fmt::Display for DatasetKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} {} seed {}", self.terrain, self.difficulty, self.seed)
    }
}

/// A matcher on one dataset's pairs (Table V).
#[derive(Debug, Clone, Serialize)]
pub struct MatchRow {
    pub dataset: DatasetKey,
    pub matcher: String,
    /// Fraction of pairs under each corner-error threshold, keys like `@5px`.
    pub accuracy: BTreeMap<String, f64>,
    pub ms_median: f64,
    pub command: String,
    pub failed: Option<String>,
}

/// A localisation result on one dataset (Tables VI, II, III, IV).
#[derive(Debug, Clone, Serialize)]
pub struct LocRow {
    pub dataset: DatasetKey,
    pub method: String,
    /// Translation APE (m).
    pub stats: Option<Statistics>,
    pub poses: usize,
    pub hz: Option<f64>,
    /// Module medians (ms) and other per-run figures.
    pub timing: BTreeMap<String, f64>,
    pub command: String,
    pub failed: Option<String>,
}

/// Everything the benchmark measured.
#[derive(Debug, Serialize)]
pub struct Report {
    pub machine: String,
    pub plan: String,
    pub date: String,
    pub commit: String,
    /// Wall time of the benchmark; with `--resume`, including the reused runs' own times.
    pub total_s: f64,
    /// Runs reused from earlier invocations (`--resume`) and their summed wall time.
    pub reused_runs: usize,
    pub reused_s: f64,
    pub matching: Vec<MatchRow>,
    pub localisation: Vec<LocRow>,
    pub fusion_frequency: Vec<LocRow>,
    pub area_prediction: Vec<LocRow>,
    pub confidence: Vec<LocRow>,
    pub envelope: Vec<EnvelopeRow>,
    pub figures: Vec<String>,
}

impl Report {
    pub fn new(machine: String, plan: &str) -> Self {
        Self {
            machine,
            plan: plan.to_string(),
            date: utc_date(),
            commit: git_commit(),
            total_s: 0.0,
            reused_runs: 0,
            reused_s: 0.0,
            matching: Vec::new(),
            localisation: Vec::new(),
            fusion_frequency: Vec::new(),
            area_prediction: Vec::new(),
            confidence: Vec::new(),
            envelope: Vec::new(),
            figures: Vec::new(),
        }
    }

    /// Writes `report.md` and `report.json` into `out`, every path in them (commands,
    /// failure reasons) as `names` shows it: relative to `out`.
    pub fn write(&self, out: &Path, names: &PathNames) -> anyhow::Result<()> {
        let json = out.join("report.json");
        let text = names.scrub(&(serde_json::to_string_pretty(self)? + "\n"));
        std::fs::write(&json, text).with_context(|| format!("writing {}", json.display()))?;
        let md = out.join("report.md");
        std::fs::write(&md, names.scrub(&self.markdown()))
            .with_context(|| format!("writing {}", md.display()))
    }

    fn markdown(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(s, "# JointLoc benchmark\n");
        let _ = writeln!(
            s,
            "{} · commit `{}` · {}  \n{} · total {:.1} min{}\n",
            self.date,
            self.commit,
            self.machine,
            self.plan,
            self.total_s / 60.0,
            if self.reused_runs > 0 {
                format!(
                    " ({} runs, {:.1} min of it, ran in earlier invocations and were reused \
                     with `--resume`)",
                    self.reused_runs,
                    self.reused_s / 60.0
                )
            } else {
                String::new()
            }
        );
        let _ = writeln!(
            s,
            "Cells are mean ± std over seeds (a single value when there is one seed). APE is the \
             translation error in metres computed as evo does (`jointloc eval`). JointLoc rows are \
             evaluated **without alignment** (its output is in the world frame): the output online \
             (`trajectory.tum`) and, from the same run, as known at the end \
             (`trajectory-final.tum`, after a global BA with every fix); VO-only rows (with loop closing, and without it) are \
             Sim(3)-aligned; absolute-only rows are 2-D errors of the fixes. Hz of a JointLoc row is \
             what its frame loop sustains (frames over the time spent processing them; the \
             real-time row replays frames at their timestamps, and its waits do not count); of a \
             VO or absolute-only row, frames per second of the process's wall time. A failed run is a \
             row that says why, as the paper's \"-\". Full data: `report.json`; logs of every run: `logs/`. \
             Paths are relative to this report's folder (`runs/`, `datasets/`); `<datasets>` \
             stands for the folder given with `--datasets` when it is elsewhere.\n"
        );
        self.matching_md(&mut s);
        loc_md(
            &mut s,
            "2. Visual localisation (paper Table VI)",
            &self.localisation,
            true,
        );
        loc_md(
            &mut s,
            "3. Fusion frequency (paper Table II)",
            &self.fusion_frequency,
            false,
        );
        area_md(&mut s, &self.area_prediction);
        loc_md(
            &mut s,
            "5. Confidence (paper Table IV)",
            &self.confidence,
            false,
        );
        self.timing_md(&mut s);
        let _ = writeln!(s, "## 7. Figures\n");
        for f in &self.figures {
            let _ = writeln!(s, "![{f}](figures/{f})\n");
        }
        envelope_md(&mut s, &self.envelope);
        s
    }

    fn matching_md(&self, s: &mut String) {
        let _ = writeln!(s, "## 1. Matching (paper Table V)\n");
        if self.matching.is_empty() {
            let _ = writeln!(s, "Not run.\n");
            return;
        }
        let _ = writeln!(
            s,
            "Mean corner error of the homography refitted over the footprint with biweight \
             weights (`jointloc match`'s default on simulated pairs, whose ground truth is the \
             whole footprint's homography; `--fit tight` gives the paper's RANSAC score).\n"
        );
        let thresholds: BTreeSet<String> = self
            .matching
            .iter()
            .flat_map(|r| r.accuracy.keys().cloned())
            .collect();
        let mut thresholds: Vec<String> = thresholds.into_iter().collect();
        thresholds.sort_by_key(|k| {
            k.trim_start_matches('@')
                .trim_end_matches("px")
                .parse::<f64>()
                .map_or(i64::MAX, |v| (v * 1000.0) as i64)
        });
        let _ = write!(s, "| terrain | difficulty | matcher |");
        for t in &thresholds {
            let _ = write!(s, " {t} |");
        }
        let _ = writeln!(s, " ms per pair |");
        let _ = writeln!(s, "|---|---|---|{}---|", "---|".repeat(thresholds.len()));
        let mut groups: BTreeMap<(String, String, String), Vec<&MatchRow>> = BTreeMap::new();
        for r in &self.matching {
            groups
                .entry((
                    r.dataset.difficulty.clone(),
                    r.dataset.terrain.clone(),
                    r.matcher.clone(),
                ))
                .or_default()
                .push(r);
        }
        for ((d, t, m), rows) in &groups {
            let _ = write!(s, "| {t} | {d} | {m} |");
            if let Some(f) = rows.iter().find_map(|r| r.failed.as_ref()) {
                let _ = writeln!(s, " failed: {} |", f.replace('|', "/"));
                continue;
            }
            for th in &thresholds {
                let v: Vec<f64> = rows
                    .iter()
                    .filter_map(|r| r.accuracy.get(th).copied())
                    .collect();
                let _ = write!(s, " {} |", fmt_ms(&v, 2));
            }
            let ms: Vec<f64> = rows
                .iter()
                .map(|r| r.ms_median)
                .filter(|v| v.is_finite())
                .collect();
            let _ = writeln!(s, " {} |", fmt_ms(&ms, 0));
        }
        commands_md(s, self.matching.iter().map(|r| (&r.dataset, &r.command)));
    }

    fn timing_md(&self, s: &mut String) {
        let _ = writeln!(s, "## 6. Module timing (paper Table VII)\n");
        let jl: Vec<&LocRow> = self
            .localisation
            .iter()
            // The sequential runs: their module times do not share the cores with a thread.
            .filter(|r| r.method.starts_with("JointLoc (") && !r.timing.is_empty())
            .collect();
        if jl.is_empty() {
            let _ = writeln!(s, "No timing was reported by the JointLoc runs.\n");
            return;
        }
        let terrains: BTreeSet<String> = jl.iter().map(|r| r.dataset.terrain.clone()).collect();
        let keys: BTreeSet<String> = jl.iter().flat_map(|r| r.timing.keys().cloned()).collect();
        let _ = write!(s, "| module (median per run, ms unless named) |");
        for t in &terrains {
            let _ = write!(s, " {t} |");
        }
        let _ = writeln!(s, "\n|---|{}", "---|".repeat(terrains.len()));
        for k in &keys {
            let _ = write!(s, "| {k} |");
            for t in &terrains {
                let v: Vec<f64> = jl
                    .iter()
                    .filter(|r| &r.dataset.terrain == t)
                    .filter_map(|r| r.timing.get(k).copied())
                    .collect();
                let _ = write!(s, " {} |", fmt_ms(&v, 1));
            }
            let _ = writeln!(s);
        }
        let _ = writeln!(s);
    }
}

fn loc_md(s: &mut String, title: &str, rows: &[LocRow], per_dataset: bool) {
    let _ = writeln!(s, "## {title}\n");
    if rows.is_empty() {
        let _ = writeln!(s, "Not run.\n");
        return;
    }
    let _ = writeln!(
        s,
        "| {}method | runs | max | rmse | std | mean | Hz |",
        if per_dataset {
            "terrain | difficulty | "
        } else {
            ""
        }
    );
    let _ = writeln!(
        s,
        "|{}---|---|---|---|---|---|---|",
        if per_dataset { "---|---|" } else { "" }
    );
    // Rows keep the order in which their method first ran (JointLoc, VO, absolute; or the
    // ablation's settings in order), grouped over seeds.
    let mut groups: BTreeMap<(String, String, usize, String), Vec<&LocRow>> = BTreeMap::new();
    for r in rows {
        let order = rows.iter().position(|o| o.method == r.method).unwrap_or(0);
        let (d, t) = if per_dataset {
            (r.dataset.difficulty.clone(), r.dataset.terrain.clone())
        } else {
            (String::new(), String::new())
        };
        groups
            .entry((d, t, order, r.method.clone()))
            .or_default()
            .push(r);
    }
    for ((d, t, _, method), group) in &groups {
        if per_dataset {
            let _ = write!(s, "| {t} | {d} | {method} |");
        } else {
            let _ = write!(s, "| {method} |");
        }
        let ok: Vec<&Statistics> = group.iter().filter_map(|r| r.stats.as_ref()).collect();
        let failed: Vec<&str> = group.iter().filter_map(|r| r.failed.as_deref()).collect();
        let runs = if failed.is_empty() {
            format!("{}", ok.len())
        } else {
            format!(
                "{} ok, {} failed: {}",
                ok.len(),
                failed.len(),
                failed[0].replace('|', "/")
            )
        };
        let col =
            |f: fn(&Statistics) -> f64| fmt_ms(&ok.iter().map(|st| f(st)).collect::<Vec<_>>(), 3);
        let hz: Vec<f64> = group.iter().filter_map(|r| r.hz).collect();
        let _ = writeln!(
            s,
            " {runs} | {} | {} | {} | {} | {} |",
            col(|st| st.max),
            col(|st| st.rmse),
            col(|st| st.std),
            col(|st| st.mean),
            fmt_ms(&hz, 1)
        );
    }
    commands_md(s, rows.iter().map(|r| (&r.dataset, &r.command)));
}

fn area_md(s: &mut String, rows: &[LocRow]) {
    let _ = writeln!(s, "## 4. Area prediction (paper Table III)\n");
    if rows.is_empty() {
        let _ = writeln!(s, "Not run.\n");
        return;
    }
    let _ = writeln!(
        s,
        "| absolute localisation, every 10th frame | runs | 2-D rmse | 2-D mean | ms per fix | tiles matched per fix |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|");
    let mut methods: Vec<&str> = Vec::new();
    for r in rows {
        if !methods.contains(&r.method.as_str()) {
            methods.push(&r.method);
        }
    }
    for m in methods {
        let group: Vec<&LocRow> = rows.iter().filter(|r| r.method == m).collect();
        let ok: Vec<&Statistics> = group.iter().filter_map(|r| r.stats.as_ref()).collect();
        let get = |k: &str| {
            group
                .iter()
                .filter_map(|r| r.timing.get(k).copied())
                .collect::<Vec<_>>()
        };
        let _ = writeln!(
            s,
            "| {m} | {} | {} | {} | {} | {} |",
            ok.len(),
            fmt_ms(&ok.iter().map(|st| st.rmse).collect::<Vec<_>>(), 3),
            fmt_ms(&ok.iter().map(|st| st.mean).collect::<Vec<_>>(), 3),
            fmt_ms(&get("ms per fix (mean)"), 1),
            fmt_ms(&get("tiles matched per fix"), 1)
        );
    }
    commands_md(s, rows.iter().map(|r| (&r.dataset, &r.command)));
}

/// The commands of the first seed, one per row, to reproduce it.
fn commands_md<'a>(s: &mut String, rows: impl Iterator<Item = (&'a DatasetKey, &'a String)>) {
    let mut seen = BTreeSet::new();
    let mut first_seed = None;
    let _ = writeln!(
        s,
        "\n<details><summary>Commands (one per row, first seed)</summary>\n\n```sh"
    );
    for (d, c) in rows {
        let fs = *first_seed.get_or_insert(d.seed);
        if d.seed == fs && seen.insert(c.clone()) {
            let _ = writeln!(s, "{c}");
        }
    }
    let _ = writeln!(s, "```\n</details>\n");
}

/// The commit the binary was built from; else the working directory's (a build without git).
fn git_commit() -> String {
    let built = env!("JOINTLOC_BUILD_COMMIT");
    if !built.is_empty() {
        return built.to_string();
    }
    std::process::Command::new("git")
        .args(["rev-parse", "--short", "HEAD"])
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .unwrap_or_else(|| "unknown".into())
}

/// `YYYY-MM-DD HH:MM UTC` from the system clock (civil-from-days, no date crate needed).
pub(super) fn utc_date() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs() as i64);
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02} {:02}:{:02} UTC",
        rem / 3600,
        rem % 3600 / 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(seed: u64, method: &str, rmse: f64) -> LocRow {
        LocRow {
            dataset: DatasetKey {
                terrain: "crater".into(),
                difficulty: "easy".into(),
                seed,
            },
            method: method.into(),
            stats: Some(Statistics {
                rmse,
                mean: rmse,
                median: rmse,
                std: 0.0,
                min: 0.0,
                max: rmse,
                sse: 0.0,
                count: 1,
            }),
            poses: 10,
            hz: Some(20.0),
            timing: BTreeMap::new(),
            command: format!("jointloc run --seed {seed}"),
            failed: None,
        }
    }

    #[test]
    fn seeds_are_aggregated_and_failures_are_rows() {
        let mut s = String::new();
        let mut rows = vec![row(1, "JointLoc", 0.1), row(2, "JointLoc", 0.3)];
        let mut failed = row(1, "every 100 frames", 0.0);
        failed.stats = None;
        failed.failed = Some("tracking lost".into());
        rows.push(failed);
        loc_md(&mut s, "t", &rows, true);
        assert!(
            s.contains("| crater | easy | JointLoc | 2 | 0.200 ± 0.100 |"),
            "{s}"
        );
        assert!(s.contains("0 ok, 1 failed: tracking lost"), "{s}");
        assert!(
            s.contains("jointloc run --seed 1") && !s.contains("jointloc run --seed 2"),
            "{s}"
        );
    }

    #[test]
    fn the_date_is_a_calendar_date() {
        let d = utc_date();
        assert!(
            d.starts_with("20") && d.ends_with("UTC") && d.len() == 20,
            "{d}"
        );
    }
}
