//! Universal Robots controller interfaces, without knowledge of cellcal.
//!
//! Module map:
//! - [`dashboard`]: Dashboard server text protocol (TCP 29999): commands, replies, robot and
//!   safety modes.
//! - [`rtde`]: RTDE protocol version 2 wire format (TCP 30004), big-endian packages.
//! - [`vars`]: the RTDE field names and types a controller knows.
//! - [`script`]: URScript `movej`/`stopj` programs: formatting, and the subset parser the
//!   simulator runs.
//! - [`client`]: async [`DashboardClient`], [`RtdeClient`], [`ScriptClient`].
//! - [`sim`]: [`SimController`], the simulated controller (modes, program, [`sim::Motion`]).
//! - [`server`]: [`UrServers`], the simulator's Dashboard, RTDE and URScript servers.
//!
//! Units: joint positions rad, speeds rad/s, accelerations rad/s² (as URScript and RTDE).

#![warn(missing_docs)]

pub mod client;
pub mod dashboard;
pub mod rtde;
pub mod script;
pub mod server;
pub mod sim;
pub mod vars;

pub use client::{
    DashboardClient, RobotState, RtdeClient, ScriptClient, UrError, DASHBOARD_PORT, REALTIME_PORT,
    RTDE_PORT, SECONDARY_PORT,
};
pub use dashboard::{RobotMode, RuntimeState, SafetyMode};
pub use server::{ServerConfig, UrServers};
pub use sim::{ControllerConfig, Motion, MotionFault, SimController, TrapezoidMotion};
