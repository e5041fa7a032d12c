//! The paper's matcher benchmark (§IV-D, Table V): image pairs with a known homography, the
//! mean corner error of the estimated homography, the fraction of pairs under 1/5/10/50/100 px,
//! and the time per pair (both extractions, matching and RANSAC).
//!
//! Pairs come from a simulated dataset (a frame and the tile that contains its centre, the true
//! homography from ground truth, see [`crate::ground_truth`]) or from a pairs file: one pair per
//! line, `query reference h00 h01 … h22` (the 3 × 3 homography query → reference, row-major),
//! paths relative to the file, `#` comments.

use std::path::{Path, PathBuf};
use std::time::Instant;

use image::GrayImage;
use jointloc_absloc::candidate::{
    AcceptConfig, Candidate, MatchContext, QueryView, evaluate, matched_points,
};
use jointloc_absloc::relight::{NotRelit, RelightConfig, relit_tiles};
use jointloc_absloc::tiles::{MapTile, MapTiles};
use jointloc_absloc::{AbsLocConfig, AbslocError, FeaturePipeline, Result};
use jointloc_features::Features;
use jointloc_formats::UavDataset;
use jointloc_geometry::homography::{
    FootprintKernel, HomographyConfig, corner_error, refit_with_kernel,
};
use nalgebra::{Matrix3, Point2};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::ground_truth::{GroundTruthSource, TerrainHeights, true_homography};

/// Corner-error thresholds of the table, pixels.
pub const THRESHOLDS_PX: [f64; 5] = [1.0, 5.0, 10.0, 50.0, 100.0];

/// The reference image of a pair, as a tile at the map origin: its pixels are the reference's.
const ORIGIN: MapTile = MapTile {
    index: 0,
    x: 0,
    y: 0,
    col: 0,
    row: 0,
};

/// One pair.
#[derive(Debug, Clone)]
pub struct MatchPair {
    /// Label for reports (frame file or pairs-file line).
    pub label: String,
    pub query: GrayImage,
    pub reference: GrayImage,
    /// Query pixels → reference pixels.
    pub h_true: Matrix3<f64>,
    /// Resampling of the query before matching: `(scale, angle)` about the query centre, as
    /// the localiser does from altimeter and heading; `None` matches at native scale.
    pub normalisation: Option<(f64, f64)>,
}

/// Which homography a pair's corner error is measured on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum HomographyFit {
    /// The localiser's estimate: RANSAC with the tight threshold, refined on its inliers (the
    /// paper's protocol, as OpenCV's `findHomography` would give).
    #[default]
    Tight,
    /// The tight estimate refitted over every match within
    /// [`BenchConfig::footprint_threshold_px`] ([`jointloc_geometry::homography::refit_over_footprint`]):
    /// the homography of the whole footprint, as the ground truth over relief is defined.
    Footprint,
    /// The same refit with each match weighted by Tukey's biweight of its error
    /// ([`FootprintKernel::Biweight`]): near-miss false matches within the threshold pull less.
    Biweight,
}

impl HomographyFit {
    /// Lower-case name, as on the command line.
    pub fn name(self) -> &'static str {
        match self {
            HomographyFit::Tight => "tight",
            HomographyFit::Footprint => "footprint",
            HomographyFit::Biweight => "biweight",
        }
    }

    /// The refit's weighting; `None` for the tight fit, which is scored as estimated.
    fn kernel(self) -> Option<FootprintKernel> {
        match self {
            HomographyFit::Tight => None,
            HomographyFit::Footprint => Some(FootprintKernel::Hard),
            HomographyFit::Biweight => Some(FootprintKernel::Biweight),
        }
    }
}

impl std::str::FromStr for HomographyFit {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, Self::Err> {
        match s {
            "tight" => Ok(HomographyFit::Tight),
            "footprint" => Ok(HomographyFit::Footprint),
            "biweight" => Ok(HomographyFit::Biweight),
            other => Err(format!(
                "unknown fit `{other}` (tight, footprint or biweight)"
            )),
        }
    }
}

