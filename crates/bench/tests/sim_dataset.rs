//! The ground truth of the matcher benchmark on a small simulated dataset (generated here): the
//! altimeter-plane homography of each true pose, and the terrain regenerated from `sim.toml`.

#[path = "../../absloc/tests/common/mod.rs"]
mod common;

use common::sim_dataset;
use jointloc_absloc::MapTiles;
use jointloc_bench::ground_truth::plane_homography;
use jointloc_formats::UavDataset;

#[test]
fn plane_homography_maps_the_principal_point_under_the_camera() {
    let dir = sim_dataset();
    let tiles = MapTiles::open(dir).unwrap();
    let ds = UavDataset::open(dir).unwrap();
    assert!(ds.has_altimeter && ds.has_ground_truth);
    for f in &ds.frames {
        let pose = f.ground_truth.unwrap();
        let c = pose.centre();
        // A nadir camera (attitude jitter ≤ ~1°) sees the ground under itself at the principal
        // point: the ground-plane homography of the true pose maps it within a few centimetres.
        let h =
            plane_homography(&pose, &ds.camera, tiles.gsd_m(), c.z - f.altitude.unwrap()).unwrap();
        let q = h * nalgebra::Point2::new(ds.camera.cx, ds.camera.cy).to_homogeneous();
        let (gx, gy) = tiles.pixel_to_world(q.x / q.z, q.y / q.z);
        let off = ((gx - c.x).powi(2) + (gy - c.y).powi(2)).sqrt();
        assert!(
            off < 0.25,
            "{}: principal ray meets the ground {off} m away",
            f.path.display()
        );
    }
}

/// The benchmark's exact ground truth: the terrain is regenerated from `sim.toml` (the map
/// carries an elevation model, which planning does not write).
#[test]
fn terrain_is_regenerated_for_the_ground_truth() {
    let dir = sim_dataset();
    let ds = UavDataset::open(dir).unwrap();
    assert!(jointloc_bench::sim_terrain::regenerate(dir, &ds).is_some());
}
