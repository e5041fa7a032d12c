//! On a small simulated dataset (generated here): the map's georeference agrees with the
//! simulator's ground truth, and absolute localisation with real matchers lands within
//! centimetres of the true positions.

mod common;

use common::{sim_dataset, sim_dataset_medium};
use jointloc_absloc::registry::{RegistryOptions, resolve};
use jointloc_absloc::{AbsLocConfig, AbsLocalizer, Fix, MapTiles, Prior};
use jointloc_formats::{MapInfo, UavDataset};

#[test]
fn georeference_agrees_with_the_ground_truth() {
    let dir = sim_dataset();
    let tiles = MapTiles::open(dir).unwrap();
    let info = MapInfo::read(&dir.join("map.toml")).unwrap();
    // Tiles cut from satellite.png are the tile files the simulator wrote.
    for (i, t) in tiles.tiles().iter().enumerate() {
        let file = dir
            .join("satellite")
            .join(format!("{}_{}_{}.png", t.index, t.x, t.y));
        assert_eq!(
            image::open(&file).unwrap().into_luma8(),
            tiles.tile_image(i),
            "{}",
            file.display()
        );
    }
    let ds = UavDataset::open(dir).unwrap();
    assert!(ds.has_altimeter && ds.has_ground_truth);
    for f in &ds.frames {
        let pose = f.ground_truth.unwrap();
        let c = pose.centre();
        let (u, v) = tiles.world_to_pixel(c.x, c.y);
        assert_eq!((u, v), info.world_to_pixel(c.x, c.y));
        let (x, y) = tiles.pixel_to_world(u, v);
        assert!((x - c.x).abs() < 1e-9 && (y - c.y).abs() < 1e-9);
        // The tile nearest to the camera contains its nadir point.
        let t = tiles.tiles()[tiles.nearest(c.x, c.y, 1)[0]];
        assert!(
            u >= t.x as f64
                && u <= (t.x + 500) as f64
                && v >= t.y as f64
                && v <= (t.y + 500) as f64
        );
    }
}

/// The matching pipeline `matcher` (weights from the model store unless it is ORB).
fn pipeline(matcher: &str) -> jointloc_absloc::FeaturePipeline {
    let opts = RegistryOptions {
        models_dir: (matcher != "orb").then(|| {
            jointloc_features::models::ready_store()
                .expect("model store (jointloc models fetch)")
                .dir()
                .to_path_buf()
        }),
        ..Default::default()
    };
    resolve(matcher, &opts).unwrap()
}

/// Localises frame `f` with `prior`; panics, naming `what` and the frame, without a fix.
fn localise(
    loc: &mut AbsLocalizer,
    f: &jointloc_formats::SequenceFrame,
    prior: &Prior,
    what: &str,
) -> Fix {
    let img = image::open(&f.path).unwrap().into_luma8();
    let out = loc.localize(&img, f.altitude.unwrap(), prior).unwrap();
    out.fix()
        .unwrap_or_else(|| panic!("{what}: {}: {out:?}", f.path.display()))
        .clone()
}

/// The true position and heading of frame `f`: an oracle standing in for the fused pose.
fn true_prior(f: &jointloc_formats::SequenceFrame) -> Prior {
    let truth = f.ground_truth.unwrap();
    let c = truth.centre();
    Prior {
        position: Some([c.x, c.y]),
        heading: Some(jointloc_absloc::heading_from_rotation(
            &truth.rotation().to_rotation_matrix(),
        )),
    }
}

/// Localises every frame of the easy dataset with `matcher`; returns the 2-D errors.
fn run(matcher: &str) -> Vec<f64> {
    run_on(sim_dataset(), matcher, 1.0)
}

