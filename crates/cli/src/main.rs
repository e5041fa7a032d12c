//! `jointloc`: real-time visual localisation for planetary UAVs (JointLoc, IROS 2024).
//!
//! One subcommand per file; each exposes `Args` (clap) and `run`.

mod absloc;
mod bench;
mod demo;
mod eval;
mod flight_sun;
mod map;
mod matching;
mod models;
mod run;
mod sim;
mod vo;

use clap::{Parser, Subcommand};
use tracing_subscriber::EnvFilter;

#[derive(Debug, Parser)]
#[command(name = "jointloc", version, about, long_about = None)]
struct Cli {
    /// Log filter (tracing `EnvFilter` syntax), e.g. `info` or `jointloc_slam=debug`.
    #[arg(long, global = true, default_value = "warn", env = "JOINTLOC_LOG")]
    log: String,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Absolute localisation only: per-frame fixes against the satellite map, with confidence.
    Absloc(absloc::Args),
    /// The paper's tables and figures on simulated datasets, in one command (report.md + JSON + SVG).
    Bench(bench::Args),
    /// The whole pipeline on an embedded default (60 m crater flight): JointLoc vs VO vs absolute only.
    Demo(demo::Args),
    /// APE/RPE of a trajectory against ground truth (same numbers as evo_ape / evo_rpe).
    Eval(eval::Args),
    /// Map folders from GeoTIFF: `map import --image ORTHO.tif [--dem DTM.tif] --out DIR`.
    Map(map::Args),
    /// Matcher benchmark on image pairs with a known homography (@N px, ms per pair).
    Match(matching::Args),
    /// Install (`fetch`) or show (`list`) the pretrained weights and the ONNX Runtime library.
    Models(models::Args),
    /// JointLoc: SLAM fused with absolute fixes; world-frame trajectory, fixes, timing, APE.
    Run(run::Args),
    /// Generate a simulated Mars dataset: terrain, satellite map + tiles, UAV images, ground truth.
    Sim(sim::Args),
    /// Relative localisation only (monocular ORB SLAM): SLAM-frame TUM trajectory, map points,
    /// timing.
    Vo(vo::Args),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let filter = EnvFilter::try_new(&cli.log).unwrap_or_else(|_| EnvFilter::new("warn"));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .init();
    let result = match cli.command {
        Command::Absloc(args) => absloc::run(args),
        Command::Bench(args) => bench::run(args),
        Command::Demo(args) => demo::run(args),
        Command::Eval(args) => eval::run(args),
        Command::Map(args) => map::run(args),
        Command::Match(args) => matching::run(args),
        Command::Models(args) => models::run(args),
        Command::Run(args) => run::run(args),
        Command::Sim(args) => sim::run(args),
        Command::Vo(args) => vo::run(args),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
