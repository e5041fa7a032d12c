//! `jointloc absloc`: absolute localisation alone on every k-th frame of a dataset. Writes the
//! fixes (TUM columns + confidence + tile) and prints the 2-D error statistics against ground
//! truth, the success rate (within 1 m of the ground point a fix measures, where the dataset has an
//! elevation model; else of the camera's x, y) and the time per fix.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use jointloc_absloc::registry::{RegistryOptions, resolve};
use jointloc_absloc::{
    AbsLocConfig, AbsLocalizer, ConfidenceMode, MapTiles, Outcome, Prior, heading_from_rotation,
};
use jointloc_bench::ground_truth::optical_axis_ground_point;
use jointloc_eval::Statistics;
use jointloc_formats::UavDataset;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset folder (uav/images.txt, uav/altimeter.txt, camera.yaml, map.toml + map).
    #[arg(long)]
    dataset: PathBuf,
    /// Matcher (see `jointloc match --list`).
    #[arg(long, value_name = "M", default_value = "xfeat-lighterglue")]
    matcher: String,
    /// Localise every K-th frame.
    #[arg(long, value_name = "K", default_value_t = 1)]
    every: usize,
    /// Search the whole map for every fix (the paper's "w/o" ablation).
    #[arg(long)]
    no_area_prediction: bool,
    /// Match every candidate tile (no predicted window, no early stop on a decisive tile, no
    /// shortlist), as the paper does.
    #[arg(long)]
    exhaustive: bool,
    /// A whole-map search matches every (rotation, tile) pair, nearest first, instead of the
    /// VLAD shortlist's best `[shortlist] candidates`.
    #[arg(long)]
    no_shortlist: bool,
    /// Confidence: adaptive, ssim, matching or fixed:V.
    #[arg(long, value_name = "MODE")]
    confidence: Option<ConfidenceMode>,
    /// Match at native scale (no resampling to the map's GSD).
    #[arg(long)]
    native_scale: bool,
    /// Give the true heading as the prior (an oracle standing in for the fused pose).
    #[arg(long)]
    heading_from_gt: bool,
    /// Give the true position (x, y) as the prior (an oracle standing in for the fused pose):
    /// with `--heading-from-gt`, the search starts with the predicted window
    /// (`predicted_window_margin_m`), as in flight.
    #[arg(long)]
    position_from_gt: bool,
    /// Localiser settings (TOML, keys of `AbsLocConfig`); flags override it.
    #[arg(long, value_name = "TOML")]
    config: Option<PathBuf>,
    /// Tile features are not read from or written to the cache.
    #[arg(long)]
    no_cache: bool,
    /// The sun during the flight, AZIMUTH,ELEVATION in degrees: the map is relit to it (see
    /// `jointloc run --help`). Default: the config's, else a simulated dataset's record.
    #[arg(long, value_name = "AZ,EL")]
    flight_sun: Option<String>,
    /// Stop after this many localised frames.
    #[arg(long, value_name = "N")]
    limit: Option<usize>,
    /// Keypoints per image (default: the detector's own).
    #[arg(long, value_name = "N")]
    max_keypoints: Option<usize>,
    /// ONNX Runtime threads per network.
    #[arg(long, value_name = "N", default_value_t = 1)]
    threads: usize,
    /// Models directory (default: $JOINTLOC_MODELS or the user cache).
    #[arg(long, value_name = "DIR")]
    models_dir: Option<PathBuf>,
    /// Fixes file: `timestamp x y z qx qy qz qw confidence tile ssim match_score inliers`;
    /// failed frames as comment lines.
    #[arg(long, value_name = "FILE")]
    out: PathBuf,
    /// Also write the summary as JSON.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Overwrite existing output files.
    #[arg(long)]
    force: bool,
}

fn refuse_overwrite(path: Option<&Path>, force: bool) -> anyhow::Result<()> {
    if let Some(p) = path
        && p.exists()
        && !force
    {
        bail!("{}: already exists (use --force to overwrite)", p.display());
    }
    Ok(())
}

