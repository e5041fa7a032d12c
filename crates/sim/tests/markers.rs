//! Acceptance: ground truth, camera model and georeference agree.
//!
//! Bright discs are painted into the albedo at known ground points. The dataset is written
//! twice, with and without them, with noise off, so the difference image holds only the
//! markers. Each marker's centroid must sit at the pixel predicted from the files on disk:
//! `gt.txt` + `camera.yaml` for the UAV frames, `map.toml` for the satellite map.

mod common;

use std::path::Path;

use common::{read_grey, read_pairs, read_tum};
use jointloc_formats::{ElevationModel, Grid, MapInfo, read_camera_yaml};
use jointloc_geometry::{Distortion, KannalaBrandt, PinholeCamera, RadTan};
use jointloc_sim::dataset::{DatasetPlan, SimConfig, plan_dataset, write_dataset};
use jointloc_sim::sensor::SensorConfig;
use jointloc_sim::{Difficulty, Sun, Terrain};
use nalgebra::Point3;

/// Smooth rolling ground (no cast shadows, nearly uniform light over a marker) with a faint
/// albedo texture.
fn smooth_terrain(plan: &DatasetPlan, cell: f64) -> Terrain {
    let e = &plan.extent;
    let mut height = Grid::filled(e.width_cells, e.height_cells, 0.0f32);
    let mut albedo = Grid::filled(e.width_cells, e.height_cells, 0.0f32);
    for r in 0..e.height_cells {
        for c in 0..e.width_cells {
            let x = e.origin_x + c as f64 * cell;
            let y = e.origin_y - r as f64 * cell;
            let z = 0.6 * (x / 4.1).sin() + 0.4 * (y / 3.3).cos() + 0.2 * ((x + y) / 1.9).sin();
            *height.at_mut(c, r) = z as f32;
            *albedo.at_mut(c, r) = (0.22 + 0.03 * (x * 3.1).sin() * (y * 2.7).cos()) as f32;
        }
    }
    Terrain {
        cell_m: cell,
        origin_x: e.origin_x,
        origin_y: e.origin_y,
        height,
        albedo,
    }
}

/// Paints a disc of `radius` cells centred on the cell nearest `(x, y)`; returns its centre.
fn paint(terrain: &mut Terrain, x: f64, y: f64, radius: f64) -> (f64, f64) {
    let (c, r) = terrain.world_to_cell(x, y);
    let (c, r) = (c.round() as isize, r.round() as isize);
    let k = radius.ceil() as isize;
    for dr in -k..=k {
        for dc in -k..=k {
            if ((dr * dr + dc * dc) as f64) <= radius * radius {
                *terrain.albedo.at_mut((c + dc) as usize, (r + dr) as usize) = 0.9;
            }
        }
    }
    terrain.cell_to_world(c as f64, r as f64)
}

/// Intensity-weighted centroid of the positive difference within `radius` of `(u, v)`, and the
/// total weight.
fn centroid(
    with: &[u8],
    without: &[u8],
    width: usize,
    height: usize,
    u: f64,
    v: f64,
    radius: f64,
) -> (f64, f64, f64) {
    let (mut su, mut sv, mut sw) = (0.0, 0.0, 0.0);
    let (u0, u1) = (
        (u - radius).floor().max(0.0) as usize,
        ((u + radius).ceil() as usize).min(width - 1),
    );
    let (v0, v1) = (
        (v - radius).floor().max(0.0) as usize,
        ((v + radius).ceil() as usize).min(height - 1),
    );
    for y in v0..=v1 {
        for x in u0..=u1 {
            let d = with[y * width + x] as f64 - without[y * width + x] as f64;
            if d > 0.0 {
                su += d * x as f64;
                sv += d * y as f64;
                sw += d;
            }
        }
    }
    (su / sw, sv / sw, sw)
}

#[derive(Debug)]
struct Case {
    difficulty: Difficulty,
    distortion: Option<Distortion>,
    seed: u64,
    /// Flight height (m); above 20 m the camera is 500 × 500 at f = 500 and the markers lie
    /// on a 25 m grid around the path instead of beside it.
    altitude_m: f64,
    /// A map larger than the flight (the detailed patch blended into a coarse render).
    map_size_m: Option<f64>,
}

