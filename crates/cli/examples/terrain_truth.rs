//! Diagnostic for simulated datasets (`docs/camera.md`): do the points a camera sees sit on
//! the map's elevation model?
//!
//! `terrain_truth DATASET [MAX_OFF_AXIS_DEG [WINDOW_FRAMES]]` casts rays of the true poses
//! (every 10th frame, every 6th pixel) onto the simulator's regenerated terrain and estimates
//! the terrain shift of those true surface points against the elevation model, per window.
//! `terrain_truth DATASET dump FILE` reads map points logged by a run (`index x y z r cx cy
//! cz` per line: estimate index, world point, its residual, the camera centre) and fits their
//! height error against the true terrain as `a + b·dx + c·dy + e·r²` around the camera.
use std::path::Path;

use anyhow::Context;

use jointloc_absloc::Ground;
use jointloc_formats::{ElevationModel, MapInfo, UavDataset};
use jointloc_system::terrain_shift::{TerrainConfig, estimate_shift};
use nalgebra::Point2;
use nalgebra::Point3;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let dir = Path::new(args.get(1).context("usage: terrain_truth DATASET ...")?);
    if args.get(2).map(String::as_str) == Some("dump") {
        return dump(dir, Path::new(args.get(3).context("dump needs a FILE")?));
    }
    let max_deg: f64 = args.get(2).map_or(Ok(70.0), |s| s.parse())?;
    let window: usize = args.get(3).map_or(Ok(50), |s| s.parse())?;
    let ds = UavDataset::open(dir)?;
    let terrain = jointloc_bench::sim_terrain::regenerate(dir, &ds)
        .context("no terrain ground truth (see the log)")?;
    let tracer = jointloc_sim::render::HeightfieldTracer::new(&terrain)?;
    let map = MapInfo::read(&dir.join("map.toml"))?;
    let dem = ElevationModel::read(
        map.elevation
            .as_ref()
            .context("the map has no elevation model")?,
        dir,
    )?;
    let ground = Ground::from_model(dem);
    let cam = ds.camera;
    let cos_max = max_deg.to_radians().cos();
    let cfg = TerrainConfig::default();
    let mut sums = [0.0; 3];
    let mut n = 0;
    let frames: Vec<_> = ds.frames.iter().filter_map(|f| f.ground_truth).collect();
    let mut dem_res = Vec::new();
    for start in (0..frames.len()).step_by(window) {
        let mut pts = Vec::new();
        for pose in frames[start..(start + window).min(frames.len())]
            .iter()
            .step_by(10)
        {
            for v in (0..cam.height).step_by(6) {
                for u in (0..cam.width).step_by(6) {
                    let Some(r) = cam.unproject(&Point2::new(u as f64, v as f64)) else {
                        continue;
                    };
                    let d = nalgebra::Vector3::new(r.x, r.y, 1.0).normalize();
                    if d.z < cos_max {
                        continue;
                    }
                    let o = pose.centre();
                    let w = pose.rotation() * d;
                    if let Some(hit) = tracer.cast(&o, &w) {
                        let p: Point3<f64> = hit.point;
                        if let Some(h) = ground.height_and_slope(p.x, p.y) {
                            dem_res.push(p.z - h.0);
                        }
                        pts.push(p);
                    }
                }
            }
        }
        if let Some(s) = estimate_shift(&pts, &ground, &cfg) {
            println!(
                "window {start:4}: {:6} pts shift ({:+.4}, {:+.4}, {:+.4}) rms {:.3}",
                s.points, s.shift.x, s.shift.y, s.shift.z, s.rms_m
            );
            for (sum, v) in sums.iter_mut().zip(s.shift.iter()) {
                *sum += v;
            }
            n += 1;
        }
    }
    let mean_res = dem_res.iter().sum::<f64>() / dem_res.len() as f64;
    println!(
        "mean shift over {n} windows: ({:+.4}, {:+.4}, {:+.4}); mean surface-DEM {:+.4}",
        sums[0] / n as f64,
        sums[1] / n as f64,
        sums[2] / n as f64,
        mean_res
    );
    Ok(())
}

