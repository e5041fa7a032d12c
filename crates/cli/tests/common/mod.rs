//! Shared by the `jointloc run` end-to-end tests (`run_cli`, `run_threaded_cli`,
//! `run_faults_cli`): the command, the simulated dataset of each seed made once per test
//! binary, and the base run on it (ORB matcher, sequential) done once per seed and shared,
//! since several scenarios compare against its accuracy, geo-referencing and first search.
#![allow(dead_code)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

/// The seeds every scenario runs on.
pub const SEEDS: [&str; 2] = ["31", "32"];

pub fn jointloc(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_jointloc"))
        .args(args)
        .output()
        .expect("running jointloc")
}

pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Positions of a TUM file by timestamp (µs), comment lines skipped.
pub fn poses(path: &Path) -> BTreeMap<i64, [f64; 3]> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
            ((v[0] * 1e6).round() as i64, [v[1], v[2], v[3]])
        })
        .collect()
}

/// A run's `summary.json`.
pub fn summary(out: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap()
}

/// One seed's shared state: the process's scratch folder holding its dataset (`data/`) and the base
/// run's outputs (`out/`), and the base run once done.
struct Seeded {
    dir: jointloc_sim::scratch::ProcessScratch,
    base: OnceLock<Base>,
}

/// The base run of a seed: `jointloc run --matcher orb --sequential` on its dataset.
pub struct Base {
    /// Its output folder (must not be written to: other tests read it concurrently).
    pub out: PathBuf,
    /// Its arguments, to run it again.
    pub args: Vec<String>,
    pub stdout: String,
    pub summary: serde_json::Value,
}

impl Base {
    pub fn args(&self) -> Vec<&str> {
        self.args.iter().map(String::as_str).collect()
    }
}

fn seeded(seed: &str) -> &'static Seeded {
    static SEED_31: OnceLock<Seeded> = OnceLock::new();
    static SEED_32: OnceLock<Seeded> = OnceLock::new();
    let cell = match seed {
        "31" => &SEED_31,
        "32" => &SEED_32,
        _ => panic!("seed {seed}: no dataset (only {SEEDS:?})"),
    };
    cell.get_or_init(|| {
        let dir =
            jointloc_sim::scratch::ProcessScratch::new(env!("CARGO_TARGET_TMPDIR"), "cli-run-seed")
                .unwrap();
        sim_crater(&dir.path().join("data"), seed, &[]);
        Seeded {
            dir,
            base: OnceLock::new(),
        }
    })
}

/// Simulates the tests' 30 m flight over a crater for `seed` into `out`, with `extra`
/// `jointloc sim` arguments (a camera, say); panics with the simulator's stderr on failure.
pub fn sim_crater(out: &Path, seed: &str, extra: &[&str]) {
    let mut args = vec![
        "sim",
        "--out",
        s(out),
        "--length-m",
        "30",
        "--seed",
        seed,
        "--terrain",
        "crater",
    ];
    args.extend_from_slice(extra);
    let sim = jointloc(&args);
    assert!(
        sim.status.success(),
        "seed {seed} {extra:?}: {}",
        String::from_utf8_lossy(&sim.stderr)
    );
}

/// The simulated dataset of a seed (a 30 m flight over a crater), made once per test binary.
pub fn dataset(seed: &str) -> PathBuf {
    seeded(seed).dir.path().join("data")
}

/// The base run of a seed, done once per test binary; its success is checked here.
pub fn base(seed: &str) -> &'static Base {
    let seeded = seeded(seed);
    seeded.base.get_or_init(|| {
        let data = seeded.dir.path().join("data");
        let out = seeded.dir.path().join("out");
        let args: Vec<String> = [
            "run",
            "--dataset",
            s(&data),
            "--out",
            s(&out),
            "--matcher",
            "orb",
            "--sequential",
        ]
        .map(String::from)
        .into();
        let run = jointloc(&args.iter().map(String::as_str).collect::<Vec<_>>());
        let stdout = String::from_utf8_lossy(&run.stdout).into_owned();
        assert!(
            run.status.success(),
            "seed {seed}: {stdout}\n{}",
            String::from_utf8_lossy(&run.stderr)
        );
        let summary = summary(&out);
        Base {
            out,
            args,
            stdout,
            summary,
        }
    })
}

/// A `jointloc run` on the seed's dataset into `out` with the ORB matcher and `extra`
/// arguments; asserts success and returns its stdout and summary.
pub fn run_orb(seed: &str, out: &Path, extra: &[&str]) -> (String, serde_json::Value) {
    run_orb_on(&dataset(seed), out, extra)
}

/// A `jointloc run` on the dataset `data` into `out` with the ORB matcher and `extra`
/// arguments; asserts success and returns its stdout and summary.
pub fn run_orb_on(data: &Path, out: &Path, extra: &[&str]) -> (String, serde_json::Value) {
    let mut args = vec![
        "run",
        "--dataset",
        s(data),
        "--out",
        s(out),
        "--matcher",
        "orb",
    ];
    args.extend_from_slice(extra);
    let run = jointloc(&args);
    let stdout = String::from_utf8_lossy(&run.stdout).into_owned();
    assert!(
        run.status.success(),
        "{args:?}\n{stdout}\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    (stdout, summary(out))
}
