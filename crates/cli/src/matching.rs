//! `jointloc match`: the paper's matcher benchmark (Table V protocol) on simulated pairs (a
//! frame and its ground-truth tile) or on any pairs file with known homographies.

use std::path::PathBuf;

use anyhow::{Context, bail};
use jointloc_absloc::registry::{MATCHERS, RegistryOptions, resolve};
use jointloc_absloc::relight::RelightConfig;
use jointloc_bench::ground_truth::{GroundTruthSource, TerrainHeights};
use jointloc_bench::match_bench::{
    BenchConfig, HomographyFit, MatchReport, THRESHOLDS_PX, pairs_from_dataset, read_pairs_file,
    run_bench, threshold_key,
};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Simulated dataset folder (pairs: random frames against their ground-truth tile).
    #[arg(long, required_unless_present_any = ["pairs_file", "list"], conflicts_with = "pairs_file")]
    dataset: Option<PathBuf>,
    /// Pairs file instead: `query reference h00 h01 h02 h10 h11 h12 h20 h21 h22` per line
    /// (homography query → reference, row-major; paths relative to the file).
    #[arg(long, value_name = "F")]
    pairs_file: Option<PathBuf>,
    /// Matcher(s), comma separated (see --list).
    #[arg(
        long,
        value_name = "M",
        value_delimiter = ',',
        default_value = "xfeat-lighterglue"
    )]
    matcher: Vec<String>,
    /// Number of pairs drawn from the dataset.
    #[arg(long, value_name = "N", default_value_t = 30)]
    pairs: usize,
    /// Seed of the pair draw.
    #[arg(long, value_name = "S", default_value_t = 0)]
    seed: u64,
    /// Match frames at native scale and orientation (default: resampled to the map's GSD from
    /// the altimeter and turned north-up by the true heading, as the localiser does).
    #[arg(long)]
    native_scale: bool,
    /// Ground truth from a flat ground at camera z − altimeter instead of the regenerated
    /// terrain heightfield.
    #[arg(long)]
    flat_ground: bool,
    /// Match against the map as it was taken, not relit to the flight's sun (the localiser's
    /// `[absloc.relight] enabled = false`).
    #[arg(long)]
    no_relight: bool,
    /// Homography scored, comma separated to score several from the same matches (one table
    /// row each): `tight` (RANSAC at 3 px, refined on its inliers: the localiser's, and
    /// OpenCV's `findHomography` in the paper's protocol), `footprint` (then refitted over
    /// every match within 20 px: the whole footprint over relief, as a simulated pair's ground
    /// truth is defined) or `biweight` (that refit with each match weighted by Tukey's
    /// biweight of its error). Default: `biweight` with --dataset, `tight` with --pairs-file
    /// (a plane homography, exact for every pixel).
    #[arg(long, value_name = "FIT", value_delimiter = ',')]
    fit: Option<Vec<HomographyFit>>,
    /// Keypoints per image (default: each detector's own).
    #[arg(long, value_name = "N")]
    max_keypoints: Option<usize>,
    /// ONNX Runtime threads per network.
    #[arg(long, value_name = "N", default_value_t = 1)]
    threads: usize,
    /// Models directory (default: $JOINTLOC_MODELS or the user cache).
    #[arg(long, value_name = "DIR")]
    models_dir: Option<PathBuf>,
    /// Write the table (and every pair's error) as JSON.
    #[arg(long, value_name = "OUT")]
    json: Option<PathBuf>,
    /// Overwrite --json.
    #[arg(long)]
    force: bool,
    /// List the matchers and exit.
    #[arg(long)]
    list: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if args.list {
        for (name, what) in MATCHERS {
            println!("{name:20} {what}");
        }
        return Ok(());
    }
    if let Some(p) = &args.json
        && p.exists()
        && !args.force
    {
        bail!("{}: already exists (use --force to overwrite)", p.display());
    }
    if args.pairs == 0 {
        bail!("--pairs must be at least 1");
    }
    let opts = RegistryOptions {
        models_dir: args.models_dir.clone(),
        threads: Some(args.threads),
        max_keypoints: args.max_keypoints,
    };
    // Resolve every matcher first: an unknown or unavailable name fails before any work.
    let pipelines = args
        .matcher
        .iter()
        .map(|m| resolve(m, &opts))
        .collect::<Result<Vec<_>, _>>()?;
    let (pairs, source) = if let Some(file) = &args.pairs_file {
        (read_pairs_file(file)?, None)
    } else {
        let dir = args
            .dataset
            .as_ref()
            .context("--dataset or --pairs-file is required")?;
        let ds = jointloc_formats::UavDataset::open(dir)?;
        let terrain = if args.flat_ground {
            None
        } else {
            jointloc_bench::sim_terrain::regenerate(dir, &ds)
        };
        let mut relight = RelightConfig {
            enabled: !args.no_relight,
            ..RelightConfig::default()
        };
        crate::flight_sun::resolve(None, &mut relight.flight_sun, dir)?;
        let (pairs, source, not_relit) = pairs_from_dataset(
            dir,
            args.pairs,
            args.seed,
            terrain.as_ref().map(|t| t as &dyn TerrainHeights),
            !args.native_scale,
            &relight,
        )?;
        match not_relit {
            None => println!("map: relit to the flight's sun"),
            Some(why) => println!("map: as taken ({why})"),
        }
        (pairs, Some(source))
    };
    let asked = args.fit.clone().unwrap_or_else(|| {
        vec![if args.pairs_file.is_some() {
            HomographyFit::Tight
        } else {
            HomographyFit::Biweight
        }]
    });
    let mut fits: Vec<HomographyFit> = Vec::new();
    for f in &asked {
        if !fits.contains(f) {
            fits.push(*f);
        }
    }
    let cfg = BenchConfig {
        fits,
        ..BenchConfig::default()
    };
    let mut reports: Vec<MatchReport> = Vec::new();
    for p in &pipelines {
        reports.extend(run_bench(p, &pairs, &cfg)?);
    }
    print_table(&reports, source);
    for fit in &cfg.fits {
        println!(
            "homography scored: {}",
            match fit {
                HomographyFit::Tight => "tight (RANSAC 3 px, refined on its inliers)".to_string(),
                HomographyFit::Footprint => format!(
                    "footprint (the tight fit refitted over every match within {} px)",
                    cfg.footprint_threshold_px
                ),
                HomographyFit::Biweight => format!(
                    "biweight (the tight fit refitted over every match within {} px, each \
                     weighted by Tukey's biweight of its error)",
                    cfg.footprint_threshold_px
                ),
            }
        );
    }
    if let Some(path) = &args.json {
        let json = serde_json::json!({
            "pairs": pairs.len(),
            "seed": args.seed,
            "dataset": args.dataset,
            "pairs_file": args.pairs_file,
            "normalised": args.pairs_file.is_none() && !args.native_scale,
            "ground_truth": source.map(|s| format!("{s:?}")),
            "fits": cfg.fits.iter().map(|f| f.name()).collect::<Vec<_>>(),
            "footprint_threshold_px": cfg.fits.iter().any(|f| *f != HomographyFit::Tight)
                .then_some(cfg.footprint_threshold_px),
            "matchers": reports,
        });
        std::fs::write(path, serde_json::to_string_pretty(&json)? + "\n")
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

fn print_table(reports: &[MatchReport], source: Option<GroundTruthSource>) {
    let heads: Vec<String> = THRESHOLDS_PX.iter().map(|&t| threshold_key(t)).collect();
    println!(
        "| matcher | fit | pairs | {} | failed | ms/pair (mean) | ms/pair (median) |",
        heads.join(" | ")
    );
    println!("|---|---|---|{}---|---|---|", "---|".repeat(heads.len()));
    for r in reports {
        let acc: Vec<String> = heads
            .iter()
            .map(|k| format!("{:.2}", r.accuracy[k]))
            .collect();
        println!(
            "| {} | {} | {} | {} | {} | {:.1} | {:.1} |",
            r.matcher,
            r.fit.name(),
            r.pairs,
            acc.join(" | "),
            r.failures,
            r.ms_mean,
            r.ms_median
        );
    }
    if let Some(s) = source {
        println!(
            "\nground truth: {}",
            match s {
                GroundTruthSource::Terrain => "terrain heightfield regenerated from sim.toml",
                GroundTruthSource::AltimeterPlane =>
                    "flat ground at camera z - altimeter (approximate)",
            }
        );
    }
}