/// Settings of the benchmark.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct BenchConfig {
    /// Homography estimation (RANSAC threshold in reference pixels).
    pub homography: HomographyConfig,
    /// Minimum matches and inliers for a homography (fewer: the pair fails, error ∞).
    pub min_inliers: usize,
    /// The homographies scored, each from the same matches: one report per fit.
    pub fits: Vec<HomographyFit>,
    /// Threshold of the footprint and biweight refits, reference pixels: it must admit the parallax of the
    /// relief (10 m of flight over metres of relief: tens of 5 cm pixels at the corners).
    pub footprint_threshold_px: f64,
}

impl Default for BenchConfig {
    fn default() -> Self {
        Self {
            homography: HomographyConfig::default(),
            min_inliers: 8,
            fits: vec![HomographyFit::Tight],
            footprint_threshold_px: 20.0,
        }
    }
}

/// Outcome of one pair.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PairResult {
    pub label: String,
    /// Mean corner error in reference pixels (∞ when no homography was found, written as
    /// `null` in JSON).
    pub corner_error_px: Option<f64>,
    pub matches: usize,
    /// Matches the scored homography was fitted to (its inliers).
    pub inliers: usize,
    pub ms: f64,
}

/// The table row of one matcher.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MatchReport {
    pub matcher: String,
    /// The homography scored.
    pub fit: HomographyFit,
    pub pairs: usize,
    /// Fraction of pairs under each threshold, keyed `@1px`, `@5px`, ...
    pub accuracy: std::collections::BTreeMap<String, f64>,
    /// Pairs without a homography.
    pub failures: usize,
    /// Mean and median time per pair.
    pub ms_mean: f64,
    pub ms_median: f64,
    pub results: Vec<PairResult>,
}

/// Key of threshold `t` in [`MatchReport::accuracy`].
pub fn threshold_key(t: f64) -> String {
    format!("@{t}px")
}

/// Runs one pair: one result per fit of `cfg.fits`, in that order, all from the same matches.
/// A refit's time is added to the shared time of extraction, matching and the tight fit.
pub fn run_pair(
    pipeline: &FeaturePipeline,
    pair: &MatchPair,
    cfg: &BenchConfig,
) -> Result<Vec<PairResult>> {
    let start = Instant::now();
    let (w, h) = pair.query.dimensions();
    let centre = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
    let (scale, angle) = pair.normalisation.unwrap_or((1.0, 0.0));
    let view = QueryView::new(
        &pair.query,
        pipeline.detector.as_ref(),
        centre,
        scale,
        angle,
        4.0,
    )?;
    let reference = pipeline.detector.detect(&pair.reference)?;
    let accept = AcceptConfig {
        min_matches: cfg.min_inliers,
        min_inliers: cfg.min_inliers,
        max_log_scale_error: f64::INFINITY,
        max_anisotropy: f64::INFINITY,
        border_margin_px: 4.0,
        ..AcceptConfig::default()
    };
    let ctx = MatchContext {
        matcher: pipeline.matcher.as_ref(),
        homography: &cfg.homography,
        accept: &accept,
        principal: centre,
        expected_scale: None,
    };
    let found = evaluate(&ctx, 0, &view, 0, &ORIGIN, &reference)?;
    let shared_ms = start.elapsed().as_secs_f64() * 1e3;
    let c = match found {
        Ok(c) => c,
        Err(rejection) => {
            tracing::debug!(pair = %pair.label, ?rejection, "no homography");
            let failed = PairResult {
                label: pair.label.clone(),
                corner_error_px: None,
                matches: 0,
                inliers: 0,
                ms: shared_ms,
            };
            return Ok(vec![failed; cfg.fits.len()]);
        }
    };
    let mut results = Vec::with_capacity(cfg.fits.len());
    for &fit in &cfg.fits {
        let refit_start = Instant::now();
        let (h_est, inliers) = match fit.kernel() {
            None => (c.h_map_from_frame, c.inliers.len()),
            Some(kernel) => footprint_homography(&c, &view, &reference, cfg, kernel)?,
        };
        results.push(PairResult {
            label: pair.label.clone(),
            corner_error_px: Some(corner_error(&h_est, &pair.h_true, w, h))
                .filter(|e| e.is_finite()),
            matches: c.matches.pairs.len(),
            inliers,
            ms: shared_ms + refit_start.elapsed().as_secs_f64() * 1e3,
        });
    }
    Ok(results)
}

