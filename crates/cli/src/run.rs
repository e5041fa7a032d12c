//! `jointloc run`: the fused system on a dataset, threaded (real time: absolute localisation on
//! its own thread; frames fed as fast as they are tracked, or with `--realtime` at their
//! timestamps, as the camera delivers them) or `--sequential` (deterministic).
//! Writes the world-frame pose of
//! every frame as it was known at that frame (TUM, online; frames before the first alignment
//! are comment lines flagged "not geo-referenced"), the whole trajectory and the keyframes as
//! known at the end (`trajectory-final.tum`, `keyframes.tum`), the fixes with
//! their confidences, per-module timing (paper Table VII) and prints APE against ground truth
//! without any alignment.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail};
use jointloc_absloc::registry::{RegistryOptions, resolve};
use jointloc_absloc::{AbsLocalizer, ConfidenceMode, MapTiles};
use jointloc_eval::{AlignMode, EvalConfig, evaluate};
use jointloc_geometry::trajectory::{Trajectory, TumOptions};
use jointloc_sim::camera_yaml::read_camera_yaml;
use jointloc_slam::sequence::Sequence;
use jointloc_slam::system::median;
use jointloc_system::{JointLoc, JointLocConfig};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset folder (DESIGN §3: uav/, camera.yaml, map.toml + satellite map).
    #[arg(long)]
    dataset: PathBuf,
    /// Output folder: trajectory.tum (online), trajectory-final.tum and keyframes.tum (as known
    /// at the end), fixes.txt, timing.json, summary.json.
    #[arg(long)]
    out: PathBuf,
    /// Matcher of the absolute localisation (see `jointloc match --list`).
    #[arg(long, value_name = "M", default_value = "xfeat-lighterglue")]
    matcher: String,
    /// Absolute localisation on every K-th frame (the paper's fusion frequency).
    #[arg(long, value_name = "K")]
    fusion_every: Option<usize>,
    /// Confidence of the fixes: adaptive (SSIM × matching score), ssim, matching or fixed:V.
    #[arg(long, value_name = "MODE")]
    confidence: Option<ConfidenceMode>,
    /// Run absolute localisation inline on its frames (deterministic, repeatable output)
    /// instead of on its own thread (real time: frames due while it is busy are skipped).
    #[arg(long)]
    sequential: bool,
    /// Replay frames at their timestamps, as the camera would deliver them, sped up by SPEED
    /// (default 1: the camera rate). Without it frames follow each other as fast as they are
    /// tracked, so a short flight can end before the first whole-map search returns.
    /// Reports the lag behind the camera.
    #[arg(long, value_name = "SPEED", num_args = 0..=1, default_missing_value = "1",
          conflicts_with = "sequential")]
    realtime: Option<f64>,
    /// Robustness test: replace this fraction of the fixes by positions 10–50 m off
    /// (seeded; the confidence is kept). Flagged in fixes.txt.
    #[arg(long, value_name = "FRACTION")]
    wrong_fixes: Option<f64>,
    /// Robustness test: no absolute localisation for DURATION seconds from START.
    #[arg(long, value_name = "START:DURATION")]
    outage: Option<String>,
    /// Robustness test: the camera sees uniform grey for DURATION seconds from START (dust,
    /// glare, a dropped video link); a long one makes the SLAM start a new map.
    #[arg(long, value_name = "START:DURATION")]
    blind: Option<String>,
    /// World x, y (metres, map frame) of the take-off, if known (e.g. the lander's position):
    /// the first absolute search starts from the map tiles nearest to it instead of searching
    /// the whole map.
    #[arg(long, value_name = "X,Y")]
    start: Option<String>,
    /// Settings (TOML, `JointLocConfig` with [slam] and [absloc] tables); flags override it.
    #[arg(long, value_name = "PATH")]
    config: Option<PathBuf>,
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
}

const OUTPUTS: [&str; 6] = [
    "trajectory.tum",
    "trajectory-final.tum",
    "keyframes.tum",
    "fixes.txt",
    "timing.json",
    "summary.json",
];

