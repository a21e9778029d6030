//! cellcal: industrial-robot calibration from partial-pose laser-tracker measurements.
//!
//! Module map (see ARCHITECTURE.md):
//! - [`model`]: robot model files, MDH chain, forward and inverse kinematics, parameter screws
//!   (Jacobians).
//! - [`campaign`]: the campaign engine (commands in, events out; measure, store, identify).
//! - [`cell`]: device traits (Tracker, Robot, Stage, Prompter) and their adapters.
//! - [`identify`]: observation models, identifiability, Levenberg–Marquardt, robust refit.
//! - [`analysis`]: accuracy metrics and significance indices.
//! - [`measure`]: measurement geometry (rigid registration, sphere fit, tool-frame setup,
//!   base registration).
//! - [`plan`]: pose sampling in the workspace box.
//! - [`simulate`]: seeded data simulator (true robot, tracker noise, stage, outliers).
//! - [`sim`]: the simulated cell (world + emScon, robotlink, Zaber servers) behind the adapters.
//! - [`dataset`]: the identify CSV format and its conversion to observations.
//! - [`report`]: the identify JSON contract, the printed summary, the corrected model file and the HTML report.
//! - [`build_info`]: the version, git commit and build date of this binary.
//! - [`compensate`]: joints that put the identified (real) robot where a target or a nominal
//!   program says, and the compensate CSV files.
//! - [`iso9283`]: ISO 9283 pose accuracy and repeatability (AP, RP) from measured cycles.
//! - [`auth`]: REST API roles, actions and token digests (constant-time checks).
//! - [`metrics`]: the daemon's Prometheus metrics (`GET /metrics`).
//! - [`wall_clock`]: wall-clock time as stored (ms since the Unix epoch).
//! - [`store`]: the SQLite campaign store (campaigns, plans, raw points, done poses, events,
//!   results); the only module that knows SQL.
//!
//! Everything here is pure (no printing, no clock, no global RNG) except reading a robot file,
//! [`store`] (file I/O by design) and the device code: [`cell`] adapters and the [`sim`] cell (clock, sockets, ptys; no printing).

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
pub mod report;
pub mod sim;
pub mod simulate;
pub mod store;
pub mod wall_clock;
