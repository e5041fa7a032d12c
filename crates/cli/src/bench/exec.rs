//! Runs `jointloc` subcommands as child processes of the current executable, one log file per
//! run, and records the exact command line so the report can show how to reproduce each row.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::Context;

use super::journal::Journal;
use super::paths::{DATASETS, PathNames};

/// One finished child run.
#[derive(Debug, Clone)]
pub struct Finished {
    /// The command as a user would type it (`jointloc …`), paths as the report shows them
    /// (relative to its folder, see [`PathNames`]).
    pub command: String,
    /// Wall time of the whole process, seconds.
    pub wall_s: f64,
    /// Exit status; `Err` holds the last lines of the log.
    pub outcome: Result<(), String>,
}

/// Runs subcommands of the current executable.
#[derive(Debug)]
pub struct Runner {
    exe: PathBuf,
    logs: PathBuf,
    counter: usize,
    journal: Journal,
    names: PathNames,
    /// Runs reused from the journal and their recorded wall time, seconds.
    pub reused: (usize, f64),
    /// Runs of this invocation by their real command line: a row that is the same run as
    /// another (the ablations' default settings) shares it instead of running it twice.
    done: std::collections::HashMap<String, Finished>,
}

impl Runner {
    /// Runs log into `logs`; successful runs are recorded in `journal` (see
    /// [`Journal`]), and with `resume` the ones recorded there before are not run again.
    /// Commands, logs and failure reasons name paths as `names` does.
    pub fn new(
        logs: &Path,
        journal: &Path,
        resume: bool,
        names: PathNames,
    ) -> anyhow::Result<Self> {
        let exe = std::env::current_exe().context("locating the jointloc executable")?;
        std::fs::create_dir_all(logs).with_context(|| format!("creating {}", logs.display()))?;
        let journal = Journal::open(journal, &exe, resume)?;
        Ok(Self {
            exe,
            logs: logs.to_path_buf(),
            counter: 0,
            journal,
            names,
            reused: (0, 0.0),
            done: Default::default(),
        })
    }

    /// Runs `jointloc <args>`; a non-zero exit is returned as a failed [`Finished`], not an
    /// error, so one failed row does not end the benchmark (the paper's "-" entries).
    pub fn run(&mut self, label: &str, args: &[String]) -> anyhow::Result<Finished> {
        self.counter += 1;
        let log = self.logs.join(format!("{:03}-{label}.log", self.counter));
        // What runs (the journal's key) and what the report shows.
        let real = format!(
            "jointloc {}",
            args.iter().map(|a| quote(a)).collect::<Vec<_>>().join(" ")
        );
        let command = format!(
            "jointloc {}",
            args.iter()
                .map(|a| {
                    let shown = self.names.arg(a);
                    // The placeholder is for a reader to replace, not quoted for a shell.
                    if shown.starts_with(DATASETS) {
                        shown
                    } else {
                        quote(&shown)
                    }
                })
                .collect::<Vec<_>>()
                .join(" ")
        );
        if let Some(f) = self.done.get(&real) {
            return Ok(f.clone());
        }
        if let Some(e) = self.journal.lookup(&real) {
            tracing::info!("reused from {}: {command}", e.date);
            self.reused.0 += 1;
            self.reused.1 += e.wall_s;
            let finished = Finished {
                command: command.clone(),
                wall_s: e.wall_s,
                outcome: Ok(()),
            };
            self.done.insert(real, finished.clone());
            return Ok(finished);
        }
        tracing::info!("{command}");
        let start = Instant::now();
        let output = Command::new(&self.exe)
            .args(args)
            .env("RUST_LOG", "warn")
            .output()
            .with_context(|| format!("starting {real}"))?;
        let wall_s = start.elapsed().as_secs_f64();
        let stdout = self.names.scrub(&String::from_utf8_lossy(&output.stdout));
        let stderr = self.names.scrub(&String::from_utf8_lossy(&output.stderr));
        std::fs::write(
            &log,
            format!("$ {command}\n{stdout}\n--- stderr ---\n{stderr}"),
        )
        .with_context(|| format!("writing {}", log.display()))?;
        let outcome = if output.status.success() {
            Ok(())
        } else {
            let tail: Vec<&str> = stderr.lines().rev().take(3).collect();
            let reason = tail.into_iter().rev().collect::<Vec<_>>().join(" / ");
            Err(if reason.is_empty() {
                format!("exit status {}", output.status)
            } else {
                reason
            })
        };
        if outcome.is_ok() {
            self.journal
                .record(&real, wall_s, super::report::utc_date())?;
        }
        let finished = Finished {
            command: command.clone(),
            wall_s,
            outcome,
        };
        self.done.insert(real, finished.clone());
        Ok(finished)
    }
}

/// Shell-quotes an argument when it needs it.
fn quote(a: &str) -> String {
    if !a.is_empty()
        && a.chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_./:=,+".contains(c))
    {
        a.to_string()
    } else {
        format!("'{}'", a.replace('\'', "'\\''"))
    }
}
