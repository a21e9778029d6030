//! cellcal: industrial-robot calibration from partial-pose laser-tracker measurements.
//!
//! The library behind the `cellcal` binary: the robot model and identification maths, the
//! campaign engine over device traits, the SQLite store, the daemon and its REST API. Where
//! each part lives, what it may know and the invariants with their tests: `ARCHITECTURE.md`;
//! the method and its conventions: `docs/method.md`.

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
pub mod progress;
pub mod report;
pub mod sim;
pub mod simulate;
pub mod store;
pub mod units;
pub mod wall_clock;
