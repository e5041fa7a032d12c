//! Two-view geometry: the fundamental matrix (uncalibrated), the essential matrix (calibrated,
//! five-point), relative pose by cheirality, and the Sampson machinery they share.
//!
//! Conventions: `x2ᵀ F x1 = 0` on homogeneous pixels, `x2ᵀ E x1 = 0` on normalised rays,
//! `E = [t]× R` where `X₂ = R X₁ + t` maps camera-1 coordinates into camera 2. All residuals and
//! thresholds are Sampson distances in pixels.
//!
//! Planar scenes (distant terrain seen from altitude) are degenerate for `F` and leave `E` with
//! a twofold ambiguity; [`recover_pose`] rejects the mirror solution when it puts many points
//! behind the cameras, but a SLAM initialiser should also fit a homography and choose the
//! model by score, as ORB-SLAM does.

mod essential;
mod five_point;
mod fundamental;
mod null_space;
mod relative_pose;
mod sampson;

pub use essential::{EssentialConfig, EssentialEstimator, EssentialResult, estimate_essential};
pub use five_point::essential_five_point;
pub use fundamental::{
    FundamentalConfig, FundamentalEstimator, FundamentalResult, eight_point, estimate_fundamental,
    sampson_distance_squared,
};
pub use relative_pose::{
    RecoverPoseConfig, RelativePose, RelativePoseConfig, TwoViewPose, decompose_essential,
    estimate_relative_pose, recover_pose,
};
