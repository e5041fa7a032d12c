//! `jointloc run`: the fused system on a dataset, threaded (absolute localisation on its own
//! thread; frames as fast as they are tracked, or with `--realtime` at their timestamps) or
//! `--sequential` (deterministic). The library assembles the system and writes the outputs
//! (`docs/architecture.md` §"Outputs"); this file feeds it the dataset's frames, skipping and
//! counting bad input unless `--strict` ([`tolerant`]).

mod progress;
mod replay;
mod report;
mod settings;
mod tolerant;

use std::path::PathBuf;

use anyhow::Context;
use jointloc_absloc::{ConfidenceMode, MapTiles};
use jointloc_formats::outputs::settings_toml;
use jointloc_formats::read_camera_yaml;
use jointloc_system::faults::BlindCamera;
use jointloc_system::{JointLoc, Mode, Outputs};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset folder (uav/, camera.yaml, map.toml + satellite map; docs/architecture.md).
    #[arg(long, required_unless_present = "print_config")]
    dataset: Option<PathBuf>,
    /// Output folder: trajectory.tum (online), trajectory-final.tum and keyframes.tum (as known
    /// at the end), fixes.txt, timing.json, summary.json, config.toml (the settings used).
    #[arg(long, required_unless_present = "print_config")]
    out: Option<PathBuf>,
    /// Matcher of the absolute localisation (`jointloc match --list`; default xfeat-lighterglue).
    #[arg(long, value_name = "M")]
    matcher: Option<String>,
    /// Absolute localisation on every K-th frame (default 5; the paper's fusion frequency is
    /// 10). The windows stay in seconds of flight (the alignment's `alignment_window_s`, 30):
    /// K changes how many fixes they hold.
    #[arg(long, value_name = "K")]
    fusion_every: Option<usize>,
    /// Confidence of the fixes: adaptive (SSIM × matching score), ssim, matching or fixed:V.
    #[arg(long, value_name = "MODE")]
    confidence: Option<ConfidenceMode>,
    /// Absolute localisation inline on its frames (deterministic, repeatable output) instead
    /// of on its own thread (real time: frames due while it is busy are skipped).
    #[arg(long)]
    sequential: bool,
    /// Replay frames at their timestamps, as the camera would deliver them, sped up by SPEED
    /// (default 1). Without it frames follow each other as fast as they are tracked.
    #[arg(long, value_name = "SPEED", num_args = 0..=1, default_missing_value = "1",
          conflicts_with = "sequential")]
    realtime: Option<f64>,
    /// Robustness test: this fraction of the fixes moved 10–50 m off (seeded; flagged in fixes.txt).
    #[arg(long, value_name = "FRACTION")]
    wrong_fixes: Option<f64>,
    /// Robustness test: no absolute localisation for DURATION seconds from START.
    #[arg(long, value_name = "START:DURATION")]
    outage: Option<String>,
    /// Robustness test: the camera sees uniform grey for DURATION seconds from START.
    #[arg(long, value_name = "START:DURATION")]
    blind: Option<String>,
    /// World x, y (metres, map frame) of the take-off, if known: the first search starts there
    /// instead of searching the whole map, and every alignment of the first map must put the
    /// take-off within `start_radius_m` (5 m; `--config`) plus allowances of it.
    #[arg(long, value_name = "X,Y")]
    start: Option<String>,
    /// The sun during the flight, AZIMUTH,ELEVATION in degrees (azimuth clockwise from
    /// north): the map is relit to it with its elevation model when `map.toml` states the
    /// map's `[sun]`. Default: `[absloc.relight] flight_sun` of `--config`, else a simulated
    /// dataset's record.
    #[arg(long, value_name = "AZ,EL")]
    flight_sun: Option<String>,
    /// Settings (TOML, `JointLocConfig` with [slam] and [absloc] tables; fields left out keep
    /// their defaults); flags override it. A run's own `config.toml` repeats it.
    #[arg(long, value_name = "PATH")]
    config: Option<PathBuf>,
    /// Print the settings (the defaults, `--config` and the flags, merged and validated) as
    /// TOML and exit without running: a starting point for a `--config` file.
    #[arg(long)]
    print_config: bool,
    /// Process only the first N frames.
    #[arg(long, value_name = "N")]
    max_frames: Option<usize>,
    /// ONNX Runtime threads per network.
    #[arg(long, value_name = "N", default_value_t = 1)]
    threads: usize,
    /// Models directory (default: $JOINTLOC_MODELS or the user cache).
    #[arg(long, value_name = "DIR")]
    models_dir: Option<PathBuf>,
    /// Replace existing outputs in OUT.
    #[arg(long)]
    force: bool,
    /// Stop at the first bad input (a line that does not parse, an unreadable frame, a bad
    /// altimeter reading) instead of skipping it, counting it and flying on.
    #[arg(long)]
    strict: bool,
    /// Frame of the trajectories and fixes written: `local` (the map's world frame, x east,
    /// y north from the centre of map pixel (0, 0)) or `map` (easting, northing and height in
    /// the map's CRS; needs a map imported from GeoTIFF, whose `map.toml` has `[crs]`).
    #[arg(long, value_enum, default_value_t = OutCrs::Local)]
    out_crs: OutCrs,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum OutCrs {
    Local,
    Map,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let config = settings::settings(&args)?;
    if args.print_config {
        print!("{}", settings_toml(&config).map_err(anyhow::Error::msg)?);
        return Ok(());
    }
    // clap requires both unless --print-config.
    let (Some(dataset), Some(out)) = (&args.dataset, &args.out) else {
        anyhow::bail!("--dataset and --out are required");
    };
    Outputs::check_writable(out, args.force)
        .context("the output folder holds a previous run (use --force to overwrite it)")?;
    let camera = read_camera_yaml(&dataset.join("camera.yaml"))?.camera;
    let size = (camera.width, camera.height);
    let (sequence, mut source) = tolerant::FrameSource::open(dataset, args.strict)?;
    let tiles = MapTiles::open(dataset)?;
    let map_crs = match args.out_crs {
        OutCrs::Local => None,
        OutCrs::Map => Some(settings::map_crs(dataset)?),
    };
    let n = args.max_frames.unwrap_or(usize::MAX).min(sequence.len());
    let mode = if args.sequential {
        Mode::Sequential
    } else {
        Mode::Threaded
    };
    let blind = BlindCamera::new(config.faults.clone());
    let first_altitude = sequence.frames.iter().find_map(|f| f.altitude);
    let mut system = JointLoc::builder(camera, tiles, config)
        .mode(mode)
        .expected_altitude(first_altitude)
        .models_dir(args.models_dir.clone())
        .threads(args.threads)
        .observer(Box::new(progress::Progress::new(n)))
        .build()?;
    let first_timestamp = sequence.frames.first().map_or(0.0, |f| f.timestamp);
    let mut replay = args
        .realtime
        .map(|speed| replay::Replay::new(speed, first_timestamp));
    for (i, f) in sequence.frames.iter().take(n).enumerate() {
        let Some(image) = source.load(&sequence, i, size)? else {
            system.skip_frame();
            continue;
        };
        if let Some(r) = &mut replay {
            r.wait_for(f.timestamp);
        }
        system
            .process(&blind.frame(&image, f.timestamp), f.timestamp, f.altitude)
            .with_context(|| format!("frame {i} ({})", f.path.display()))?;
        if let Some(r) = &mut replay {
            r.record_done(f.timestamp);
        }
    }
    let mut outputs = system.finish()?;
    if let Some(r) = &replay {
        r.record_in(&mut outputs.summary);
    }
    source.report(&mut outputs);
    if let Some(crs) = &map_crs {
        outputs.into_map_frame(crs);
    }
    outputs.write(out, args.force)?;
    report::print(&outputs);
    report::evaluate_against_ground_truth(dataset, out, &mut outputs)?;
    println!("wrote {}", out.display());
    Ok(())
}