fn run_case(case: &Case, tmp: &Path) {
    let mut cfg = SimConfig {
        seed: case.seed,
        difficulty: case.difficulty,
        uav_sun: Some(Sun {
            azimuth_deg: 120.0,
            elevation_deg: 55.0,
        }),
        sensor: SensorConfig {
            blur_sigma_px: 0.6,
            ..SensorConfig::ideal(0.7)
        },
        ..Default::default()
    };
    cfg.trajectory.length_m = 10.0;
    cfg.trajectory.rate_hz = 2.0;
    cfg.trajectory.altitude_m = case.altitude_m;
    cfg.map_size_m = case.map_size_m;
    // Larger than the default jitter, so roll and pitch matter.
    cfg.trajectory.attitude_jitter_deg = 3.0;
    let high = case.altitude_m > 20.0;
    if !high {
        cfg.camera.width = 240;
        cfg.camera.height = 200;
        cfg.camera.fx = 240.0;
        cfg.camera.fy = 236.0;
        cfg.camera.cx = 121.3;
        cfg.camera.cy = 98.2;
    }
    cfg.camera.distortion = case.distortion;
    if let Some(Distortion::KannalaBrandt(lens)) = case.distortion {
        // 133° across the width: f = (W / 2) / θ_d(66.5°).
        cfg.camera = PinholeCamera {
            cx: 121.3,
            cy: 98.2,
            ..PinholeCamera::fisheye(133.0, 240, 200, lens).unwrap()
        };
    }
    let mut sat = case.difficulty.satellite_config();
    sat.sensor = SensorConfig {
        blur_sigma_px: sat.sensor.blur_sigma_px,
        ..SensorConfig::ideal(0.7)
    };
    cfg.satellite = Some(sat.clone());

    let plan = plan_dataset(&cfg).unwrap();
    let cell = plan.terrain.cell_m;
    let plain = smooth_terrain(&plan, cell);
    let mut marked = plain.clone();
    // Small enough that the light does not change across a marker (which would pull its
    // centroid), large enough to be seen: 8 cells, 4 when a cell is a map pixel (1 m at 25 cm).
    let min_radius = if high { 4.0 } else { 8.0 };
    let radius_cells = (1.5 * sat.gsd_m / cell).max(min_radius);
    let mut markers = Vec::new();
    if high {
        // A 25 m grid over the footprint around the start.
        let s0 = &plan.path.samples[0];
        for i in -2..=2 {
            for j in -2..=2 {
                let (x, y) = (s0.x + 25.0 * i as f64, s0.y + 25.0 * j as f64);
                let (x, y) = paint(&mut marked, x, y, radius_cells);
                markers.push(Point3::new(x, y, marked.height_at(x, y)));
            }
        }
    } else {
        // Every 3 m along the path, 1.7 m to alternate sides: far enough apart that no window
        // sees two markers.
        for (k, s) in plan.path.samples.iter().enumerate().step_by(6) {
            let side = if k % 12 == 0 { 1.0 } else { -1.0 };
            let (dx, dy) = (side * 1.7 * s.heading.sin(), -side * 1.7 * s.heading.cos());
            let (x, y) = paint(&mut marked, s.x + dx, s.y + dy, radius_cells);
            markers.push(Point3::new(x, y, marked.height_at(x, y)));
        }
    }

    let (a, b) = (tmp.join("with"), tmp.join("without"));
    let summary = write_dataset(&cfg, &plan, &marked, &a, &mut |_, _, _| {}).unwrap();
    write_dataset(&cfg, &plan, &plain, &b, &mut |_, _, _| {}).unwrap();
    // The map's margin covers every pixel it should; only a fisheye's rays beyond the covered
    // angle see the background.
    assert_eq!(summary.missed_pixels, 0, "{case:?}");
    let fisheye = matches!(case.distortion, Some(Distortion::KannalaBrandt(_)));
    assert_eq!(summary.beyond_cover_pixels > 0, fisheye, "{case:?}");

    // Everything below comes from the files.
    let cam = read_camera_yaml(&a.join("camera.yaml")).unwrap().camera;
    let gt = read_tum(&a.join("uav/gt.txt"));
    let images = read_pairs(&a.join("uav/images.txt"));
    assert_eq!(gt.len(), images.len());
    let marker_px = radius_cells * cell * cam.fx / cfg.trajectory.altitude_m;
    let window = 1.6 * marker_px + 4.0;
    let mut checked = 0;
    let mut worst: f64 = 0.0;
    for ((ts, pose), (ts_img, file)) in gt.iter().zip(&images) {
        assert_eq!(ts, ts_img);
        let (w, h, with) = read_grey(&a.join("uav").join(file));
        let (_, _, without) = read_grey(&b.join("uav").join(file));
        let world_to_cam = pose.inverse();
        for m in &markers {
            let Some(uv) = cam.project(&world_to_cam.transform_point(m)) else {
                continue;
            };
            if !cam.contains(&uv, window + 2.0) {
                continue;
            }
            let (cu, cv, weight) = centroid(&with, &without, w, h, uv.x, uv.y, window);
            assert!(
                weight > 1000.0,
                "{ts}: marker at {uv} is not visible ({weight})"
            );
            let err = ((cu - uv.x).powi(2) + (cv - uv.y).powi(2)).sqrt();
            worst = worst.max(err);
            assert!(
                err <= 0.5,
                "{ts}: marker at ({:.2}, {:.2}), centroid ({cu:.2}, {cv:.2})",
                uv.x,
                uv.y
            );
            checked += 1;
        }
    }
    assert!(checked >= 10, "only {checked} marker sightings");

    let map = MapInfo::read(&a.join("map.toml")).unwrap();
    let (mw, mh, with) = read_grey(&a.join(&map.image));
    let (_, _, without) = read_grey(&b.join(&map.image));
    assert_eq!((mw, mh), (map.width_px as usize, map.height_px as usize));
    let map_window = 1.6 * radius_cells * cell / map.gsd_m + 4.0;
    let mut map_worst: f64 = 0.0;
    for m in &markers {
        let (u, v) = map.world_to_pixel(m.x, m.y);
        let (cu, cv, weight) = centroid(&with, &without, mw, mh, u, v, map_window);
        assert!(weight > 100.0, "map marker at ({u}, {v}) not visible");
        let err = ((cu - u).powi(2) + (cv - v).powi(2)).sqrt();
        map_worst = map_worst.max(err);
        assert!(
            err <= 0.5,
            "map marker at ({u:.2}, {v:.2}), centroid ({cu:.2}, {cv:.2})"
        );
    }
    eprintln!(
        "{:?} {} m distortion={:?}: {checked} UAV sightings, worst {worst:.3} px; {} map markers, worst {map_worst:.3} px",
        case.difficulty,
        case.altitude_m,
        case.distortion.map(|d| d.coefficients()),
        markers.len()
    );

    // The altimeter reads the true height above the ground below, plus small noise.
    let alt = read_pairs(&a.join("uav/altimeter.txt"));
    let errors: Vec<f64> = alt
        .iter()
        .zip(&gt)
        .map(|((ts, value), (ts_gt, pose))| {
            assert_eq!(ts, ts_gt);
            let c = pose.centre();
            value.parse::<f64>().unwrap() - (c.z - plain.height_at(c.x, c.y))
        })
        .collect();
    assert!(
        errors
            .iter()
            .all(|e| e.abs() < 5.0 * cfg.altimeter_noise_m())
    );
    assert!(
        errors.iter().any(|e| e.abs() > 1e-3),
        "altimeter must not be exact"
    );

    // The elevation model beside the map is the terrain under the flight, smoothed over its
    // posts and with its stated noise.
    let info = map.elevation.as_ref().expect("simulated maps carry a DEM");
    let dem = ElevationModel::read(info, &a).unwrap();
    let mut worst_dem: f64 = 0.0;
    for (_, pose) in &gt {
        let c = pose.centre();
        let err = dem.height_at(c.x, c.y) - plain.height_at(c.x, c.y);
        worst_dem = worst_dem.max(err.abs());
    }
    assert!(
        worst_dem < 5.0 * info.sigma_m + 0.02,
        "DEM off by {worst_dem:.3} m"
    );
}

