//! `jointloc bench`: the paper's tables (V, VI, II, III, IV, VII) and figures on simulated
//! datasets, in one command. Each row is produced by running the corresponding `jointloc`
//! subcommand as a child process (so every row has a command that reproduces it) and reading
//! what it wrote; metrics come from `jointloc_eval`, i.e. evo's numbers.

mod exec;
mod figures;
mod journal;
mod machine;
mod metrics;
mod report;

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail};
use jointloc_eval::AlignMode;
use jointloc_geometry::trajectory::{Trajectory, TumOptions};

use exec::{Finished, Runner};
use report::{Dataset, LocRow, MatchRow, Report};

macro_rules! args {
    ($($a:expr),* $(,)?) => { [$($a.to_string()),*] };
}

const ALL_MATCHERS: [&str; 6] = [
    "orb",
    "xfeat-mnn",
    "xfeat-lighterglue",
    "aliked-lightglue",
    "disk-lightglue",
    "superpoint-mnn",
];

const TABLES: [&str; 5] = ["matching", "localisation", "fusion", "area", "confidence"];

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Output folder: report.md, report.json, figures/, logs/ (and datasets/ unless --datasets).
    #[arg(long)]
    out: PathBuf,
    /// Short protocol for a first look (≤ 20 min on 2 cores): one seed, 60 m flights, easy only,
    /// the three fastest matchers in the matching table. Ablations are on the first terrain and
    /// difficulty in both protocols.
    #[arg(long)]
    quick: bool,
    /// Seeds per terrain and difficulty (default 3; 1 with --quick).
    #[arg(long, value_name = "N")]
    seeds: Option<u64>,
    /// First dataset seed (seeds are consecutive from it).
    #[arg(long, value_name = "S", default_value_t = 201)]
    first_seed: u64,
    /// Terrains, comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = ["crater".to_string(), "gravel".to_string(), "mountain".to_string()])]
    terrains: Vec<String>,
    /// Difficulties, comma separated (default easy,medium; easy with --quick).
    #[arg(long, value_delimiter = ',')]
    difficulty: Option<Vec<String>>,
    /// Flight length in metres (default 150; 60 with --quick).
    #[arg(long, value_name = "M")]
    length_m: Option<f64>,
    /// Where datasets are generated, or reused when already there (default OUT/datasets).
    #[arg(long, value_name = "DIR")]
    datasets: Option<PathBuf>,
    /// Matchers of the matching table, comma separated (default all six; with --quick orb,
    /// xfeat-mnn, xfeat-lighterglue).
    #[arg(long, value_delimiter = ',')]
    matchers: Option<Vec<String>>,
    /// Matcher of the JointLoc and absolute-only rows.
    #[arg(long, value_name = "M", default_value = "xfeat-lighterglue")]
    matcher: String,
    /// Absolute-only rows localise every K-th frame (the frames JointLoc fuses; the paper's
    /// baseline localises every frame, which gives the same error statistics at 10× the time).
    #[arg(long, value_name = "K", default_value_t = 10)]
    abs_every: usize,
    /// Image pairs per dataset in the matching table (so 10 × seeds per terrain and
    /// difficulty).
    #[arg(long, value_name = "N", default_value_t = 10)]
    pairs: usize,
    /// The real-time rows replay each flight at this multiple of its camera rate (`jointloc
    /// run --realtime S`); above 1 the absolute thread has less time per fix than in flight.
    #[arg(long, value_name = "S", default_value_t = 1.0)]
    replay_speed: f64,
    /// Tables to produce, comma separated: matching, localisation, fusion, area, confidence
    /// (module timing and figures come with localisation).
    #[arg(long, value_delimiter = ',', default_values_t = TABLES.map(String::from))]
    tables: Vec<String>,
    /// Replace an existing report in OUT.
    #[arg(long)]
    force: bool,
    /// Go on with an interrupted (or extended) benchmark in OUT: runs that finished there
    /// before, with the same executable and command line (OUT/runs/journal.jsonl), are not
    /// repeated; their outputs are read again. Replaces the report.
    #[arg(long)]
    resume: bool,
}

/// What to run, after defaults.
#[derive(Debug, Clone)]
struct Plan {
    quick: bool,
    seeds: Vec<u64>,
    terrains: Vec<String>,
    difficulties: Vec<String>,
    length_m: f64,
    matchers: Vec<String>,
    matcher: String,
    pairs: usize,
    /// Absolute-only: localise every K-th frame.
    abs_every: usize,
    /// Real-time rows: replay speed, × the camera rate.
    replay_speed: f64,
    tables: Vec<String>,
}

impl Plan {
    fn wants(&self, table: &str) -> bool {
        self.tables.iter().any(|t| t == table)
    }
}

