//! Mars terrain simulator and dataset generator (stands in for the paper's Unreal Engine +
//! AirSim data, DESIGN §4): terrain synthesis, shading, UAV and satellite rendering, dataset
//! writer in the layout of DESIGN §3.

pub mod error;
pub mod grid;
pub mod terrain;
pub mod craters;
pub mod noise;
pub mod rocks;
pub mod shading;
pub mod surface;

pub use error::{Result, SimError};
pub use grid::Grid;
pub use shading::{ShadingConfig, Sun, shade};
pub use terrain::{
    Terrain, TerrainConfig, TerrainExtent, TerrainKind, generate_terrain,
};