#[test]
fn markers_land_where_ground_truth_and_georeference_predict() {
    let cases = [
        Case {
            difficulty: Difficulty::Easy,
            distortion: None,
            seed: 1,
            altitude_m: 10.0,
            map_size_m: None,
        },
        Case {
            difficulty: Difficulty::Medium,
            distortion: Some(
                RadTan {
                    k1: -0.08,
                    k2: 0.015,
                    p1: 1e-3,
                    p2: -6e-4,
                    k3: 0.0,
                }
                .into(),
            ),
            seed: 2,
            altitude_m: 10.0,
            map_size_m: None,
        },
        Case {
            difficulty: Difficulty::Hard,
            distortion: None,
            seed: 3,
            altitude_m: 10.0,
            map_size_m: None,
        },
        // A 133° Kannala-Brandt fisheye (TUM-VI's cam0 coefficients).
        Case {
            difficulty: Difficulty::Easy,
            distortion: Some(Distortion::KannalaBrandt(KannalaBrandt {
                k1: 0.0034823894022493434,
                k2: 0.0007150348452162257,
                k3: -0.0020532361418706202,
                k4: 0.00020293673591811182,
            })),
            seed: 5,
            altitude_m: 10.0,
            map_size_m: None,
        },
        // 200 m over a 25 cm/px map larger than the flight.
        Case {
            difficulty: Difficulty::Hard,
            distortion: None,
            seed: 4,
            altitude_m: 200.0,
            map_size_m: Some(500.0),
        },
    ];
    for case in &cases {
        let tmp = tempfile::tempdir().unwrap();
        run_case(case, tmp.path());
    }
}
