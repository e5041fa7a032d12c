//! `jointloc vo`: relative localisation only (monocular ORB SLAM) on a dataset folder. Writes
//! every tracked frame's camera-to-world pose in the SLAM frame (TUM), optionally the keyframe
//! trajectory and the map points (PLY), and prints a per-module timing summary.
//!
//! Existing outputs are refused unless `--force`.
//!
//! Lost frames (and frames before the initialisation) have no pose: they are not written, and
//! the summary lists them.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail};
use jointloc_features::orb::GrayImageView;
use jointloc_formats::{Sequence, read_camera_yaml};
use jointloc_slam::cpu_time::{cpu_ms, thread_cpu_ns};
use jointloc_slam::map::Map;
use jointloc_slam::system::{System, SystemConfig, median};
use jointloc_slam::tracking::TrackingState;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset folder (uav/images.txt, uav/altimeter.txt, camera.yaml; see docs/architecture.md).
    #[arg(long)]
    dataset: PathBuf,
    /// Output trajectory (TUM, camera-to-world, SLAM frame; metric scale from the altimeter).
    #[arg(long)]
    out: PathBuf,
    /// Process every frame in order, mapping each keyframe and closing each loop (global BA
    /// included) before the next frame: deterministic. Without it, the global BA after a loop
    /// runs on its own thread and lands when done, as in ORB-SLAM2: tracking does not stall
    /// for it, but runs are not reproducible.
    #[arg(long)]
    sequential: bool,
    /// Keyframe trajectory output (TUM).
    #[arg(long, value_name = "PATH")]
    keyframes: Option<PathBuf>,
    /// Map points output (ASCII PLY).
    #[arg(long, value_name = "PATH")]
    map_points: Option<PathBuf>,
    /// Write each frame's pose as estimated when it was tracked, instead of through its
    /// reference keyframe's final pose (ORB-SLAM2's way, the default).
    #[arg(long)]
    online: bool,
    /// Process only the first N frames.
    #[arg(long, value_name = "N")]
    max_frames: Option<usize>,
    /// Settings (TOML, `SystemConfig`: max_keyframes, [orb], [tracking], [local_mapping],
    /// [loop_closing]);
    /// defaults otherwise.
    #[arg(long, value_name = "PATH")]
    config: Option<PathBuf>,
    /// Ignore the altimeter (the scale is then the ORB-SLAM2 median depth of 1).
    #[arg(long)]
    no_altimeter: bool,
    /// Sliding-window cap on the map's keyframes (overrides the config's `max_keyframes`;
    /// 0, the default: no cap). Bounds memory on long flights, but loops back to retired
    /// keyframes are not found. Retired keyframes keep their poses in both trajectories.
    #[arg(long, value_name = "N")]
    max_keyframes: Option<usize>,
    /// Turn loop closing off (overrides the config's `[loop_closing] enabled`): the SLAM as
    /// it was without it, for comparison.
    #[arg(long)]
    no_loop_closing: bool,
    /// Replace existing outputs (`--out`, `--keyframes`, `--map-points`).
    #[arg(long)]
    force: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    // Checked before the (long) run, so a forgotten `--force` costs nothing.
    let outputs = [
        Some(&args.out),
        args.keyframes.as_ref(),
        args.map_points.as_ref(),
    ];
    for p in outputs.into_iter().flatten() {
        if p.exists() && !args.force {
            bail!("{}: already exists (use --force to overwrite)", p.display());
        }
    }
    let camera = read_camera_yaml(&args.dataset.join("camera.yaml"))?.camera;
    let sequence = Sequence::open(&args.dataset)?;
    // No keyframe cap unless the settings or the command line ask for one: loop closing
    // needs the old keyframes (docs/vo.md §6.1a).
    let (mut config, cap_given): (SystemConfig, bool) = match &args.config {
        Some(p) => {
            let text =
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            let config: SystemConfig =
                toml::from_str(&text).with_context(|| format!("parsing {}", p.display()))?;
            let given =
                toml::from_str::<toml::Table>(&text).is_ok_and(|t| t.contains_key("max_keyframes"));
            (config, given)
        }
        None => (SystemConfig::default(), false),
    };
    config.max_keyframes = match (args.max_keyframes, cap_given) {
        (Some(n), _) => n,
        (None, true) => config.max_keyframes,
        (None, false) => 0,
    };
    if args.no_loop_closing {
        config.loop_closing.enabled = false;
    }
    config.loop_closing.global_ba_thread = !args.sequential;
    let mut system = System::new(camera, config).with_context(|| {
        let settings = match &args.config {
            Some(p) => format!("settings {} and the command line", p.display()),
            None => "default settings".to_string(),
        };
        format!(
            "starting the SLAM (camera {}, {settings})",
            args.dataset.join("camera.yaml").display()
        )
    })?;
    let n = args.max_frames.unwrap_or(usize::MAX).min(sequence.len());
    let start = Instant::now();
    let start_cpu = thread_cpu_ns();
    let mut online_t = Vec::new();
    let mut online_p = Vec::new();
    let mut lost = Vec::new();
    let mut relocalised = Vec::new();
    let mut initialised_at = None;
    for i in 0..n {
        let f = &sequence.frames[i];
        let image = sequence.load_image(i)?;
        let altitude = if args.no_altimeter { None } else { f.altitude };
        let r = system
            .process(GrayImageView::from(&image), f.timestamp, altitude)
            .with_context(|| format!("frame {i} ({})", f.path.display()))?;
        match r.state {
            TrackingState::Ok => {
                initialised_at.get_or_insert(i);
            }
            TrackingState::Lost => lost.push(i),
            TrackingState::NotInitialized => {}
        }
        if r.relocalised {
            relocalised.push(i);
        }
        if let Some(p) = r.pose {
            online_t.push(r.timestamp);
            online_p.push(p);
        }
        if i % 100 == 99 {
            tracing::info!(
                frame = i + 1,
                of = n,
                keyframes = system.map().n_keyframes(),
                retired = system.retired_keyframes().len(),
                points = system.map().n_points(),
                rss_mb = proc_status_mb("VmRSS:"),
                "progress"
            );
        }
    }
    system
        .finish_background_work()
        .context("the global BA on its thread")?;
    let wall = start.elapsed().as_secs_f64();
    let cpu_s = cpu_ms(start_cpu, thread_cpu_ns()).map(|ms| ms * 1e-3);
    let trajectory = if args.online {
        jointloc_geometry::trajectory::Trajectory::new(online_t, online_p)?
    } else {
        system.trajectory()?
    };
    if trajectory.is_empty() {
        bail!("no frame was tracked (the map never initialised)");
    }
    trajectory.write_tum(&args.out)?;
    if let Some(p) = &args.keyframes {
        system.keyframe_trajectory()?.write_tum(p)?;
    }
    if let Some(p) = &args.map_points {
        write_ply(system.map(), p)?;
    }
    let t = system.timing();
    println!(
        "{n} frames: {} tracked, initialised at frame {}, {} lost{}, {} relocalised",
        trajectory.len(),
        initialised_at.map_or("-".to_string(), |i| i.to_string()),
        lost.len(),
        if lost.is_empty() {
            String::new()
        } else {
            format!(" ({})", ranges(&lost))
        },
        relocalised.len()
    );
    let loops = system.loops_closed();
    println!(
        "loops closed: {}{}",
        loops.len(),
        loops
            .iter()
            .map(|l| format!(
                " frame {} (keyframe {} → {}, moved {:.3}, {:.0} ms: {:.0} detection, {:.0} correction, {:.0} global BA)",
                l.frame_index,
                l.keyframe,
                l.loop_keyframe,
                l.correction,
                l.ms,
                l.detection_ms,
                l.correction_ms,
                l.global_ba_ms
            ))
            .collect::<Vec<_>>()
            .join(",")
    );
    println!(
        "map: {} keyframes ({} retired by the cap), {} points",
        system.map().n_keyframes(),
        system.retired_keyframes().len(),
        system.map().n_points()
    );
    if let Some(mb) = proc_status_mb("VmHWM:") {
        println!("peak RSS: {mb:.1} MB");
    }
    let sum = |a: &[f64], b: &[f64]| -> Vec<f64> { a.iter().zip(b).map(|(x, y)| x + y).collect() };
    println!(
        "median ms: ORB extraction {:.1}, tracking {:.1}, ORB + tracking {:.1}, local mapping {:.1} (per keyframe, {} keyframes inserted), local BA {:.1}",
        median(&t.orb_ms),
        median(&t.tracking_ms),
        median(&sum(&t.orb_ms, &t.tracking_ms)),
        median(&t.local_mapping_ms),
        t.local_mapping_ms.len(),
        median(&t.lba_ms)
    );
    // Thread CPU time advances at scheduler ticks and switches (a few ms), so one short
    // interval is coarse; the mean over many is not, hence means rather than medians.
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let c = &t.cpu;
    if !c.frame_ms.is_empty() {
        println!(
            "mean CPU ms: ORB extraction {:.1}, tracking {:.1}, ORB + tracking {:.1}, local mapping {:.1}, local BA {:.1}",
            mean(&c.orb_ms),
            mean(&c.tracking_ms),
            mean(&sum(&c.orb_ms, &c.tracking_ms)),
            mean(&c.local_mapping_ms),
            mean(&c.lba_ms)
        );
    }
    if let Some((i, ms)) = t
        .frame_ms
        .iter()
        .copied()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(&b.1))
    {
        let at = |v: &[f64]| v.get(i).copied().unwrap_or(f64::NAN);
        println!(
            "slowest frame: {ms:.0} ms (frame {i}: ORB {:.0}, tracking {:.0}, the rest mapping and loop closing)",
            at(&t.orb_ms),
            at(&t.tracking_ms)
        );
    }
    println!(
        "throughput: {:.1} Hz ({n} frames in {wall:.1} s, image decoding included)",
        n as f64 / wall.max(1e-9)
    );
    if let Some(cpu_s) = cpu_s {
        println!(
            "CPU time: {cpu_s:.1} s, {:.1} Hz if the core were not shared",
            n as f64 / cpu_s.max(1e-9)
        );
    }
    println!("wrote {}", args.out.display());
    Ok(())
}

