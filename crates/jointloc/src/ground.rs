//! The map's elevation model as the SLAM's [`GroundModel`]: once geo-referenced, the local BA
//! puts the window's map points onto it, which fixes the tilt of the local map (see
//! `docs/jointloc.md` §"Ground factors").

use jointloc_absloc::Ground;
use jointloc_slam::ba::GroundPlane;
use jointloc_slam::local_mapping::GroundModel;

/// An elevation model (the map has one: flat ground at the datum is an assumption, not a
/// measurement, and gets no factors).
#[derive(Debug, Clone)]
pub struct ElevationGround(pub Ground);

impl GroundModel for ElevationGround {
    fn plane_at(&self, x: f64, y: f64) -> Option<GroundPlane> {
        let (height, slope) = self.0.height_and_slope(x, y)?;
        Some(GroundPlane {
            anchor: [x, y],
            height,
            slope,
        })
    }

    fn sigma_m(&self) -> f64 {
        self.0.stated_sigma_m().unwrap_or(0.0)
    }
}
