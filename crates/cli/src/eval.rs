//! `jointloc eval`: APE/RPE of an estimated trajectory against ground truth, with the numbers
//! `evo_ape` / `evo_rpe` would print for the same options.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use jointloc_eval::{
    AlignMode, AssociationConfig, DeltaUnit, EvalConfig, EvalReport, MetricResult, RpeConfig,
};
use jointloc_geometry::trajectory::{QuaternionOrder, Trajectory, TumOptions};

/// Alignment of the estimate before measuring errors.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum AlignArg {
    /// Compare as is.
    None,
    /// Rigid Umeyama alignment (evo `-a`).
    Se3,
    /// Similarity Umeyama alignment, for monocular scale (evo `-as`).
    Sim3,
    /// Scale correction only (evo `-s`).
    Scale,
    /// Make the first poses coincide (evo `--align_origin`).
    Origin,
}

/// Unit of the RPE step.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum RpeUnitArg {
    /// Index distance.
    Frames,
    /// Travelled distance in metres.
    M,
}

/// Ground-truth file format.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum GtFormat {
    /// `timestamp tx ty tz qx qy qz qw` (seconds).
    Tum,
    /// EuRoC `state_groundtruth_estimate0/data.csv` (nanoseconds, qw first).
    Euroc,
}

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Ground-truth trajectory.
    #[arg(long)]
    gt: PathBuf,
    /// Estimated trajectory (TUM format, camera-to-world).
    #[arg(long)]
    est: PathBuf,
    /// Alignment of the estimate to the ground truth.
    #[arg(long, value_enum, default_value = "none")]
    align: AlignArg,
    /// Fit the alignment on the first N associated poses only.
    #[arg(long, value_name = "N")]
    n_to_align: Option<usize>,
    /// Largest time difference (s) for associating poses.
    #[arg(long, default_value_t = 0.01, value_name = "S")]
    t_max_diff: f64,
    /// Offset (s) added to the estimate's timestamps before association.
    #[arg(
        long,
        default_value_t = 0.0,
        allow_negative_numbers = true,
        value_name = "S"
    )]
    t_offset: f64,
    /// RPE step, in `--rpe-unit`.
    #[arg(long, default_value_t = 1.0, value_name = "N")]
    rpe_delta: f64,
    /// Unit of `--rpe-delta`.
    #[arg(long, value_enum, default_value = "frames")]
    rpe_unit: RpeUnitArg,
    /// RPE over all pose pairs at distance delta instead of consecutive ones.
    #[arg(long)]
    rpe_all_pairs: bool,
    /// Format of the ground-truth file.
    #[arg(long, value_enum, default_value = "tum")]
    gt_format: GtFormat,
    /// The ground-truth TUM file has the quaternion scalar first (`qw qx qy qz`).
    #[arg(long)]
    gt_qw_first: bool,
    /// The estimate has the quaternion scalar first (`qw qx qy qz`), as the paper's code writes.
    #[arg(long)]
    est_qw_first: bool,
    /// Write every statistic (and the per-pose errors) as JSON.
    #[arg(long, value_name = "OUT.json")]
    json: Option<PathBuf>,
    /// Plot the top view coloured by APE and the APE over time (.svg labelled, .png no text).
    #[arg(long, value_name = "OUT.svg|png")]
    plot: Option<PathBuf>,
    /// Overwrite existing output files.
    #[arg(long)]
    force: bool,
}

fn tum_options(qw_first: bool) -> TumOptions {
    TumOptions {
        quaternion_order: if qw_first {
            QuaternionOrder::Wxyz
        } else {
            QuaternionOrder::Xyzw
        },
    }
}

fn refuse_overwrite(path: &Option<PathBuf>, force: bool) -> anyhow::Result<()> {
    if let Some(p) = path
        && p.exists()
        && !force
    {
        bail!("{}: already exists (use --force to overwrite)", p.display());
    }
    Ok(())
}

