//! Planning: pose sampling in the workspace box (METHOD.md §7) and campaign plans.

pub mod campaign;
pub mod sampling;

pub use campaign::{plan_campaign, target_ok, Plan, PlanEntry, PlanRequest};
pub use sampling::{sample_poses, PlanError, Workspace};
