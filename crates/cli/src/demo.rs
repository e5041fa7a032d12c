//! `jointloc demo`: the whole pipeline on an embedded default, with no arguments. Generates a
//! 60 m easy crater flight, installs the models if missing (`jointloc models fetch`), runs
//! JointLoc, VO only and absolute localisation only (through `jointloc bench`'s localisation
//! table), prints the three APE rows and the rates, and leaves the trajectories, figures over
//! the satellite map and a report in `./jointloc-demo/`.

use std::path::PathBuf;
use std::process::Command;

use anyhow::{Context, bail};
use clap::Parser;

use crate::bench;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Output folder.
    #[arg(long, default_value = "jointloc-demo")]
    out: PathBuf,
    /// Replace an earlier demo's report in OUT.
    #[arg(long)]
    force: bool,
}

#[derive(Debug, Parser)]
struct BenchArgs {
    #[command(flatten)]
    args: bench::Args,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let exe = std::env::current_exe().context("locating the jointloc executable")?;
    println!("jointloc demo: models (fetched once, then verified)…");
    let status = Command::new(&exe)
        .args(["models", "fetch"])
        .status()
        .context("running `jointloc models fetch`")?;
    if !status.success() {
        bail!("`jointloc models fetch` failed; see above");
    }
    let out = args.out.display().to_string();
    let datasets = args.out.join("datasets").display().to_string();
    let mut argv = vec![
        "bench",
        "--out",
        &out,
        "--quick",
        "--terrains",
        "crater",
        "--difficulty",
        "easy",
        "--length-m",
        "60",
        "--seeds",
        "1",
        "--first-seed",
        "7",
        "--tables",
        "localisation",
        "--datasets",
        &datasets,
    ];
    if args.force {
        argv.push("--force");
    }
    println!("jointloc demo: 60 m crater flight (easy), JointLoc vs VO only vs absolute only…");
    let parsed = BenchArgs::try_parse_from(&argv).context("demo settings")?;
    bench::run(parsed.args)?;
    let json = args.out.join("report.json");
    let text =
        std::fs::read_to_string(&json).with_context(|| format!("reading {}", json.display()))?;
    let report: serde_json::Value = serde_json::from_str(&text)?;
    let rows: Vec<&serde_json::Value> = report["localisation"]
        .as_array()
        .into_iter()
        .flatten()
        .collect();
    let width = rows
        .iter()
        .filter_map(|r| r["method"].as_str())
        .map(|m| m.chars().count())
        .max()
        .unwrap_or(6);
    println!(
        "\n{:<width$} {:>9} {:>9} {:>7}",
        "method", "APE rmse", "APE max", "Hz"
    );
    for row in rows {
        let method = row["method"].as_str().unwrap_or("?");
        match (row["stats"]["rmse"].as_f64(), row["stats"]["max"].as_f64()) {
            (Some(rmse), Some(max)) => println!(
                "{method:<width$} {rmse:>8.3}m {max:>8.3}m {:>7.1}",
                row["hz"].as_f64().unwrap_or(f64::NAN)
            ),
            _ => println!(
                "{method:<width$} failed: {}",
                row["failed"].as_str().unwrap_or("?")
            ),
        }
    }
    println!(
        "\nJointLoc is evaluated in the world frame without alignment, VO only after a Sim(3) \
         alignment, absolute only as 2-D fix errors. Hz: for JointLoc what its frame loop \
         sustains (the real-time row replays the frames at the camera's rate, 5 Hz); for VO and \
         absolute only, frames per second of wall time.\nReport, trajectories and figures: {}",
        args.out.join("report.md").display()
    );
    Ok(())
}
