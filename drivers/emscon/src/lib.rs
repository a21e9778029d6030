//! Leica emScon TPI binary protocol (TPI/SDK 3.6 wire format, AT960 family) over TCP.
//!
//! Module map:
//! - [`types`]: protocol constants (data types, command ids, status and status-change codes)
//!   and plain data structs (units, settings, system status, measurement status bits).
//! - [`codec`]: typed packets ([`codec::Command`], [`codec::ServerPacket`]), exact-size
//!   encode/decode and the incremental [`codec::FrameDecoder`].
//! - [`error`]: [`EmsconError`], the typed client error.
//! - [`client`]: async [`Client`] (reader task, one outstanding command, unsolicited events).
//! - [`backend`]: [`TrackerBackend`], the physics seam of the simulator, plus [`SimpleBackend`].
//! - [`fault`]: [`FaultConfig`], fault injection for the simulator.
//! - [`server`]: [`server::serve`], the simulator-side emScon server.
//!
//! Wire format: little-endian, `#pragma pack(4)`, C `long` = i32, every packet starts with
//! `{ i32 size (header included), i32 type }`.

#![warn(missing_docs)]

pub mod backend;
pub mod client;
pub mod codec;
pub mod error;
pub mod fault;
pub mod server;
pub mod types;

pub use backend::{
    BackendMeasurement, BackendPoint, Meteo, SimpleBackend, SimpleState, TrackerBackend,
};
pub use client::{Client, ClientConfig, Event, Measurement, StationarySetup};
pub use codec::{Command, FrameDecoder, ServerPacket};
pub use error::EmsconError;
pub use fault::{FaultConfig, ForcedStatus, Malformed, SharedFaults};
pub use server::{serve, serve_with_options, ServerOptions};
pub use types::{MeasurementStatusInfo, SystemSettings, SystemStatus, Units};
