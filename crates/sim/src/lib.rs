//! Mars terrain simulator and dataset generator (stands in for the paper's Unreal Engine +
//! AirSim data, DESIGN §4): terrain synthesis, shading, UAV and satellite rendering, dataset
//! writer in the layout of DESIGN §3.

pub mod error;
pub mod grid;
pub mod terrain;

pub use error::{Result, SimError};
pub use grid::Grid;
pub use terrain::{Terrain, TerrainKind};
