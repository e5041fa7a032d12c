//! `jointloc map import`: a GeoTIFF orthoimage (and DTM) into a map folder jointloc reads.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use jointloc_formats::map_import::{MapImportConfig, import_map};

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    command: MapCommand,
}

#[derive(Debug, clap::Subcommand)]
enum MapCommand {
    /// Read a GeoTIFF orthoimage (north-up, square pixels, projected CRS in metres; stripped or
    /// tiled, BigTIFF, 8/16-bit or float) and optionally its DTM, and write `map.toml` (with
    /// the CRS), `satellite.png`, its tiles and `elevation.png` into a dataset or map folder.
    Import(ImportArgs),
}

#[derive(Debug, clap::Args)]
struct ImportArgs {
    /// The orthoimage (GeoTIFF, one band).
    #[arg(long)]
    image: PathBuf,
    /// The elevation model (GeoTIFF, one band, heights in metres, same CRS).
    #[arg(long)]
    dem: Option<PathBuf>,
    /// The folder to write into (a dataset folder: uav/ and camera.yaml may already be there).
    #[arg(long)]
    out: PathBuf,
    /// Tile width in pixels: the UAV image's width.
    #[arg(long, default_value_t = 500)]
    tile_width: u32,
    /// Tile height in pixels: the UAV image's height.
    #[arg(long, default_value_t = 500)]
    tile_height: u32,
    /// Overlap of neighbouring tiles.
    #[arg(long, default_value_t = 0.5)]
    overlap: f64,
    /// Stated vertical precision of the DTM (1 σ), metres.
    #[arg(long, default_value_t = 0.25)]
    dem_sigma_m: f64,
    /// The sun when the image was taken, AZIMUTH,ELEVATION in degrees (azimuth clockwise
    /// from north, elevation above the horizon; for HiRISE, from the product's solar
    /// geometry): written as `map.toml`'s `[sun]`, so that runs relight the map to the
    /// flight's sun with the DTM.
    #[arg(long, value_name = "AZ,EL")]
    sun: Option<String>,
    /// Replace map files already in the folder (other files are kept).
    #[arg(long)]
    force: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    match args.command {
        MapCommand::Import(a) => import(a),
    }
}

fn import(a: ImportArgs) -> anyhow::Result<()> {
    let cfg = MapImportConfig {
        tile_width_px: a.tile_width,
        tile_height_px: a.tile_height,
        tile_overlap: a.overlap,
        dem_sigma_m: a.dem_sigma_m,
        sun: a
            .sun
            .as_deref()
            .map(|t| crate::flight_sun::parse_sun(t).with_context(|| format!("--sun {t}")))
            .transpose()?,
    };
    let clock = Instant::now();
    let report = import_map(&a.image, a.dem.as_deref(), &a.out, &cfg, a.force)
        .with_context(|| format!("importing {} into {}", a.image.display(), a.out.display()))?;
    let map = &report.map;
    let crs = map.crs.as_ref().map_or(String::new(), |c| match c.epsg {
        Some(code) => format!("EPSG:{code}"),
        None => c
            .citation
            .clone()
            .unwrap_or_else(|| "a CRS given by its GeoKeys".into()),
    });
    println!(
        "wrote a {}x{} px map at {} m/px ({crs}) and {} tiles to {} in {:.1} s",
        map.width_px,
        map.height_px,
        map.gsd_m,
        report.tiles,
        a.out.display(),
        clock.elapsed().as_secs_f64()
    );
    if let Some(e) = &map.elevation {
        println!(
            "elevation model: {}x{} posts at {} m",
            e.width_px, e.height_px, e.gsd_m
        );
    }
    if report.nodata_pixels > 0 {
        tracing::warn!(
            pixels = report.nodata_pixels,
            "nodata pixels in the orthoimage, written as 0"
        );
    }
    if report.dem_nodata_posts > 0 {
        tracing::warn!(
            posts = report.dem_nodata_posts,
            "nodata posts in the DTM, filled from their nearest neighbours"
        );
    }
    Ok(())
}
