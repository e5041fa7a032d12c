//! Fixes from virtual frames on a dataset, with the frames' ground-truth poses standing in for
//! the SLAM's: the registration alone, as `jointloc absloc --heading-from-gt` measures single
//! frames. Every EVERY-th frame, the frames within SPAN_M metres are rendered into a virtual
//! frame ZOOM times wider, which is registered within the correlation's radius of a prior
//! 3.6 m off the truth, with the true heading.
//!
//! `cargo run --release -p jointloc-absloc --example mosaic_probe -- DATASET ZOOM SPAN_M EVERY`
use jointloc_absloc::mosaic::{GroundPlane, MosaicSource, Thumbnail, render};
use jointloc_absloc::registry::{RegistryOptions, resolve};
use jointloc_absloc::{
    AbsLocConfig, AbsLocalizer, FrameView, MapTiles, Prior, heading_from_rotation,
};
use jointloc_formats::UavDataset;
use nalgebra::Vector3;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() != 5 {
        return Err("usage: mosaic_probe DATASET ZOOM SPAN_M EVERY".into());
    }
    let dir = std::path::PathBuf::from(&args[1]);
    let zoom: f64 = args[2].parse()?;
    let span: f64 = args[3].parse()?;
    let every: usize = args[4].parse()?;
    let ds = UavDataset::open(&dir)?;
    let tiles = MapTiles::open(&dir)?;
    let ground = tiles.ground();
    let pipeline = resolve("xfeat-lighterglue", &RegistryOptions::default())?;
    let camera = ds.camera;
    let mut loc = AbsLocalizer::new(tiles, camera, pipeline, AbsLocConfig::default())?;
    let factor = (zoom.floor() as u32).max(1);
    let mut kept: Vec<(jointloc_geometry::CameraToWorld, Thumbnail)> = Vec::new();
    let (mut errors, mut tried, mut render_ms, mut search_ms) = (Vec::new(), 0, vec![], vec![]);
    for (i, f) in ds.frames.iter().enumerate() {
        let (Some(gt), Some(altitude)) = (f.ground_truth, f.altitude) else {
            continue;
        };
        kept.push((gt, Thumbnail::new(&ds.load_frame(i)?, factor)));
        let c = gt.centre();
        kept.retain(|(p, _)| (p.centre() - c).norm() <= span);
        if i % every != 0 || i == 0 {
            continue;
        }
        // The true ground point under the optical axis (flat ground at its height).
        let axis = gt.rotation_matrix() * Vector3::z();
        let g = ground.height_at(c.x, c.y);
        let truth = c + axis * ((g - c.z) / axis.z);
        let plane = GroundPlane {
            normal: Vector3::z(),
            offset: ground.height_at(truth.x, truth.y),
        };
        let sources: Vec<_> = kept
            .iter()
            .map(|(p, t)| MosaicSource {
                pose: *p,
                thumbnail: t,
            })
            .collect();
        let t0 = std::time::Instant::now();
        let m = render(&camera, &gt, &plane, zoom, &sources, 4.0);
        render_ms.push(t0.elapsed().as_secs_f64() * 1e3);
        // SWEEP=1: no heading, the prior at the first frame (a take-off position).
        let sweep = std::env::var("SWEEP").is_ok();
        let first = ds.frames[0].ground_truth.map_or(c, |p| p.centre());
        let prior = if sweep {
            loc.reset();
            Prior {
                position: Some([first.x, first.y]),
                heading: None,
            }
        } else {
            Prior {
                position: Some([c.x + 3.0, c.y - 2.0]),
                heading: Some(heading_from_rotation(&gt.rotation().to_rotation_matrix())),
            }
        };
        let view = FrameView {
            image: &m.image,
            altitude,
            zoom,
            valid: Some(&m.valid),
        };
        let outcome = loc.localize_view(&view, &prior)?;
        search_ms.push(outcome.ms());
        tried += 1;
        match outcome.fix() {
            Some(fix) => {
                let e = (fix.position[0] - truth.x).hypot(fix.position[1] - truth.y);
                errors.push(e);
                println!(
                    "frame {i}: error {e:.3} m, w {:.3}, coverage {:.2}, {} frames",
                    fix.confidence, m.coverage, m.sources_used
                );
            }
            None => println!("frame {i}: no fix {outcome:?}"),
        }
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
    };
    let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len().max(1) as f64).sqrt();
    let within = errors.iter().filter(|&&e| e < 1.0).count();
    println!(
        "fixes {}/{tried}, rmse {rms:.3} m, median {:.3} m, within 1 m {within}; median ms: render {:.0}, registration {:.0}",
        errors.len(),
        median(&mut errors),
        median(&mut render_ms),
        median(&mut search_ms)
    );
    Ok(())
}
