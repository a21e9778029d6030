//! zaber: drivers for a Zaber ASCII linear stage and a generic RS-232 gauge, with simulators.
//!
//! * [`ascii`]: Zaber ASCII codec (commands, replies, info/alert lines, LRC checksum).
//! * [`stage::ZaberStage`]: async stage client (`home`, `move_abs_mm`, `position_mm`, ...).
//! * [`gauge::GaugeClient`]: async request/response gauge client (`read_mm`).
//! * [`sim`]: stage and gauge simulators over any async stream, with fault injection.
//! * [`product`]: which device facts give mm per microstep (known products).
//! * [`pty`]: run a simulator on a pseudo-terminal so the real serial code path is exercised.
//! * [`serial`]: serial port settings and opening via tokio-serial.
#![warn(missing_docs)]

pub mod ascii;
pub mod gauge;
mod lineio;
pub mod product;
pub mod pty;
pub mod serial;
pub mod sim;
pub mod stage;

pub use gauge::{GaugeClient, GaugeConfig, GaugeError};
pub use serial::SerialSettings;
pub use stage::{StageConfig, StageError, StageIdentity, ZaberStage};