pub fn run(args: Args) -> anyhow::Result<()> {
    for name in OUTPUTS {
        let p = args.out.join(name);
        if p.exists() && !args.force {
            bail!("{}: already exists (use --force to overwrite)", p.display());
        }
    }
    let mut config: JointLocConfig = match &args.config {
        Some(p) => {
            let text =
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            toml::from_str(&text).with_context(|| format!("parsing {}", p.display()))?
        }
        None => JointLocConfig::default(),
    };
    if let Some(k) = args.fusion_every {
        config.fusion_every = k;
    }
    if let Some(c) = args.confidence {
        config.absloc.confidence = c;
    }
    if let Some(f) = args.wrong_fixes {
        config.faults.wrong_fix_fraction = f;
    }
    if let Some(o) = &args.outage {
        let (start, duration) = number_pair(o, ':')
            .with_context(|| format!("--outage {o}: expected START:DURATION in seconds"))?;
        config.faults.outage_start_s = Some(start);
        config.faults.outage_duration_s = duration;
    }
    if let Some(b) = &args.blind {
        let (start, duration) = number_pair(b, ':')
            .with_context(|| format!("--blind {b}: expected START:DURATION in seconds"))?;
        config.faults.blind_start_s = Some(start);
        config.faults.blind_duration_s = duration;
    }
    if let Some(p) = &args.start {
        let (x, y) =
            number_pair(p, ',').with_context(|| format!("--start {p}: expected X,Y in metres"))?;
        config.start_position = Some([x, y]);
    }
    if let Some(speed) = args.realtime
        && !(speed.is_finite() && speed > 0.0)
    {
        bail!("--realtime {speed}: the replay speed must be a positive number");
    }
    config.validate().with_context(|| match &args.config {
        Some(p) => format!("invalid settings in {} or on the command line", p.display()),
        None => "invalid settings on the command line".to_string(),
    })?;
    let camera = read_camera_yaml(&args.dataset.join("camera.yaml"))?.camera;
    let sequence = Sequence::open(&args.dataset)?;
    let tiles = MapTiles::open(&args.dataset)?;
    let pipeline = resolve(
        &args.matcher,
        &RegistryOptions {
            models_dir: args.models_dir.clone(),
            threads: Some(args.threads),
            max_keypoints: None,
        },
    )?;
    let absolute = AbsLocalizer::new(tiles, camera, pipeline, config.absloc.clone())?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let mut system = if args.sequential {
        JointLoc::new(camera, absolute, config.clone())?
    } else {
        JointLoc::threaded(camera, absolute, config.clone())?
    };
    let mode = match (args.sequential, args.realtime) {
        (true, _) => "sequential",
        (false, None) => "threaded",
        (false, Some(_)) => "threaded, real-time replay",
    };
    let traj_path = args.out.join("trajectory.tum");
    let mut traj = std::io::BufWriter::new(
        std::fs::File::create(&traj_path)
            .with_context(|| format!("creating {}", traj_path.display()))?,
    );
    writeln!(
        traj,
        "# timestamp tx ty tz qx qy qz qw (camera-to-world, world frame of map.toml, as known online)"
    )?;
    let n = args.max_frames.unwrap_or(usize::MAX).min(sequence.len());
    let (mut geo_from, mut written, mut lost) = (None, 0usize, 0usize);
    let start = Instant::now();
    let mut replay = args
        .realtime
        .map(|speed| Replay::new(speed, sequence.frames.first().map_or(0.0, |f| f.timestamp)));
    let mut busy_s = 0.0;
    for i in 0..n {
        let f = &sequence.frames[i];
        let image = sequence.load_image(i)?;
        if let Some(r) = &mut replay {
            r.wait_for(f.timestamp);
        }
        let began = Instant::now();
        let r = system
            .process(&image, f.timestamp, f.altitude)
            .with_context(|| format!("frame {i} ({})", f.path.display()))?;
        busy_s += began.elapsed().as_secs_f64();
        if let Some(r) = &mut replay {
            r.record_done(f.timestamp);
        }
        if r.state == jointloc_slam::tracking::TrackingState::Lost {
            lost += 1;
        }
        match r.world_pose {
            Some(p) => {
                geo_from.get_or_insert(i);
                let t = p.0.translation.vector;
                let q = p.0.rotation;
                writeln!(
                    traj,
                    "{:.6} {:.6} {:.6} {:.6} {:.9} {:.9} {:.9} {:.9}",
                    f.timestamp, t.x, t.y, t.z, q.i, q.j, q.k, q.w
                )?;
                written += 1;
            }
            None => writeln!(
                traj,
                "# {:.6} {}",
                f.timestamp,
                if r.slam_pose.is_some() {
                    "not geo-referenced"
                } else {
                    "not tracked"
                }
            )?,
        }
        traj.flush()?;
        if i % 100 == 99 {
            tracing::info!(
                frame = i + 1,
                of = n,
                fixes = system.fixes().len(),
                "progress"
            );
        }
    }
    let wall = start.elapsed().as_secs_f64();
    drop(traj);
    let end = system.end_outputs()?;
    if let Some(kf) = &end.keyframes {
        kf.write_tum(args.out.join("keyframes.tum"))?;
    }
    let final_path = args.out.join("trajectory-final.tum");
    let final_traj = end.frames;
    if let Some(t) = &final_traj {
        t.write_tum(&final_path)?;
    }
    write_fixes(&args.out.join("fixes.txt"), &system)?;
    let slam_t = system.slam().timing();
    let fus_t = system.timing();
    let hz = n as f64 / wall.max(1e-9);
    // What the frame loop could sustain: frames over the time spent in `process`.
    let capacity_hz = n as f64 / busy_s.max(1e-9);
    let timing = serde_json::json!({
        "absolute_localisation_ms": median(&fus_t.absolute_ms),
        "alignment_ms": median(&fus_t.alignment_ms),
        "orb_extraction_ms": median(&slam_t.orb_ms),
        "tracking_ms": median(&slam_t.tracking_ms),
        "local_mapping_ms": median(&slam_t.local_mapping_ms),
        "local_ba_ms": median(&slam_t.lba_ms),
        "frame_ms": median(&fus_t.frame_ms),
        "hz": hz,
        "capacity_hz": capacity_hz,
    });
    std::fs::write(
        args.out.join("timing.json"),
        serde_json::to_string_pretty(&timing)? + "\n",
    )?;
    let used = system.fixes().iter().filter(|f| f.used).count();
    let inliers = system.fixes().iter().filter(|f| f.inlier).count();
    println!(
        "{n} frames in {wall:.1} s ({hz:.1} Hz, {mode}); {lost} lost; {} new maps after losses; geo-referenced from frame {}; {written} world poses written",
        system.new_maps(),
        geo_from.map_or("-".into(), |i: usize| i.to_string())
    );
    if let Some(r) = &replay {
        println!(
            "real-time replay at {}× the camera rate: capacity {capacity_hz:.1} Hz; lag behind the \
             camera median {:.1} ms, max {:.1} ms; {} of {n} frames due before the previous one was done",
            r.speed,
            r.lag_median_ms(),
            r.lag_max_ms(),
            r.late
        );
    }
    let injected = system.fixes().iter().filter(|f| f.injected).count();
    println!(
        "fixes: {} attempts, {} found, {used} used, {inliers} inliers of the final alignment; \
         {} skipped (thread busy), {} skipped (not tracked yet), {} skipped (outage), \
         {injected} made wrong on purpose",
        fus_t.absolute_ms.len(),
        system.fixes().len(),
        fus_t.skipped_busy,
        fus_t.skipped_untracked,
        fus_t.skipped_outage,
    );
    let terrain = system.terrain_correction();
    if terrain.updates > 0 {
        println!(
            "terrain correction of the fixes: ({:+.3}, {:+.3}) m after {} estimates",
            terrain.offset.x, terrain.offset.y, terrain.updates
        );
    }
    if let Some(b) = &end.final_ba {
        println!(
            "final global BA: {} keyframes, {} points, {} fix factors ({} left out: wrong, or \
             their keyframe retired), {} \
             ground factors; {} iterations, {:.0} ms",
            b.keyframes,
            b.points,
            b.global_factors,
            b.factors_left_out,
            b.ground_factors,
            b.iterations,
            b.ms
        );
    }
    println!(
        "median ms: absolute localisation {:.1}, ORB {:.1}, tracking {:.1}, local mapping {:.1}, local BA {:.1}",
        median(&fus_t.absolute_ms),
        median(&slam_t.orb_ms),
        median(&slam_t.tracking_ms),
        median(&slam_t.local_mapping_ms),
        median(&slam_t.lba_ms)
    );
    let mut summary = serde_json::json!({
        "frames": n, "world_poses": written, "geo_referenced_from": geo_from, "lost": lost,
        "new_maps": system.new_maps(),
        "fixes_found": system.fixes().len(), "fixes_used": used, "fixes_inliers": inliers, "hz": hz,
        "mode": mode, "absolute_attempts": fus_t.absolute_ms.len(),
        "skipped_busy": fus_t.skipped_busy, "skipped_outage": fus_t.skipped_outage,
        "skipped_untracked": fus_t.skipped_untracked,
        "fixes_injected_wrong": injected,
        "first_fix_global": system.fixes().first().map(|f| f.global),
        "first_fix_searched_tiles": system.fixes().first().map(|f| f.searched_tiles),
        "capacity_hz": capacity_hz,
        "terrain_correction_m": {
            "x": terrain.offset.x,
            "y": terrain.offset.y,
            "updates": terrain.updates,
        },
        "final_ba": end.final_ba,
    });
    if let Some(r) = &replay {
        summary["realtime"] = serde_json::json!({
            "speed": r.speed,
            "lag_median_ms": r.lag_median_ms(),
            "lag_max_ms": r.lag_max_ms(),
            "frames_late": r.late,
        });
    }
    let gt_path = args.dataset.join("uav/gt.txt");
    if gt_path.exists() && written >= 3 {
        let gt = Trajectory::read_tum(&gt_path, &TumOptions::default())?;
        let est = Trajectory::read_tum(&traj_path, &TumOptions::default())?;
        let no_alignment = EvalConfig {
            align: AlignMode::None,
            ..Default::default()
        };
        let report = evaluate(&gt, &est, &no_alignment)?;
        let st = report.ape_translation.stats;
        println!(
            "APE (world frame, no alignment, {} poses): rmse {:.3} m, mean {:.3}, median {:.3}, std {:.3}, max {:.3}",
            report.associated_poses, st.rmse, st.mean, st.median, st.std, st.max
        );
        summary["ape_translation"] = serde_json::to_value(st)?;
        if let Some(fin) = &final_traj
            && fin.len() >= 3
        {
            let report = evaluate(&gt, fin, &no_alignment)?;
            let st = report.ape_translation.stats;
            println!(
                "APE of trajectory-final.tum (as known at the end, {} poses): rmse {:.3} m, mean {:.3}, max {:.3}",
                report.associated_poses, st.rmse, st.mean, st.max
            );
            summary["ape_translation_final"] = serde_json::to_value(st)?;
        }
    }
    std::fs::write(
        args.out.join("summary.json"),
        serde_json::to_string_pretty(&summary)? + "\n",
    )?;
    println!("wrote {}", args.out.display());
    Ok(())
}