impl Plan {
    fn from_args(a: &Args) -> anyhow::Result<Self> {
        let seeds = a.seeds.unwrap_or(if a.quick { 1 } else { 3 });
        if seeds == 0 {
            bail!("--seeds must be at least 1");
        }
        if a.abs_every == 0 {
            bail!("--abs-every must be at least 1");
        }
        if a.pairs == 0 {
            bail!("--pairs must be at least 1");
        }
        if !(a.replay_speed.is_finite() && a.replay_speed > 0.0) {
            bail!("--replay-speed must be a positive number");
        }
        let difficulties = a.difficulty.clone().unwrap_or_else(|| {
            if a.quick {
                vec!["easy".into()]
            } else {
                vec!["easy".into(), "medium".into()]
            }
        });
        let matchers = a.matchers.clone().unwrap_or_else(|| {
            let n = if a.quick { 3 } else { ALL_MATCHERS.len() };
            ALL_MATCHERS[..n].iter().map(|s| s.to_string()).collect()
        });
        for t in &a.terrains {
            if !["crater", "gravel", "mountain"].contains(&t.as_str()) {
                bail!("unknown terrain {t:?} (crater, gravel, mountain)");
            }
        }
        for d in &difficulties {
            if !["easy", "medium", "hard"].contains(&d.as_str()) {
                bail!("unknown difficulty {d:?} (easy, medium, hard)");
            }
        }
        for t in &a.tables {
            if !TABLES.contains(&t.as_str()) {
                bail!("unknown table {t:?} ({})", TABLES.join(", "));
            }
        }
        let length_m = a.length_m.unwrap_or(if a.quick { 60.0 } else { 150.0 });
        if !(length_m.is_finite() && length_m >= 20.0) {
            bail!("--length-m must be at least 20");
        }
        Ok(Self {
            quick: a.quick,
            seeds: (a.first_seed..a.first_seed + seeds).collect(),
            terrains: a.terrains.clone(),
            difficulties,
            length_m,
            matchers,
            matcher: a.matcher.clone(),
            pairs: a.pairs,
            abs_every: a.abs_every,
            replay_speed: a.replay_speed,
            tables: a.tables.clone(),
        })
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let plan = Plan::from_args(&args)?;
    let out = args.out.clone();
    let report_path = out.join("report.md");
    if report_path.exists() && !args.force && !args.resume {
        bail!(
            "{}: already exists (use --force to replace the report, --resume to go on with it)",
            report_path.display()
        );
    }
    for sub in ["figures", "logs", "runs"] {
        std::fs::create_dir_all(out.join(sub))
            .with_context(|| format!("creating {}", out.join(sub).display()))?;
    }
    let data_root = args
        .datasets
        .clone()
        .unwrap_or_else(|| out.join("datasets"));
    std::fs::create_dir_all(&data_root)
        .with_context(|| format!("creating {}", data_root.display()))?;
    let started = Instant::now();
    let mut runner = Runner::new(
        &out.join("logs"),
        &out.join("runs").join("journal.jsonl"),
        args.resume,
    )?;
    let mut rep = Report::new(machine::describe(), &plan_summary(&plan));

    let datasets = make_datasets(&plan, &data_root, &mut runner)?;
    if plan.wants("matching") {
        matching_table(&plan, &datasets, &out, &mut runner, &mut rep)?;
    }
    if plan.wants("localisation") {
        for d in &datasets {
            localisation_rows(&plan, d, &out, &mut runner, &mut rep)?;
        }
    }
    // Ablations on the first terrain and difficulty, every seed (one with --quick): enough to
    // tell a setting's effect from seed noise at a fraction of the time of every flight.
    let ablation_sets: Vec<&Dataset> = datasets
        .iter()
        .filter(|d| d.terrain == plan.terrains[0] && d.difficulty == plan.difficulties[0])
        .collect();
    for d in ablation_sets {
        ablations(&plan, d, &out, &mut runner, &mut rep)?;
    }
    // Reused runs count with the time they took when they ran.
    rep.reused_runs = runner.reused.0;
    rep.reused_s = runner.reused.1;
    rep.total_s = started.elapsed().as_secs_f64() + runner.reused.1;
    rep.write(&out)?;
    println!(
        "report: {} ({:.1} min)",
        report_path.display(),
        rep.total_s / 60.0
    );
    Ok(())
}

fn plan_summary(p: &Plan) -> String {
    format!(
        "{}: terrains {}, difficulty {}, seeds {:?}, {} m flights, {} pairs per dataset, JointLoc/absolute matcher {}",
        if p.quick {
            "quick protocol"
        } else {
            "full protocol"
        },
        p.terrains.join(", "),
        p.difficulties.join(", "),
        p.seeds,
        p.length_m,
        p.pairs,
        p.matcher
    )
}

fn make_datasets(plan: &Plan, root: &Path, runner: &mut Runner) -> anyhow::Result<Vec<Dataset>> {
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

fn matching_table(
    plan: &Plan,
    datasets: &[Dataset],
    out: &Path,
    runner: &mut Runner,
    rep: &mut Report,
) -> anyhow::Result<()> {
    for d in datasets {
        let json = out.join("runs").join(format!("{}-match.json", d.name()));
        let done = runner.run(
            &format!("match-{}", d.name()),
            &args![
                "match",
                "--dataset",
                d.path.display(),
                "--matcher",
                plan.matchers.join(","),
                "--pairs",
                plan.pairs,
                "--seed",
                d.seed,
                "--json",
                json.display(),
                "--force"
            ],
        )?;
        let parsed = done
            .outcome
            .clone()
            .and_then(|()| read_match_json(&json).map_err(|e| format!("{e:#}")));
        match parsed {
            Ok(rows) => {
                for (matcher, accuracy, ms) in rows {
                    rep.matching.push(MatchRow {
                        dataset: d.key(),
                        matcher,
                        accuracy,
                        ms_median: ms,
                        command: done.command.clone(),
                        failed: None,
                    });
                }
            }
            Err(reason) => {
                for m in &plan.matchers {
                    rep.matching.push(MatchRow {
                        dataset: d.key(),
                        matcher: m.clone(),
                        accuracy: Default::default(),
                        ms_median: f64::NAN,
                        command: done.command.clone(),
                        failed: Some(reason.clone()),
                    });
                }
            }
        }
    }
    Ok(())
}

type MatchJsonRow = (String, std::collections::BTreeMap<String, f64>, f64);

fn read_match_json(path: &Path) -> anyhow::Result<Vec<MatchJsonRow>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let v: serde_json::Value = serde_json::from_str(&text)?;
    let mut rows = Vec::new();
    for m in v["matchers"].as_array().context("no \"matchers\" array")? {
        let name = m["matcher"].as_str().unwrap_or("?").to_string();
        let acc = m["accuracy"]
            .as_object()
            .map(|o| {
                o.iter()
                    .filter_map(|(k, v)| Some((k.clone(), v.as_f64()?)))
                    .collect()
            })
            .unwrap_or_default();
        rows.push((name, acc, m["ms_median"].as_f64().unwrap_or(f64::NAN)));
    }
    Ok(rows)
}

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

fn jointloc_run(
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

fn loc_row(
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

fn localisation_rows(
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
    let (done, dir) = jointloc_run(
        d,
        out,
        runner,
        "realtime",
        &args!["--realtime", plan.replay_speed],
        &plan.matcher,
    )?;
    let timing_t = metrics::timing_medians(&dir.join("timing.json")).ok();
    let speed = if plan.replay_speed == 1.0 {
        "camera rate".to_string()
    } else {
        format!("{}× camera rate", plan.replay_speed)
    };
    let (row, _) = loc_row(
        d,
        format!("JointLoc real time ({}, {speed})", plan.matcher),
        &done,
        &dir.join("trajectory.tum"),
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

    // Figures for the first seed.
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

#[allow(clippy::too_many_arguments)]
fn figures_for(
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
    let fixes_path = if run_dir.join("fixes.txt").exists() {
        run_dir.join("fixes.txt")
    } else {
        abs_fixes.to_path_buf()
    };
    let fix_xyw: Vec<(f64, f64, f64)> = match (
        metrics::read_tum_prefix(&fixes_path),
        metrics::read_fix_confidences(&fixes_path),
    ) {
        (Ok(t), Ok(w)) if t.len() == w.len() => t
            .positions()
            .iter()
            .zip(&w)
            .map(|(p, &(_, w))| (p.x, p.y, w))
            .collect(),
        _ => Vec::new(),
    };
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
                Some(&figures::Fixes { xyw: &fix_xyw }),
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
    if let Ok(w) = metrics::read_fix_confidences(&fixes_path)
        && !w.is_empty()
    {
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
                    points: &w,
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

fn ablations(
    plan: &Plan,
    d: &Dataset,
    out: &Path,
    runner: &mut Runner,
    rep: &mut Report,
) -> anyhow::Result<()> {
    // Table II: fusion frequency.
    let frequencies: &[usize] = if plan.wants("fusion") {
        &[1, 10, 50, 100]
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
        let fixes = out
            .join("runs")
            .join(format!("{}-absloc-{tag}.txt", d.name()));
        let json = out
            .join("runs")
            .join(format!("{}-absloc-{tag}.json", d.name()));
        let mut a: Vec<String> = args![
            "absloc",
            "--dataset",
            d.path.display(),
            "--matcher",
            plan.matcher,
            "--every",
            10,
            "--out",
            fixes.display(),
            "--json",
            json.display(),
            "--force"
        ]
        .to_vec();
        a.extend(extra);
        let done = runner.run(&format!("absloc-{}-{tag}", d.name()), &a)?;
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