/// The tight estimate of `c` refitted over the footprint ([`HomographyFit::Footprint`],
/// [`HomographyFit::Biweight`]): frame → reference pixels, and the number of matches it was
/// fitted to. The refit runs in the normalised view's pixels, where the matches are.
fn footprint_homography(
    c: &Candidate,
    view: &QueryView,
    reference: &Features,
    cfg: &BenchConfig,
    kernel: FootprintKernel,
) -> Result<(Matrix3<f64>, usize)> {
    let (src, dst) = matched_points(&view.features, reference, &c.matches, &ORIGIN);
    let to_view = view.normalised.transform.matrix();
    // A similarity of positive scale: invertible. Were it not, the zero start homography is
    // reported by the refit as degenerate.
    let h_view = c.h_map_from_frame * to_view.try_inverse().unwrap_or_else(Matrix3::zeros);
    let passes = match kernel {
        FootprintKernel::Hard => 3,
        FootprintKernel::Biweight => 10,
    };
    let fit = refit_with_kernel(
        &h_view,
        &src,
        &dst,
        cfg.footprint_threshold_px,
        kernel,
        passes,
        cfg.homography.refine_iterations,
    )?;
    let h = fit.h * to_view;
    Ok((h / h[(2, 2)], fit.inliers.len()))
}

/// Runs every pair and summarises: one report per fit of `cfg.fits`, in that order.
pub fn run_bench(
    pipeline: &FeaturePipeline,
    pairs: &[MatchPair],
    cfg: &BenchConfig,
) -> Result<Vec<MatchReport>> {
    let mut per_fit: Vec<Vec<PairResult>> = vec![Vec::with_capacity(pairs.len()); cfg.fits.len()];
    for p in pairs {
        for (fit_results, r) in per_fit.iter_mut().zip(run_pair(pipeline, p, cfg)?) {
            fit_results.push(r);
        }
    }
    Ok(cfg
        .fits
        .iter()
        .zip(per_fit)
        .map(|(&fit, results)| summarise(&pipeline.name, fit, results))
        .collect())
}

/// The table row of `results`.
pub fn summarise(matcher: &str, fit: HomographyFit, results: Vec<PairResult>) -> MatchReport {
    let n = results.len().max(1) as f64;
    let accuracy = THRESHOLDS_PX
        .iter()
        .map(|&t| {
            let ok = results
                .iter()
                .filter(|r| r.corner_error_px.is_some_and(|e| e < t))
                .count();
            (threshold_key(t), ok as f64 / n)
        })
        .collect();
    let mut ms: Vec<f64> = results.iter().map(|r| r.ms).collect();
    ms.sort_by(f64::total_cmp);
    MatchReport {
        matcher: matcher.to_string(),
        fit,
        pairs: results.len(),
        accuracy,
        failures: results
            .iter()
            .filter(|r| r.corner_error_px.is_none())
            .count(),
        ms_mean: ms.iter().sum::<f64>() / n,
        ms_median: ms.get(ms.len() / 2).copied().unwrap_or(0.0),
        results,
    }
}

