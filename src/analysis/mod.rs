//! Analysis: accuracy metrics (METHOD.md §6) and significance indices (METHOD.md §3).

pub mod metrics;
pub mod significance;

pub use metrics::{evaluate, Metrics};
pub use significance::{significance, Significance};
