//! `jointloc bench`: the paper's tables (V, VI, II, III, IV, VII) and figures on simulated
//! datasets, in one command. Each row is produced by running the corresponding `jointloc`
//! subcommand as a child process (so every row has a command that reproduces it) and reading
//! what it wrote; metrics come from `jointloc_eval`, i.e. evo's numbers.

// Before the modules, so that they see it: the arguments of a subcommand, as strings.
macro_rules! args {
    ($($a:expr),* $(,)?) => { [$($a.to_string()),*] };
}

mod ablations;
mod dataset_figures;
mod datasets;
mod envelope;
mod exec;
mod figures;
mod flights;
mod journal;
mod localisation;
mod machine;
mod matching;
mod metrics;
mod paths;
mod plan;
mod report;

use std::time::Instant;

use anyhow::{Context, bail};

use exec::Runner;
use report::{Dataset, Report};

pub use plan::Args;
use plan::{Plan, plan_summary};

pub fn run(args: Args) -> anyhow::Result<()> {
    let plan = Plan::from_args(&args)?;
    // Absolute from here, so every path a run prints can be shown relative to OUT.
    let out = paths::absolute(&args.out);
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
        .as_deref()
        .map_or_else(|| out.join("datasets"), paths::absolute);
    std::fs::create_dir_all(&data_root)
        .with_context(|| format!("creating {}", data_root.display()))?;
    let started = Instant::now();
    // The report, its logs and its commands name files relative to OUT.
    let names = paths::PathNames::new(&out, &data_root);
    let mut runner = Runner::new(
        &out.join("logs"),
        &out.join("runs").join("journal.jsonl"),
        args.resume,
        names.clone(),
    )?;
    let mut rep = Report::new(machine::describe(), &plan_summary(&plan));

    // The envelope table flies datasets of its own.
    let datasets = if plan.tables.iter().all(|t| t == "envelope") {
        Vec::new()
    } else {
        datasets::make_datasets(&plan, &data_root, &mut runner)?
    };
    if plan.wants("matching") {
        matching::matching_table(&plan, &datasets, &out, &mut runner, &mut rep)?;
    }
    if plan.wants("localisation") {
        for d in &datasets {
            localisation::localisation_rows(&plan, d, &out, &mut runner, &mut rep)?;
        }
    }
    // Ablations on the first terrain and difficulty, every seed (one with --quick): enough to
    // tell a setting's effect from seed noise at a fraction of the time of every flight.
    let ablation_sets: Vec<&Dataset> = datasets
        .iter()
        .filter(|d| d.terrain == plan.terrains[0] && d.difficulty == plan.difficulties[0])
        .collect();
    for d in ablation_sets {
        ablations::ablations(&plan, d, &out, &mut runner, &mut rep)?;
    }
    if plan.wants("envelope") {
        rep.envelope = envelope::envelope_rows(&plan, &data_root, &out, &mut runner)?;
    }
    // Reused runs count with the time they took when they ran.
    rep.reused_runs = runner.reused.0;
    rep.reused_s = runner.reused.1;
    rep.total_s = started.elapsed().as_secs_f64() + runner.reused.1;
    rep.write(&out, &names)?;
    println!(
        "report: {} ({:.1} min)",
        report_path.display(),
        rep.total_s / 60.0
    );
    Ok(())
}
