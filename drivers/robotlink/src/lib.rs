//! robotlink: driver for the cellcal robot line protocol (see `PROTOCOL.md`).
//!
//! * [`auth`]: the shared secret, nonces and HMAC-SHA256 proofs of a v3 session.
//! * [`codec`]: pure parse/format of request, reply and event lines.
//! * [`client`]: async [`RobotClient`] over TCP (or any async stream).
//! * [`server`]: protocol server over a [`RobotBackend`], with fault injection for tests.
//! * [`sim`]: [`SimpleBackend`], a joint-space-only simulated arm.
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod auth;
pub mod client;
pub mod codec;
pub mod server;
pub mod sim;

pub use auth::{Nonce, Proof, SecretError, SharedSecret};
pub use client::{ClientConfig, RobotClient, RobotError, StopHandle};
pub use codec::{ErrorCode, Event, EventName, Identity, Pose, RobotState};
pub use server::{
    serve, serve_connection, BackendError, FaultConfig, FaultHandle, RobotBackend, ServerAccess,
};
pub use sim::{SimpleBackend, SimpleConfig};

/// TCP port of the controller application's robotlink server unless a site sets another on
/// the pendant (`deploy/staubli/README.md`, PROTOCOL.md §1); `[robot_controller] address`
/// names it.
pub const DEFAULT_PORT: u16 = 11100;
