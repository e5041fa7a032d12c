//! The heightfield of a simulated dataset, regenerated from its `sim.toml` (the simulator is
//! deterministic), for exact ground-truth homographies. Trusted only when it reproduces the
//! dataset: the same map layout as `map.toml`, and camera heights above it that agree with the
//! altimeter.

use std::path::Path;

use jointloc_formats::MapInfo;
use jointloc_formats::UavDataset;
use jointloc_sim::dataset::sub_seed;
use jointloc_sim::{SimConfig, Terrain, generate_terrain_with, plan_dataset};

/// The simulator's random stream for terrain synthesis (`jointloc_sim::dataset`); the check
/// against the altimeter catches a change.
const TERRAIN_STREAM: u64 = 2;

/// Regenerates the terrain of the dataset in `dir`; `None` (with the reason logged) when the
/// dataset has no `sim.toml` or the regenerated terrain does not match it.
pub fn regenerate(dir: &Path, dataset: &UavDataset) -> Option<Terrain> {
    let why_not = |reason: String| {
        tracing::warn!(dataset = %dir.display(), "no terrain ground truth: {reason}");
        None
    };
    let sim_toml = dir.join("sim.toml");
    if !sim_toml.is_file() {
        tracing::info!(dataset = %dir.display(), "no sim.toml: ground truth from the altimeter plane");
        return None;
    }
    let cfg = match SimConfig::read(&sim_toml) {
        Ok(c) => c,
        Err(e) => return why_not(e.to_string()),
    };
    let plan = match plan_dataset(&cfg) {
        Ok(p) => p,
        Err(e) => return why_not(e.to_string()),
    };
    match MapInfo::read(&dir.join("map.toml")) {
        // The elevation model is written beside the map, after planning.
        Ok(map)
            if MapInfo {
                elevation: None,
                ..map.clone()
            } == plan.map => {}
        Ok(_) => return why_not("map.toml differs from the plan of sim.toml".into()),
        Err(e) => return why_not(e.to_string()),
    }
    let clock = std::time::Instant::now();
    let terrain = match generate_terrain_with(
        cfg.terrain_kind,
        &plan.extent,
        &plan.terrain,
        sub_seed(cfg.seed, TERRAIN_STREAM),
        plan.layout,
    ) {
        Ok(t) => t,
        Err(e) => return why_not(e.to_string()),
    };
    // Camera height above the terrain under it must be the altimeter reading (± its noise).
    let mut residuals: Vec<f64> = dataset
        .frames
        .iter()
        .filter_map(|f| {
            let (pose, alt) = (f.ground_truth?, f.altitude?);
            let c = pose.centre();
            Some((c.z - terrain.height_at(c.x, c.y) - alt).abs())
        })
        .collect();
    if residuals.is_empty() {
        return why_not("no frame with both ground truth and altimeter to check it".into());
    }
    residuals.sort_by(f64::total_cmp);
    let median = residuals[residuals.len() / 2];
    let tolerance = 3.0 * cfg.altimeter_noise_m() + 0.02;
    if median > tolerance {
        return why_not(format!(
            "camera heights disagree with the altimeter (median {median:.3} m)"
        ));
    }
    tracing::info!(
        seconds = clock.elapsed().as_secs_f64(),
        median_residual_m = median,
        "terrain regenerated"
    );
    Some(terrain)
}