/// A memory figure of this process from `/proc/self/status` (`VmRSS:` now, `VmHWM:` peak),
/// MB; `None` where there is no procfs.
fn proc_status_mb(key: &str) -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with(key))?;
    let kb: f64 = line[key.len()..]
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kb / 1024.0)
}

/// `3-7, 12` style list of sorted indices.
fn ranges(v: &[usize]) -> String {
    let mut out = String::new();
    let mut i = 0;
    while i < v.len() {
        let mut j = i;
        while j + 1 < v.len() && v[j + 1] == v[j] + 1 {
            j += 1;
        }
        if !out.is_empty() {
            out += ", ";
        }
        if i == j {
            let _ = write!(out, "{}", v[i]);
        } else {
            let _ = write!(out, "{}-{}", v[i], v[j]);
        }
        i = j + 1;
    }
    out
}

/// Map points as an ASCII PLY (x y z in the SLAM frame).
fn write_ply(map: &Map, path: &Path) -> anyhow::Result<()> {
    let mut s = String::new();
    let _ = write!(
        s,
        "ply\nformat ascii 1.0\ncomment jointloc vo map points, SLAM frame\nelement vertex {}\nproperty double x\nproperty double y\nproperty double z\nend_header\n",
        map.n_points()
    );
    for p in map.points() {
        let _ = writeln!(s, "{} {} {}", p.position.x, p.position.y, p.position.z);
    }
    std::fs::write(path, s).with_context(|| format!("writing {}", path.display()))
}