/// `n` pairs from a simulated dataset, frames drawn with `seed` (without replacement when
/// possible): each frame against the tile nearest to its true centre point, with the
/// homography from ground truth (`terrain` heights when given, else the altimeter plane).
/// `normalise` resamples the query to map scale (altimeter) and north-up (true heading), as the
/// localiser does with a fused heading, after upsampling a coarse map as the localiser does
/// ([`jointloc_absloc::localizer::map_upsample_factor`]). The map is relit first as the
/// localiser relights it (`relight`; [`jointloc_absloc::relight`]); the third value says why
/// not when it was not.
pub fn pairs_from_dataset(
    dir: &Path,
    n: usize,
    seed: u64,
    terrain: Option<&dyn TerrainHeights>,
    normalise: bool,
    relight: &RelightConfig,
) -> Result<(Vec<MatchPair>, GroundTruthSource, Option<NotRelit>)> {
    let ds = UavDataset::open(dir)?;
    let mut tiles = MapTiles::open(dir)?;
    tiles.check_frame_size(ds.camera.width, ds.camera.height)?;
    let not_relit = match relit_tiles(&tiles, relight)? {
        Ok(relit) => {
            tiles = relit;
            None
        }
        Err(why) => Some(why),
    };
    if normalise {
        // As the localiser: a map too coarse for the frames is upsampled first (at the first
        // frame's altitude), so pixel errors are in the upsampled map's pixels.
        let focal = 0.5 * (ds.camera.fx + ds.camera.fy);
        if let Some(alt) = ds
            .frames
            .iter()
            .find_map(|f| f.altitude.filter(|a| a.is_finite() && *a > 0.0))
        {
            let factor = jointloc_absloc::localizer::map_upsample_factor(
                alt / (focal * tiles.gsd_m()),
                AbsLocConfig::default().min_match_scale,
            );
            if factor > 1.0 {
                tiles = tiles.upsampled(factor, 0.5)?;
            }
        }
    }
    let usable: Vec<usize> = (0..ds.frames.len())
        .filter(|&i| ds.frames[i].ground_truth.is_some())
        .collect();
    if usable.is_empty() {
        return Err(AbslocError::Parse {
            path: dir.join("uav/gt.txt"),
            line: 0,
            message: "no frame has ground truth".into(),
        });
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let picks: Vec<usize> = if n <= usable.len() {
        let mut idx = rand::seq::index::sample(&mut rng, usable.len(), n).into_vec();
        idx.sort_unstable();
        idx.into_iter().map(|k| usable[k]).collect()
    } else {
        (0..n).map(|k| usable[k % usable.len()]).collect()
    };
    let mut source = GroundTruthSource::Terrain;
    let mut pairs = Vec::with_capacity(picks.len());
    for i in picks {
        let f = &ds.frames[i];
        let pose = f
            .ground_truth
            .unwrap_or_else(jointloc_geometry::CameraToWorld::identity);
        let (h_map, src) = true_homography(&pose, &ds.camera, tiles.gsd_m(), terrain, f.altitude)?;
        if src == GroundTruthSource::AltimeterPlane {
            source = src;
        }
        let c = h_map * Point2::new(ds.camera.cx, ds.camera.cy).to_homogeneous();
        let (x, y) = tiles.pixel_to_world(c.x / c.z, c.y / c.z);
        let t = tiles.nearest(x, y, 1)[0];
        let tile = tiles.tiles()[t];
        let shift = Matrix3::new(
            1.0,
            0.0,
            -(tile.x as f64),
            0.0,
            1.0,
            -(tile.y as f64),
            0.0,
            0.0,
            1.0,
        );
        let h_true = shift * h_map;
        let normalisation = if normalise {
            let j = jointloc_absloc::candidate::jacobian(&h_true, ds.camera.cx, ds.camera.cy);
            let heading = j.map_or(0.0, |j| jointloc_absloc::candidate::rotation_of(&j));
            let alt = f.altitude.filter(|a| a.is_finite() && *a > 0.0).ok_or(
                AbslocError::InvalidAltitude {
                    value: f.altitude.unwrap_or(f64::NAN),
                },
            )?;
            let scale = alt / (0.5 * (ds.camera.fx + ds.camera.fy) * tiles.gsd_m());
            Some((scale, heading))
        } else {
            None
        };
        pairs.push(MatchPair {
            label: f
                .path
                .file_name()
                .map_or_else(String::new, |s| s.to_string_lossy().into_owned()),
            query: read_gray(&f.path)?,
            reference: tiles.tile_image(t),
            h_true,
            normalisation,
        });
    }
    Ok((pairs, source, not_relit))
}

/// Reads a pairs file (see the module docs).
pub fn read_pairs_file(path: &Path) -> Result<Vec<MatchPair>> {
    let text = std::fs::read_to_string(path).map_err(|source| AbslocError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let base = path
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_else(|| PathBuf::from("."));
    let mut out = Vec::new();
    for (k, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let err = |m: String| AbslocError::Parse {
            path: path.to_path_buf(),
            line: k + 1,
            message: m,
        };
        let f: Vec<&str> = line.split_whitespace().collect();
        if f.len() != 11 {
            return Err(err(format!(
                "expected `query reference h00 h01 h02 h10 h11 h12 h20 h21 h22`, found {} fields",
                f.len()
            )));
        }
        let mut h = [0.0; 9];
        for (v, s) in h.iter_mut().zip(&f[2..]) {
            *v = s
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| err(format!("`{s}` is not a finite number")))?;
        }
        let h_true = Matrix3::from_row_slice(&h);
        if h_true.try_inverse().is_none() {
            return Err(err("the homography is singular".into()));
        }
        out.push(MatchPair {
            label: format!("{}:{}", path.display(), k + 1),
            query: read_gray(&base.join(f[0]))?,
            reference: read_gray(&base.join(f[1]))?,
            h_true,
            normalisation: None,
        });
    }
    if out.is_empty() {
        return Err(AbslocError::Parse {
            path: path.to_path_buf(),
            line: 0,
            message: "no pairs".into(),
        });
    }
    Ok(out)
}

/// Reads an image as grey (colour is converted).
fn read_gray(path: &Path) -> Result<GrayImage> {
    image::open(path)
        .map(|img| img.into_luma8())
        .map_err(|e| AbslocError::Image {
            path: path.to_path_buf(),
            message: e.to_string(),
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn summary_counts_thresholds_strictly() {
        let r = |e: Option<f64>| PairResult {
            label: String::new(),
            corner_error_px: e,
            matches: 0,
            inliers: 0,
            ms: 2.0,
        };
        let rep = summarise(
            "m",
            HomographyFit::Tight,
            vec![r(Some(0.5)), r(Some(5.0)), r(Some(7.0)), r(None)],
        );
        assert_eq!(rep.accuracy["@1px"], 0.25);
        assert_eq!(rep.accuracy["@5px"], 0.25);
        assert_eq!(rep.accuracy["@10px"], 0.75);
        assert_eq!(rep.accuracy["@100px"], 0.75);
        assert_eq!(rep.failures, 1);
        assert_eq!(rep.ms_mean, 2.0);
        let json = serde_json::to_value(&rep).unwrap();
        assert!(json["accuracy"]["@5px"].is_number());
    }

    #[test]
    fn pairs_files_parse_and_fail_clearly() {
        let dir = tempfile::tempdir().unwrap();
        let img = GrayImage::new(20, 20);
        img.save(dir.path().join("a.png")).unwrap();
        img.save(dir.path().join("b.png")).unwrap();
        let file = dir.path().join("pairs.txt");
        std::fs::write(&file, "# q r H\na.png b.png 1 0 2 0 1 3 0 0 1\n").unwrap();
        let pairs = read_pairs_file(&file).unwrap();
        assert_eq!(pairs.len(), 1);
        assert_eq!(pairs[0].h_true[(1, 2)], 3.0);
        for bad in [
            "a.png b.png 1 0 2 0 1 3 0 0\n",
            "a.png b.png 1 0 2 0 1 3 0 0 x\n",
            "a.png b.png 0 0 0 0 0 0 0 0 0\n",
            "a.png c.png 1 0 0 0 1 0 0 0 1\n",
            "# nothing\n",
        ] {
            std::fs::write(&file, bad).unwrap();
            assert!(read_pairs_file(&file).is_err(), "{bad}");
        }
    }
}