fn config_of(args: &Args) -> anyhow::Result<AbsLocConfig> {
    let mut cfg = match &args.config {
        Some(p) => {
            let text =
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            toml::from_str(&text)
                .with_context(|| format!("{}: not a valid localiser config", p.display()))?
        }
        None => AbsLocConfig::default(),
    };
    if args.no_area_prediction {
        cfg.area_prediction = false;
    }
    if args.exhaustive {
        cfg.early_stop_inliers = None;
        cfg.predicted_window_margin_m = 0.0;
    }
    if args.exhaustive || args.no_shortlist {
        cfg.shortlist.candidates = 0;
        cfg.coarse_places_first = false;
    }
    if let Some(c) = args.confidence {
        cfg.confidence = c;
    }
    if args.native_scale {
        cfg.scale_normalisation = false;
    }
    if args.no_cache {
        cfg.cache = false;
    }
    crate::flight_sun::resolve(
        args.flight_sun.as_deref(),
        &mut cfg.relight.flight_sun,
        &args.dataset,
    )?;
    Ok(cfg)
}

/// One localised frame, for the summary.
struct Row {
    fix: Option<[f64; 2]>,
    confidence: f64,
    error: Option<f64>,
    /// Against the true ground point under the optical axis (with an elevation model).
    ground_error: Option<f64>,
    ms: f64,
    searched: usize,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if args.every == 0 {
        bail!("--every must be at least 1");
    }
    refuse_overwrite(Some(&args.out), args.force)?;
    refuse_overwrite(args.json.as_deref(), args.force)?;
    let cfg = config_of(&args)?;
    let ds = UavDataset::open(&args.dataset)?;
    if !ds.has_altimeter {
        bail!(
            "{}: missing; absolute localisation needs the altitude of every frame",
            args.dataset.join("uav/altimeter.txt").display()
        );
    }
    let tiles = MapTiles::open(&args.dataset)?;
    // The ground under the optical axis needs the terrain's heights; flat ground at the datum
    // would be a guess.
    let ground = tiles.has_elevation().then(|| tiles.ground());
    let pipeline = resolve(
        &args.matcher,
        &RegistryOptions {
            models_dir: args.models_dir.clone(),
            threads: Some(args.threads),
            max_keypoints: args.max_keypoints,
        },
    )?;
    let clock = std::time::Instant::now();
    let mut loc = AbsLocalizer::new(tiles, ds.camera, pipeline, cfg)?;
    // The tile features at the first frame's scale, before the clock of the first search.
    let first_altitude = ds
        .frames
        .iter()
        .filter_map(|f| f.altitude)
        .find(|a| a.is_finite() && *a > 0.0);
    let status = match first_altitude {
        Some(a) => format!("{:?}", loc.prepare(a)?),
        None => "not opened (no usable altitude)".to_string(),
    };
    eprintln!(
        "{} tiles, features {status} in {:.1} s",
        loc.tiles().len(),
        clock.elapsed().as_secs_f64()
    );
    let mut text = format!(
        "# jointloc absloc: matcher {} every {} area_prediction {} early_stop {:?} confidence {}\n\
         # timestamp x y z qx qy qz qw confidence tile ssim match_score inliers (camera-to-world, world frame of map.toml)\n",
        args.matcher,
        args.every,
        loc.config().area_prediction,
        loc.config().early_stop_inliers,
        loc.config().confidence
    );
    let mut rows: Vec<Row> = Vec::new();
    let frames = ds
        .frames
        .iter()
        .step_by(args.every)
        .take(args.limit.unwrap_or(usize::MAX));
    for f in frames {
        let image = image::open(&f.path)
            .with_context(|| format!("reading {}", f.path.display()))?
            .into_luma8();
        let prior = Prior {
            position: if args.position_from_gt {
                f.ground_truth.map(|p| [p.centre().x, p.centre().y])
            } else {
                None
            },
            heading: if args.heading_from_gt {
                f.ground_truth
                    .map(|p| heading_from_rotation(&p.rotation().to_rotation_matrix()))
            } else {
                None
            },
        };
        let altitude = f.altitude.unwrap_or(f64::NAN);
        let outcome = match loc.localize(&image, altitude, &prior) {
            Ok(o) => o,
            Err(jointloc_absloc::AbslocError::InvalidAltitude { value }) => {
                writeln!(
                    text,
                    "# {:.6} failed: altimeter reading {value} unusable",
                    f.timestamp
                )?;
                rows.push(Row {
                    fix: None,
                    confidence: 0.0,
                    error: None,
                    ground_error: None,
                    ms: 0.0,
                    searched: 0,
                });
                continue;
            }
            Err(e) => return Err(e).with_context(|| format!("frame {}", f.path.display())),
        };
        let truth = f.ground_truth.map(|p| p.centre());
        let row = match &outcome {
            Outcome::Fix(fix) => {
                let q = fix.orientation();
                let [x, y, z] = fix.position;
                writeln!(
                    text,
                    "{:.6} {x:.6} {y:.6} {z:.6} {:.9} {:.9} {:.9} {:.9} {:.6} {} {:.6} {:.6} {}",
                    f.timestamp,
                    q.i,
                    q.j,
                    q.k,
                    q.w,
                    fix.confidence,
                    fix.tile,
                    fix.ssim,
                    fix.match_score,
                    fix.inliers
                )?;
                Row {
                    fix: Some([x, y]),
                    confidence: fix.confidence,
                    error: truth.map(|t| ((x - t.x).powi(2) + (y - t.y).powi(2)).sqrt()),
                    ground_error: f
                        .ground_truth
                        .zip(ground.as_ref())
                        .and_then(|(p, g)| optical_axis_ground_point(&p, g))
                        .map(|(gx, gy)| (x - gx).hypot(y - gy)),
                    ms: fix.ms,
                    searched: fix.searched_tiles,
                }
            }
            Outcome::Failed(fail) => {
                writeln!(
                    text,
                    "# {:.6} failed: {:?} ({} tiles searched)",
                    f.timestamp, fail.reason, fail.searched_tiles
                )?;
                Row {
                    fix: None,
                    confidence: 0.0,
                    error: None,
                    ground_error: None,
                    ms: fail.ms,
                    searched: fail.searched_tiles,
                }
            }
        };
        tracing::info!(t = f.timestamp, error = ?row.error, w = row.confidence, ms = row.ms, "frame");
        rows.push(row);
    }
    std::fs::write(&args.out, &text).with_context(|| format!("writing {}", args.out.display()))?;
    let summary = summarise(&rows);
    print!("{}", summary.0);
    if let Some(p) = &args.json {
        std::fs::write(p, serde_json::to_string_pretty(&summary.1)? + "\n")
            .with_context(|| format!("writing {}", p.display()))?;
    }
    Ok(())
}

