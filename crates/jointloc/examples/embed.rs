//! JointLoc inside your own frame loop: what a flight-software engineer copies. The camera and
//! altimeter drivers are stood in for by a recorded flight's files, read by hand here so that
//! nothing but the frames, their timestamps and the altimeter enters the system.
//!
//! `cargo run --release -p jointloc-system --example embed -- <dataset>` (needs the models:
//! `jointloc models fetch`); replays the flight at its camera rate and prints
//! `timestamp x y z` in the map's world frame per frame.

use std::collections::HashMap;
use std::path::PathBuf;

use jointloc_system::{JointLoc, JointLocConfig, MapTiles, Mode};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dataset = PathBuf::from(std::env::args().nth(1).ok_or("usage: embed <dataset>")?);
    let camera_file = dataset.join("camera.yaml");
    let camera = jointloc_formats::camera_yaml::read_camera_yaml(&camera_file)?.camera;
    let map = MapTiles::open(&dataset)?;
    let mut system = JointLoc::builder(camera, map, JointLocConfig::default())
        .mode(Mode::Threaded) // absolute localisation on its own thread, as in flight
        .build()?;

    // The altimeter's readings by timestamp (your driver gives one with each frame).
    let uav = dataset.join("uav");
    let altimeter: HashMap<String, f64> = std::fs::read_to_string(uav.join("altimeter.txt"))?
        .lines()
        .filter(|l| !l.starts_with('#'))
        .filter_map(|l| l.split_once(' '))
        .filter_map(|(t, a)| Some((t.to_string(), a.trim().parse().ok()?)))
        .collect();
    let started = std::time::Instant::now();
    for line in std::fs::read_to_string(uav.join("images.txt"))?.lines() {
        let Some((stamp, file)) = line.split_once(' ').filter(|_| !line.starts_with('#')) else {
            continue;
        };
        let (image, t) = (
            image::open(uav.join(file.trim()))?.to_luma8(),
            stamp.parse()?,
        );
        // A camera delivers frames at its rate; the absolute fixes arrive meanwhile.
        let due = std::time::Duration::from_secs_f64(t);
        std::thread::sleep(due.saturating_sub(started.elapsed()));
        let frame = system.process(&image, t, altimeter.get(stamp).copied())?;
        match frame.world_pose {
            Some(pose) => {
                let c = pose.centre();
                println!("{stamp} {:.3} {:.3} {:.3}", c.x, c.y, c.z);
            }
            None => println!("{stamp} - ({:?}, not geo-referenced yet)", frame.state),
        }
    }
    let outputs = system.finish()?;
    let s = &outputs.summary;
    eprintln!(
        "{} frames, {} world poses, {} fixes ({} used)",
        s.frames, s.world_poses, s.fixes_found, s.fixes_used
    );
    Ok(())
}
