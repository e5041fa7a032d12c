//! Runs the sequential SLAM system on a dataset folder and writes the TUM trajectory: the
//! library-only counterpart of `jointloc vo`, for profiling and debugging.
//!
//! `cargo run --release -p jointloc-slam --example vo_sequence -- DATASET OUT.tum [MAX_FRAMES]`

use std::path::PathBuf;

use jointloc_features::orb::GrayImageView;
use jointloc_formats::{Sequence, read_camera_yaml};
use jointloc_slam::system::{System, SystemConfig, median};
use jointloc_slam::tracking::TrackingState;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    tracing_subscriber_init();
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        return Err("usage: vo_sequence DATASET OUT.tum [MAX_FRAMES]".into());
    }
    let dir = PathBuf::from(&args[1]);
    let camera = read_camera_yaml(&dir.join("camera.yaml"))?.camera;
    let seq = Sequence::open(&dir)?;
    let n = args
        .get(3)
        .map_or(Ok(seq.len()), |s| s.parse())?
        .min(seq.len());
    let mut system = System::new(camera, SystemConfig::default())?;
    let mut lost = Vec::new();
    for i in 0..n {
        let img = seq.load_image(i)?;
        let f = &seq.frames[i];
        let r = system.process(GrayImageView::from(&img), f.timestamp, f.altitude)?;
        if r.state == TrackingState::Lost {
            lost.push(i);
        }
    }
    system.trajectory()?.write_tum(&args[2])?;
    let t = system.timing();
    println!(
        "{n} frames, lost {:?}, {} keyframes, {} points; median ms ORB {:.1} tracking {:.1} mapping {:.1} LBA {:.1}",
        lost,
        system.map().n_keyframes(),
        system.map().n_points(),
        median(&t.orb_ms),
        median(&t.tracking_ms),
        median(&t.local_mapping_ms),
        median(&t.lba_ms)
    );
    Ok(())
}

fn tracing_subscriber_init() {}
