//! cellcal: industrial-robot calibration from partial-pose laser-tracker measurements.
//!
//! The library behind the `cellcal` binary: the robot model and identification maths, the
//! campaign engine over device traits, the SQLite store, the daemon and its REST API. Where
//! each part lives, what it may know and the invariants with their tests: `ARCHITECTURE.md`;
//! the method and its conventions: `docs/method.md`.

/// `impl From<$cause> for $error` giving `$error::$variant(cause)`, for a variant whose
/// message prints its cause: `#[from]` would also make the cause its `source()`, and printed
/// with its causes (anyhow's `{:#}`) the cause would appear twice. Every error of the crate
/// prints its cause and gives no `source()`
/// (`tests/it/messages.rs::every_error_message_prints_its_cause_and_none_is_also_a_source`).
macro_rules! from_cause {
    ($cause:ty => $error:ident :: $variant:ident) => {
        impl From<$cause> for $error {
            fn from(cause: $cause) -> Self {
                $error::$variant(cause)
            }
        }
    };
}

pub mod analysis;
pub mod api;
pub mod auth;
pub mod build_info;
pub mod calibrate;
pub mod campaign;
pub mod cell;
pub mod compensate;
pub mod config;
pub mod daemon;
pub mod dataset;
pub mod identify;
pub mod iso9283;
pub mod lsq;
pub mod measure;
pub mod metrics;
pub mod model;
pub mod plan;
pub mod predict;
pub mod progress;
pub mod report;
pub mod sim;
pub mod simulate;
pub mod store;
pub mod units;
pub mod wall_clock;
