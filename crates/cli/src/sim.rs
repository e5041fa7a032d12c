//! `jointloc sim`: generate a simulated Mars dataset (terrain, satellite map + tiles, UAV
//! images, ground truth, altimeter) in the dataset layout of `docs/architecture.md`.

use std::path::PathBuf;

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use jointloc_geometry::{Distortion, PinholeCamera};
use jointloc_sim::dataset::{generate_dataset, prepare_output_dir};
use jointloc_sim::{Difficulty, SimConfig, SimError, Stage, TerrainKind};

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum TerrainArg {
    Crater,
    Gravel,
    Mountain,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum CameraArg {
    Pinhole,
    Fisheye,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum DifficultyArg {
    Easy,
    Medium,
    Hard,
    Mars,
}

/// Options of `jointloc sim`. Without `--config`, unset options take the defaults shown.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Output folder: created if missing; must be empty unless --force.
    #[arg(long)]
    out: PathBuf,
    /// Replace the dataset in a non-empty output folder (other files there are kept).
    #[arg(long)]
    force: bool,
    /// Terrain kind [default: crater].
    #[arg(long, value_enum)]
    terrain: Option<TerrainArg>,
    /// Flight length in metres [default: 150].
    #[arg(long, value_parser = positive)]
    length_m: Option<f64>,
    /// Master seed: the same seed gives byte-identical files [default: 0].
    #[arg(long)]
    seed: Option<u64>,
    /// UAV-to-map gap: easy 5 cm/px, medium 12.5 cm/px + 45° sun change, hard 25 cm/px
    /// (HiRISE class) + low sun + 1 m stereo DTM, mars = hard on a 2 km map with the suns
    /// drawn over the Mars envelope [default: easy].
    #[arg(long, value_enum)]
    difficulty: Option<DifficultyArg>,
    /// Start from a full simulator configuration (TOML, as written to <out>/sim.toml); the
    /// options given on the command line override it.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Image width in pixels [default: 500].
    #[arg(long, value_parser = clap::value_parser!(u32).range(2..=16384))]
    width: Option<u32>,
    /// Image height in pixels [default: 500].
    #[arg(long, value_parser = clap::value_parser!(u32).range(2..=16384))]
    height: Option<u32>,
    /// Lens: an ideal pinhole, or a Kannala-Brandt fisheye (TUM-VI's cam0 coefficients) whose
    /// focal length gives --fov-deg across the image width [default: pinhole].
    #[arg(long, value_enum)]
    camera: Option<CameraArg>,
    /// Horizontal field of view across the image width, degrees: sets the focal length
    /// (pinhole: (W/2)/tan(fov/2); fisheye: (W/2)/θ_d(fov/2)) [default: fisheye 133,
    /// pinhole from --fx].
    #[arg(long, value_parser = positive)]
    fov_deg: Option<f64>,
    /// Focal length in pixels, x [default: 500].
    #[arg(long, value_parser = positive)]
    fx: Option<f64>,
    /// Focal length in pixels, y [default: fx].
    #[arg(long, value_parser = positive)]
    fy: Option<f64>,
    /// Principal point x [default: (width − 1) / 2].
    #[arg(long)]
    cx: Option<f64>,
    /// Principal point y [default: (height − 1) / 2].
    #[arg(long)]
    cy: Option<f64>,
    /// Ground speed in m/s [default: 1].
    #[arg(long, value_parser = positive)]
    speed: Option<f64>,
    /// Frame rate in Hz [default: 5].
    #[arg(long, value_parser = positive)]
    rate: Option<f64>,
    /// Flight height above the ground in metres [default: 10].
    #[arg(long, value_parser = positive)]
    altitude: Option<f64>,
    /// Altimeter noise σ at short range in metres; above it, σ is 0.5 % of the altitude
    /// (from 20 m up with the default) [default: 0.1].
    #[arg(long)]
    altimeter_sigma: Option<f64>,
    /// Side of a square map larger than the flight, metres; the flight is placed in it at a
    /// seeded position [default: the flight's bounding box plus margin; mars: 2000].
    #[arg(long, value_parser = positive)]
    map_size_m: Option<f64>,
    /// Azimuth difference between the map's sun and the flight's, degrees, 0–180
    /// [default: the preset's].
    #[arg(long)]
    sun_azimuth_change_deg: Option<f64>,
    /// Elevation of the map's sun, degrees [default: the preset's].
    #[arg(long)]
    sun_elevation_deg: Option<f64>,
    /// Elevation of the flight's sun, degrees [default: drawn from the seed].
    #[arg(long)]
    flight_sun_elevation_deg: Option<f64>,
    /// Also write the map and DEM as GeoTIFF (satellite.tif, elevation.tif) in the Mars
    /// equirectangular CRS, for `jointloc map import`.
    #[arg(long)]
    geotiff: bool,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

fn positive(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|_| format!("`{s}` is not a number"))?;
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(format!("must be a positive number, got {s}"))
    }
}

