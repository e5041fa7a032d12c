//! Geometry core of jointloc (f64 throughout): typed poses, cameras, robust kernels, RANSAC
//! estimators (homography, fundamental/essential, PnP), triangulation, Umeyama alignment and
//! trajectory I/O. Every other stage builds on these types.

pub mod camera;
pub mod error;
pub mod homography;
pub mod pnp;
pub mod pose;
pub mod ransac;
pub mod robust;
pub mod rotation;
pub mod trajectory;
pub mod triangulation;
pub mod two_view;
pub mod umeyama;

pub use camera::{Distortion, KannalaBrandt, PinholeCamera, RadTan};
pub use error::{GeometryError, Result};
pub use pose::{CameraToWorld, Sim3, WorldToCamera};
pub use ransac::{Estimator, RansacConfig, RansacResult, ransac};
pub use robust::RobustKernel;