pub fn run(args: Args) -> anyhow::Result<()> {
    refuse_overwrite(&args.json, args.force)?;
    refuse_overwrite(&args.plot, args.force)?;
    if let Some(plot) = &args.plot {
        let ext = plot
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        if !matches!(ext.as_deref(), Some("svg" | "png")) {
            bail!("{}: plot file must end in .svg or .png", plot.display());
        }
    }

    let gt = match args.gt_format {
        GtFormat::Tum => Trajectory::read_tum(&args.gt, &tum_options(args.gt_qw_first))?,
        GtFormat::Euroc => Trajectory::read_euroc(&args.gt)?,
    };
    let est = Trajectory::read_tum(&args.est, &tum_options(args.est_qw_first))?;
    let config = EvalConfig {
        association: AssociationConfig {
            max_diff: args.t_max_diff,
            offset: args.t_offset,
        },
        align: match args.align {
            AlignArg::None => AlignMode::None,
            AlignArg::Se3 => AlignMode::Se3,
            AlignArg::Sim3 => AlignMode::Sim3,
            AlignArg::Scale => AlignMode::Scale,
            AlignArg::Origin => AlignMode::Origin,
        },
        n_to_align: args.n_to_align,
        rpe: RpeConfig {
            delta: args.rpe_delta,
            unit: match args.rpe_unit {
                RpeUnitArg::Frames => DeltaUnit::Frames,
                RpeUnitArg::M => DeltaUnit::Meters,
            },
            all_pairs: args.rpe_all_pairs,
            ..Default::default()
        },
    };
    let report = jointloc_eval::evaluate(&gt, &est, &config).with_context(|| {
        format!(
            "evaluating {} against {}",
            args.est.display(),
            args.gt.display()
        )
    })?;

    print!("{}", format_report(&report, &args.gt, &args.est));

    if let Some(path) = &args.json {
        let text = serde_json::to_string_pretty(&report)?;
        std::fs::write(path, text + "\n")
            .with_context(|| format!("{}: cannot write", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    if let Some(path) = &args.plot {
        jointloc_eval::plot_report(&report, path)?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

/// The human-readable summary printed to stdout.
fn format_report(report: &EvalReport, gt: &Path, est: &Path) -> String {
    let c = &report.config;
    let mut out = format!(
        "ground truth: {} ({} poses)\nestimate:     {} ({} poses)\n\
         associated:   {} pose pairs (max. time diff {} s, offset {} s)\n",
        gt.display(),
        report.reference_poses,
        est.display(),
        report.estimate_poses,
        report.associated_poses,
        c.association.max_diff,
        c.association.offset,
    );
    match &report.alignment {
        None => out.push_str("alignment:    none\n"),
        Some(a) => {
            out.push_str(&format!("alignment:    {:?}", a.mode).to_lowercase());
            if matches!(a.mode, AlignMode::Sim3 | AlignMode::Scale) {
                out.push_str(&format!(" (scale {:.6})", a.scale));
            }
            out.push('\n');
        }
    }
    out.push_str(&format!(
        "RPE pairs:    delta {} {}{}, {} pairs\n\n",
        c.rpe.delta,
        c.rpe.unit.label(),
        if c.rpe.all_pairs {
            ", all pairs"
        } else {
            ", consecutive"
        },
        report.rpe_translation.errors.len(),
    ));
    out.push_str(&format!(
        "{:<18} {:>11} {:>11} {:>11} {:>11} {:>11} {:>11}\n",
        "metric", "rmse", "mean", "median", "std", "min", "max"
    ));
    let row = |name: &str, m: &MetricResult| {
        let s = &m.stats;
        format!(
            "{:<18} {:>11.6} {:>11.6} {:>11.6} {:>11.6} {:>11.6} {:>11.6}\n",
            format!("{name} [{}]", m.unit),
            s.rmse,
            s.mean,
            s.median,
            s.std,
            s.min,
            s.max
        )
    };
    out.push_str(&row("APE trans", &report.ape_translation));
    out.push_str(&row("APE rot", &report.ape_rotation));
    out.push_str(&row("RPE trans", &report.rpe_translation));
    out.push_str(&row("RPE rot", &report.rpe_rotation));
    out
}
