//! Mars terrain simulator and dataset generator (stands in for the paper's Unreal Engine +
//! AirSim data): terrain synthesis, shading, UAV and satellite rendering, and the dataset
//! writer. The dataset's files (map.toml, elevation model, camera.yaml, the UAV sequence) are
//! written through `jointloc_formats`, whose readers every other crate uses.

pub mod config;
pub mod craters;
pub mod dataset;
pub mod dem;
pub mod error;
pub mod noise;
pub mod regional;
pub mod render;
pub mod rocks;
pub mod satellite;
pub mod scratch;
pub mod sensor;
pub mod shading;
pub mod surface;
pub mod terrain;
pub mod trajectory;
pub mod world_features;

pub use dataset::{
    DatasetPlan, DatasetSummary, SimConfig, Stage, generate_dataset, plan_dataset, write_dataset,
};
pub use dem::DemConfig;
pub use error::{Result, SimError};
// The simulator's own convenience; other crates import these from jointloc_formats.
pub use jointloc_formats::{ElevationInfo, ElevationModel, Grid, MapInfo};
pub use satellite::{Difficulty, SatelliteConfig};
pub use shading::{ShadingConfig, Sun, shade};
pub use terrain::{
    FeatureLayout, Terrain, TerrainConfig, TerrainExtent, TerrainKind, generate_terrain,
    generate_terrain_with,
};