/// The configuration: `--config` or the defaults, then the command-line overrides.
fn config(args: &Args) -> anyhow::Result<SimConfig> {
    let mut cfg = match &args.config {
        Some(path) => SimConfig::read(path).context("invalid --config")?,
        None => SimConfig::default(),
    };
    if let Some(t) = args.terrain {
        cfg.terrain_kind = match t {
            TerrainArg::Crater => TerrainKind::Crater,
            TerrainArg::Gravel => TerrainKind::Gravel,
            TerrainArg::Mountain => TerrainKind::Mountain,
        };
    }
    if let Some(d) = args.difficulty {
        cfg.difficulty = match d {
            DifficultyArg::Easy => Difficulty::Easy,
            DifficultyArg::Medium => Difficulty::Medium,
            DifficultyArg::Hard => Difficulty::Hard,
            DifficultyArg::Mars => Difficulty::Mars,
        };
    }
    if let Some(seed) = args.seed {
        cfg.seed = seed;
    }
    let traj = &mut cfg.trajectory;
    if let Some(v) = args.length_m {
        traj.length_m = v;
    }
    if let Some(v) = args.speed {
        traj.speed_mps = v;
    }
    if let Some(v) = args.rate {
        traj.rate_hz = v;
    }
    if let Some(v) = args.altitude {
        traj.altitude_m = v;
    }
    if let Some(v) = args.altimeter_sigma {
        cfg.altimeter_sigma_m = v;
    }
    let cam = &mut cfg.camera;
    if let Some(w) = args.width {
        cam.width = w;
        cam.cx = (w as f64 - 1.0) / 2.0;
    }
    if let Some(h) = args.height {
        cam.height = h;
        cam.cy = (h as f64 - 1.0) / 2.0;
    }
    let (w, h) = (cam.width, cam.height);
    match (args.camera, args.fov_deg) {
        (Some(CameraArg::Fisheye), fov) => {
            *cam = jointloc_sim::config::fisheye_camera(fov.unwrap_or(133.0), w, h)?;
        }
        (Some(CameraArg::Pinhole), fov) => {
            let f = match fov {
                Some(fov) => jointloc_sim::config::pinhole_camera(fov, w, h)?.fx,
                None => cam.fx,
            };
            *cam = PinholeCamera::ideal(f, w, h);
        }
        (None, Some(fov)) => {
            let f = match cam.distortion {
                Some(Distortion::KannalaBrandt(_)) => {
                    jointloc_sim::config::fisheye_camera(fov, w, h)?.fx
                }
                _ => jointloc_sim::config::pinhole_camera(fov, w, h)?.fx,
            };
            cam.fx = f;
            cam.fy = f;
        }
        (None, None) => {}
    }
    if let Some(fx) = args.fx {
        cam.fx = fx;
        cam.fy = fx;
    }
    if let Some(fy) = args.fy {
        cam.fy = fy;
    }
    if let Some(cx) = args.cx {
        cam.cx = cx;
    }
    if let Some(cy) = args.cy {
        cam.cy = cy;
    }
    if args.map_size_m.is_some() {
        cfg.map_size_m = args.map_size_m;
    }
    if args.sun_azimuth_change_deg.is_some() {
        cfg.sun_azimuth_change_deg = args.sun_azimuth_change_deg;
    }
    if args.sun_elevation_deg.is_some() {
        cfg.sun_elevation_deg = args.sun_elevation_deg;
    }
    if args.flight_sun_elevation_deg.is_some() {
        cfg.flight_sun_elevation_deg = args.flight_sun_elevation_deg;
    }
    cfg.geotiff |= args.geotiff;
    cfg.validate().context("invalid simulator configuration")?;
    Ok(cfg)
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let cfg = config(&args)?;
    let out = &args.out;
    prepare_output_dir(out, args.force).map_err(|e| match e {
        SimError::OutputNotEmpty { .. } => {
            anyhow::anyhow!("{e} (use --force to replace the dataset in it)")
        }
        SimError::Io { path, source } => {
            anyhow::anyhow!("cannot use output directory {}: {source}", path.display())
        }
        other => anyhow::anyhow!("cannot use output directory {}: {other}", out.display()),
    })?;
    let bar = if args.quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(1)
    };
    bar.set_style(
        ProgressStyle::with_template("{prefix:>9} [{bar:40}] {pos}/{len} {elapsed_precise}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    let mut current: Option<Stage> = None;
    let mut progress = |stage: Stage, done: usize, total: usize| {
        if current != Some(stage) {
            current = Some(stage);
            bar.reset();
            bar.set_prefix(stage.name());
        }
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    };
    let summary = generate_dataset(&cfg, out, &mut progress)
        .with_context(|| format!("generating the dataset in {}", out.display()))?;
    bar.finish_and_clear();
    println!(
        "wrote {} frames ({:.1} m), a {}x{} px map at {} m/px and {} tiles to {} \
         (terrain {:.1} s, shading {:.1} s, satellite {:.1} s, frames {:.1} s)",
        summary.frames,
        summary.path_length_m,
        summary.map_width_px,
        summary.map_height_px,
        summary.map_gsd_m,
        summary.tiles,
        out.display(),
        summary.seconds[0],
        summary.seconds[1],
        summary.seconds[2],
        summary.seconds[3],
    );
    Ok(())
}
