//! Mars terrain simulator and dataset generator (stands in for the paper's Unreal Engine +
//! AirSim data, DESIGN §4): terrain synthesis, shading, UAV and satellite rendering, dataset
//! writer in the layout of DESIGN §3.

pub mod camera_yaml;
pub mod craters;
pub mod dataset;
pub mod elevation;
pub mod error;
pub mod grid;
pub mod map_toml;
pub mod noise;
pub mod render;
pub mod rocks;
pub mod satellite;
pub mod sensor;
pub mod shading;
pub mod surface;
pub mod terrain;
pub mod trajectory;

pub use dataset::{
    DatasetPlan, DatasetSummary, SimConfig, Stage, generate_dataset, plan_dataset, write_dataset,
};
pub use elevation::{DemConfig, ElevationInfo, ElevationModel};
pub use error::{Result, SimError};
pub use grid::Grid;
pub use map_toml::MapInfo;
pub use satellite::{Difficulty, SatelliteConfig};
pub use shading::{ShadingConfig, Sun, shade};
pub use terrain::{Terrain, TerrainConfig, TerrainExtent, TerrainKind, generate_terrain};
