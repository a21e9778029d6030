//! Typed errors returned by the client.

use crate::codec::CodecError;

/// Errors surfaced by [`crate::client::Client`].
#[derive(Debug, thiserror::Error)]
pub enum EmsconError {
    /// The laser beam was interrupted (target lost) before or during a measurement.
    #[error("beam broken (target lost)")]
    BeamBroken,
    /// FindReflector / GoLastMeasuredPoint could not lock onto a target.
    #[error("target not found")]
    TargetNotFound,
    /// The tracker is not initialised (status 39).
    #[error("tracker not initialized")]
    NotInitialized,
    /// The sensor is not warmed up (status 10012).
    #[error("sensor not warmed up")]
    NotWarmedUp,
    /// The server is busy with a pending command (status 1).
    #[error("server busy")]
    Busy,
    /// A wait ran out of time.
    #[error("timeout waiting for {what}")]
    Timeout {
        /// What was awaited.
        what: &'static str,
    },
    /// The server answered with a non-OK status not mapped to a more specific variant.
    #[error("device error: command {command} status {status}")]
    Device {
        /// Command id.
        command: i32,
        /// `ES_ResultStatus`.
        status: i32,
    },
    /// The server refused the connection (status 10011, another client is connected).
    #[error("connection refused by server: another client is connected (status 10011)")]
    ConnectionRefused,
    /// The server violated the protocol (bad packet, wrong echo, NaN values, ...).
    #[error("protocol error: {0}")]
    Protocol(String),
    /// The connection is closed; create a new client to reconnect.
    #[error("disconnected")]
    Disconnected,
    /// I/O error while connecting or writing.
    #[error("i/o error: {0}")]
    Io(std::io::Error),
}

/// The message prints the I/O error, so it is not also the `source()` (printed with its
/// causes, it would appear twice).
impl From<std::io::Error> for EmsconError {
    fn from(cause: std::io::Error) -> Self {
        EmsconError::Io(cause)
    }
}

impl From<CodecError> for EmsconError {
    fn from(e: CodecError) -> Self {
        EmsconError::Protocol(e.to_string())
    }
}

impl EmsconError {
    /// The emScon status code behind this error, if any.
    pub fn status(&self) -> Option<i32> {
        match self {
            EmsconError::NotInitialized => Some(crate::types::status::TRACKER_NOT_INITIALIZED),
            EmsconError::NotWarmedUp => Some(crate::types::status::SENSOR_NOT_WARMED_UP),
            EmsconError::Busy => Some(crate::types::status::SERVER_BUSY),
            EmsconError::ConnectionRefused => {
                Some(crate::types::status::MULTI_CONNECTIONS_NOT_ALLOWED)
            }
            EmsconError::Device { status, .. } => Some(*status),
            _ => None,
        }
    }
    /// True if the connection is gone and a new client is needed.
    pub fn is_connection_lost(&self) -> bool {
        matches!(
            self,
            EmsconError::Disconnected | EmsconError::ConnectionRefused | EmsconError::Io(_)
        )
    }
}