fn write_fixes(path: &Path, system: &JointLoc) -> anyhow::Result<()> {
    let mut s = String::from(
        "# timestamp x y z qx qy qz qw confidence tile ssim match_score inliers used inlier injected (x, y: map point under the image centre; z: map elevation there + altimeter; injected: made wrong on purpose)\n",
    );
    for f in system.fixes() {
        s.push_str(&format!(
            "{:.6} {:.4} {:.4} {:.4} 0 0 0 1 {:.4} {} {:.4} {:.4} {} {} {} {}\n",
            f.timestamp,
            f.position[0],
            f.position[1],
            f.position[2],
            f.confidence,
            f.tile,
            f.ssim,
            f.match_score,
            f.inliers,
            u8::from(f.used),
            u8::from(f.inlier),
            u8::from(f.injected)
        ));
    }
    std::fs::write(path, s).with_context(|| format!("writing {}", path.display()))
}

/// Frames released at their timestamps (scaled by `speed`) from the start of the run, and how
/// far behind the camera the processing of each one finished.
struct Replay {
    speed: f64,
    first_timestamp: f64,
    started: Instant,
    lags_ms: Vec<f64>,
    /// Frames that were due before the previous one was done (the loop fell behind).
    late: usize,
}

impl Replay {
    fn new(speed: f64, first_timestamp: f64) -> Self {
        Self {
            speed,
            first_timestamp,
            started: Instant::now(),
            lags_ms: Vec::new(),
            late: 0,
        }
    }

