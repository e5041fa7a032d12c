//! The files jointloc reads and writes, one module per format, each with its reader and its
//! writer and one set of rules, so every crate above reads a dataset the same way:
//!
//! - [`error`]: [`FormatError`], naming the file (and line) and what is wrong.
//! - [`map_import`]: a GeoTIFF orthoimage and DTM into a map folder (`jointloc map import`).
//! - [`map_toml`]: `map.toml`, the georeference of the satellite map and its tiles.
//! - [`elevation`]: the map's elevation model (16-bit PNG + `[elevation]` of `map.toml`).
//! - [`geotiff`]: GeoTIFF orthoimages and DTMs with their georeference and CRS.
//! - [`grid`]: the row-major grid the elevation model (and the simulator) store values in.
//! - [`camera_yaml`]: `camera.yaml`, the UAV camera in ORB-SLAM2's settings layout.
//! - [`sequence`]: the UAV sequence (`uav/images.txt`, `altimeter.txt`, `gt.txt`).
//! - [`dataset`]: `camera.yaml` and the sequence of a dataset folder, read at once.
//! - [`outputs`]: the output files of a run (online TUM with its comment lines, fixes, summary).

pub mod camera_yaml;
pub mod dataset;
pub mod elevation;
pub mod error;
pub mod geotiff;
pub mod grid;
pub mod map_import;
pub mod map_toml;
pub mod outputs;
pub mod sequence;

pub use camera_yaml::{CameraYaml, read_camera_yaml, write_camera_yaml};
pub use dataset::UavDataset;
pub use elevation::{ElevationInfo, ElevationModel};
pub use error::{FormatError, Result};
pub use grid::Grid;
pub use map_toml::{MapCrs, MapInfo, SceneInfo, SunInfo, Tile, TileGrid};
pub use sequence::{InputFault, InputFaultKind, Sequence, SequenceFrame};
