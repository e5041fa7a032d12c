//! Trajectory evaluation with the same numbers as evo (`evo_ape` / `evo_rpe`): timestamp
//! association, Umeyama SE(3)/Sim(3) alignment, APE and RPE with evo's statistics, and plots.
//!
//! The parity is tested against the pinned evo release in `tests/evo_parity.rs`.

pub mod align;
pub mod error;
pub mod metrics;
pub mod plot;
pub mod report;
pub mod stats;
pub mod sync;

pub use align::{AlignMode, AlignedEstimate, align_estimate};
pub use error::{EvalError, Result};
pub use metrics::{DeltaUnit, PoseRelation, RpeConfig, ape, rpe, rpe_pairs};
pub use plot::plot_report;
pub use report::{AlignmentInfo, EvalConfig, EvalReport, MetricResult, evaluate};
pub use stats::Statistics;
pub use sync::{Associated, AssociationConfig, associate, matching_time_indices};