/// Text and JSON summaries.
fn summarise(rows: &[Row]) -> (String, serde_json::Value) {
    let n = rows.len();
    let fixes = rows.iter().filter(|r| r.fix.is_some()).count();
    let errors: Vec<f64> = rows.iter().filter_map(|r| r.error).collect();
    let stats = Statistics::from_errors(&errors).ok();
    // A fix is judged by the point it measures, the ground under the optical axis, where the
    // dataset has an elevation model: at 200 m a tilt of 0.7° moves the camera's x, y 2.4 m
    // from it. Without one, by the camera's x, y.
    let judged = |r: &Row| r.ground_error.or(r.error);
    let success = rows
        .iter()
        .filter(|r| judged(r).is_some_and(|e| e < 1.0))
        .count();
    let wrong: Vec<&Row> = rows
        .iter()
        .filter(|r| judged(r).is_some_and(|e| e >= 1.0))
        .collect();
    let mut ms: Vec<f64> = rows.iter().map(|r| r.ms).collect();
    ms.sort_by(f64::total_cmp);
    let mean = |v: &[f64]| {
        if v.is_empty() {
            0.0
        } else {
            v.iter().sum::<f64>() / v.len() as f64
        }
    };
    let ms_mean = mean(&ms);
    let ms_median = ms.get(ms.len() / 2).copied().unwrap_or(0.0);
    let searched = mean(&rows.iter().map(|r| r.searched as f64).collect::<Vec<_>>());
    let w_right = mean(
        &rows
            .iter()
            .filter(|r| judged(r).is_some_and(|e| e < 1.0))
            .map(|r| r.confidence)
            .collect::<Vec<_>>(),
    );
    let w_wrong: Vec<f64> = wrong.iter().map(|r| r.confidence).collect();
    let mut s = String::new();
    let _ = writeln!(
        s,
        "frames localised: {n}, fixes: {fixes}, failed: {}",
        n - fixes
    );
    match &stats {
        Some(st) => {
            let _ = writeln!(
                s,
                "2-D error (m): rmse {:.3}  mean {:.3}  median {:.3}  std {:.3}  min {:.3}  max {:.3}",
                st.rmse, st.mean, st.median, st.std, st.min, st.max
            );
        }
        None => {
            let _ = writeln!(s, "2-D error: no fix with ground truth");
        }
    }
    // Fixes within 1 m only: the wrong ones are counted below.
    let ground: Vec<f64> = rows
        .iter()
        .filter_map(|r| r.ground_error)
        .filter(|&e| e < 1.0)
        .collect();
    let ground_stats = Statistics::from_errors(&ground).ok();
    if let Some(st) = &ground_stats {
        let _ = writeln!(
            s,
            "2-D error against the ground point under the optical axis (what a fix measures; the \
             camera's x, y differ by the tilt), fixes < 1 m off: rmse {:.3}  median {:.3}  max {:.3}",
            st.rmse, st.median, st.max
        );
    }
    let rate = if n == 0 {
        0.0
    } else {
        success as f64 / n as f64
    };
    let _ = writeln!(
        s,
        "success rate (< 1 m from the point measured, failures count as misses): {rate:.3} ({success}/{n})"
    );
    let _ = writeln!(
        s,
        "fixes >= 1 m off: {} (confidence mean {:.3}, max {:.3}); confidence of good fixes: mean {w_right:.3}",
        wrong.len(),
        mean(&w_wrong),
        w_wrong.iter().copied().fold(0.0, f64::max)
    );
    let _ = writeln!(
        s,
        "ms per fix: mean {ms_mean:.1}, median {ms_median:.1}; tiles matched per fix: {searched:.1}"
    );
    let json = serde_json::json!({
        "frames": n,
        "fixes": fixes,
        "failed": n - fixes,
        "error_2d_m": stats,
        "error_ground_point_2d_m": ground_stats,
        "success_rate_1m": rate,
        "wrong_fixes": wrong.len(),
        "wrong_fix_confidence_max": w_wrong.iter().copied().fold(0.0, f64::max),
        "good_fix_confidence_mean": w_right,
        "ms_per_fix_mean": ms_mean,
        "ms_per_fix_median": ms_median,
        "tiles_per_fix_mean": searched,
    });
    (s, json)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(error: f64, ground_error: Option<f64>) -> Row {
        Row {
            fix: Some([0.0, 0.0]),
            confidence: 0.5,
            error: Some(error),
            ground_error,
            ms: 1.0,
            searched: 1,
        }
    }

    /// At altitude the camera's x, y is metres from the ground point a fix measures: a fix is
    /// judged by the latter where the dataset has an elevation model, else by the former.
    #[test]
    fn fixes_are_judged_by_the_point_they_measure() {
        let rows = [
            row(2.4, Some(0.1)),
            row(2.6, Some(0.2)),
            row(0.3, Some(1.5)),
            row(0.4, None),
            row(1.2, None),
        ];
        let (text, json) = summarise(&rows);
        // 0.1 and 0.2 from their ground points, 0.4 from the camera's x, y: right.
        let rate = json["success_rate_1m"].as_f64().unwrap();
        assert!((rate - 0.6).abs() < 1e-12, "{rate}: {text}");
        // 1.5 from its ground point, 1.2 from the camera's x, y: wrong.
        assert_eq!(json["wrong_fixes"], 2, "{text}");
        let rmse = json["error_ground_point_2d_m"]["rmse"].as_f64().unwrap();
        assert!((rmse - 0.025f64.sqrt()).abs() < 1e-12, "{rmse}: {text}");
    }
}
