//! Planning: pose sampling in the workspace box (METHOD.md §7).

pub mod sampling;

pub use sampling::{sample_poses, PlanError, Workspace};