    /// Seconds after the start at which the camera delivers the frame stamped `timestamp`.
    fn due_s(&self, timestamp: f64) -> f64 {
        ((timestamp - self.first_timestamp) / self.speed).max(0.0)
    }

    fn wait_for(&mut self, timestamp: f64) {
        let due = self.due_s(timestamp);
        let now = self.started.elapsed().as_secs_f64();
        if due > now {
            std::thread::sleep(std::time::Duration::from_secs_f64(due - now));
        } else if !self.lags_ms.is_empty() {
            self.late += 1;
        }
    }

    fn record_done(&mut self, timestamp: f64) {
        let lag = self.started.elapsed().as_secs_f64() - self.due_s(timestamp);
        self.lags_ms.push(lag * 1e3);
    }

    fn lag_median_ms(&self) -> f64 {
        median(&self.lags_ms)
    }

    fn lag_max_ms(&self) -> f64 {
        self.lags_ms.iter().copied().fold(0.0, f64::max)
    }
}

/// Two numbers separated by `separator` (`"60:30"`, `"36.5,-41"`).
fn number_pair(text: &str, separator: char) -> Option<(f64, f64)> {
    let (a, b) = text.split_once(separator)?;
    Some((a.trim().parse().ok()?, b.trim().parse().ok()?))
}
