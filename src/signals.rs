//! The signals that stop a campaign front end (`run`, `serve`) and their exit codes.
//!
//! SIGINT (Ctrl-C), SIGTERM and SIGHUP all mean "stop the robot now, leave the campaign
//! resumable". The exit code of an aborted `run` tells which one came: 128 + the signal number,
//! as a shell reports a process killed by it (130, 143, 129).

use tokio::signal::unix::{signal, SignalKind};

/// A signal that asks a front end to stop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopSignal {
    /// SIGINT: Ctrl-C at the terminal.
    Interrupt,
    /// SIGTERM: `kill`, systemd stop.
    Terminate,
    /// SIGHUP: the terminal went away (ssh dropped, window closed).
    Hangup,
}

impl StopSignal {
    /// 128 + the signal number.
    pub fn exit_code(self) -> u8 {
        match self {
            StopSignal::Interrupt => 130,
            StopSignal::Terminate => 143,
            StopSignal::Hangup => 129,
        }
    }

    /// The signal's name, for messages.
    pub fn name(self) -> &'static str {
        match self {
            StopSignal::Interrupt => "SIGINT",
            StopSignal::Terminate => "SIGTERM",
            StopSignal::Hangup => "SIGHUP",
        }
    }
}

/// Handlers for SIGINT, SIGTERM and SIGHUP, installed at once (so a signal that arrives before
/// anyone awaits [`StopSignals::next`] is not lost and does not kill the process).
pub struct StopSignals {
    int: tokio::signal::unix::Signal,
    term: tokio::signal::unix::Signal,
    hup: tokio::signal::unix::Signal,
}

impl StopSignals {
    /// Install the handlers (inside a runtime).
    pub fn install() -> std::io::Result<StopSignals> {
        Ok(StopSignals {
            int: signal(SignalKind::interrupt())?,
            term: signal(SignalKind::terminate())?,
            hup: signal(SignalKind::hangup())?,
        })
    }

    /// The next stop signal. Cancel-safe: a signal that arrives while the future is dropped
    /// is delivered to the next call.
    pub async fn next(&mut self) -> StopSignal {
        tokio::select! {
            _ = self.int.recv() => StopSignal::Interrupt,
            _ = self.term.recv() => StopSignal::Terminate,
            _ = self.hup.recv() => StopSignal::Hangup,
        }
    }
}