/// Localises every frame of `dir` with `matcher`, checking the map upsampling chosen; returns
/// the 2-D errors.
fn run_on(dir: &std::path::Path, matcher: &str, upsample: f64) -> Vec<f64> {
    let pipeline = pipeline(matcher);
    let ds = UavDataset::open(dir).unwrap();
    let tiles = MapTiles::open(dir).unwrap();
    assert!(tiles.has_elevation());
    let cache_dir = tempfile::tempdir().unwrap();
    let config = AbsLocConfig {
        cache_dir: Some(cache_dir.path().to_path_buf()),
        ..Default::default()
    };
    let mut loc = AbsLocalizer::new(tiles, ds.camera, pipeline, config).unwrap();
    let errors = ds
        .frames
        .iter()
        .map(|f| {
            let fix = localise(&mut loc, f, &Prior::default(), matcher);
            let c = f.ground_truth.unwrap().centre();
            // z = the map's elevation model under the fix + the altimeter: within the
            // altimeter's and the DEM's noise of the truth, on any terrain height.
            assert!(
                (fix.position[2] - c.z).abs() < 0.5,
                "{matcher}: z {} vs true {}",
                fix.position[2],
                c.z
            );
            ((fix.position[0] - c.x).powi(2) + (fix.position[1] - c.y).powi(2)).sqrt()
        })
        .collect();
    assert_eq!(loc.upsample_factor(), Some(upsample), "{matcher}");
    errors
}

fn check(matcher: &str, errors: &[f64]) {
    let rmse = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
    let max = errors.iter().copied().fold(0.0, f64::max);
    assert!(
        rmse < 0.3 && max < 0.6,
        "{matcher}: rmse {rmse} m, max {max} m: {errors:?}"
    );
}

#[test]
fn orb_localises_every_frame() {
    check("orb", &run("orb"));
}

#[test]
fn xfeat_mnn_localises_every_frame() {
    check("xfeat-mnn", &run("xfeat-mnn"));
}

/// A map 6 times coarser than the frames: the localiser upsamples it 2.5 times and still finds
/// every frame.
#[test]
fn xfeat_lighterglue_localises_every_frame_on_a_coarse_map() {
    check(
        "xfeat-lighterglue (medium)",
        &run_on(sim_dataset_medium(), "xfeat-lighterglue", 2.5),
    );
}

/// Whole-map searches with the rotation sweep on rendered frames and real weights: with a
/// shortlist of 8 (rotation, tile) pairs ranked by VLAD, each frame is found where the
/// exhaustive search finds it, from fewer pairs.
#[test]
fn a_shortlisted_whole_map_search_finds_the_exhaustive_fixes() {
    let dir = sim_dataset();
    let ds = UavDataset::open(dir).unwrap();
    let cache_dir = tempfile::tempdir().unwrap();
    let mut searched = Vec::new();
    let mut positions = Vec::new();
    for candidates in [0, 8] {
        let mut config = AbsLocConfig {
            cache_dir: Some(cache_dir.path().to_path_buf()),
            area_prediction: false,
            use_last_heading: false,
            ..Default::default()
        };
        config.shortlist.candidates = candidates;
        // The shortlist also where the coarse places find nothing.
        config.shortlist.after_coarse_places = candidates;
        let tiles = MapTiles::open(dir).unwrap();
        let pairs = tiles.len() * config.rotation_hypotheses;
        assert!(pairs > 8, "{pairs} pairs: the shortlist would not cut");
        let pipeline = pipeline("xfeat-lighterglue");
        let mut loc = AbsLocalizer::new(tiles, ds.camera, pipeline, config).unwrap();
        let mut n = 0;
        let mut at = Vec::new();
        for f in ds.frames.iter().step_by(4) {
            let fix = localise(
                &mut loc,
                f,
                &Prior::default(),
                &format!("shortlist {candidates}"),
            );
            assert!(fix.global);
            let c = f.ground_truth.unwrap().centre();
            let err = ((fix.position[0] - c.x).powi(2) + (fix.position[1] - c.y).powi(2)).sqrt();
            assert!(err < 0.3, "{candidates}: {}: {err} m", f.path.display());
            if candidates > 0 {
                assert!(
                    fix.searched_tiles <= candidates + 3,
                    "{}",
                    fix.searched_tiles
                );
            }
            n += fix.searched_tiles;
            at.push([fix.position[0], fix.position[1]]);
        }
        searched.push(n);
        positions.push(at);
    }
    assert!(searched[1] < searched[0], "pairs matched: {searched:?}");
    for (a, b) in positions[0].iter().zip(&positions[1]) {
        let d = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt();
        assert!(d < 0.1, "exhaustive {a:?} vs shortlist {b:?}");
    }
}

