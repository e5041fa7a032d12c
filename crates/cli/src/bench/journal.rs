//! The run journal: one JSON line per successful child run (`OUT/runs/journal.jsonl`), so a
//! long benchmark interrupted or split over several sittings can go on with `--resume`
//! instead of starting again. A run is reused only when the very same executable ran the very
//! same command line; its outputs are read again from `OUT/runs`.

use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

/// One successful run as recorded.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Entry {
    pub command: String,
    pub wall_s: f64,
    /// SHA-256 of the executable that ran it (hex).
    pub exe_sha256: String,
    pub date: String,
}

/// The journal file and the entries reusable by this executable.
#[derive(Debug)]
pub struct Journal {
    path: PathBuf,
    exe_sha256: String,
    reusable: BTreeMap<String, Entry>,
}

impl Journal {
    /// Opens (creating on first write) `path`. With `resume`, the existing entries of this
    /// executable become reusable; without it an existing journal is started afresh.
    pub fn open(path: &Path, exe: &Path, resume: bool) -> anyhow::Result<Self> {
        let exe_sha256 = sha256_of(exe)?;
        let mut reusable = BTreeMap::new();
        if resume && path.exists() {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("reading {}", path.display()))?;
            for (i, line) in text
                .lines()
                .enumerate()
                .filter(|(_, l)| !l.trim().is_empty())
            {
                let e: Entry = match serde_json::from_str(line) {
                    Ok(e) => e,
                    Err(err) => bail!(
                        "{}: line {} is not a journal entry ({err}); delete the line or the file \
                         to run those rows again",
                        path.display(),
                        i + 1
                    ),
                };
                if e.exe_sha256 == exe_sha256 {
                    reusable.insert(e.command.clone(), e);
                }
            }
        } else if path.exists() {
            std::fs::remove_file(path).with_context(|| format!("removing {}", path.display()))?;
        }
        Ok(Self {
            path: path.to_path_buf(),
            exe_sha256,
            reusable,
        })
    }

    /// The earlier successful run of exactly `command`, if any.
    pub fn lookup(&self, command: &str) -> Option<&Entry> {
        self.reusable.get(command)
    }

    /// Appends a successful run (reusable by later invocations only).
    pub fn record(&mut self, command: &str, wall_s: f64, date: String) -> anyhow::Result<()> {
        let e = Entry {
            command: command.to_string(),
            wall_s,
            exe_sha256: self.exe_sha256.clone(),
            date,
        };
        let mut f = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&self.path)
            .with_context(|| format!("opening {}", self.path.display()))?;
        writeln!(f, "{}", serde_json::to_string(&e)?)
            .with_context(|| format!("writing {}", self.path.display()))?;
        Ok(())
    }
}

fn sha256_of(path: &Path) -> anyhow::Result<String> {
    let mut f = std::fs::File::open(path).with_context(|| format!("reading {}", path.display()))?;
    let mut hasher = Sha256::new();
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = f
            .read(&mut buf)
            .with_context(|| format!("reading {}", path.display()))?;
        if n == 0 {
            break;
        }
        hasher.update(&buf[..n]);
    }
    Ok(hasher
        .finalize()
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect())
}
