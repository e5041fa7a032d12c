//! The paper's evaluation protocols that need ground truth. They live apart from the
//! localisation crates because they need the simulator and true poses, which a flight has not.
//!
//! - [`ground_truth`]: the true homography from a UAV frame to the map (from the terrain where
//!   it is known, else the altimeter plane);
//! - [`sim_terrain`]: a simulated dataset's heightfield, regenerated from its `sim.toml`;
//! - [`match_bench`]: the matcher benchmark (§IV-D, Table V): corner error, accuracy at
//!   1 to 100 px, time per pair.

pub mod ground_truth;
pub mod match_bench;
pub mod sim_terrain;