/// In flight the fused pose predicts the frame's place: with the true position and heading as
/// the prior (an oracle standing in for it), the predicted window fixes every frame of the
/// coarse map from one matcher call, as accurately as the tiles around the prediction.
#[test]
fn the_predicted_window_fixes_every_frame_from_one_call_on_a_coarse_map() {
    let dir = sim_dataset_medium();
    let ds = UavDataset::open(dir).unwrap();
    let cache_dir = tempfile::tempdir().unwrap();
    let mut rmse = Vec::new();
    let mut searched = Vec::new();
    for margin in [0.0, 1.5] {
        let config = AbsLocConfig {
            cache_dir: Some(cache_dir.path().to_path_buf()),
            predicted_window_margin_m: margin,
            ..Default::default()
        };
        let tiles = MapTiles::open(dir).unwrap();
        let pipeline = pipeline("xfeat-lighterglue");
        let mut loc = AbsLocalizer::new(tiles, ds.camera, pipeline, config).unwrap();
        let (mut sse, mut n, mut calls) = (0.0, 0usize, 0usize);
        for f in &ds.frames {
            let c = f.ground_truth.unwrap().centre();
            let fix = localise(&mut loc, f, &true_prior(f), &format!("margin {margin}"));
            if margin > 0.0 {
                assert_eq!(fix.searched_tiles, 1, "{}", f.path.display());
                assert!(!fix.global);
            }
            sse += (fix.position[0] - c.x).powi(2) + (fix.position[1] - c.y).powi(2);
            n += 1;
            calls += fix.searched_tiles;
        }
        rmse.push((sse / n as f64).sqrt());
        searched.push(calls);
    }
    let (tiles, window) = (rmse[0], rmse[1]);
    assert!(window < 0.3, "window rmse {window} m");
    assert!(
        window <= 1.25 * tiles + 0.01,
        "window {window} m against tiles {tiles} m"
    );
    assert!(searched[1] < searched[0], "matcher calls {searched:?}");
}

/// At 200 m over a HiRISE-class map (25 cm/px) the frame resampled to the map holds fewer
/// keypoints per pixel than the map's tiles, and the predicted window is capped to
/// `window_keypoints_over_view` of the view's count, the strongest: the fixes stay where the
/// whole window puts them. The camera does not wobble here, so the ground point under the
/// image centre is under the camera.
#[test]
fn at_200_m_the_capped_window_fixes_every_frame_as_the_whole_window_does() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("ds");
    let mut cfg = jointloc_sim::dataset::SimConfig {
        seed: 20261207,
        difficulty: jointloc_sim::Difficulty::Mars,
        map_size_m: Some(420.0),
        ..Default::default()
    };
    cfg.trajectory.altitude_m = 200.0;
    cfg.trajectory.length_m = 12.0;
    cfg.trajectory.rate_hz = 0.5;
    cfg.trajectory.attitude_jitter_deg = 0.0;
    jointloc_sim::dataset::generate_dataset(&cfg, &dir, &mut |_, _, _| {}).unwrap();
    let ds = UavDataset::open(&dir).unwrap();
    assert!(ds.frames.len() >= 5, "{} frames", ds.frames.len());
    let cache_dir = tempfile::tempdir().unwrap();
    let fixes: Vec<Vec<Fix>> = [0.0, 1.0]
        .into_iter()
        .map(|ratio| {
            let config = AbsLocConfig {
                cache_dir: Some(cache_dir.path().to_path_buf()),
                window_keypoints_over_view: ratio,
                ..Default::default()
            };
            let tiles = MapTiles::open(&dir).unwrap();
            let pipeline = pipeline("xfeat-lighterglue");
            let mut loc = AbsLocalizer::new(tiles, ds.camera, pipeline, config).unwrap();
            ds.frames
                .iter()
                .map(|f| {
                    let c = f.ground_truth.unwrap().centre();
                    let fix = localise(&mut loc, f, &true_prior(f), &format!("ratio {ratio}"));
                    assert_eq!(fix.searched_tiles, 1, "ratio {ratio}: one matcher call");
                    let err = (fix.position[0] - c.x).hypot(fix.position[1] - c.y);
                    assert!(err < 0.5, "ratio {ratio}: {}: {err} m", f.path.display());
                    fix
                })
                .collect()
        })
        .collect();
    for (all, capped) in fixes[0].iter().zip(&fixes[1]) {
        let d = (all.position[0] - capped.position[0]).hypot(all.position[1] - capped.position[1]);
        assert!(d < 0.3, "capped and whole window {d} m apart");
        // Fewer map keypoints to match: the cap took some away.
        assert!(
            capped.inliers < all.inliers,
            "{} vs {}",
            capped.inliers,
            all.inliers
        );
    }
}