fn dump(dir: &Path, file: &Path) -> anyhow::Result<()> {
    let ds = UavDataset::open(dir)?;
    let terrain = jointloc_bench::sim_terrain::regenerate(dir, &ds)
        .context("no terrain ground truth (see the log)")?;
    let map = MapInfo::read(&dir.join("map.toml"))?;
    let info = map
        .elevation
        .clone()
        .context("the map has no elevation model")?;
    let dem = Ground::from_model(ElevationModel::read(&info, dir)?);
    let truth_info = jointloc_formats::ElevationInfo {
        gsd_m: terrain.cell_m,
        width_px: terrain.height.width as u32,
        height_px: terrain.height.height as u32,
        origin_x_m: terrain.origin_x,
        origin_y_m: terrain.origin_y,
        ..info
    };
    let truth = Ground::from_model(
        ElevationModel::from_heights(truth_info, terrain.height.clone()).context("terrain grid")?,
    );
    let text = std::fs::read_to_string(file).with_context(|| format!("{}", file.display()))?;
    let mut groups: std::collections::BTreeMap<usize, Vec<[f64; 7]>> = Default::default();
    for line in text.lines() {
        let v = line
            .split_whitespace()
            .map(str::parse)
            .collect::<Result<Vec<f64>, _>>()
            .with_context(|| format!("{}: {line}", file.display()))?;
        anyhow::ensure!(
            v.len() >= 8,
            "{}: 8 columns expected: {line}",
            file.display()
        );
        groups
            .entry(v[0] as usize)
            .or_default()
            .push([v[1], v[2], v[3], v[4], v[5], v[6], v[7]]);
    }
    let cfg = TerrainConfig::default();
    let (mut sd, mut st, mut n) = (nalgebra::Vector3::zeros(), nalgebra::Vector3::zeros(), 0.0);
    let mut bins = [(0.0f64, 0usize); 8];
    let mut coef = nalgebra::Vector4::zeros();
    for g in groups.values() {
        let pts: Vec<Point3<f64>> = g.iter().map(|p| Point3::new(p[0], p[1], p[2])).collect();
        let (Some(a), Some(b)) = (
            estimate_shift(&pts, &dem, &cfg),
            estimate_shift(&pts, &truth, &cfg),
        ) else {
            continue;
        };
        sd += a.shift;
        st += b.shift;
        n += 1.0;
        // r_true = a + b dx + c dy + e r²
        let mut ata = nalgebra::Matrix4::zeros();
        let mut atb = nalgebra::Vector4::zeros();
        for p in g {
            let h = terrain.height_at(p[0], p[1]);
            let r = p[2] - h;
            if r.abs() > 0.3 {
                continue;
            }
            let (dx, dy) = (p[0] - p[4], p[1] - p[5]);
            let rad = dx.hypot(dy);
            let bin = ((rad / 5.0) as usize).min(7);
            bins[bin].0 += r;
            bins[bin].1 += 1;
            let row = nalgebra::Vector4::new(1.0, dx, dy, rad * rad);
            ata += row * row.transpose();
            atb += row * r;
        }
        if let Some(c) = ata.try_inverse() {
            coef += c * atb;
        }
    }
    println!(
        "groups {n}: mean shift vs DEM ({:+.4}, {:+.4}, {:+.4}); vs truth ({:+.4}, {:+.4}, {:+.4})",
        sd.x / n,
        sd.y / n,
        sd.z / n,
        st.x / n,
        st.y / n,
        st.z / n
    );
    println!(
        "mean fit r_true = {:+.4} + {:+.5} dx + {:+.5} dy + {:+.6} r^2",
        coef[0] / n,
        coef[1] / n,
        coef[2] / n,
        coef[3] / n
    );
    for (i, (s, c)) in bins.iter().enumerate() {
        if *c > 0 {
            println!(
                "  horiz dist {:2}-{:2} m: n {:6} mean z - H_true {:+.4}",
                i * 5,
                i * 5 + 5,
                c,
                s / *c as f64
            );
        }
    }
    Ok(())
}
