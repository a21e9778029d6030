//! Analysis: accuracy metrics (docs/method.md §6) and significance indices (docs/method.md §3).

pub mod metrics;
pub mod significance;

pub use metrics::{evaluate, Metrics};
pub use significance::{significance, Significance};
